"""SINDy on state data: our STLSQ against pysindy's STLSQ, exact recovery and fit time.

Two tables: noise-free transitions (below), then noisy ones (``--noise``, see
:func:`noisy_table`); ``--noise 0`` skips the second.

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

    PYTHONPATH=src .venv/bin/python benchmarks/fit_state.py [--seeds 5] [--repeats 5] \
        [--noise 0.01] [--window 10]
    PYTHONPATH=src .venv/bin/python benchmarks/fit_state.py --smoke   # Duffing, one seed (tests)
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
from scipy.signal import savgol_filter

from latent_sindy.script_args import parse_with_smoke
from latent_sindy.sindy import STLSQ, EnsembleSTLSQ
from latent_sindy.sindy.fit import (
    fit_trajectory_data,
    library_regression_data,
    window_regression_data,
)
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


def clean_table(args: argparse.Namespace) -> None:
    """Noise-free transitions: ours and pysindy's STLSQ per system and seed, with times."""
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
    for name, make in ((n, SYSTEMS[n]) for n in args.systems):
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


Fit = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
"""(Θ (N, p), target (N, m), seed) -> coefficients (p, m)."""


def _noisy(make: Callable[..., KnownSystem], seed: int, noise: float):
    """The system's 10 trajectories of 500 steps, measured with Gaussian noise of ``noise``
    times each state's standard deviation (seeded by 1000 + seed) on every state, so a
    measurement's noise enters the transition it ends and the one it starts.

    Returns (system, X (B, T+1, nz) noisy states, U (B, T, nu))."""
    system = make(seed=seed, n_traj=10, steps=500)
    nz, nu = system.Z.shape[1], system.U.shape[1]
    X = torch.cat([system.Z.view(10, 500, nz), system.Znext.view(10, 500, nz)[:, -1:]], dim=1)
    assert torch.equal(X[:, 1:-1], system.Znext.view(10, 500, nz)[:, :-1])
    gen = torch.Generator().manual_seed(1000 + seed)
    scale = X.reshape(-1, nz).std(dim=0)  # (nz,)
    X = X + noise * scale * torch.randn(X.shape, generator=gen, dtype=torch.float64)
    return system, X, system.U.view(10, 500, nu)


def _ps_ensemble(threshold: float, library: bool, n_models: int) -> Fit:
    def fit(th: np.ndarray, tg: np.ndarray, seed: int) -> np.ndarray:
        np.random.seed(seed)  # noqa: NPY002 (pysindy draws from numpy's global generator)
        opt = ps.EnsembleOptimizer(ps.STLSQ(threshold=threshold), bagging=True,
                                   library_ensemble=library, n_models=n_models)  # fmt: skip
        return opt.fit(th, tg).coef_.T

    return fit


def noisy_table(args: argparse.Namespace) -> None:
    """Noisy measurements: every method's exact recoveries over the seeds, per system.

    Each method fits either the one-step pairs of the noisy trajectories ("pairs"), the same
    after a Savitzky-Golay smoother (window 9, order 3) on each noisy trajectory ("smoothed"),
    or their windowed (integral) form of ``--window`` steps ("windows",
    ``window_regression_data``). worst err: the largest relative coefficient error over the
    true terms and the seeds, a missed term counting 1; terms: median active count.
    """
    w, k = args.window, args.models
    ours_ens = functools.partial(EnsembleSTLSQ, n_models=k)
    methods: dict[str, tuple[str, Fit]] = {
        "ours STLSQ()": ("pairs", lambda th, tg, s: STLSQ().fit(th, tg).coef_.numpy()),
        "ours STLSQ(), smoothed": ("smoothed", lambda th, tg, s: STLSQ().fit(th, tg).coef_.numpy()),
        f"ours EnsembleSTLSQ(n_models={k})": (
            "pairs", lambda th, tg, s: ours_ens(seed=s).fit(th, tg).coef_.numpy()),
        "ours STLSQ(), windows": ("windows", lambda th, tg, s: STLSQ().fit(th, tg).coef_.numpy()),
        f"ours EnsembleSTLSQ(n_models={k}, z_min=0), windows": (  # inclusion rule alone
            "windows", lambda th, tg, s: ours_ens(seed=s, z_min=0).fit(th, tg).coef_.numpy()),
        f"ours EnsembleSTLSQ(n_models={k}), windows": (
            "windows", lambda th, tg, s: ours_ens(seed=s).fit(th, tg).coef_.numpy()),
        "ours fit_trajectory_data(library, X, U), defaults": (
            "trajectories", lambda lib, xu, s: fit_trajectory_data(lib, *xu).coef_.numpy()),
    }  # fmt: skip
    for t in (args.ps_threshold, 3 * args.ps_threshold):
        methods[f"ps STLSQ({t:g})"] = (
            "pairs", lambda th, tg, s, t=t: ps.STLSQ(threshold=t).fit(th, tg).coef_.T)  # fmt: skip
    t = args.ps_threshold
    methods[f"ps Ensemble(STLSQ({t:g}), bagging)"] = ("pairs", _ps_ensemble(t, False, k))
    methods[f"ps Ensemble(STLSQ({t:g}), bagging+library)"] = ("pairs", _ps_ensemble(t, True, k))
    methods[f"ps STLSQ({t:g}), windows"] = (
        "windows", lambda th, tg, s: ps.STLSQ(threshold=t).fit(th, tg).coef_.T)  # fmt: skip
    methods[f"ps Ensemble(STLSQ({t:g}), bagging), windows"] = ("windows", _ps_ensemble(t, False, k))
    print(
        f"\nnoisy: {args.noise:g} x each state's std on every measurement, "
        f"{args.seeds} seeds, windows of {w} steps"
    )
    print(f"{'system':8} {'method':50} {'exact':>5} {'worst err':>9} {'terms':>5} {'ms':>7}")
    for name, make in ((n, SYSTEMS[n]) for n in args.systems):
        results: dict[str, list[tuple[bool, float, int, float]]] = {m: [] for m in methods}
        for seed in range(args.seeds):
            system, X, U = _noisy(make, seed, args.noise)
            true = system.true_coefficients().numpy()
            smooth = torch.as_tensor(savgol_filter(X.numpy(), 9, 3, axis=1))
            problems = {
                "pairs": window_regression_data(system.library, X, U, 1),
                "smoothed": window_regression_data(system.library, smooth, U, 1),
                "windows": window_regression_data(system.library, X, U, w),
            }
            problems = {key: (a.numpy(), b.numpy()) for key, (a, b) in problems.items()}
            problems["trajectories"] = (system.library, (X, U))  # the fit as users call it
            for method, (form, fit) in methods.items():
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    coef = np.asarray(fit(*problems[form], seed))
                ms = 1e3 * (time.perf_counter() - t0)
                exact, _ = _score(coef, true)
                err = _missed_error(coef, true)
                results[method].append((exact, err, int((coef != 0).sum()), ms))
        for method, rows in results.items():
            print(
                f"{name:8} {method:50} {sum(r[0] for r in rows):>3}/{len(rows)} "
                f"{max(r[1] for r in rows):>9.3f} {statistics.median(r[2] for r in rows):>5.0f} "
                f"{statistics.median(r[3] for r in rows):>7.1f}"
            )


def _missed_error(coef: np.ndarray, true: np.ndarray) -> float:
    """Largest relative error over the true terms of ``coef`` (p, m); a missed term counts 1."""
    active = true != 0
    return float(np.max(np.abs(coef[active] - true[active]) / np.abs(true[active])))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="data seeds per system")
    ap.add_argument("--repeats", type=int, default=5, help="timed fits per row (best kept)")
    ap.add_argument("--ps-threshold", type=float, default=1e-3,
                    help="pysindy's tuned absolute threshold")  # fmt: skip
    ap.add_argument(
        "--noise",
        type=float,
        default=0.01,
        help="noisy table: measurement noise, a share of each state's std (0: skip)",
    )
    ap.add_argument("--window", type=int, default=10, help="noisy table: steps per window")
    ap.add_argument("--models", type=int, default=20, help="noisy table: models per ensemble")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    args = parse_with_smoke(ap, argv, {"seeds": 1, "repeats": 1, "models": 2,
                                       "systems": ["duffing"]})
    torch.set_num_threads(args.threads)
    clean_table(args)
    if args.noise > 0:
        noisy_table(args)


if __name__ == "__main__":
    main()
