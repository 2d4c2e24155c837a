"""SINDy on state data: our STLSQ against pysindy's STLSQ, exact recovery and fit time.

For each known system of :mod:`latent_sindy.sindy.systems` (Euler-discretised Lorenz with a
control input, forced Duffing oscillator with the forcing phase as an input; 5000 noise-free
transitions each) and each data seed, both optimisers fit the same problem: the same library
matrix Θ(Z, U) (our library, float64) and the same target Znext − Z. Printed per row:

  * exact: the active set equals the true one; err: the largest relative coefficient error
    over the true terms (exact rows only);
  * ms: the best over ``--repeats`` of the optimiser's fit time on that Θ (the library is
    evaluated once, its time shown apart); ratio: pysindy's time / ours;
  * pysindy twice: with its defaults (``STLSQ()``, absolute threshold 0.1) and with an
    absolute threshold tuned to these systems' coefficient sizes (``--ps-threshold``).

    PYTHONPATH=src .venv/bin/python benchmarks/fit_state.py [--seeds 5] [--repeats 5]
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
import warnings
from collections.abc import Callable
from importlib.metadata import version
from typing import Any

import numpy as np
import pysindy as ps
import torch

from latent_sindy.sindy import STLSQ
from latent_sindy.sindy.fit import library_regression_data
from latent_sindy.sindy.systems import KnownSystem, duffing_forced, lorenz_control

SYSTEMS: dict[str, Callable[..., KnownSystem]] = {
    "lorenz": lorenz_control,
    "duffing": duffing_forced,
}


def _best_ms(make: Callable[[], Any], x: Any, y: Any, repeats: int) -> tuple[float, Any]:
    """Best time of ``make().fit(x, y)`` over ``repeats`` (ms), and the last fitted object."""
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = make().fit(x, y)
        best = min(best, time.perf_counter() - t0)
    return 1e3 * best, out


def _score(coef: np.ndarray, true: np.ndarray) -> tuple[bool, float]:
    """(exact active set, largest relative error over the true terms); coef, true (p, m)."""
    active = true != 0
    exact = bool(np.array_equal(coef != 0, active))
    err = float(np.max(np.abs(coef[active] - true[active]) / np.abs(true[active])))
    return exact, err


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="data seeds per system")
    ap.add_argument("--repeats", type=int, default=5, help="timed fits per row (best kept)")
    ap.add_argument("--ps-threshold", type=float, default=1e-3,
                    help="pysindy's tuned absolute threshold")  # fmt: skip
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    tuned_ps = functools.partial(ps.STLSQ, threshold=args.ps_threshold)
    print(
        f"torch {torch.__version__}, pysindy {version('pysindy')}, {args.threads} torch "
        f"thread(s); ours: {STLSQ()}; pysindy: STLSQ() and STLSQ(threshold={args.ps_threshold:g})"
    )
    header = (
        f"{'system':8} {'seed':>4} {'p':>3} {'lib ms':>6} | {'ours':>5} {'err':>8} {'ms':>6} | "
        f"{'ps()':>5} {'ms':>6} {'ratio':>6} | {'ps(tuned)':>9} {'err':>8} {'ms':>6} {'ratio':>6}"
    )
    print(header)
    yes = {True: "yes", False: "no"}
    counts = {"ours": 0, "ps": 0, "ps_tuned": 0}
    ratios: dict[str, list[float]] = {"ps": [], "ps_tuned": []}
    rows = 0
    for name, make in SYSTEMS.items():
        for seed in range(args.seeds):
            system = make(seed=seed)
            true = system.true_coefficients().numpy()
            t0 = time.perf_counter()
            theta, target = library_regression_data(
                system.library, system.Z, system.U, system.Znext
            )
            lib_ms = 1e3 * (time.perf_counter() - t0)
            th, tg = theta.numpy(), target.numpy()
            ms, opt = _best_ms(STLSQ, theta, target, args.repeats)
            exact, err = _score(opt.coef_.numpy(), true)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pysindy warns when it prunes every term
                ps_ms, ref = _best_ms(ps.STLSQ, th, tg, args.repeats)
                tuned_ms, tuned = _best_ms(tuned_ps, th, tg, args.repeats)
            ps_exact, _ = _score(ref.coef_.T, true)
            tuned_exact, tuned_err = _score(tuned.coef_.T, true)
            counts["ours"] += exact
            counts["ps"] += ps_exact
            counts["ps_tuned"] += tuned_exact
            ratios["ps"].append(ps_ms / ms)
            ratios["ps_tuned"].append(tuned_ms / ms)
            rows += 1
            print(
                f"{name:8} {seed:>4} {theta.shape[1]:>3} {lib_ms:>6.1f} | {yes[exact]:>5} "
                f"{err if exact else float('nan'):>8.1e} {ms:>6.2f} | {yes[ps_exact]:>5} "
                f"{ps_ms:>6.2f} {ps_ms / ms:>5.1f}x | {yes[tuned_exact]:>9} "
                f"{tuned_err if tuned_exact else float('nan'):>8.1e} {tuned_ms:>6.2f} "
                f"{tuned_ms / ms:>5.1f}x"
            )
    med = {k: statistics.median(v) for k, v in ratios.items()}
    print(
        f"exact recovery: ours {counts['ours']}/{rows}, pysindy defaults {counts['ps']}/{rows}, "
        f"pysindy tuned {counts['ps_tuned']}/{rows}; median time ratio pysindy/ours: defaults "
        f"{med['ps']:.1f}x, tuned {med['ps_tuned']:.1f}x"
    )


if __name__ == "__main__":
    main()
