"""MPPI planning speed: ms per control command, ours against pytorch_mppi, for every latent model.

Prints, for K=1000/H=15 and the course setting K=100/H=10 (nz=16, nu=3, Σ=0.1·I, λ=0.01,
Q=I, the pushing env's action box):
  * ms per command of our MPPI for SINDy orders 1-4, linear and MLP models, next to
    ``pytorch_mppi.MPPI`` running the same step function in the same process, and next to
    pytorch_mppi with the dense SINDy model (every library term, as a user would plug it in);
  * the two speed targets (our SINDy-2 <= 1.5x our linear; >= 5x faster than pytorch_mppi with
    the dense SINDy-2 model);
  * what each optimisation bought, on the SINDy order-2 model.

The models: with ``--runs DIR`` the trained ones of a study (``DIR/sindy1`` .. ``sindy4``,
``linear``, ``mlp``, e.g. ``results/demo/runs/seed0`` after ``make demo``), pruned as trained.
Without it, random-initialised SINDy models pruned by magnitude to keep ``--keep`` of their
coefficients (default 4%, like the paper's 95-98% sparsity); random pruning spreads the kept
coefficients over many terms, a pessimistic case for the sparse step.

Times are the best over ``--rounds`` interleaved rounds of the mean ms per command in a round
(robust to other jobs on a shared machine).

    .venv/bin/python benchmarks/mppi.py --threads 2 [--runs results/demo/runs/seed0]
    .venv/bin/python benchmarks/mppi.py --smoke          # tiny K and H, one round (the tests)
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import time
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import pytorch_mppi
import torch

from latent_sindy.control import MPPI, LatentCost, MPPIConfig, latent_step
from latent_sindy.models import LatentDynamics, SindyDynamics, make_dynamics
from latent_sindy.script_args import parse_with_smoke
from latent_sindy.training import load_run
from latent_sindy.worlds.push.config import PushEnvConfig

ENV = PushEnvConfig()
NZ, NU = 16, ENV.action_dim
SETTINGS = ((1000, 15), (100, 10))
MODELS = ("sindy1", "sindy2", "sindy3", "sindy4", "linear", "mlp")


def pruned_sindy(order: int, keep: float) -> SindyDynamics:
    """A random SINDy model keeping the ``keep`` fraction of coefficients largest in |Ψ|."""
    model = SindyDynamics(NZ, NU, order=order, seed=order)
    mags = model.psi.detach().abs().flatten()
    tau = float(mags.kthvalue(max(1, int(mags.numel() * (1 - keep)))).values)
    model.prune(math.nextafter(tau, math.inf))
    return model


def build(name: str, keep: float, runs: Path | None) -> LatentDynamics:
    if runs is not None:
        return load_run(runs / name).model.dynamics
    if name.startswith("sindy"):
        return pruned_sindy(int(name[-1]), keep)
    torch.manual_seed(0)
    return make_dynamics(name, NZ, NU)


def ours(step: Callable, cfg: MPPIConfig, goal: torch.Tensor) -> MPPI:
    return MPPI(step, LatentCost(goal), cfg, ENV.action_low, ENV.action_high)


def theirs(step: Callable, cfg: MPPIConfig, goal: torch.Tensor) -> pytorch_mppi.MPPI:
    """pytorch_mppi configured like ``ours``: same K, H, Σ, λ, bounds, cost, first nominal."""
    cost = LatentCost(goal)
    like = ours(step, cfg, goal)
    return pytorch_mppi.MPPI(
        step, lambda z, u: cost(z), NZ, torch.diag(like.sigma), num_samples=cfg.samples,
        horizon=cfg.horizon, lambda_=cfg.lambda_, u_min=like.low, u_max=like.high,
        u_init=like.u_init, U_init=like.nominal, device="cpu")


def no_grad_command(ctl: pytorch_mppi.MPPI, z: torch.Tensor) -> Callable[[], object]:
    def run() -> object:
        with torch.no_grad():
            return ctl.command(z)

    return run


def in_grad_mode(ctl: MPPI, mode: Callable[[], object], z: torch.Tensor
                 ) -> Callable[[], object]:
    """Our planner's update under ``mode()`` (enable_grad, no_grad) instead of inference_mode."""
    def run() -> object:
        with mode():
            return ctl.update(z)

    return run


def time_cases(cases: dict[str, Callable[[], object]], rounds: int, min_time: float
               ) -> dict[str, float]:
    """Best over interleaved rounds of the mean ms per call.

    Cases taking over a second per call run in two rounds only.
    """
    best = dict.fromkeys(cases, math.inf)
    warm = {}
    for name, fn in cases.items():  # warm up: first-call allocations, compilation
        fn()
        t0 = time.perf_counter()
        fn()
        warm[name] = time.perf_counter() - t0
    for r in range(rounds):
        for name, fn in cases.items():
            if r >= 2 and warm[name] > 1.0:
                continue
            n, t0 = 0, time.perf_counter()
            while True:
                fn()
                n += 1
                elapsed = time.perf_counter() - t0
                if elapsed >= min_time:
                    break
            best[name] = min(best[name], 1e3 * elapsed / n)
    return best


# What each optimisation bought, on SINDy order 2: (label, case key); linear for reference.
OPTIMISATIONS = (
    ("pytorch_mppi, dense model, autograd on", "pm-dense-grad sindy2"),
    ("pytorch_mppi, dense model, no_grad", "pm-dense sindy2"),
    ("ours, dense model, autograd on", "ours-dense-grad sindy2"),
    ("ours, dense model, no_grad", "ours-dense-nograd sindy2"),
    ("ours, dense model, inference_mode", "ours-dense sindy2"),
    ("ours, active terms (compile_sparse)", "ours-lib-sparse sindy2"),
    ("ours, fused numba kernel, called per step", "ours-kernel-steps sindy2"),
    ("ours, fused kernel, whole horizon (default)", "ours sindy2"),
    ("linear model, ours (reference)", "ours linear"),
)


def make_cases(models: dict[str, LatentDynamics], cfg: MPPIConfig, z: torch.Tensor,
               goal: torch.Tensor) -> dict[str, Callable[[], object]]:
    cases: dict[str, Callable[[], object]] = {}
    for name, m in models.items():
        step = latent_step(m)
        cases[f"ours {name}"] = functools.partial(ours(step, cfg, goal).command, z)
        cases[f"pm {name}"] = no_grad_command(theirs(step, cfg, goal), z)
        if isinstance(m, SindyDynamics):
            cases[f"pm-dense {name}"] = no_grad_command(theirs(m.step, cfg, goal), z)
    m = models["sindy2"]
    assert isinstance(m, SindyDynamics)
    cases["pm-dense-grad sindy2"] = functools.partial(theirs(m.step, cfg, goal).command, z)
    for key, mode in (("ours-dense-grad", torch.enable_grad), ("ours-dense-nograd", torch.no_grad)):
        cases[f"{key} sindy2"] = in_grad_mode(ours(m.step, cfg, goal), mode, z)
    cases["ours-dense sindy2"] = functools.partial(ours(m.step, cfg, goal).command, z)
    cases["ours-lib-sparse sindy2"] = functools.partial(
        ours(m.compile_sparse().step, cfg, goal).command, z)
    kernel = latent_step(m)  # hidden behind a plain function: MPPI calls it H times
    cases["ours-kernel-steps sindy2"] = functools.partial(
        ours(lambda z, u: kernel(z, u), cfg, goal).command, z)
    return cases


def setting(text: str) -> tuple[int, int]:
    """``K,H``: MPPI's samples and horizon."""
    k, comma, h = text.partition(",")
    try:
        pair = int(k), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give K,H, e.g. 1000,15") from None
    if not comma or min(pair) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give K,H, both 1 or more, e.g. 1000,15")
    return pair


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    ap.add_argument("--keep", type=float, default=0.04, help="fraction of SINDy coefficients kept")
    ap.add_argument("--runs", type=Path, default=None,
                    help="folder of trained runs sindy1..sindy4, linear, mlp (default: random)")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--min-time", type=float, default=0.1, help="seconds per case per round")
    ap.add_argument("--settings", type=setting, nargs="+", default=list(SETTINGS),
                    metavar="K,H", help="MPPI samples and horizon (default 1000,15 100,10)")
    args = parse_with_smoke(ap, argv, {"threads": 1, "rounds": 1, "min_time": 0.0,
                                       "settings": [(16, 3), (8, 2)]})
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    print(f"torch {torch.__version__}, pytorch_mppi {version('pytorch-mppi')} (same process), "
          f"{args.threads} torch threads, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.2f} at start")
    print(f"models: trained, from {args.runs}" if args.runs else
          f"SINDy models: random-initialised, pruned to keep {args.keep:.0%} of coefficients "
          "by magnitude")
    models = {name: build(name, args.keep, args.runs) for name in MODELS}
    for name, m in models.items():
        if isinstance(m, SindyDynamics):
            print(f"  {name}: {m.n_active()} of {m.mask.numel()} coefficients active "
                  f"(sparsity {m.sparsity():.1%}), {len(m.active_terms())} of "
                  f"{m.library.n_terms} library terms active in some state")
    t0 = time.perf_counter()
    latent_step(models["sindy2"])(torch.zeros(1, NZ), torch.zeros(1, NU))
    print(f"  first SINDy step (numba compiles the kernel, or loads it from its disk cache): "
          f"{time.perf_counter() - t0:.2f} s")
    z = 0.1 * torch.randn(NZ)
    goal = torch.zeros(NZ)
    results = {}
    for K, H in args.settings:
        cfg = MPPIConfig(samples=K, horizon=H, sigma=0.1, lambda_=0.01, Q=1.0)
        cases = make_cases(models, cfg, z, goal)
        results[(K, H)] = time_cases(cases, args.rounds, args.min_time)
        print(f"  K={K} H={H} timed, load average {os.getloadavg()[0]:.2f}")

    for (K, H), res in results.items():
        print(f"\nK={K}, H={H}: ms per command (pytorch_mppi under torch.no_grad; pm/ours > 1: "
              "ours faster)")
        print(f"{'model':<8} {'ours':>9} {'pytorch_mppi':>13} {'pm/ours':>8} "
              f"{'pm dense':>10} {'pm dense/ours':>14}")
        for name in MODELS:
            a, b = res[f"ours {name}"], res[f"pm {name}"]
            dense = res.get(f"pm-dense {name}")
            tail = (f"{dense:>10.2f} {dense / a:>13.1f}x" if dense is not None
                    else f"{'-':>10} {'-':>14}")
            print(f"{name:<8} {a:>9.2f} {b:>13.2f} {b / a:>7.2f}x {tail}")

    print("\nWhat each optimisation bought (SINDy order 2; ms per command; in brackets the "
          "speed-up over the row above, and over the first row)")
    print(f"{'':<44}" + "".join(f"{f'K={K} H={H}':>26}" for K, H in args.settings))
    first_key, prev = OPTIMISATIONS[0][1], None
    for label, key in OPTIMISATIONS:
        if key not in results[args.settings[0]]:
            continue
        cells = []
        for s in args.settings:
            ms = results[s][key]
            up = f"{results[s][prev] / ms:.2f}x" if prev and "linear" not in key else "-"
            cells.append(f"{ms:>8.2f} ({up:>6}, {results[s][first_key] / ms:>5.1f}x)")
        print(f"{label:<44}" + "".join(f"{c:>26}" for c in cells))
        prev = prev if "linear" in key else key
    print("\nTargets (SINDy order 2):")
    for (K, H), res in results.items():
        r1 = res["ours sindy2"] / res["ours linear"]
        r2 = res["pm-dense sindy2"] / res["ours sindy2"]
        r3 = res["pm-dense-grad sindy2"] / res["ours sindy2"]
        print(f"  K={K} H={H}: ours SINDy-2 / ours linear = {r1:.2f}x (target <= 1.5x: "
              f"{'met' if r1 <= 1.5 else 'NOT met'});\n    pytorch_mppi dense SINDy-2 / ours "
              f"SINDy-2 = {r2:.1f}x under no_grad (target >= 5x: "
              f"{'met' if r2 >= 5 else 'NOT met'}), {r3:.1f}x with autograd on")
    print("\nNotes: pytorch_mppi shifts its nominal before planning (ours after), leaves the "
          "nominal unclamped and\n  samples from the global RNG; both clamp candidates into "
          "the box and use the clamped perturbation in\n  the action cost and the update. Our "
          "times include the diagnostics (discarded count, min/mean cost).")
    print(f"load average {os.getloadavg()[0]:.2f} at end")


if __name__ == "__main__":
    main()
