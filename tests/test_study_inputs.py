"""What a study accepts before it runs: a given file of its world, sweeps that apply only
where they mean something and are checked whole up front, seed lists by their size, a reused
folder's collection settings named where they differ, and a help that lists every sweepable
setting. Every refusal comes before a file is written."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from latent_sindy.cli import main
from latent_sindy.configs import to_json
from latent_sindy.data import write_sequences
from latent_sindy.errors import UserError
from latent_sindy.study.settings import StudySettings, parse_seeds
from latent_sindy.worlds.push.collect import CollectionPlan
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.data import push_data
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.config import PushStudyConfig, study_specs
from latent_sindy.worlds.push.study.scales import SCALES
from latent_sindy.worlds.push.study.stages import check_given_data
from latent_sindy.worlds.push.study.sweeps import SWEEPABLE, Sweep
from push_study import run_push
from synthetic import make_trajectories


def _error_line(capsys, *args: str) -> str:
    """Run ``latent-sindy ARGS`` in this process; the one error line it printed."""
    code = main(list(args))
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), lines
    return lines[0].removeprefix("latent-sindy: error: ")


# ----------------------------------------------------------------------------- D2: --data's world
def test_a_given_file_of_another_world_is_refused(tmp_path):
    """A symmetric-world file given to a study of the paper's world is refused (naming both
    worlds) before anything is written, as a file of another image size is."""
    path = tmp_path / "symmetric.h5"
    data = make_trajectories()
    write_sequences(path, data)
    out = tmp_path / "study"
    cfg = PushStudyConfig(scale="tiny", out=out, world="paper", data=path, workers=1,
                          verbose=False, models=("state_linear",))
    with pytest.raises(UserError, match=r"--world paper.*symmetric"):
        check_given_data(cfg, data)
    with pytest.raises(UserError, match=r"--world paper.*symmetric"):
        run_push(out, scale="tiny", world="paper", data=path, workers=1,
                 models=("state_linear",))
    assert not out.exists()
    check_given_data(PushStudyConfig(scale="tiny", out=out, data=path), data)  # its own world


def test_a_textured_world_file_is_told_from_the_symmetric_world() -> None:
    """The textured world pushes like the symmetric one; its table, light and distractor still
    make it another world for a study (and the symmetric file is not the textured study's)."""
    rng = np.random.default_rng(0)
    plain = make_trajectories()
    textured = push_data(plain.images, plain.actions, rng.uniform(-0.3, 0.7, (6, 5, 3)),
                         plain.split, PushEnvConfig.named("textured"), seed=0)
    with pytest.raises(UserError, match=r"--world symmetric.*the textured world.*--world "
                                        r"textured"):
        check_given_data(PushStudyConfig(scale="tiny", data=Path("t.h5")), textured)
    with pytest.raises(UserError, match=r"--world textured.*the symmetric world"):
        check_given_data(PushStudyConfig(scale="tiny", world="textured", data=Path("s.h5")),
                         plain)
    check_given_data(PushStudyConfig(scale="tiny", world="textured", data=Path("t.h5")),
                     textured)


# ----------------------------------------------------------------------------- D3, D12: where
def _names(**settings) -> list[str]:
    return [s.name for s in study_specs(PushStudyConfig(scale="tiny", **settings))]


def test_a_sweep_varies_only_the_models_that_have_the_setting(tmp_path):
    """λ3 weighs SINDy's coefficients: a linear model has none, so sweeping it would train
    identical models under different names; refused when no chosen model has it, and
    otherwise only the SINDy models get variants."""
    l1 = (Sweep.parse("lambda_l1=1e-3,1e-2"),)
    with pytest.raises(UserError, match=r"--sweep lambda_l1.*none of the chosen models.*linear"):
        PushStudyConfig(scale="tiny", out=tmp_path, models=("linear",), sweep=l1)
    names = _names(out=tmp_path, sweep=l1)
    for plain in ("linear", "mlp", "state_linear", "state_mlp"):
        assert plain in names and not any(n.startswith(f"{plain}.") for n in names)
    assert {"sindy2.lambda_l1=0.001", "sindy2.lambda_l1=0.01",
            "state_sindy.lambda_l1=0.001"} <= set(names)


def test_an_order_sweep_skips_the_libraries_of_fixed_order(tmp_path):
    """The face and frame libraries are order 1 by construction: --sweep order over the
    default models varies the others, and a choice of only those is refused by name."""
    names = _names(out=tmp_path, sweep=(Sweep.parse("order=1,2"),))
    assert {"sindy1.order=2", "sindy2_push.order=1", "sindy_moments", "state_sindy",
            "linear"} <= set(names)
    assert not any(n.startswith(("sindy_moments.", "state_sindy.", "sindy_pose.")) for n in names)
    with pytest.raises(UserError, match=r"--sweep order.*none of the chosen models.*"
                                        r"sindy_moments, state_sindy"):
        PushStudyConfig(scale="tiny", out=tmp_path, models=("sindy_moments", "state_sindy"),
                        sweep=(Sweep.parse("order=2"),))


# ----------------------------------------------------------------------------- D11, D12: values
BAD_SWEEPS = ["prune_below=-1", "prune_below=nan", "init_share=-0.5", "window=100",
              "lambda_l1=nan", "lambda_pred_x=inf", "lambda_pred_z=-1", "order=0", "window=0"]


@pytest.mark.parametrize("sweep", BAD_SWEEPS)
def test_every_sweep_value_is_checked_up_front_and_named_as_the_sweeps(tmp_path, sweep):
    with pytest.raises(UserError, match="^" + re.escape(f"--sweep {sweep}: ")):
        PushStudyConfig(scale="tiny", out=tmp_path, sweep=(Sweep.parse(sweep),))


@pytest.mark.parametrize("sweep", ["prune_below=-1", "window=100"])
def test_a_bad_sweep_value_collects_nothing(tmp_path, capsys, sweep):
    out = tmp_path / "study"
    line = _error_line(capsys, "reproduce", "--scale", "tiny", "--out", str(out), "--workers",
                       "1", "--models", "sindy2", "--sweep", sweep)
    assert line.startswith(f"--sweep {sweep}: ")
    assert not out.exists()


def test_a_swept_window_must_fit_a_given_files_trajectories(tmp_path):
    """With --data the trajectories' length is the file's: a longer window is refused by
    the sweep's name before anything runs."""
    path = tmp_path / "d.h5"
    data = make_trajectories(steps=4)
    write_sequences(path, data)
    cfg = PushStudyConfig(scale="tiny", out=tmp_path / "s", data=path, models=("sindy2",),
                          sweep=(Sweep.parse("window=4,5"),))
    with pytest.raises(UserError, match=r"^--sweep window=4,5: .*4 pushes"):
        check_given_data(cfg, data)


# ----------------------------------------------------------------------------- D9: seeds
def test_a_huge_seed_range_is_refused_from_its_size():
    t0 = time.perf_counter()
    with pytest.raises(UserError, match=r"--seeds 0\.\.1000000000000"):
        parse_seeds(["0..1000000000000"])
    with pytest.raises(UserError, match="--seeds"):
        parse_seeds(["0..600", "601..1200"])  # each small, together too many
    with pytest.raises(UserError, match="99999999999999999999 seeds"):
        parse_seeds(["1..99999999999999999999"])  # more than a C size
    assert time.perf_counter() - t0 < 1.0
    assert len(parse_seeds(["0..99"])) == 100


# ----------------------------------------------------------------------------- D15: reuse
def _study_file(out, plan: CollectionPlan) -> None:
    """OUT/data.h5 as a study of ``plan`` leaves it (synthetic images, the plan recorded)."""
    rng = np.random.default_rng(0)
    n, steps, env = plan.trajectories, plan.steps, plan.env
    images = rng.integers(100, 240, (n, steps + 1, 1, env.image_size, env.image_size),
                          dtype=np.uint8)
    actions = rng.uniform(env.action_low, env.action_high, (n, steps, 3)).astype(np.float32)
    poses = rng.uniform(-0.3, 0.7, (n, steps + 1, 3)).astype(np.float32)
    out.mkdir(parents=True)
    write_sequences(out / "data.h5", push_data(
        images, actions, poses, plan.split_ids(), env, seed=plan.seed,
        collection={"plan": to_json(plan), "attempts": [1] * n}))


@pytest.mark.parametrize(("other", "named"), [
    ({"world": "paper"}, "--world paper"), ({"image_size": 16}, "--image-size 16"),
    ({"data_seed": 7}, "--data-seed 7"), ({"scale": "demo"}, "--scale demo")])
def test_a_reused_folder_names_the_collection_setting_that_differs(tmp_path, other, named):
    tiny = SCALES["tiny"]
    out = tmp_path / "study"
    _study_file(out, CollectionPlan(tiny.trajectories, tiny.steps, 0,
                                    env=PushEnvConfig.named("symmetric")))
    lines: list[str] = []
    with pytest.raises(UserError, match="already exists with other collection settings") as e:
        run_push(out, lines.append, **{"scale": "tiny", "workers": 1,
                                       "models": ("state_linear",), **other})
    assert named in str(e.value), str(e.value)
    assert not any("reusing" in line for line in lines)


# ----------------------------------------------------------------------------- D18, D22
def test_a_ray_address_needs_the_ray_executor(tmp_path, capsys):
    with pytest.raises(UserError, match=r"--ray-address localhost:6379 is for --executor ray"):
        StudySettings(out=tmp_path, ray_address="localhost:6379")
    out = tmp_path / "study"
    line = _error_line(capsys, "reproduce", "--scale", "tiny", "--out", str(out),
                       "--ray-address", "auto")
    assert "--executor ray" in line and not out.exists()


def test_reproduce_help_lists_every_sweepable_setting(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")  # no line breaks inside a name
    with pytest.raises(SystemExit):
        main(["reproduce", "--help"])
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    start = text.index("--sweep SETTING=V1,V2")
    sweep_help = text[start:]
    for name, setting in SWEEPABLE.items():
        assert re.search(rf"\b{name}\b", sweep_help), name
        assert setting.label in sweep_help, (name, setting.label)


def test_the_catalogue_without_sweeps_is_as_it_was(tmp_path):
    assert study_specs(PushStudyConfig(scale="tiny", out=tmp_path)) == model_specs(SCALES["tiny"])


def test_every_named_world_is_described_for_the_report_and_help() -> None:
    """The study's report and --help describe each pushing world; a world without its phrase
    crashed the textured world's report."""
    from latent_sindy.study.runner import world_help
    from latent_sindy.worlds.push.config import ENV_PRESETS, WORLD_ABOUT
    from latent_sindy.worlds.push.study.scales import SCALE_ABOUT

    assert set(WORLD_ABOUT) == set(ENV_PRESETS) and set(SCALE_ABOUT) == set(SCALES)
    text = world_help()
    assert all(f"{name} ({about})" in text for name, about in WORLD_ABOUT.items())


def test_the_push_study_trains_on_the_cpu_and_runs_a_named_world(tmp_path):
    """Its reproduce hook refuses --device cuda (it trains on the CPU; on Ray, --gpus) and a
    world rebuilt on settings that make no named world, before anything is written."""
    from latent_sindy.plugins import get_world
    from latent_sindy.worlds.push.plugin import PushWorld

    out = tmp_path / "study"
    with pytest.raises(UserError, match="--device cuda: the push study trains on the CPU"):
        get_world("push").reproduce("tiny", out, None, "cuda", 1, print)
    odd = PushWorld(PushEnvConfig(block_look="marked"))  # a marked block, symmetric pushes
    with pytest.raises(UserError, match="runs a named world as it is"):
        odd.reproduce("tiny", out, None, "cpu", 1, print)
    assert not out.exists()


@pytest.mark.parametrize(("world", "old"), [("push", "round-one"), ("dmc", "read-benchmark")])
def test_an_old_scale_name_is_refused_as_an_unknown_one(tmp_path, capsys, world, old):
    """Scales were renamed for what they run (demo-long, read-100k): no alias keeps the old
    name, which meets the error of any unknown one."""
    old_line, unknown = (_error_line(capsys, "reproduce", "--world", world, "--scale", name,
                                     "--out", str(tmp_path / "s")) for name in (old, "nonsense"))
    assert old_line == unknown.replace("nonsense", old) and not (tmp_path / "s").exists()


def test_an_old_schedule_name_is_refused_as_an_unknown_one():
    from latent_sindy.worlds.pendulum.video_study import VideoStudyConfig

    said = []
    for name in ("lite100", "nonsense"):
        with pytest.raises(UserError) as e:
            VideoStudyConfig(schedule=name)
        said.append(str(e.value))
    assert said[0] == said[1].replace("nonsense", "lite100") and "uncalibrated" in said[0]
