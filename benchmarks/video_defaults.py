"""Does the estimator with nothing but its defaults recover a pendulum video's law?

For each seed: the benchmark's video (100/10/10 trajectories of 51x51 frames, every 5th of
500, exact derivatives) of θ̈ = −ω² sin θ at ``--omega2``, then

    LatentSINDy(latent_dim=1, time="continuous", derivative_order=2, seed=seed).fit(video)

on the raw frames, and whether its equation is z̈ = c sin z with c within 2 % of −ω². One
JSON line per seed (``--out``: appended, and seeds already there are skipped, so a killed
run resumes), then the count.

    python benchmarks/video_defaults.py --omega2 1.44 --seeds 0..9 --out video144.jsonl
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from latent_sindy.script_args import check_output_file, positive_float, seed_range


def one_seed(omega2: float, seed: int, starts: str) -> dict:
    import torch

    from latent_sindy import LatentSINDy
    from latent_sindy.worlds.pendulum.video import pendulum_video

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    video = pendulum_video(omega2=omega2, frames_every=5, starts=starts)
    t1 = time.perf_counter()
    est = LatentSINDy(latent_dim=1, time="continuous", derivative_order=2, seed=seed)
    est.fit(video)
    t2 = time.perf_counter()
    names, coef = est.get_feature_names(), est.coefficients()[0]
    active = [n for n, c in zip(names, coef, strict=True) if c != 0]
    c = float(coef[names.index("sin(z0)")]) if active == ["sin(z0)"] else None
    return {"omega2": omega2, "starts": starts, "seed": seed, "equation": est.equations()[0],
            "coefficient": c, "recovered": c is not None and abs(c / omega2 + 1) <= 0.02,
            "time_unit": est.record_["model"]["dynamics"]["time_unit"],
            "components": est.record_["model"]["observation"]["pca_components"],
            "restarts": est.kept_.get("restarts"), "data_s": round(t1 - t0, 1),
            "fit_s": round(t2 - t1, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--omega2", type=positive_float, default=1.44, help="ω² of θ̈ = −ω² sin θ")
    p.add_argument("--seeds", type=seed_range, default=[0], help="model seeds: 0..9 or 0,3,5")
    p.add_argument("--starts", default="own_time", choices=["own_time", "benchmark"])
    p.add_argument("--out", type=Path, help="append one JSON line per seed; skip those there")
    args = p.parse_args(argv)
    # every mistake is refused here, before the first seed (argparse's line, exit status 2)
    if args.starts == "benchmark" and args.omega2 < 1:
        p.error(f"--starts benchmark with --omega2 {args.omega2}: use --omega2 >= 1 (below, "
                "some of its starts turn full circles), or --starts own_time")
    check_output_file(p, args.out, "--out")
    done = {}
    if args.out is not None and args.out.exists():
        for number, line in enumerate(args.out.read_text().splitlines(), 1):
            try:
                row = json.loads(line)
                key = (row["omega2"], row["starts"], row["seed"])
            except (ValueError, TypeError, KeyError):
                p.error(f"--out {args.out}: line {number} is not a row this script wrote; "
                        "choose another file")
            if key[:2] == (args.omega2, args.starts):
                done[row["seed"]] = row
    rows = []
    for seed in args.seeds:
        row = done.get(seed) or one_seed(args.omega2, seed, args.starts)
        if seed not in done and args.out is not None:
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
        rows.append(row)
        print(f"seed {seed}: {row['equation']}  recovered {'yes' if row['recovered'] else 'no'}"
              f"  {row['fit_s']:.0f} s", flush=True)
    print(f"recovered {sum(r['recovered'] for r in rows)} of {len(rows)} at ω² = {args.omega2}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
