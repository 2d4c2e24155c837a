"""Choosing a sparsifier's setting on held-out rollouts: the true law of a known system is
kept over sparser fits that roll out worse; the choice is the sparsest within the slack;
diverging rollouts count as infinitely wrong; bad input is refused."""

from __future__ import annotations

import math

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import (
    Polynomial,
    SindyLibrary,
    StepwiseSR,
    rollout_error,
    select_on_rollouts,
)
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


def test_a_rollout_is_judged_with_the_models_own_map_after_each_step():
    """A turn of a point on the unit circle by 0.1 rad a step, fitted as a linear step that
    also stretches the point by 2 %: unprojected its rollouts spiral out; scaled back onto
    the circle after each step (the model's own map) they are exact, and the selection
    judges its fits by those rollouts."""
    library = SindyLibrary(Polynomial("z,u", 1), n_state=2, n_control=1)
    names = library.names  # "1", "z0", "z1", "u0"

    def turn(stretch: float) -> torch.Tensor:
        """x' = x + Θ(x) coef = stretch · (x turned by 0.1 rad)."""
        c, s = stretch * math.cos(0.1), stretch * math.sin(0.1)
        coef = torch.zeros(len(names), 2, dtype=torch.float64)
        coef[names.index("z0")] = torch.tensor([c - 1, s], dtype=torch.float64)
        coef[names.index("z1")] = torch.tensor([-s, c - 1], dtype=torch.float64)
        return coef

    coef = turn(1.0)
    stretched = turn(1.02)
    gen = torch.Generator().manual_seed(0)
    angles = 6 * torch.rand(6, 1, dtype=torch.float64, generator=gen) + 0.1 * torch.arange(21)
    X = torch.stack([angles.cos(), angles.sin()], -1)  # (6, 21, 2) on the unit circle
    U = torch.zeros(6, 20, 1, dtype=torch.float64)

    def unit(x):
        return x / x.norm(dim=-1, keepdim=True)

    assert rollout_error(library, coef, X, U) < 1e-6
    assert rollout_error(library, stretched, X, U) > 0.1
    assert rollout_error(library, stretched, X, U, project=unit) < 1e-6
    Z = X[:, :-1].reshape(-1, 2)
    Znext = X[:, 1:].reshape(-1, 2)
    choice = select_on_rollouts(library, Z, U.reshape(-1, 1), Znext, X, U, settings=(1e-3,),
                                make=lambda _: _Fixed(stretched), project=unit)
    assert choice.path[0].error < 1e-6
    assert select_on_rollouts(library, Z, U.reshape(-1, 1), Znext, X, U, settings=(1e-3,),
                              make=lambda _: _Fixed(stretched)).path[0].error > 0.1


class _Fixed(StepwiseSR):
    """A sparsifier whose fit is given coefficients."""

    def __init__(self, coef):
        super().__init__()
        self._coef = coef

    def fit(self, theta, target, mask=None):
        self.coef_ = self._coef
        self.mask_ = self._coef != 0
        return self
