"""State-space reference models: the same trainer and MPPI on the block's true pose."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.cli import main
from latent_sindy.data.windows import pose_features
from latent_sindy.training import RunDir, read_metrics
from latent_sindy.worlds.push.collect import CollectionPlan, collect

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_sindy_on_a_fixed_encoder_starts_at_the_least_squares_fit(data: Path,
                                                                   tmp_path: Path) -> None:
    """--sindy-init auto fits the coefficients to the encoded training transitions before
    the first epoch where the encoder learns nothing (the state's): the first epoch's
    prediction loss is already far below a random start's, and the fit is reproducible."""
    losses = {}
    for init in ("random", "auto", "regression"):
        out = tmp_path / init
        assert main(["train", "--data", str(data), "--out", str(out), "--epochs", "2",
                     "--batch-size", "4", "--sindy-init", init, "--no-progress", "sindy",
                     "--order", "1", "state"]) == 0
        losses[init] = read_metrics(out)[0]["train/pred_z"]
    assert losses["auto"] == losses["regression"] < 0.2 * losses["random"], losses
    # a thresholded regression starts, and so ends, with fewer terms (pruning only removes)
    out = tmp_path / "sparse"
    assert main(["train", "--data", str(data), "--out", str(out), "--epochs", "2",
                 "--batch-size", "4", "--sindy-init-share", "0.3", "--no-progress", "sindy",
                 "--order", "1", "state"]) == 0
    active = {name: RunDir(tmp_path / name).load().model.dynamics.n_active()
              for name in ("regression", "sparse")}
    assert 0 < active["sparse"] < active["regression"], active


def test_regression_init_refuses_an_encoder_that_learns(data: Path, tmp_path: Path,
                                                        capsys) -> None:
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--epochs", "1",
                 "--sindy-init", "regression", "--no-progress", "sindy", "image",
                 "--decoder", "conv"]) != 0
    assert "--sindy-init regression fits the dynamics to fixed latents" in (
        capsys.readouterr().err)


def test_pose_features_equal_exactly_for_poses_the_camera_cannot_tell_apart() -> None:
    period = math.pi / 2
    poses = np.array([[0.5, 0.1, 0.3], [0.5, 0.1, 0.3 + period], [0.5, 0.1, 0.3 - 3 * period],
                      [0.5, 0.1, 0.3 + period / 2]])
    f = pose_features(poses, period)
    torch.testing.assert_close(f[1], f[0], atol=1e-6, rtol=0)
    torch.testing.assert_close(f[2], f[0], atol=1e-6, rtol=0)
    assert (f[3] - f[0]).abs().max() > 1  # a quarter period on: opposite features
    assert f.shape == (4, 4) and torch.allclose(f[:, 2] ** 2 + f[:, 3] ** 2, torch.ones(4))


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return collect(tmp_path_factory.mktemp("d") / "d.h5",
                   CollectionPlan(trajectories=4, steps=3, val_fraction=0.25, test_fraction=0),
                   workers=1)


@pytest.mark.parametrize("kind", ["sindy", "linear", "mlp"])
def test_a_state_model_trains_on_poses_and_pushes(data: Path, tmp_path: Path, kind: str) -> None:
    out = tmp_path / kind
    assert main(["train", kind, "state", "--data", str(data), "--out", str(out), "--epochs", "30",
                 "--batch-size", "4", "--lr", "1e-2", "--sindy-init", "random",
                 "--no-progress"]) == 0
    rows = read_metrics(out)
    assert all(r["train/recon"] == 0 for r in rows)  # the state is observed exactly
    assert rows[-1]["train/pred_z"] < rows[0]["train/pred_z"]
    run = RunDir(out).load()
    assert run.model.config.observation.latent_dim == 4 and run.normalizer.std == 1.0
    assert main(["control", str(out), "--task", "random", "--max-steps", "2", "--samples", "16",
                 "--horizon", "2", "--gif-episodes", "0", "--no-progress"]) == 0
    assert (out / "control-random-latent" / "results.json").exists()


def test_a_saved_face_library_run_keeps_the_angle_features_on_the_circle(tmp_path: Path) -> None:
    """The projection follows from the run's config: after training, saving and loading, the
    state SINDy's rollouts (torch and MPPI's fused kernel alike) keep (z2, z3) on the unit
    circle over 50 random pushes, and its equations say so."""
    from latent_sindy.control import SindyKernelStep, latent_step
    from latent_sindy.data import write_sequences
    from latent_sindy.equations import equations_report
    from synthetic import make_trajectories

    data, out = tmp_path / "d.h5", tmp_path / "run"
    write_sequences(data, make_trajectories(n=6, steps=3))
    assert main(["train", "sindy", "--order", "1", "--library", "face", "--no-include-sine",
                 "--init-scale", "0.05", "state", "--data", str(data), "--out", str(out),
                 "--epochs", "3", "--batch-size", "4", "--sindy-init", "random",
                 "--no-progress"]) == 0
    model = RunDir(out).load().model
    assert model.dynamics.circle == (2, 3)
    gen = torch.Generator().manual_seed(0)
    angle = 2 * math.pi * torch.rand(64, generator=gen)
    z0 = torch.stack([torch.full((64,), 0.5), torch.zeros(64), angle.cos(), angle.sin()], -1)
    actions = torch.rand(64, 50, 3, generator=gen) * 2 - 1
    with torch.no_grad():
        zs = model.rollout_latent(z0, actions)
        assert (model.dynamics._step(z0, actions[:, 0])[:, 2:].norm(dim=-1) - 1).abs().max() > 1e-3
    norms = zs[:, 1:, 2:].norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-5)
    step = latent_step(model.dynamics)
    assert isinstance(step, SindyKernelStep) and step.circle == (2, 3)
    torch.testing.assert_close(step.rollout(z0, actions), zs, rtol=1e-4, atol=1e-4)
    assert "(z2, z3) is scaled onto the unit circle" in equations_report(out, export=False)


@pytest.fixture(scope="module")
def symmetric_pushes(tmp_path_factory) -> tuple:
    """Transitions of 48 random trajectories (5 pushes each) in the default world, as
    (Z, U, Znext) of encoded poses: three quarters for fitting, a quarter held out."""
    from latent_sindy.data import read_sequences

    path = collect(tmp_path_factory.mktemp("sym") / "d.h5",
                   CollectionPlan(trajectories=48, steps=5, seed=3, val_fraction=0.25,
                                  test_fraction=0), workers=2)
    d = read_sequences(path)

    def transitions(split: str):
        s = d.split(split)
        f = pose_features(s.poses, s.world_config.angle_period).double()  # (N, T+1, 4)
        u = torch.as_tensor(s.actions).double().reshape(-1, 3)
        return f[:, :-1].reshape(-1, 4), u, f[:, 1:].reshape(-1, 4)

    return transitions("train"), transitions("val")


def test_sindy_on_simulated_poses_prints_the_push_kinematics(symmetric_pushes) -> None:
    """Sparse regression on the simulator's poses finds Δx ∝ ℓ cos ψ and Δy ∝ ℓ sin ψ, and
    predicts one push's position about as well as an MLP fitted to the same transitions."""
    from latent_sindy.models import MlpDynamics, SindyConfig
    from latent_sindy.sindy import STLSQ

    (Z, U, Zn), (Zv, Uv, Znv) = symmetric_pushes
    sindy = SindyConfig(order=1, library="push", include_sine=False).build(4, 3).double()
    sindy.fit_state_data(Z, U, Zn, optimizer=STLSQ(min_share=0.1))
    rows = sindy.coefficient_rows()

    def gain(state: str, term: str, x: float = 0.525) -> float:
        """d state / d term at the workspace's centre x (terms may carry a factor z0 = x)."""
        c = {r[1]: r[2] for r in rows if r[0] == state}
        return c.get(term, 0.0) + x * c.get(f"z0 {term}", 0.0)

    assert sindy.sparsity() > 0.6
    eqs = sindy.equations()
    assert 0.05 < gain("z0", "u2 cos(u1)") < 0.15, eqs[0]  # x: a push of ℓ = 1 moves ~0.1 m
    assert 0.05 < gain("z1", "u2 sin(u1)") < 0.15, eqs[1]  # y: likewise along sin ψ
    assert abs(gain("z0", "u2 sin(u1)")) < 0.2 * gain("z0", "u2 cos(u1)"), eqs[0]
    assert abs(gain("z1", "u2 cos(u1)")) < 0.2 * gain("z1", "u2 sin(u1)"), eqs[1]
    torch.manual_seed(0)
    mlp = MlpDynamics(4, 3).double()
    opt = torch.optim.Adam(mlp.parameters(), lr=3e-3)
    for _ in range(1500):  # full batch: the mean squared one-step error
        opt.zero_grad()
        (mlp.step(Z, U) - Zn).square().mean().backward()
        opt.step()
    with torch.no_grad():
        err_sindy = (sindy.step(Zv, Uv) - Znv)[:, :2].norm(dim=1).mean()
        err_mlp = (mlp.step(Zv, Uv) - Znv)[:, :2].norm(dim=1).mean()
        err_still = (Zv - Znv)[:, :2].norm(dim=1).mean()
    assert err_sindy < 0.5 * err_still
    assert err_sindy <= 1.2 * err_mlp, (float(err_sindy), float(err_mlp))


def test_the_state_cost_is_one_at_the_strict_tolerances() -> None:
    """MPPI's cost of a state error: 2 cm of position, or 10° of orientation modulo the
    block's symmetry, cost 1 (metres would cost 4e-4, which λ = 0.01 cannot tell apart)."""
    from latent_sindy.control.costs import LatentCost
    from latent_sindy.models.state import StateConfig

    for period in (math.pi / 2, 2 * math.pi):
        goal = pose_features(np.array([0.5, 0.1, 0.3]), period)
        cost = LatentCost(goal, StateConfig().build().cost_weights(period))
        for pose in ([0.52, 0.1, 0.3], [0.5, 0.08, 0.3], [0.5, 0.1, 0.3 + math.radians(10)],
                     [0.5, 0.1, 0.3 - math.radians(10) + period]):
            assert float(cost(pose_features(np.array(pose), period)[None])) == pytest.approx(
                1.0, rel=1e-4)
        far = pose_features(np.array([0.6, 0.1, 0.3]), period)[None]
        assert float(cost(far)) == pytest.approx(25.0, rel=1e-4)


def test_angle_harmonics_let_the_mlp_learn_what_turns_four_times_per_revolution(
        capsys: pytest.CaptureFixture[str]) -> None:
    """z' = z + 0.1 sin(4 u1): the same MLP and budget fit it with the harmonics, not without;
    models without harmonics keep their old parameters (no new state-dict entries)."""
    from latent_sindy.models.dynamics import MlpDynamics

    gen = torch.Generator().manual_seed(0)
    u = (torch.rand(512, 3, generator=gen) * 2 - 1) * torch.tensor([1.0, math.pi, 1.0])
    z = torch.randn(512, 2, generator=gen)
    target = z + 0.1 * torch.sin(4 * u[:, 1:2])
    errors = {}
    for harmonics in (0, 4):
        torch.manual_seed(0)
        model = MlpDynamics(2, 3, hidden=32, layers=2, harmonics=harmonics)
        opt = torch.optim.Adam(model.parameters(), 1e-2)
        for _ in range(300):
            loss = ((model.step(z, u) - target) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        errors[harmonics] = loss.item()
    assert errors[4] < 1e-4 < errors[0], errors
    assert set(MlpDynamics(2, 3).state_dict()) == set(
        MlpDynamics(2, 3, harmonics=4).state_dict())
    assert main(["train", "mlp", "--harmonics", "-1", "state", "--data", "x.h5", "--out",
                 "y"]) != 0
    assert "--harmonics -1: use 0 to 64" in capsys.readouterr().err


def _angle_error_deg(pred: torch.Tensor, true: torch.Tensor, period: float) -> torch.Tensor:
    """Orientation error (degrees, modulo the symmetry) between encoded poses (N, 4)."""
    a = torch.atan2(pred[:, 3], pred[:, 2]) - torch.atan2(true[:, 3], true[:, 2])
    return torch.rad2deg(torch.atan2(torch.sin(a), torch.cos(a)).abs()) * period / (2 * math.pi)


def test_the_face_library_predicts_the_turn_that_the_push_library_cannot(
        symmetric_pushes) -> None:
    """A push turns the block by an amount set by where and at which angle the face is hit:
    the face library (push angle relative to the face, sin 4ψ · cos 4θ ...) predicts the
    orientation after one push far better than the push library (which does no better than
    "nothing turns"), and keeps the push kinematics in x and y readable."""
    from latent_sindy.models import SindyConfig
    from latent_sindy.sindy import STLSQ

    (Z, U, Zn), (Zv, Uv, Znv) = symmetric_pushes
    period = math.pi / 2
    errors = {}
    for library in ("push", "face"):
        model = SindyConfig(order=1, library=library, include_sine=False).build(4, 3).double()
        model.fit_state_data(Z, U, Zn, optimizer=STLSQ(min_share=0.1))
        with torch.no_grad():
            errors[library] = float(_angle_error_deg(model.step(Zv, Uv), Znv, period).mean())
        if library == "face":
            c = {(r[0], r[1]): r[2] for r in model.coefficient_rows()}
            assert 0.05 < c[("z0", "u2 cos(u1)")] < 0.15 and 0.05 < c[("z1", "u2 sin(u1)")] < 0.15
    still = float(_angle_error_deg(Zv, Znv, period).mean())
    assert errors["push"] > 0.8 * still, (errors, still)
    assert errors["face"] < 0.6 * errors["push"], (errors, still)


def test_the_frame_library_predicts_the_push_closer_than_the_face_library(
        symmetric_pushes) -> None:
    """Written in the pushed face's frame (the angle a from the face normal, the normal's
    direction n), a few terms predict where one push takes the block: closer than the face
    library's harmonics of 4(ψ − θ)."""
    from latent_sindy.models import SindyConfig
    from latent_sindy.sindy import STLSQ

    (Z, U, Zn), (Zv, Uv, Znv) = symmetric_pushes
    errors = {}
    for library in ("face", "frame"):
        model = SindyConfig(order=1, library=library, include_sine=False).build(
            4, 3, circle=(2, 3)).double()
        model.fit_state_data(Z, U, Zn, optimizer=STLSQ(min_share=0.1))
        with torch.no_grad():
            errors[library] = float((model.step(Zv, Uv)[:, :2] - Znv[:, :2]).norm(dim=1).mean())
    still = float((Zv[:, :2] - Znv[:, :2]).norm(dim=1).mean())
    assert errors["frame"] < 0.8 * errors["face"] < 0.8 * still, (errors, still)


def test_a_model_that_turns_its_orientation_predicts_the_turn_closer(symmetric_pushes) -> None:
    """A push turns the block by up to about 45°, 180° of the square's orientation features
    (cos 4θ, sin 4θ): updating the features term by term, then projecting, cannot follow
    such turns; turning them by an angle that one equation gives (``turn``) can."""
    from latent_sindy.models import SindyConfig
    from latent_sindy.sindy import STLSQ

    (Z, U, Zn), (Zv, Uv, Znv) = symmetric_pushes
    period = math.pi / 2
    errors, lines = {}, {}
    for turn in (False, True):
        model = SindyConfig(order=1, library="frame", include_sine=False).build(
            4, 3, circle=(2, 3), turn=turn).double()
        model.fit_state_data(Z, U, Zn, optimizer=STLSQ(min_share=0.05))
        with torch.no_grad():
            errors[turn] = float(_angle_error_deg(model.step(Zv, Uv), Znv, period).mean())
        lines[turn] = model.equations()
    still = float(_angle_error_deg(Zv, Znv, period).mean())
    assert errors[True] < 0.8 * errors[False] < 0.8 * still, (errors, still)
    assert len(lines[True]) == 3 and lines[True][2].startswith("ω = turn of (z2, z3) = ")


def test_the_study_writes_world_direction_pushes_with_the_face_library_only() -> None:
    """The face library's relative angle is ψ − θ for a push in a world direction ψ; where
    the push angle is measured from the block (the paper's and the marked world) the state
    and pose-latent rows keep the push library."""
    from latent_sindy.worlds.push.study.catalogue import model_specs
    from latent_sindy.worlds.push.study.scales import SCALES

    for push, library in (("symmetric", "face"), ("paper", "push")):
        specs = {s.name: s for s in model_specs(SCALES["tiny"], push=push)}
        for name in ("state_sindy", "sindy_pose"):
            assert specs[name].model.dynamics.library == library, (push, name)
            assert library in specs[name].label


def test_a_turning_frame_run_reloads_turning(data: Path, tmp_path: Path) -> None:
    """--turn and the frame library survive saving and loading: the reloaded model, its
    sparse form and MPPI's kernel turn the pair, z3's column stays free of terms, and the
    coefficient files say that z2's coefficients are the turn."""
    from latent_sindy.control import SindyKernelStep, latent_step

    out = tmp_path / "run"
    assert main(["train", "--data", str(data), "--out", str(out), "--epochs", "2",
                 "--batch-size", "4", "--no-progress", "--turn", "sindy", "--order", "1",
                 "--library", "frame", "--no-include-sine", "state"]) == 0
    dyn = RunDir(out).load().model.dynamics
    assert dyn.turn and not dyn.mask[:, 3].any() and dyn.mask[:, 2].any()
    assert dyn.compile_sparse().turn
    step = latent_step(dyn)
    assert isinstance(step, SindyKernelStep) and step._turn
    assert dyn.export_info()["turn"] is True and dyn.export_info()["circle"] == [2, 3]
    # a state dict of a model that did not turn cannot switch z3's column back on
    plain = type(dyn)(**{**dyn.hparams(), "turn": False})
    dyn.load_state_dict(plain.state_dict())
    assert not dyn.mask[:, 3].any() and 0 <= dyn.sparsity() <= 1


def test_sindy_init_settings_that_would_be_ignored_are_refused(data: Path, tmp_path: Path,
                                                               capsys) -> None:
    from latent_sindy.errors import UserError
    from latent_sindy.training import TrainConfig

    common = ["train", "--data", str(data), "--epochs", "1", "--no-progress"]
    assert main([*common, "--out", str(tmp_path / "a"), "--sindy-init", "regression",
                 "linear", "state"]) != 0
    assert "dynamics are linear" in capsys.readouterr().err
    assert main([*common, "--out", str(tmp_path / "b"), "--sindy-init", "random",
                 "--sindy-init-share", "0.1", "sindy", "state"]) != 0
    assert "--sindy-init-share 0.1 is for a SINDy model" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    with pytest.raises(UserError, match="--sindy-init 'regresion'"):
        TrainConfig(sindy_init="regresion")  # type: ignore[arg-type]


def test_the_frame_library_needs_a_block_whose_symmetry_counts_its_faces(
        data: Path, tmp_path: Path, capsys) -> None:
    from latent_sindy.errors import UserError
    from latent_sindy.models import SindyConfig

    with pytest.raises(UserError, match="nearest face normal"):
        SindyConfig(order=1, library="frame", library_options=("frequency=1",))
    # the data's square looks alike every 90°: a face library at another frequency is refused
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--epochs", "1",
                 "--no-progress", "sindy", "--order", "1", "--library", "face",
                 "--library-options", "frequency=2", "state"]) != 0
    assert "use --library-options frequency=4" in capsys.readouterr().err


def test_the_init_share_sweep_applies_to_fixed_encoders_only(tmp_path: Path) -> None:
    from latent_sindy.worlds.push.study.config import PushStudyConfig, study_specs
    from latent_sindy.worlds.push.study.sweeps import Sweep

    cfg = PushStudyConfig(scale="tiny", out=tmp_path,
                          models=("sindy2", "sindy_moments", "state_sindy"),
                          sweep=(Sweep.parse("init_share=0,0.2"),))
    names = [s.name for s in study_specs(cfg)]
    assert names == ["sindy2", "sindy_moments.init_share=0",
                     "sindy_moments.init_share=0.2", "state_sindy.init_share=0",
                     "state_sindy.init_share=0.2"], names


def test_a_turning_models_coefficient_map_counts_its_candidates(data: Path, tmp_path: Path,
                                                                 monkeypatch) -> None:
    """The coefficient figure's sparsity is the model's own (z3's column is no candidate of
    a turning model), not the mask's share."""
    import matplotlib.pyplot as plt

    from latent_sindy.worlds.push.study import figures

    out = tmp_path / "run"
    assert main(["train", "--data", str(data), "--out", str(out), "--epochs", "1",
                 "--batch-size", "4", "--no-progress", "--turn", "sindy", "--order", "1",
                 "--library", "frame", "--no-include-sine", "state"]) == 0
    dyn = RunDir(out).load().model.dynamics
    seen = {}
    real = plt.Axes.set_title

    def keep(ax, text, *args, **kwargs):
        seen["title"] = text
        return real(ax, text, *args, **kwargs)

    monkeypatch.setattr(plt.Axes, "set_title", keep)
    figures.coefficient_map(dyn, "m", tmp_path / "c.png")
    assert f"of {dyn.n_candidates()} ({100 * dyn.sparsity():.1f}% sparse)" in seen["title"]
    assert dyn.n_candidates() == 3 * dyn.mask.shape[0]
