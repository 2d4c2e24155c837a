"""What backward elimination (StepwiseSR) costs beside STLSQ, and what it buys on a circle.

Two parts, in one process, one torch thread:

1. Time: both sparsifiers on polynomial libraries of random states and inputs (N rows, a
   target of the linear terms plus noise), at growing library sizes; the ratio is StepwiseSR's
   time over STLSQ's.
2. Terms kept where the library is dependent: states on circles (two points on the unit
   circle, as the pendulum's two frame centroids), a target that is a cubic law of them plus
   noise, an order-4 library: the terms each sparsifier keeps.

    .venv/bin/python benchmarks/sparsifiers.py
"""

from __future__ import annotations

import argparse
import time

import torch

from latent_sindy.sindy import STLSQ, Polynomial, SindyLibrary, StepwiseSR


def _timed(opt, theta, target) -> tuple[float, int]:
    t0 = time.perf_counter()
    opt.fit(theta, target)
    return time.perf_counter() - t0, int(opt.mask_.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(args.seed)

    print("time: library (states, inputs, order) | terms p | columns | STLSQ s | StepwiseSR s "
          "| ratio")
    for nz, nu, order in ((4, 1, 3), (4, 1, 4), (8, 3, 3), (16, 3, 2)):
        lib = SindyLibrary(Polynomial("z,u", order), nz, nu)
        z = torch.randn(args.rows, nz, generator=gen, dtype=torch.float64)
        u = torch.randn(args.rows, nu, generator=gen, dtype=torch.float64)
        theta = lib(z, u)
        target = 0.5 * z + 0.01 * torch.randn(args.rows, nz, generator=gen, dtype=torch.float64)
        a, _ = _timed(STLSQ(min_share=0.01), theta, target)
        b, _ = _timed(StepwiseSR(1e-4, complexity=lib.degrees), theta, target)
        print(f"  ({nz}, {nu}, {order}) | {lib.n_terms} | {nz} | {a:.3f} | {b:.3f} | {b / a:.0f}")

    print("\nterms kept on circles (order-4 library of (p, q), a law of 8 terms + noise 1e-4):")
    angle = torch.rand(args.rows, 2, generator=gen, dtype=torch.float64) * 6.2832
    z = torch.cat([angle[:, :1].cos(), angle[:, :1].sin(),
                   angle[:, 1:].cos(), angle[:, 1:].sin()], 1)  # q, p on unit circles
    lib = SindyLibrary(Polynomial("z", 4), 4, 0)
    theta = lib(z)
    q, p = z[:, :2], z[:, 2:]
    dot = (p * q).sum(1, keepdim=True)
    law = 2 * dot * p - q - p  # a steady turn's step, p' - p, written in (p, q)
    target = law + 1e-4 * torch.randn(law.shape, generator=gen, dtype=torch.float64)
    for name, opt in (("STLSQ 0.01", STLSQ(min_share=0.01)),
                      ("STLSQ 0.1", STLSQ(min_share=0.1)),
                      ("StepwiseSR 1e-4, no complexity", StepwiseSR(1e-4)),
                      ("StepwiseSR 1e-4, by degree", StepwiseSR(1e-4, complexity=lib.degrees))):
        seconds, kept = _timed(opt, theta, target)
        err = float((theta @ opt.coef_ - target).square().mean() / target.square().mean())
        print(f"  {name}: {kept} of {opt.mask_.numel()} terms, relative residual {err:.1e}, "
              f"{seconds:.2f} s")


if __name__ == "__main__":
    main()
