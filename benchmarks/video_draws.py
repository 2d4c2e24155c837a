"""Does the estimator's bare default recover the law of videos it was never tuned on?

Each draw is a video from the family of :mod:`latent_sindy.worlds.pendulum.video_draws`
(a damped pendulum, a damped spring, or two pendulums side by side, filmed with every
layout choice drawn at random), fitted with nothing but the default:

    LatentSINDy(latent_dim=d, time="continuous", derivative_order=2, seed=0).fit(video)

once with the video's exact derivatives and once on its frames alone (``--derivatives``).
A draw is recovered when every true term is present with its coefficient within 5 % (the
friction term within 10 %) and no other term is. One JSON line per fit (``--out``: appended;
fits already there are skipped, so a killed run resumes), then the table and the count.
Draw i of ``--seed S`` is the same video on any machine: rerun one with ``--only i``.

    python benchmarks/video_draws.py --draws 20 --seed 0 --out draws0.jsonl --workers 2
    python benchmarks/video_draws.py --smoke          # one tiny draw, two epochs (tests)

``--record results`` also writes one row per fit into the tracked result file
``results/pendulum-video/family-draws.csv`` under the model ``--label`` (then
``python -m latent_sindy.results_page`` regenerates RESULTS.md).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from latent_sindy.script_args import check_output_file, positive_int, seed_range

MODES = ("exact", "frames")
#: How each mode is named in the tracked result file's model column.
MODE_NAMES = {"exact": "exact derivatives", "frames": "frames alone"}


def video_of(seed: int, index: int, mode: str, smoke: bool = False,
             generator: str = "family") -> Any:
    """The draw ``index`` of ``seed`` (its frames; exact derivatives kept for "exact"), of
    the family or of the second generator (``benchmarks/second_generator.py``)."""
    import dataclasses

    import numpy as np

    if generator == "second":
        from second_generator import second_draw

        d = second_draw(np.random.default_rng([seed, index, 2]))
        d = dataclasses.replace(d, exact=(mode == "exact"), uint8=d.uint8 and mode != "exact")
        return d.shrunk(16, 6, 30) if smoke else d
    from latent_sindy.worlds.pendulum.video_draws import draw

    d = draw(np.random.default_rng([seed, index]))
    d = dataclasses.replace(d, exact=(mode == "exact"))
    if smoke:
        d = dataclasses.replace(d, size=16, trajectories=6, frames=30)
    return d


def one_fit(seed: int, index: int, mode: str, smoke: bool, save: str | None,
            generator: str = "family") -> dict:
    import torch

    from latent_sindy import LatentSINDy
    from latent_sindy.api import AllTermsPruned, UncertainLaw

    torch.set_num_threads(1)
    d = video_of(seed, index, mode, smoke, generator)
    t0 = time.perf_counter()
    video = d.video()
    t1 = time.perf_counter()
    est = LatentSINDy(latent_dim=d.latent_dim, time="continuous", derivative_order=2, seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            est.fit(video, **({"epochs": 2} if smoke else {}))
        except Exception as e:  # a fit that fails is a failure of the default: recorded
            return {"generator": generator, "seed": seed, "draw": index, "mode": mode,
                    "system": d.system,
                    "settings": d.to_dict(), "law": d.law_text(), "equations": [],
                    "recovered": False, "why": f"error: {type(e).__name__}: {e}",
                    "warnings": [], "fit_s": round(time.perf_counter() - t1, 1)}
    t2 = time.perf_counter()
    verdict = d.judge(est)
    if save:
        est.save(Path(save) / f"s{seed}-d{index}-{mode}")
    return {"generator": generator, "seed": seed, "draw": index, "mode": mode,
            "system": d.system, "settings": d.to_dict(), "law": d.law_text(),
            "equations": est.equations(),
            **verdict, "warnings": [str(w.message) for w in caught
                                    if not issubclass(w.category, DeprecationWarning)],
            "warned": any(issubclass(w.category, (UncertainLaw, AllTermsPruned))
                          for w in caught),
            "restarts": est.kept_.get("restarts"),
            "time_unit": est.record_["model"]["dynamics"].get("time_unit"),
            "data_s": round(t1 - t0, 1), "fit_s": round(t2 - t1, 1)}


def derivative_error(seed: int, index: int) -> str:
    """How far central differences of the draw's frames (as ``--derivatives central``
    takes them) are from its exact ẍ: ‖estimate − exact‖ / ‖exact‖ over every pixel."""
    import numpy as np

    from latent_sindy.models.derivatives import estimate_derivatives

    d = video_of(seed, index, "exact")
    v = d.video()
    ddx = estimate_derivatives(v.images, d.dt, 2, "central")[1]
    err = float(np.linalg.norm(ddx - v.images_ddot) / np.linalg.norm(v.images_ddot))
    omega = max(d.omega2) ** 0.5
    return (f"draw {index} {d.system:13s} dt·ω {d.dt * omega:.3f} noise {d.noise:.3f}: "
            f"central differences of the frames miss ẍ by {100 * err:.0f} %")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--draws", type=positive_int, default=20,
                   help="how many draws (0 .. draws-1)")
    p.add_argument("--only", type=seed_range, help="these draws instead: 3, 0..9 or 1,4,7")
    p.add_argument("--seed", type=int, default=0, help="the draws' seed")
    p.add_argument("--derivatives", default="exact,frames",
                   help="exact (the video's derivatives), frames (none given), or both")
    p.add_argument("--workers", type=positive_int, default=1,
                   help="fits at a time (one torch thread each)")
    p.add_argument("--out", type=Path, help="append one JSON line per fit; skip those there")
    p.add_argument("--save", help="save each fitted model under this folder")
    p.add_argument("--smoke", action="store_true", help="one tiny draw, two epochs (tests)")
    p.add_argument("--generator", choices=("family", "second"), default="family",
                   help="family: the library's video family; second: a generator written "
                        "apart from it for the same ranges (benchmarks/second_generator.py)")
    p.add_argument("--record", type=Path, metavar="DIR",
                   help="also write each fit's row into DIR/pendulum-video/family-draws.csv "
                        "(the tracked results: DIR is results)")
    p.add_argument("--label", default="default",
                   help="the model's name in the recorded rows (the mode is added to it)")
    p.add_argument("--derivative-error", action="store_true",
                   help="only print how far central differences of each draw's frames are "
                        "from its exact second derivative (no fit)")
    args = p.parse_args(argv)
    modes = args.derivatives.split(",")
    if not modes or any(m not in MODES for m in modes):
        p.error(f"--derivatives {args.derivatives!r}: use exact, frames or exact,frames")
    check_output_file(p, args.out, "--out")
    indices = [0] if args.smoke else (args.only or list(range(args.draws)))
    if args.derivative_error:
        for i in indices:
            print(derivative_error(args.seed, i), flush=True)
        return 0
    done: dict[tuple, dict] = {}
    if args.out is not None and args.out.exists():
        for line in args.out.read_text().splitlines():
            row = json.loads(line)
            if row.get("generator", "family") == args.generator:
                done[(row["seed"], row["draw"], row["mode"])] = row
    jobs = [(args.seed, i, m) for i in indices for m in modes]
    todo = [j for j in jobs if j not in done]
    rows = {j: done[j] for j in jobs if j in done}

    def keep(job: tuple, row: dict) -> None:
        rows[job] = row
        if args.out is not None:
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
        eq = " | ".join(row["equations"])
        print(f"draw {job[1]} {job[2]:6s} {row['system']:13s} "
              f"{'recovered' if row['recovered'] else 'NOT: ' + row['why']}  [{eq}]  "
              f"{row['fit_s']:.0f} s", flush=True)

    if args.workers == 1 or len(todo) <= 1:
        for job in todo:
            keep(job, one_fit(*job, args.smoke, args.save, args.generator))
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            futures = {pool.submit(one_fit, *job, args.smoke, args.save,
                                   args.generator): job for job in todo}
            for fut in futures:
                keep(futures[fut], fut.result())
    if args.record is not None:
        from latent_sindy.result_files import record_rows

        record_rows(args.record, "pendulum-video", "family-draws", [
            {"model": f"{args.label}, {MODE_NAMES[j[2]]}", "seed": j[0], "case": f"draw {j[1]}",
             "system": r["system"].replace("_", " "), "recovered": r["recovered"],
             "warned": r.get("warned", bool(r["warnings"])), "fit_s": r["fit_s"]}
            for j, r in rows.items()])
    for mode in modes:
        got = [rows[j] for j in jobs if j[2] == mode]
        print(f"{mode}: recovered {sum(r['recovered'] for r in got)} of {len(got)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
