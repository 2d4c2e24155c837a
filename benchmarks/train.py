"""Training speed and memory of the latent models on synthetic images (no data file needed).

One training step = LatentModel.loss (encode H+1 frames, roll out H latent steps, decode
2H+1 frames) + backward + AdamW step, on a batch of random 1×32×32 images and actions.
Every (model, H) runs in a fresh subprocess so its memory figure is its own:

  * samples/s: batch / median step time over ``--repeats`` timed steps (after 2 warm-up),
    and "best": batch / fastest step, the figure least disturbed by other jobs on the CPUs;
  * peak ΔRSS: the process's peak resident set size (``resource.getrusage`` ru_maxrss)
    minus its resident size just before the first step (model, optimizer and batch already
    allocated), i.e. the extra memory a training step needs (activations, gradients, AdamW
    moments); CPU only, tracemalloc cannot see torch's allocator.

``--wins`` adds a second table: what the thread count, the encoder's channels-last layout
(the default; "nchw" is the plain layout) and torch.compile of the loss buy.

    .venv/bin/python benchmarks/train.py --threads 2 --repeats 5
    .venv/bin/python benchmarks/train.py --cases sindy2 linear --horizons 1 --wins
    .venv/bin/python benchmarks/train.py --smoke         # SINDy-2, batch 8, one step (the tests)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

from latent_sindy.script_args import parse_with_smoke

CASES = ("sindy1", "sindy2", "sindy3", "sindy4", "linear", "mlp")
VARIANTS = ("default", "nchw", "compile")


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(case: str, horizon: int, batch: int, repeats: int, threads: int, variant: str) -> dict:
    """Time training steps of one model in this process; returns the figures as a dict."""
    import torch

    from latent_sindy.models import DYNAMICS_KINDS, LatentModel, ModelConfig, SindyConfig

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    dynamics = (SindyConfig(order=int(case[5])) if case.startswith("sindy")
                else DYNAMICS_KINDS[case]())
    model = LatentModel(ModelConfig(dynamics=dynamics).resolve(1, 32, 3))
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    x = torch.randn(batch, horizon + 1, 1, 32, 32)  # (B, H+1, C, S, S)
    u = torch.rand(batch, horizon, 3)  # (B, H, nu)
    loss_fn = model.loss
    if variant == "nchw":  # undo the encoder's channels-last weights (the plain layout)
        model.autoencoder.encoder.to(memory_format=torch.contiguous_format)
    elif variant == "compile":
        loss_fn = torch.compile(model.loss)

    def step() -> None:
        terms = loss_fn(x, u)
        opt.zero_grad(set_to_none=True)
        terms["total"].backward()
        opt.step()

    rss0 = _rss_mb()
    t0 = time.perf_counter()
    step()  # the first call compiles (compile variant) and allocates the AdamW moments
    first = time.perf_counter() - t0
    step()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB -> MB on Linux
    med = statistics.median(times)
    terms = model.dynamics.library.n_terms if hasattr(model.dynamics, "library") else None
    return {
        "case": case,
        "H": horizon,
        "variant": variant,
        "threads": threads,
        "samples_s": batch / med,
        "best_s": batch / min(times),
        "step_ms": 1e3 * med,
        "first_s": first,
        "peak_drss_mb": peak - rss0,
        "terms": terms,
        "params": sum(p.numel() for p in model.parameters()),
    }


def run_child(
    case: str, horizon: int, args: argparse.Namespace, threads: int, variant: str = "default"
) -> dict:
    cmd = [
        sys.executable,
        __file__,
        "--child",
        case,
        str(horizon),
        variant,
        "--batch",
        str(args.batch),
        "--repeats",
        str(args.repeats),
        "--threads",
        str(threads),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
    if out.returncode:
        return {
            "case": case,
            "H": horizon,
            "variant": variant,
            "threads": threads,
            "error": (out.stderr.strip().splitlines() or ["?"])[-1][:60],
        }
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    p.add_argument("--repeats", type=int, default=5, help="timed steps per model (median)")
    p.add_argument("--batch", type=int, default=500, help="windows per step (paper: 500)")
    p.add_argument("--horizons", type=int, nargs="+", default=[1, 4])
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    p.add_argument("--wins", action="store_true", help="also try threads, layout, compile")
    p.add_argument("--timeout", type=float, default=600, help="seconds per subprocess")
    p.add_argument("--child", nargs=3, metavar=("CASE", "H", "VARIANT"), help=argparse.SUPPRESS)
    args = parse_with_smoke(p, argv, {"threads": 1, "repeats": 1, "batch": 8, "horizons": [1],
                                      "cases": ["sindy2"]})
    if args.child:
        case, h, variant = args.child
        print(json.dumps(measure(case, int(h), args.batch, args.repeats, args.threads, variant)))
        return

    load = os.getloadavg()
    print(
        f"training step = loss + backward + AdamW, batch {args.batch}, 1x32x32 images, "
        f"nz 16, {args.threads} thread(s), median of {args.repeats}; "
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs"
    )
    print(
        f"{'model':<8} {'H':>2} {'terms':>6} {'params':>8} {'samples/s':>10} {'best':>6} "
        f"{'ms/step':>8} {'peak dRSS MB':>13}"
    )
    for case in args.cases:
        for h in args.horizons:
            r = run_child(case, h, args, args.threads)
            if "error" in r:
                print(f"{case:<8} {h:>2} failed: {r['error']}")
                continue
            print(
                f"{case:<8} {h:>2} {r['terms'] or '-':>6} {r['params']:>8} "
                f"{r['samples_s']:>10.0f} {r['best_s']:>6.0f} {r['step_ms']:>8.1f} "
                f"{r['peak_drss_mb']:>13.0f}"
            )
    if not args.wins:
        return
    print(
        f"\ncheap wins (H = 1; load average now {os.getloadavg()[0]:.2f}): best samples/s "
        "relative to the default (channels-last encoder, eager) with the same threads; "
        "'first s' = first step, compile time included"
    )
    print(
        f"{'model':<8} {'variant':<14} {'threads':>7} {'samples/s':>10} {'best':>6} "
        f"{'x default':>9} {'first s':>8}"
    )
    for case in [c for c in ("sindy2", "sindy4", "mlp") if c in args.cases]:
        for threads in sorted({1, args.threads}):
            base = None
            for variant in VARIANTS:
                r = run_child(case, 1, args, threads, variant)
                if "error" in r:
                    print(f"{case:<8} {variant:<14} {threads:>7} failed: {r['error']}")
                    continue
                base = base or r["best_s"]
                print(
                    f"{case:<8} {variant:<14} {threads:>7} {r['samples_s']:>10.0f} "
                    f"{r['best_s']:>6.0f} {r['best_s'] / base:>9.2f} {r['first_s']:>8.1f}"
                )
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
