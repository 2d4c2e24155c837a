"""Dynamics and a reward head fitted on a latent that a reader gives (ReadLatent), on a toy
system whose "frames" carry its position: the fits, the out-of-view frames, the planner's
previous action, and SINDy, linear and MLP side by side."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.read_latent import (
    ERROR_CAP,
    FIT_CHOICES,
    FitSetting,
    ReadLatent,
    ReadLatentConfig,
    choose_fit,
    filter_step,
    filtered,
    held_out_rollouts,
)

DT, STIFF, DAMP, GAIN, GOAL, EDGE = 0.1, 4.0, 0.5, 2.0, 0.5, 1.2


class PositionReader:
    """Reads (x, its change per second, the previous action) from two stacked one-pixel
    frames (x_{t-1}, x_t), each pixel (x + 2) / 4; a frame beyond |x| = EDGE is not seen."""

    circle = None
    names = ("x", "ẋ", "previous u")

    def __init__(self) -> None:
        self.fitted, self.fitted_on = False, 0

    def fit_episodes(self, images):
        self.fitted, self.fitted_on = True, len(images)
        return self

    def latent(self, obs, previous, dt):
        before, now = 4 * obs[:, 0, 0, 0].double() - 2, 4 * obs[:, 1, 0, 0].double() - 2
        z = torch.stack([now, (now - before) / dt], -1)
        return torch.cat([z, previous.double()], -1), now.abs() < EDGE

    def episode(self, images, actions, dt):
        previous = torch.cat([torch.zeros_like(actions[:1]), actions]).double()
        return self.latent(images, previous, dt)


def _pixel(x: float) -> float:
    return (x + 2) / 4


def _step(x, v, u):
    v = v + DT * (-STIFF * x - DAMP * v + GAIN * u)
    return x + DT * v, v


def _episodes(n: int, steps: int, seed: int, noise: float = 0.0,
              truth: list | None = None) -> SequenceData:
    """Random-action episodes; ``noise``: each frame's x read with that Gaussian error
    (one draw a frame, as a camera's); ``truth`` gets each episode's true (x, v) (T+1, 2)."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, steps + 1, 2, 1, 1), np.float32)
    actions = rng.uniform(-1, 1, (n, steps, 1))
    rewards = np.zeros((n, steps), np.float32)
    for e in range(n):
        x, v = rng.uniform(-0.5, 0.5), 0.0
        seen = x + noise * rng.standard_normal()
        images[e, 0], states = _pixel(seen), [(x, v)]
        for t in range(steps):
            before = seen
            x, v = _step(x, v, actions[e, t, 0])
            seen = x + noise * rng.standard_normal()
            images[e, t + 1, 0], images[e, t + 1, 1] = _pixel(before), _pixel(seen)
            rewards[e, t] = -(x - GOAL) ** 2
            states.append((x, v))
        if truth is not None:
            truth.append(np.asarray(states))
    return SequenceData(images, actions.astype(np.float32), action_low=[-1.0],
                        action_high=[1.0], rewards=rewards, dt=DT)


@pytest.fixture(scope="module")
def data():
    return _episodes(12, 60, 0)


def test_sindy_finds_the_few_terms_of_the_toy_system(data):
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=300), seed=0).fit(data)
    assert est.reader.fitted
    lines = est.equations()
    assert len(lines) == 4 and lines[0].startswith("latent: z0 = x, z1 = ẋ, z2 = previous u")
    # x, its change and the previous action: a linear system, each change a few terms
    assert 3 <= int(np.count_nonzero(est.coefficients())) <= 12, lines
    assert est.coefficients().shape[1] == 3


def test_the_reader_is_fitted_on_the_first_episodes_only_when_told(data):
    # (a loop's planned episodes hold the object in one place: a median background fitted
    # on them would hold the object too)
    assert ReadLatent(PositionReader(), ReadLatentConfig(updates=10)).fit(
        data).reader.fitted_on == data.n
    assert ReadLatent(PositionReader(), ReadLatentConfig(updates=10, reader_episodes=3)).fit(
        data).reader.fitted_on == 3
    with pytest.raises(UserError, match="reader_episodes=0"):
        ReadLatentConfig(reader_episodes=0)


def test_the_planner_knows_the_range_of_the_latents_in_view(data):
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(data)
    low, high = est.support_
    images = torch.from_numpy(data.images)
    read = [est.reader.episode(images[e], torch.from_numpy(data.actions[e]).double(), DT)
            for e in range(data.n)]
    z = torch.cat([z[s] for z, s in read])
    zs = ((z - est.mean) / est.sd).float()
    assert torch.allclose(low, zs.min(0).values) and torch.allclose(high, zs.max(0).values)
    cost = est.planner().mppi.cost
    assert cost.weight == 10.0 and torch.equal(cost.high, high)


def test_frames_out_of_view_are_left_out(data):
    images = data.images.copy()
    images[0, 10:15, 1] = 1.0  # a reading gone wrong (x = 2), and not seen
    broken = SequenceData(images, data.actions, action_low=[-1.0], action_high=[1.0],
                          rewards=data.rewards, dt=DT)
    clean = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(data)
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(broken)
    assert est.seen_share_ < 1.0
    assert np.isfinite(est.coefficients()).all()
    assert np.allclose(est.coefficients(), clean.coefficients(), atol=0.05)


@pytest.mark.parametrize("dynamics", ["sindy", "linear", "mlp"])
def test_each_dynamics_plans_toward_the_reward_better_than_random_actions(data, dynamics):
    est = ReadLatent(PositionReader(), ReadLatentConfig(dynamics=dynamics, updates=600),
                     seed=0).fit(data)
    planner = est.planner(MPPIConfig(samples=100, horizon=8, sigma=0.5, lambda_=0.1), seed=1)
    rng = np.random.default_rng(3)
    totals = {}
    for kind in ("planned", "random"):
        x, v, before, total = 0.0, 0.0, 0.0, 0.0
        planner.reset(None, seed=2)
        for _ in range(30):
            obs = np.array([_pixel(before), _pixel(x)], np.float32).reshape(2, 1, 1)
            u = planner.act(obs) if kind == "planned" else rng.uniform(-1, 1, 1)
            assert u.shape == (1,) and -1 <= u[0] <= 1
            before = x
            x, v = _step(x, v, float(u[0]))
            total += -(x - GOAL) ** 2
        totals[kind] = total
    assert totals["planned"] > 0.5 * totals["random"], totals  # (returns are negative)
    if dynamics == "mlp":
        with pytest.raises(NotImplementedError):
            est.coefficients()


def test_the_planner_reads_the_action_carried_out():
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(
        _episodes(4, 30, 1))
    planner = est.planner(MPPIConfig(samples=50, horizon=5))
    obs = np.full((2, 1, 1), 0.5, np.float32)
    u = planner.act(obs)
    assert np.array_equal(planner.previous, u)
    planner.note_action(np.array([0.25]))
    assert planner.previous.tolist() == [0.25]
    planner.reset()
    assert planner.previous.tolist() == [0.0]


def test_the_filter_follows_exact_readings_and_averages_noisy_ones():
    exact = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(
        _episodes(8, 60, 2))
    assert exact.gain_ == 1.0  # a reading without error: no gain filters better
    truth: list = []
    noisy = _episodes(16, 60, 3, noise=0.02, truth=truth)
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10), seed=0).fit(noisy)
    assert est.gain_ < 1.0, est.gain_errors_
    assert est.gain_errors_[est.gain_] < est.gain_errors_[1.0]
    # the filtered latent is nearer the true state than the reading, in x and more so in ẋ
    images, actions = torch.from_numpy(noisy.images), torch.from_numpy(noisy.actions).double()
    read = torch.stack([PositionReader().episode(images[e], actions[e], DT)[0]
                        for e in range(noisy.n)])
    seen = torch.ones(read.shape[:2], dtype=torch.bool)
    zs = ((read - est.mean) / est.sd).float()
    with torch.no_grad():
        f = filtered(est.model, zs, actions.float(), seen, est.gain_) * est.sd.float() + (
            est.mean.float())
    true = torch.from_numpy(np.stack(truth))[:, 5:]  # (after the filter's first steps)
    true_v = (true[:, 1:, 0] - true[:, :-1, 0]) / DT  # (a frame difference's velocity)
    err_read_v = (read[:, 6:, 1] - true_v).square().mean()
    err_f_v = (f[:, 6:, 1].double() - true_v).square().mean()
    assert err_f_v < 0.5 * err_read_v, (float(err_f_v), float(err_read_v))
    assert (f[:, 5:, 0].double() - true[..., 0]).square().mean() < (
        read[:, 5:, 0] - true[..., 0]).square().mean()
    # out of view, the filter takes the reading, and goes on from it
    seen[:, 10:13] = False
    with torch.no_grad():
        f = filtered(est.model, zs, actions.float(), seen, 0.5)
        ahead = est.model(zs[:, 12], actions[:, 12].float())
    assert torch.equal(f[:, 10:13], zs[:, 10:13])
    assert torch.equal(filter_step(zs[:, 3] + 1.0, zs[:, 3], seen[:, 3], 1.0, None), zs[:, 3])
    assert torch.allclose(f[:, 13], ahead + 0.5 * (zs[:, 13] - ahead))
    assert not torch.allclose(f[:, 9], zs[:, 9])
    with pytest.raises(UserError, match="gain=0"):
        ReadLatentConfig(gain=0)


class _Scaled(torch.nn.Module):
    """z[t+1] = a z[t] (+ 0 u), with ``terms`` active coefficients, for choose_fit."""

    def __init__(self, a: float, terms: int) -> None:
        super().__init__()
        self.a, self.terms = a, terms

    def forward(self, z, u):
        return self.a * z

    def coefficients(self):
        return torch.arange(self.terms) + 1.0


def _decay(n: int = 10, steps: int = 30, rate: float = 0.9):
    z0 = torch.linspace(1.0, 2.0, n)[:, None, None]
    Z = z0 * rate ** torch.arange(steps + 1.0)[None, :, None]  # (n, T+1, 1)
    return Z.double(), torch.zeros(n, steps, 1).double(), torch.ones(n, steps + 1, dtype=bool)


def test_held_out_rollouts_follow_the_model_and_count_the_diverged():
    Z, U, seen = _decay()
    exact = held_out_rollouts(_Scaled(0.9, 1), Z, U, seen, 10)
    assert exact.error < 1e-10 and exact.diverged == 0.0
    still = held_out_rollouts(_Scaled(1.0, 1), Z, U, seen, 10)  # (nothing moves)
    assert still.error > 1e-3 and still.diverged == 0.0
    # rollouts that blow up within the horizon cost the cap a step, no more
    wild = held_out_rollouts(_Scaled(1e6, 1), Z, U, seen, 10)
    assert ERROR_CAP / 2 < wild.error <= ERROR_CAP and wild.diverged == 1.0
    # a start counts only where its whole horizon is seen
    seen[:, 5] = False
    wrong_there = Z.clone()
    wrong_there[:, 5] = 100.0
    assert held_out_rollouts(_Scaled(0.9, 1), wrong_there, U, seen, 10).error < 1e-10
    assert np.isnan(held_out_rollouts(_Scaled(0.9, 1), Z, U, seen, 40).error)


def test_choose_fit_keeps_the_set_fit_unless_it_diverges():
    Z, U, seen = _decay()
    keep, a, b, c, d = (FitSetting(5, 0.3, 0.03), FitSetting(5, 0.1, 0.03),
                        FitSetting(1, 0.0, 0.1), FitSetting(5, 0.0, 0.2), FitSetting(1, 0.3, 0.2))
    models = {keep: _Scaled(0.95, 40), a: _Scaled(0.9, 30), b: _Scaled(0.9, 8),
              c: _Scaled(1.0, 2), d: _Scaled(1e3, 1)}
    used = []

    def fit(setting, episodes):
        used.append((setting, episodes.tolist()))
        return models[setting]

    # the set fit, though others predict better, is kept while its rollouts do not diverge
    kept = choose_fit(fit, Z, U, seen, keep, (a, b, c, d), 10, seed=0)
    assert kept.setting == keep and [s for s, _ in used] == [keep]
    assert "* window 5, trim 0.3, min_share 0.03: 40 terms" in kept.table()
    # diverging, it is replaced: b as good as a with fewer terms; c sparser but wrong; d wild
    models[keep] = _Scaled(1e3, 40)
    used.clear()
    choice = choose_fit(fit, Z, U, seen, keep, (a, b, c, d), 10, seed=0)
    assert choice.setting == b
    assert [p[1] for p in choice.path] == [40, 30, 8, 2, 1]
    assert choice.path[0][2].diverged == 1.0 and choice.path[2][2].diverged == 0.0
    held = set(choice.held_out)
    assert len(held) == 2 and all(held.isdisjoint(e) and len(e) == 8 for _, e in used)
    assert "* window 1, trim 0, min_share 0.1: 8 terms" in choice.table()
    assert choose_fit(fit, Z, U, seen, keep, (a, b), 10, seed=1).held_out != choice.held_out
    # always: every fit judged though the set one holds; the slack trades error for terms
    models[keep] = _Scaled(0.95, 40)
    assert choose_fit(fit, Z, U, seen, keep, (a, b, c, d), 10, seed=0,
                      always=True).setting == b
    models[a], models[b] = _Scaled(0.905, 30), _Scaled(0.91, 8)  # (b a little worse)
    tight = choose_fit(fit, Z, U, seen, keep, (a, b, c, d), 10, seed=0, always=True)
    loose = choose_fit(fit, Z, U, seen, keep, (a, b, c, d), 10, seed=0, slack=10.0,
                       always=True)
    assert tight.setting == a and loose.setting == b and len(loose.path) == 5
    # too few episodes, or no held-out run long enough: nothing to judge by
    assert choose_fit(fit, Z[:4], U[:4], seen[:4], keep, (a, b), 10, seed=0) is None
    assert choose_fit(fit, Z, U, seen, keep, (a, b), 40, seed=0) is None


def test_the_checked_fit_is_the_set_fit_where_it_does_not_diverge(data):
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10, horizon=10),
                     seed=3).fit(data)
    cfg = est.config
    assert est.selection_.setting == FitSetting(cfg.window, cfg.trim, cfg.min_share)
    assert len(est.selection_.path) == 1 and est.selection_.path[0][2].diverged == 0.0
    fixed = ReadLatent(PositionReader(), ReadLatentConfig(updates=10, select=False),
                       seed=3).fit(data)
    assert fixed.selection_ is None
    assert np.array_equal(est.coefficients(), fixed.coefficients())
    record = est.latent_record()
    assert record["sindy_fit"]["window"] == cfg.window
    assert len(record["sindy_fit"]["tried"]) == 1
    assert "diverged in 0.0% of the rollouts on 2 held-out episodes, kept" in record["summary"]
    sparse = ReadLatent(PositionReader(), ReadLatentConfig(updates=10, horizon=10,
                                                           sparsest_within=2.0),
                        seed=3).fit(data)
    tried = sparse.latent_record()["sindy_fit"]["tried"]
    assert len(tried) == len(FIT_CHOICES) and tried[0]["terms"] == record["sindy_fit"][
        "tried"][0]["terms"]
    # the chosen one is the sparsest within 2 of the best held-out error (none diverged)
    chosen = sparse.selection_.setting
    assert max(t["diverged"] for t in tried) == 0.0
    best = min(t["held_out_error"] for t in tried)
    near = [t for t in tried if t["held_out_error"] <= 2.0 * best]
    fewest = min(t["terms"] for t in near)
    assert any((t["window"], t["trim"], t["min_share"]) ==
               (chosen.window, chosen.trim, chosen.min_share) and t["terms"] == fewest
               for t in near)
    assert f"the sparsest of {len(FIT_CHOICES)} fits within 2 of the best" in (
        sparse.latent_record()["summary"])


def test_bad_input_raises_user_errors(data):
    with pytest.raises(UserError, match="dynamics 'koopman'"):
        ReadLatentConfig(dynamics="koopman")
    with pytest.raises(UserError, match="window=0"):
        ReadLatentConfig(window=0)
    with pytest.raises(UserError, match="horizon=0"):
        ReadLatentConfig(horizon=0)
    with pytest.raises(UserError, match="select='yes'"):
        ReadLatentConfig(select="yes")
    for within, select in ((0.5, True), (2.0, False), ("2", True)):
        with pytest.raises(UserError, match="sparsest_within="):
            ReadLatentConfig(sparsest_within=within, select=select)
    with pytest.raises(UserError, match="support=-1"):
        ReadLatentConfig(support=-1.0)
    with pytest.raises(UserError, match="reader with fit_episodes"):
        ReadLatent(object())
    with pytest.raises(UserError, match="fit it first"):
        ReadLatent(PositionReader()).planner()
    no_rewards = SequenceData(data.images, data.actions, action_low=[-1.0], action_high=[1.0],
                              dt=DT)
    with pytest.raises(UserError, match="rewards"):
        ReadLatent(PositionReader()).fit(no_rewards)
    est = ReadLatent(PositionReader(), ReadLatentConfig(updates=10)).fit(data)
    with pytest.raises(UserError, match="objective 'goal'"):
        est.planner(objective="goal")
