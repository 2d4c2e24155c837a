"""The HTML report is self-contained and its tables and images really render in a browser."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import imageio.v3 as iio
import numpy as np
import pytest

from fake_study import fake_study
from latent_sindy.study.report import Report
from latent_sindy.worlds.push.study.study_report import study_page

CHECK = """
<script>
window.addEventListener('load', () => {
  const imgs = [...document.images];
  const ok = imgs.filter(i => i.complete && i.naturalWidth > 0).length;
  const cells = document.querySelectorAll('td').length;
  document.title = `RENDER images ${ok}/${imgs.length} cells ${cells}`;
});
</script>
"""


def _chromium() -> str:
    """Path of a headless-capable Chromium, installed from Debian where missing and possible."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        pytest.skip("Chromium is missing and cannot be installed here (needs root and apt-get): "
                    "install Debian's 'chromium' package to run this test")
    try:
        subprocess.run("apt-get update -qq && apt-get install -y -qq chromium", shell=True,
                       check=True, capture_output=True, timeout=900)
    except (subprocess.SubprocessError, OSError) as e:
        pytest.skip(f"Chromium is missing and 'apt-get install chromium' failed ({e})")
    path = shutil.which("chromium")
    if path is None:
        pytest.skip("Chromium is missing and apt-get did not provide it")
    return path


@pytest.fixture(scope="module")
def chromium() -> str:
    return _chromium()


def _render_title(browser: str, page, tmp_path) -> str:
    """Load `page` in headless Chromium and return the document title after load."""
    r = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
         "--virtual-time-budget=10000", "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120)
    m = re.search(r"<title>(.*?)</title>", r.stdout)
    assert m, r.stderr[-2000:]
    return m.group(1)


def _report(tmp_path) -> Report:
    png = tmp_path / "a.png"
    iio.imwrite(png, np.tile(np.arange(64, dtype=np.uint8), (32, 1)))
    gif = tmp_path / "b.gif"
    frames = np.stack([np.full((16, 16, 3), v, np.uint8) for v in (0, 120, 240)])
    iio.imwrite(gif, frames, duration=200, loop=0)
    r = Report("test <report>")
    r.heading("Table").table(["model", "loss"], [["sindy", 0.1], ["linear <&>", 0.2]])
    r.image(png, "a plot").gallery([(gif, "episode 1"), (gif, "episode 2")])
    r.preformatted("z0[t+1] = z0 + 0.5 u0")
    return r


def test_report_is_self_contained(tmp_path):
    out = _report(tmp_path).write(tmp_path / "out" / "report.html")
    text = out.read_text()
    assert text.count("data:image/png;base64,") == 1 and text.count("data:image/gif;base64,") == 2
    assert "linear &lt;&amp;&gt;" in text and "test &lt;report&gt;" in text
    assert not re.search(r'(src|href)="(?!data:)', text)  # nothing fetched from anywhere
    assert [p.name for p in out.parent.iterdir()] == ["report.html"]  # no temporary left


def test_unsupported_image_is_refused(tmp_path):
    bad = tmp_path / "x.bmp"
    bad.write_bytes(b"BM")
    with pytest.raises(ValueError, match="bmp"):
        Report("r").image(bad)


def test_report_renders_in_headless_chromium(tmp_path, chromium):
    out = _report(tmp_path).write(tmp_path / "report.html")
    page = tmp_path / "checked.html"
    page.write_text(out.read_text().replace("</body>", CHECK + "</body>"))
    assert _render_title(chromium, page, tmp_path) == "RENDER images 3/3 cells 4"
    # the check itself fails on a broken image
    broken = tmp_path / "broken.html"
    broken.write_text(page.read_text().replace("base64,", "base64,AAAA", 1))
    assert _render_title(chromium, broken, tmp_path) == "RENDER images 2/3 cells 4"


def test_study_report_opens_with_the_overview(tmp_path):
    study, files, summary = fake_study(tmp_path, models=("sindy2", "mlp", "state_sindy"))
    text = study_page(study, files, summary).write(tmp_path / "report.html").read_text()
    body = text.split("<body>", 1)[1]
    order = ['<figure class="overview">', '<table class="overview">',
             "How these numbers reproduce", "<h2>The study</h2>", "Table I",
             "Closed-loop control"]
    at = [body.find(s) for s in order]
    assert -1 not in at and at == sorted(at), dict(zip(order, at, strict=True))
    assert body.count("<table") == body.count('<div class="scroll"><table') == 3
    assert (tmp_path / "figures" / "overview.png").exists()
