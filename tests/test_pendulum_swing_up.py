"""The pendulum's centroid latent and its models: the latent holds the angle and the rate,
the SINDy on it finds the frame shift exactly and predicts steps closely, and the study
fits and runs its rows."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import rollout_error
from latent_sindy.worlds.pendulum import PendulumConfig, PendulumWorld, physics
from latent_sindy.worlds.pendulum.centroid_sindy import (
    CentroidMlp,
    CentroidSindy,
    frame_centroids,
    geodesic_latent,
    on_circles,
    transitions,
)
from latent_sindy.worlds.pendulum.render import observe
from latent_sindy.worlds.pendulum.state_sindy import sindy_step
from latent_sindy.worlds.pendulum.study import StudyConfig, compare_swing_ups


@pytest.fixture(scope="module")
def data():
    return PendulumWorld(PendulumConfig(start="random", image_size=16)).collect(60, 12, seed=1)


def test_the_centroids_are_the_rods_direction_a_step_ago_and_now():
    theta = np.array([0.0, 0.7, -2.0, 3.0, -0.3])
    rate = np.array([0.0, 2.0, -4.0, 1.0, 6.0])
    z = frame_centroids(observe(theta, rate, 16)).numpy()  # (5, 4): (x, y) before, now
    assert z.shape == (5, 4)
    # x right, y down: the rod at θ points to (−sin θ, −cos θ)
    for frame, angle in ((1, theta), (0, theta - rate * physics.DT)):
        got = np.arctan2(-z[:, 2 * frame], -z[:, 2 * frame + 1])
        assert np.abs(physics.wrap_angle(got - angle)).max() < np.radians(2)
    blank = frame_centroids(np.zeros((2, 16, 16), np.uint8))
    assert torch.equal(blank, torch.zeros(4))


def test_the_centroid_sindy_finds_the_frame_shift_and_predicts_steps(data):
    model = CentroidSindy().fit(data)  # order 4, stepwise, tolerance chosen on rollouts
    assert model.equations()[:2] == ["z0[t+1] = z0 -1 z0 +1 z2", "z1[t+1] = z1 -1 z1 +1 z3"]
    z, u, z_next = transitions(data)
    err = (model.step(z, u) - z_next).norm(dim=1).mean()
    motion = (z_next - z).norm(dim=1).mean()
    assert float(err) < 0.1 * float(motion)  # the step, not just "stay put"
    assert model.sparsity() > 0.9
    assert model.selection_ is not None and model.setting_ == model.selection_.setting
    # STLSQ judges coefficients, and on the circles the terms are dependent: it keeps more
    stlsq = CentroidSindy(order=4, min_share=0.03, sparsifier="stlsq").fit(data)
    assert stlsq.sparsity() < model.sparsity() and stlsq.selection_ is None
    with pytest.raises(UserError, match="sparsifier"):
        CentroidSindy(sparsifier="lasso")
    linear = CentroidSindy(order=1, min_share=0.0, sparsifier="stlsq").fit(data)
    assert float((linear.step(z, u) - z_next).norm(dim=1).mean()) > float(err)
    mlp = CentroidMlp(width=16, epochs=2, seed=0).fit(data)
    assert mlp.step(z[:3].float(), u[:3].float()).shape == (3, 4)


def test_the_study_runs_the_centroid_rows_with_its_settings():
    assert StudyConfig().centroid_models == ("sindy", "mlp", "linear")
    assert (StudyConfig().centroid_order, StudyConfig().centroid_min_share,
            StudyConfig().centroid_sparsifier) == (4, None, "stepwise")
    assert (StudyConfig().samples, StudyConfig().lambda_) == (500, 0.3)
    with pytest.raises(UserError, match="models"):
        StudyConfig(models=(), centroid_models=())
    with pytest.raises(UserError, match=r"last 20 must lie in 1\.\.episode_steps"):
        StudyConfig(episode_steps=10)
    cfg = StudyConfig(sequences=40, steps=6, window=2, models=(), centroid_models=("sindy",),
                      state_control=False, episodes=1, episode_steps=4, last=2, samples=8,
                      horizon=3, nodes=20, neighbours=4, grid=8, cost_check=0)
    result = compare_swing_ups(cfg, report=lambda _: None)
    (row,) = result.rows
    assert row.name == "sindy (images, centroid latent)"
    assert len(row.episodes) == 1 and row.sparsity is not None
    assert row.equations[0] == "z0[t+1] = z0 -1 z0 +1 z2"


def test_the_geodesic_latent_learned_from_the_frames_steps_like_the_centroid(data):
    """The geodesic latent (no world knowledge): per frame the angle about the centre of
    the frames' geodesic coordinates, a monotone function of the rod's; the SINDy on it
    finds the frame shift and predicts the step (a little less closely than on the
    centroids: the latent's angle runs 0.92-1.12 times as fast as the rod's)."""
    encode = geodesic_latent(data.split("train").images, seed=0)
    theta = np.linspace(-np.pi, np.pi, 73)[:-1]
    z = encode(observe(theta, np.zeros_like(theta), 16)).numpy()  # (72, 4)
    np.testing.assert_allclose(np.hypot(z[:, 2], z[:, 3]), 1.0, atol=1e-5)
    phi = np.unwrap(np.arctan2(z[:, 3], z[:, 2]))
    turn = np.sign(phi[-1] - phi[0])
    assert np.all(turn * np.diff(phi) >= 0)  # one turn of the rod, one of the latent
    assert abs(phi[-1] - phi[0]) > np.radians(330)
    model = CentroidSindy(encode=encode).fit(data)
    assert model.equations()[:2] == ["z0[t+1] = z0 -1 z0 +1 z2", "z1[t+1] = z1 -1 z1 +1 z3"]
    zz, u, z_next = transitions(data, encode)
    err = (model.step(zz, u) - z_next).norm(dim=1).mean()
    assert float(err) < 0.2 * float((z_next - zz).norm(dim=1).mean())


def test_models_on_the_geodesic_latent_keep_each_frames_angle_on_the_unit_circle(data):
    """Each frame's (cos φ, sin φ) lies on the unit circle by construction: the sparse and
    linear models scale the pairs back there after each step, so a rollout of many steps
    holds them, and the SINDy's setting is chosen on rollouts made so (as it will plan).
    The MLP steps as it was trained, unprojected. The centroids, whose circle is the data's
    and not of radius 1, are left as stepped."""
    encode = geodesic_latent(data.split("train").images, seed=0)
    assert encode.circles == ((0, 1), (2, 3))
    zz, u, _ = transitions(data, encode)
    gen = torch.Generator().manual_seed(0)
    torques = 4 * torch.rand(30, len(zz), 1, generator=gen, dtype=torch.float64) - 2
    val = data.split("val")
    held = encode(val.images).double()
    held_u = torch.as_tensor(val.actions, dtype=torch.float64)
    for model in (CentroidSindy(encode=encode).fit(data),
                  CentroidSindy(order=1, min_share=0.0, sparsifier="stlsq",
                                encode=encode).fit(data)):
        z = zz.clone()
        for t in range(30):
            z = model.step(z, torques[t])
            assert torch.isfinite(z).all()
        for a, b in encode.circles:
            np.testing.assert_allclose(torch.hypot(z[:, a], z[:, b]).numpy(), 1.0, atol=1e-6)
    mlp = CentroidMlp(width=16, epochs=2, seed=0, encode=encode).fit(data)
    with torch.no_grad():
        inputs = torch.cat([zz.float(), u.float() / physics.MAX_TORQUE], 1)
        raw = zz.float() + mlp.net(inputs) * mlp.scale
    np.testing.assert_allclose(mlp.step(zz, u).numpy(), raw.double().numpy(), rtol=1e-6)
    assert not np.allclose(torch.hypot(raw[:, 0], raw[:, 1]).numpy(), 1.0, atol=1e-6)
    sindy = CentroidSindy(encode=encode).fit(data)
    chosen = next(p for p in sindy.selection_.path if p.setting == sindy.setting_)
    assert chosen.error == pytest.approx(rollout_error(
        sindy.library, sindy.coef_, held, held_u, project=lambda x: on_circles(x, encode.circles)))
    assert chosen.error != pytest.approx(rollout_error(sindy.library, sindy.coef_, held, held_u))
    centroid = CentroidSindy().fit(data)
    assert centroid.circles == ()
    z, u, _ = transitions(data)
    np.testing.assert_array_equal(centroid.step(z, u).numpy(), sindy_step(
        centroid.library, centroid.coef_, z, u).numpy())
    # frames of a bar sliding along a line: coordinates that do not wind round, no angle
    bar = np.zeros((12, 7, 2, 16, 16), np.uint8)
    for e in range(12):
        for t in range(7):
            for c in range(2):
                bar[e, t, c, :, (e + t + c) % 16] = 255
    with pytest.raises(UserError, match="do not wind round"):
        geodesic_latent(bar)


def test_the_geodesic_scales_cost_graph_leads_to_upright_from_either_side():
    """The cost is the distance to the goal's code along a graph of the training codes. On
    seed 4's draw a graph of 8 neighbours a node breaks just beside upright: from one side
    the distance runs the long way round (about 8.8, against 4.7 from hanging), and every
    model swung up about half the time. The geodesic scale's graph (16 neighbours) grows
    with |θ| from upright on both sides."""
    from latent_sindy.worlds.pendulum.graph_cost import GraphDistanceCost
    from latent_sindy.worlds.pendulum.reproduce import pendulum_config
    from latent_sindy.worlds.pendulum.world import UPRIGHT

    cfg = pendulum_config("geodesic", 4, "cpu")
    data = PendulumWorld(PendulumConfig(start="random", image_size=cfg.image_size)).collect(
        cfg.sequences, cfg.steps, seed=cfg.seed)
    train = data.split("train")
    encode = geodesic_latent(train.images, cfg.seed)
    codes = encode(train.images.reshape(-1, *data.frame_shape)).numpy()
    goal = encode(observe(*UPRIGHT, cfg.image_size)).numpy()
    theta = np.linspace(-np.pi, np.pi, 25)
    at_rest = encode(observe(theta, np.zeros_like(theta), cfg.image_size))

    def distances(neighbours):
        cost = GraphDistanceCost(codes, goal, neighbours, cfg.nodes, seed=cfg.seed)
        return cost.distance(at_rest).numpy()

    d = distances(cfg.neighbours)
    assert np.all(np.diff(d[:13]) < 0) and np.all(np.diff(d[12:]) > 0)
    assert d.max() < 1.2 * d[0]  # hanging is the farthest
    assert distances(8).max() > 1.5 * d.max()  # the broken graph this setting avoids
