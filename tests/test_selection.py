"""Choosing a sparsifier's setting on held-out rollouts: the true law of a known system is
kept over sparser fits that roll out worse; the choice is the sparsest within the slack;
diverging rollouts count as infinitely wrong; bad input is refused."""

from __future__ import annotations

import math

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import StepwiseSR, rollout_error, select_on_rollouts
from latent_sindy.sindy.systems import lorenz_control


def _held_out(system, n: int = 8, steps: int = 40, seed: int = 5):
    """Trajectories of the true law from training states, under fresh random inputs."""
    gen = torch.Generator().manual_seed(seed)
    start = system.Z[torch.randint(len(system.Z), (n,), generator=gen)]
    inputs = 10 * torch.randn(n, steps, system.U.shape[1], generator=gen, dtype=torch.float64)
    true = system.true_coefficients()
    xs = [start]
    for t in range(steps):
        xs.append(xs[-1] + system.library(xs[-1], inputs[:, t]) @ true)
    return torch.stack(xs, 1), inputs


def test_the_choice_is_the_true_law_and_the_sparsest_within_the_slack():
    system = lorenz_control(seed=0)
    X, U = _held_out(system)
    choice = select_on_rollouts(system.library, system.Z, system.U, system.Znext, X, U,
                                settings=(1e-9, 1e-6, 1e-3, 1e-2, 1e-1))
    assert torch.equal(choice.model.mask_, system.true_coefficients() != 0)
    best = min(p.error for p in choice.path)
    chosen = next(p for p in choice.path if p.setting == choice.setting)
    assert chosen.error <= 3 * best
    assert all(p.active >= chosen.active or p.error > 3 * best for p in choice.path)
    assert any(p.active < chosen.active for p in choice.path)  # sparser fits were refused
    assert "* setting" in choice.table() and len(choice.table().splitlines()) == 5


def test_the_rollout_error_is_zero_for_the_true_law_and_inf_when_it_diverges():
    system = lorenz_control(seed=0)
    X, U = _held_out(system, n=3, steps=10)
    true = system.true_coefficients()
    assert rollout_error(system.library, true, X, U) < 1e-9
    assert rollout_error(system.library, 1e6 * true, X, U) == math.inf
    assert 0 < rollout_error(system.library, 0.9 * true, X, U) < math.inf


def test_bad_input_is_refused():
    system = lorenz_control(seed=0)
    X, U = _held_out(system, n=2, steps=5)
    args = (system.library, system.Z, system.U, system.Znext, X, U)
    with pytest.raises(UserError, match="slack"):
        select_on_rollouts(*args, slack=0.5)
    with pytest.raises(UserError, match="at least one setting"):
        select_on_rollouts(*args, settings=())
    with pytest.raises(ValueError, match="do not match"):
        rollout_error(system.library, system.true_coefficients(), X, U[:, :3])

    def blow_up(setting):
        return _Exploding(system.true_coefficients())

    with pytest.raises(UserError, match="diverged"):
        select_on_rollouts(*args, settings=(1e-3,), make=blow_up)


class _Exploding(StepwiseSR):
    """A sparsifier whose fit rolls out to infinity (the true law, scaled up)."""

    def __init__(self, true):
        super().__init__()
        self._true = true

    def fit(self, theta, target, mask=None):
        self.coef_ = 1e100 * self._true
        self.mask_ = self._true != 0
        return self
