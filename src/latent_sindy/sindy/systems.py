"""Known controlled discrete-time systems for testing and benchmarking SINDy fits.

Each system is an explicit Euler step of a classic ODE with control inputs, so its one-step
map ``z_{t+1} = z_t + Θ(z_t, u_t) Ψ`` lies exactly in a small library: a fit on noise-free
data should recover the active set and the coefficients. Data are trajectories from random
initial states under random inputs, all drawn from a generator seeded by ``seed``.

* :func:`lorenz_control`: Lorenz (σ=10, ρ=28, β=8/3) with an input on ẋ, dt = 0.01.
* :func:`duffing_forced`: Duffing oscillator (δ=0.3, α=−1, β=1) with periodic forcing
  γ cos(φ) whose phase φ = ω t is an input, plus a random force, dt = 0.01.

    >>> data = lorenz_control(seed=0)  # 5000 transitions
    >>> data.Z.shape, data.U.shape, data.library.n_terms
    (torch.Size([5000, 3]), torch.Size([5000, 1]), 35)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from latent_sindy.sindy.grammar import Cosine, Polynomial, Sine
from latent_sindy.sindy.named_libraries import poly_library
from latent_sindy.sindy.torch_library import SindyLibrary

__all__ = ["KnownSystem", "duffing_forced", "lorenz_control"]


@dataclass(frozen=True)
class KnownSystem:
    """Transitions of a known system and its true coefficients in ``library``'s terms."""

    name: str
    Z: torch.Tensor
    """(N, nz) float64 states."""
    U: torch.Tensor
    """(N, nu) float64 inputs."""
    Znext: torch.Tensor
    """(N, nz) float64 next states."""
    library: SindyLibrary
    true: dict[tuple[str, str], float]
    """(state, term name) -> coefficient of every true term of ``Znext − Z``."""

    def true_coefficients(self) -> torch.Tensor:
        """The true Ψ as a (p, nz) float64 matrix."""
        psi = torch.zeros(self.library.n_terms, self.Z.shape[1], dtype=torch.float64)
        for (state, term), value in self.true.items():
            psi[self.library.names.index(term), int(state[1:])] = value
        return psi


def _trajectories(
    step, z0: torch.Tensor, inputs: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Roll ``step`` from z0 (B, nz) under inputs (B, T, nu): flattened (B·T, ·) transitions."""
    zs = [z0]
    for t in range(inputs.shape[1]):
        zs.append(step(zs[-1], inputs[:, t]))
    traj = torch.stack(zs, dim=1)  # (B, T+1, nz)
    nz, nu = z0.shape[1], inputs.shape[2]
    return (traj[:, :-1].reshape(-1, nz), inputs.reshape(-1, nu), traj[:, 1:].reshape(-1, nz))


def lorenz_control(
    seed: int = 0, n_traj: int = 10, steps: int = 500, order: int = 3, dt: float = 0.01
) -> KnownSystem:
    """Euler-discretised Lorenz with input u0 ~ U(−10, 10) on ẋ; library: monomials of
    [z, u] up to ``order`` (35 terms for order 3)."""
    sigma, rho, beta = 10.0, 28.0, 8.0 / 3.0
    gen = torch.Generator().manual_seed(seed)
    z0 = torch.rand(n_traj, 3, generator=gen, dtype=torch.float64)
    z0 = z0 * torch.tensor([30.0, 30.0, 30.0], dtype=torch.float64) + torch.tensor(
        [-15.0, -15.0, 10.0], dtype=torch.float64
    )
    inputs = 20.0 * torch.rand(n_traj, steps, 1, generator=gen, dtype=torch.float64) - 10.0

    def step(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        x, y, w = z.unbind(-1)
        dz = torch.stack([sigma * (y - x) + u[:, 0], x * (rho - w) - y, x * y - beta * w], dim=-1)
        return z + dt * dz

    Z, U, Znext = _trajectories(step, z0, inputs)
    true = {
        ("z0", "z0"): -dt * sigma,
        ("z0", "z1"): dt * sigma,
        ("z0", "u0"): dt,
        ("z1", "z0"): dt * rho,
        ("z1", "z1"): -dt,
        ("z1", "z0 z2"): -dt,
        ("z2", "z0 z1"): dt,
        ("z2", "z2"): -dt * beta,
    }
    library = SindyLibrary(poly_library(order, include_sine=False), 3, 1)
    return KnownSystem("lorenz", Z, U, Znext, library, true)


def duffing_forced(
    seed: int = 0, n_traj: int = 10, steps: int = 500, order: int = 3, dt: float = 0.01
) -> KnownSystem:
    """Euler-discretised forced Duffing oscillator, state (x, v), inputs u0 ~ U(−1, 1) (a
    force) and u1 = φ (the forcing phase, advancing by ω dt per step from a random start);
    library: monomials of [z, u0] up to ``order`` with the constant, then sin(u1), cos(u1)
    (22 terms for order 3)."""
    delta, alpha, beta, gamma, omega = 0.3, -1.0, 1.0, 0.5, 1.2
    gen = torch.Generator().manual_seed(seed)
    z0 = 4.0 * torch.rand(n_traj, 2, generator=gen, dtype=torch.float64) - 2.0
    force = 2.0 * torch.rand(n_traj, steps, 1, generator=gen, dtype=torch.float64) - 1.0
    phase0 = 2 * math.pi * torch.rand(n_traj, 1, 1, generator=gen, dtype=torch.float64)
    phase = phase0 + omega * dt * torch.arange(steps, dtype=torch.float64)[None, :, None]
    inputs = torch.cat([force, torch.remainder(phase, 2 * math.pi)], dim=-1)  # (B, T, 2)

    def step(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        x, v = z.unbind(-1)
        acc = -delta * v - alpha * x - beta * x**3 + gamma * torch.cos(u[:, 1]) + u[:, 0]
        return z + dt * torch.stack([v, acc], dim=-1)

    Z, U, Znext = _trajectories(step, z0, inputs)
    true = {
        ("z0", "z1"): dt,
        ("z1", "z1"): -dt * delta,
        ("z1", "z0"): -dt * alpha,
        ("z1", "z0^3"): -dt * beta,
        ("z1", "cos(u1)"): dt * gamma,
        ("z1", "u0"): dt,
    }
    spec = Polynomial(("z", "u0"), order, bias=True) + Sine("u1") + Cosine("u1")
    library = SindyLibrary(spec, 2, 2)
    return KnownSystem("duffing", Z, U, Znext, library, true)
