"""The study report's first screen answers "which model, how well", and fits the screen.

The overview's rows (pooled success intervals, best first, the prediction error they show),
its figure written atomically, and the page measured in headless Chromium at 1280 × 800:
no sideways scrolling, and the figure and the short table inside the first 800 px.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import imageio.v3 as iio
import pytest
from matplotlib.figure import Figure

from fake_study import fake_study
from latent_sindy.stats import wilson_interval
from latent_sindy.study.evaluation import aggregate
from latent_sindy.worlds.push.study import figures
from latent_sindy.worlds.push.study.overview import overview, overview_table
from latent_sindy.worlds.push.study.study_report import study_page

WIDTH, HEIGHT = 1280, 800

#: Appended to the page: writes what the browser laid out into <pre id="layout"> as JSON.
MEASURE = """
<script>
window.addEventListener('load', () => {
  const box = e => { const r = e.getBoundingClientRect();
                     return {top: r.top, bottom: r.bottom, left: r.left, right: r.right}; };
  const img = document.querySelector('figure.overview img');
  const table = document.querySelector('table.overview');
  const wide = document.querySelector('table.wide').parentElement;
  const out = document.createElement('pre');
  out.id = 'layout';
  out.textContent = JSON.stringify({
    scrollWidth: document.documentElement.scrollWidth, innerWidth: window.innerWidth,
    figure: box(img), loaded: img.complete && img.naturalWidth > 0,
    table: box(table), rows: table.tBodies[0].rows.length,
    tableI: {scrollWidth: wide.scrollWidth, clientWidth: wide.clientWidth}});
  document.body.appendChild(out);
});
</script>
"""


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    pytest.skip("no Chromium found (chromium, chromium-browser or google-chrome on PATH): "
                "the report's layout is measured in a browser")


def _layout(page: Path, tmp_path: Path) -> dict:
    """Load ``page`` in headless Chromium at 1280 × 800 and return what MEASURE wrote."""
    r = subprocess.run(
        [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}",
         f"--window-size={WIDTH},{HEIGHT}", "--virtual-time-budget=5000", "--dump-dom",
         page.as_uri()], capture_output=True, text=True, timeout=60)
    m = re.search(r'<pre id="layout">(.*?)</pre>', r.stdout, re.S)
    assert m, r.stderr[-2000:]
    return json.loads(m.group(1))


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("study")
    study, files, summary = fake_study(out)
    return study_page(study, files, summary).write(out / "report.html")


def test_overview_pools_seeds_and_ranks_best_first(tmp_path):
    study, _, _ = fake_study(tmp_path, seeds=(0, 1))
    seed0, seed1 = study.per_seed[0]["sindy2"], study.per_seed[1]["sindy2"]
    seed0.update({"control/random/latent/episodes": 20,
                  "control/random/latent/success_rate": 0.55,
                  "control/random/latent/strict_success_rate": 0.5})
    seed1.update({"control/random/latent/episodes": 20,
                  "control/random/latent/success_rate": 0.85,
                  "control/random/latent/strict_success_rate": 0.7})
    view = overview(study)
    row = next(r for r in view.rows if r.name == "sindy2")
    assert (row.strict.k, row.strict.n, row.coarse.k, row.coarse.n) == (24, 40, 28, 40)
    assert row.strict.interval == wilson_interval(24, 40)
    assert row.strict.text() == "60% (45–74%)"
    strict = [r.strict.rate for r in view.rows]
    assert strict == sorted(strict, reverse=True) and len(view.rows) == len(study.models)
    assert view.error_key == "pos_err/h10"

    header, rows = overview_table(view, seeds=2)
    table = dict(zip([r[1] for r in rows], rows, strict=True))
    mlp, sindy2 = table["MLP"], table["SINDy-2"]
    assert mlp[2:6] == ["MLP", "image", "21136 ± 0", "dense"]  # a dense net: its parameters
    assert table["linear, state"][2:4] == ["linear", "state"]
    assert table["linear, state"][5] == "dense"  # every coefficient of a linear model is active
    active = study.stats["sindy2"]["sindy/active"].mean
    total = study.stats["sindy2"]["sindy/coefficients"].mean
    assert sindy2[5] == f"{100 * (1 - active / total):.1f}%"
    assert header[6] == "error, 10 pushes (cm)"

    # a model without the position measure: every row falls back to the test loss
    for s in (0, 1):
        del study.per_seed[s]["mlp"]["pos_err/h10"], study.per_seed[s]["mlp"]["pos_err/h5"]
        del study.per_seed[s]["mlp"]["pos_err/h1"]
    study.stats["mlp"] = aggregate([study.per_seed[s]["mlp"] for s in (0, 1)])
    assert overview(study).error_key == "loss/test"


def test_a_diverged_or_failed_model_keeps_the_position_error(tmp_path):
    study, _, _ = fake_study(tmp_path, models=("sindy2", "linear", "mlp"))
    study.per_seed[0]["linear"]["pos_err/h10"] = math.inf  # its rollout diverged
    study.stats["linear"] = aggregate([study.per_seed[0]["linear"]])
    del study.per_seed[0]["mlp"], study.stats["mlp"]  # it failed to train
    view = overview(study)
    assert view.error_key == "pos_err/h10"
    rows = {r[1]: r for r in overview_table(view, seeds=1)[1]}
    assert rows["linear (E2C)"][6] == "diverged"
    assert rows["MLP"][0] == "3" and rows["MLP"][4:] == ["n/a", "n/a", "n/a", "—", "—"]


def test_overview_figure_replaces_its_file_only_when_drawn(tmp_path, monkeypatch):
    study, _, _ = fake_study(tmp_path, models=("sindy2", "linear", "mlp", "state_sindy"))
    path = tmp_path / "figures" / "overview.png"
    figures.overview_figure(overview(study), path)
    height, width = iio.imread(path).shape[:2]
    assert width == 1150 and 220 <= height <= 280  # 11.5 × 2.2-2.8 in at 100 dpi
    before = path.read_bytes()

    def fail(self, fname, **kw):
        Path(fname).write_bytes(b"half a PNG")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", fail)
    with pytest.raises(OSError, match="disk full"):
        figures.overview_figure(overview(study), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == ["overview.png"]  # no temporary


def test_first_screen_fits_1280_wide(report, tmp_path):
    study, _, _ = fake_study(tmp_path / "same")  # the report's study: the rows it shows
    page = tmp_path / "measured.html"
    page.write_text(report.read_text().replace("</body>", MEASURE + "</body>"))
    got = _layout(page, tmp_path)
    assert got["innerWidth"] == WIDTH
    assert got["scrollWidth"] <= WIDTH, got  # the page never scrolls sideways
    fig, table = got["figure"], got["table"]
    assert got["loaded"] and got["rows"] == len(overview_table(overview(study), seeds=1)[1])
    assert 0 <= fig["top"] < fig["bottom"] <= table["top"] < table["bottom"] <= HEIGHT, got
    assert 0 <= fig["left"] and fig["right"] <= WIDTH and table["right"] <= WIDTH, got
    # Table I is wider than the page: it scrolls inside its own box
    assert got["tableI"]["scrollWidth"] > got["tableI"]["clientWidth"], got

    # the measure sees the overflow when tables may push the page wider
    loose = tmp_path / "loose.html"
    loose.write_text(page.read_text().replace("</style>",
                                              ".scroll { overflow-x: visible; }</style>", 1))
    assert _layout(loose, tmp_path)["scrollWidth"] > WIDTH
