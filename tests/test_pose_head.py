"""The privileged pose head: off by default, teaches the latent the orientation, its cost,
its run files and its errors."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from latent_sindy.cli import main
from latent_sindy.control.costs import PoseCost
from latent_sindy.data import write_sequences
from latent_sindy.data.windows import pose_features
from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.costs import cost_weights
from latent_sindy.models.dynamics import SindyConfig
from latent_sindy.models.latent_model import LatentModel, LossWeights, ModelConfig
from latent_sindy.models.state import StateConfig, pose_cost_weights
from latent_sindy.training import RunDir, TrainConfig, train
from latent_sindy.worlds.push.config import ACTION_HIGH, ACTION_LOW, PushEnvConfig
from latent_sindy.worlds.push.controller import COSTS, ControlConfig, Controller
from latent_sindy.worlds.push.data import push_data
from latent_sindy.worlds.push.scene import CameraView
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.probe import latent_probe
from latent_sindy.worlds.push.study.scales import SCALES

pytestmark = pytest.mark.usefixtures("one_torch_thread")

PERIOD = math.pi / 2


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """SequenceData of true images of random poses (no pushing simulated: the poses of a
    trajectory are independent), 40 of 2 steps: 32 train, 4 val, 4 test."""
    cfg = PushEnvConfig()
    rng = np.random.default_rng(0)
    shape = (40, 3)  # trajectories, steps + 1
    poses = np.stack([rng.uniform(0.4, 0.65, shape), rng.uniform(-0.25, 0.25, shape),
                      rng.uniform(-math.pi / 2, math.pi / 2, shape)], -1)
    view = CameraView(cfg)
    try:
        images = np.stack([[view.observe(tuple(p)) for p in traj] for traj in poses])
    finally:
        view.close()
    actions = rng.uniform(ACTION_LOW, ACTION_HIGH, (40, 2, 3))
    split = np.array([0] * 32 + [1] * 4 + [2] * 4, dtype=np.uint8)
    path = tmp_path_factory.mktemp("rendered") / "d.h5"
    write_sequences(path, push_data(images.astype(np.uint8), actions.astype(np.float32),
                                          poses.astype(np.float32), split, cfg, seed=0))
    return path


def config(data: Path, out: Path, head: str, lambda_pose: float, **kw) -> TrainConfig:
    model = ModelConfig(observation=AutoencoderConfig(decoder_kind="conv"),
                        dynamics=SindyConfig(order=1), pose_head=head)
    kw = {"epochs": 3, "batch_size": 16, "prune_every": 0, **kw}
    return TrainConfig(data=data, out=out, model=model,
                       loss=LossWeights(lambda_pose=lambda_pose), **kw)


def test_no_head_by_default_and_a_zero_pose_term() -> None:
    model = LatentModel(ModelConfig().resolve(1, 32, 3))
    assert model.pose_head is None and not any("pose" in k for k in model.state_dict())
    terms = model.loss(torch.zeros(2, 2, 1, 32, 32), torch.zeros(2, 1, 3),
                       poses=torch.ones(2, 2, 4))
    assert terms["pose"] == 0 and LossWeights().lambda_pose == 0


def test_an_unweighted_pose_term_stays_out_of_the_total() -> None:
    """λ4 = 0: a non-finite pose error (NaN poses) is reported but leaves the total alone."""
    torch.manual_seed(0)
    model = LatentModel(dataclasses.replace(ModelConfig(), pose_head="linear").resolve(1, 32, 3))
    x, u = torch.randn(2, 2, 1, 32, 32), torch.rand(2, 1, 3)
    nan_poses = torch.full((2, 2, 4), math.nan)
    with torch.no_grad():
        without = model.loss(x, u)
        unweighted = model.loss(x, u, poses=nan_poses)
        weighted = model.loss(x, u, LossWeights(lambda_pose=1.0), poses=nan_poses)
    assert torch.isnan(unweighted["pose"])
    torch.testing.assert_close(unweighted["total"], without["total"])
    assert torch.isnan(weighted["total"])  # a weighted term counts, NaN included


def test_an_unweighted_head_changes_nothing_else(rendered: Path, tmp_path: Path) -> None:
    plain = RunDir(train(config(rendered, tmp_path / "a", "none", 0.0))).load().model
    headed = RunDir(train(config(rendered, tmp_path / "b", "linear", 0.0))).load().model
    a, b = plain.state_dict(), headed.state_dict()
    assert set(b) - set(a) == {"pose_head.linear.weight", "pose_head.linear.bias",
                               "pose_head.mean", "pose_head.std"}
    for k in a:
        assert torch.equal(a[k], b[k]), f"{k} differs"


@pytest.mark.slow  # over a minute of training on 2 cores
def test_pose_supervision_puts_the_orientation_into_the_latent(rendered: Path,
                                                               tmp_path: Path) -> None:
    from latent_sindy.data import read_sequences

    data = read_sequences(rendered)
    r2 = {}
    for lam in (0.0, 10.0):
        run = RunDir(train(config(rendered, tmp_path / str(lam), "linear", lam, epochs=150,
                                  keep_best=False))).load()
        probe = latent_probe(run.model, data, run.normalizer, "train")
        r2[lam] = (probe["cos"] + probe["sin"]) / 2
    assert r2[10.0] > 0.5 and r2[10.0] > r2[0.0] + 0.3, r2


def _planning_cost(model: LatentModel, goal: torch.Tensor):
    """The cost --space pose plans on for the goal image (1, 32, 32), as the controller
    builds it."""
    controller = SimpleNamespace(model=model.eval(), period=PERIOD)
    with torch.no_grad():
        return COSTS["pose"](controller, goal), model.encode(goal[None])[0]


def test_the_pose_cost_of_a_coordinates_head_weighs_the_first_four_coordinates() -> None:
    """Q-weighted squared error of z_0..3 against the encoded goal's, in the pose's own units
    (the head's standardisation plays no part); the other latent coordinates cost nothing."""
    torch.manual_seed(0)
    cfg = ModelConfig(observation=AutoencoderConfig(latent_dim=7),
                      pose_head="coordinates").resolve(1, 32, 3)
    model = LatentModel(cfg)
    model.pose_head.fit_statistics(torch.randn(50, 4) * 3 + 1)  # not the identity
    cost, z_goal = _planning_cost(model, torch.randn(1, 32, 32))
    q = pose_cost_weights(PERIOD)
    z = torch.randn(3, 5, 7)  # (H, K, nz)
    want = ((z[..., :4] - z_goal[:4]).square() * q).sum(-1)  # (H, K)
    torch.testing.assert_close(cost(z), want)
    other = z.clone()
    other[..., 4:] = torch.randn(3, 5, 3) * 10
    torch.testing.assert_close(cost(other), want)
    at_goal = z.clone()
    at_goal[..., :4] = z_goal[:4]
    torch.testing.assert_close(cost(at_goal), torch.zeros(3, 5))


def test_the_pose_cost_of_a_linear_head_follows_its_weights() -> None:
    """cost(z) = Σ Q (s(z) − s(z_goal))², s(z) = (W z + b) ⊙ std + mean the head's reading in
    pose units: other weights give another cost, by the same formula."""
    torch.manual_seed(0)
    model = LatentModel(dataclasses.replace(ModelConfig(), pose_head="linear").resolve(1, 32, 3))
    head = model.pose_head
    head.fit_statistics(torch.randn(50, 4) * torch.tensor([0.1, 0.15, 0.7, 0.7]))
    goal, z = torch.randn(1, 32, 32), torch.randn(3, 5, 16)
    q = pose_cost_weights(PERIOD)

    def by_hand(z_goal: torch.Tensor) -> torch.Tensor:
        w, b = head.linear.weight.detach(), head.linear.bias.detach()  # (4, nz), (4,)

        def s(v: torch.Tensor) -> torch.Tensor:
            return (v @ w.T + b) * head.std + head.mean

        return ((s(z) - s(z_goal)).square() * q).sum(-1)  # (H, K)

    costs = []
    for scale in (1.0, 3.0):
        with torch.no_grad():
            head.linear.weight.mul_(scale)
            head.linear.weight[2].neg_()  # and another direction for cos
        cost, z_goal = _planning_cost(model, goal)
        with torch.no_grad():
            costs.append(cost(z))
        torch.testing.assert_close(costs[-1], by_hand(z_goal))
    assert not torch.allclose(costs[0], costs[1], rtol=1e-2)
    assert costs[0].shape == (3, 5)


def test_a_pose_2cm_or_10_degrees_off_costs_1() -> None:
    identity = torch.nn.Identity()  # a readout that is the pose features themselves
    goal = pose_features(np.array([0.5, 0.1, 0.3]), PERIOD)
    cost = PoseCost(identity, goal, pose_cost_weights(PERIOD))
    for off in ([0.52, 0.1, 0.3], [0.5, 0.08, 0.3], [0.5, 0.1, 0.3 + math.radians(10)],
                [0.5, 0.1, 0.3 - math.radians(10) + PERIOD]):
        assert float(cost(pose_features(np.array(off), PERIOD))) == pytest.approx(1, rel=1e-4)


def test_a_run_with_a_head_round_trips(rendered: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert main(["train", "sindy", "--order", "1", "--pose-head", "linear", "--lambda-pose", "1",
                 "--data", str(rendered), "--out", str(out), "--epochs", "2",
                 "--batch-size", "16", "--no-progress"]) == 0
    model = RunDir(out).load().model  # weights_only=True, as every run file
    saved = torch.load(out / RunDir.MODEL, weights_only=True)["model"]
    assert model.pose_head is not None
    for k, v in model.state_dict().items():
        assert torch.equal(v, saved[k])
    from latent_sindy.data import read_sequences

    train_poses = pose_features(read_sequences(rendered).split("train").poses, PERIOD)
    torch.testing.assert_close(model.pose_head.mean, train_poses.flatten(0, 1).mean(0))
    assert RunDir(out).read_metrics()[-1]["train/pose"] > 0


def test_pose_space_control_plans_on_the_heads_reading(rendered: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    train(config(rendered, out, "linear", 1.0, epochs=1))
    assert main(["control", str(out), "--task", "random", "--space", "pose", "--max-steps", "1",
                 "--samples", "8", "--horizon", "2", "--gif-episodes", "0",
                 "--no-progress"]) == 0
    assert (out / "control-random-pose" / "results.json").exists()


def test_the_study_row_plans_on_its_pose_cost() -> None:
    scale = SCALES["demo"]
    spec = next(s for s in model_specs(scale) if s.name == "sindy2_pose")
    assert spec.model.has_pose_head and spec.loss.lambda_pose > 0
    latent = [c for c in scale.conditions(spec) if c.space == "latent"]
    assert latent and all(scale.control_config(c, 0, "symmetric").space == "pose"
                          for c in latent)
    push = next(s for s in model_specs(scale) if s.name == "sindy2_push")
    assert all(scale.control_config(c, 0, "symmetric").space == c.space
               for c in scale.conditions(push))


@pytest.mark.parametrize(("build", "message"), [
    (lambda: LossWeights(lambda_pose=-1.0), "--lambda-pose -1.0: use a finite number >= 0"),
    (lambda: TrainConfig(loss=LossWeights(lambda_pose=1.0)), "add --pose-head"),
    (lambda: ModelConfig(observation=StateConfig(), pose_head="linear"), "drop --pose-head"),
    (lambda: ModelConfig(pose_head="coordinates",
                         observation=AutoencoderConfig(latent_dim=3)), "--latent-dim 4 or more"),
    (lambda: ModelConfig(pose_head="yes"), "--pose-head 'yes': use none, linear"),
    (lambda: ModelConfig(dynamics=SindyConfig(order=1, library="face")),
     "use it with the state encoder, the moments encoder"),
])
def test_bad_pose_settings_are_one_line(build, message: str) -> None:
    with pytest.raises(UserError, match=message) as e:
        build()
    assert "\n" not in str(e.value)


def test_pose_space_without_a_head_is_one_line() -> None:
    model = LatentModel(ModelConfig().resolve(1, 32, 3))
    from latent_sindy.data.windows import Normalizer

    with pytest.raises(UserError, match="--space pose needs a model trained with a pose head"):
        Controller(model, Normalizer(0.0, 1.0), ControlConfig(space="pose"), PushEnvConfig())
    assert set(COSTS) == {"latent", "image", "pose"}


def test_a_coordinates_head_reads_the_first_four_latent_coordinates() -> None:
    """No parameters: the pose is the latent's first four coordinates, the loss compares
    them in standardised units, and the head's statistics are the only state."""
    cfg = ModelConfig(observation=AutoencoderConfig(decoder_kind="conv", latent_dim=4),
                      dynamics=SindyConfig(order=1, library="face", include_sine=False),
                      pose_head="coordinates").resolve(1, 32, 3)
    model = LatentModel(cfg)
    head = model.pose_head
    assert head is not None and not list(head.parameters())
    assert {k for k in model.state_dict() if k.startswith("pose_head")} == {
        "pose_head.mean", "pose_head.std"}
    head.fit_statistics(torch.tensor([[0.4, -0.1, 1.0, 0.0], [0.6, 0.1, -1.0, 0.0]]))
    z = torch.tensor([[0.5, 0.0, 0.6, 0.8]])
    torch.testing.assert_close(head(z), z)
    torch.testing.assert_close(head.standardized(z), (z - head.mean) / head.std)
    # the loss's pose term: the coordinates of the encoded and the predicted latents against
    # the poses, in standardised units
    x, u = torch.randn(2, 2, 1, 32, 32), torch.rand(2, 1, 3)
    poses = torch.tensor([[0.5, 0.0, 0.6, 0.8], [0.55, 0.02, 0.0, 1.0]]).expand(2, 2, 4)
    with torch.no_grad():
        zx = model.encode(x)
        zhat = model.rollout_latent(zx[:, 0], u)[:, 1:]
        got = model.loss(x, u, poses=poses)["pose"]
    std = head.std
    want = (((zx - poses) / std).square().mean()
            + ((zhat - poses[:, 1:]) / std).square().mean())
    torch.testing.assert_close(got, want)


def test_cost_weights_come_from_what_the_coordinates_are() -> None:
    """An error of the position scale, or of the angle scale (modulo the period), costs 1;
    other coordinates weigh 1. The pose's and the moments latent's weights are instances."""
    q = cost_weights(6, positions=(0, 1), position_scale=0.02, circle=(2, 3), period=PERIOD,
                     angle_scale=math.radians(10))
    assert torch.equal(q[:4], pose_cost_weights(PERIOD)) and torch.equal(q[4:], torch.ones(2))
    assert float(q[0]) * 0.02**2 == pytest.approx(1.0)
    f = 2 * math.pi / PERIOD  # the features are (cos fθ, sin fθ)
    e = torch.tensor([math.cos(f * math.radians(10)) - 1, math.sin(f * math.radians(10))])
    assert float((q[2:4] * e.square()).sum()) == pytest.approx(1.0, rel=1e-6)
    moments = AutoencoderConfig(latent_dim=4, encoder_kind="moments").resolve(1, 32).build()
    want = cost_weights(4, positions=(0, 1), position_scale=2 / 31, circle=(2, 3),
                        period=PERIOD, angle_scale=math.radians(10))
    torch.testing.assert_close(moments.cost_weights(PERIOD), want)
    assert torch.equal(StateConfig().build().cost_weights(PERIOD), pose_cost_weights(PERIOD))
    with pytest.raises(ValueError, match="cost scales must be > 0"):
        cost_weights(4, positions=(0,), position_scale=0.0)
