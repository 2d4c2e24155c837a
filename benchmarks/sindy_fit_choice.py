"""SINDy's fit on a learned reader's latent, as set or checked on held-out episodes, judged
by how it predicts episodes neither saw, over the planner's horizon.

``--study OUT --seed S`` takes a model-based study's own latent and episodes (``latent-sindy
reproduce --world dmc|gym`` on a geodesic or keypoints scale; a keypoint reader's fit loads
from ``OUT/readers``, so nothing is trained again). ``ReadLatent`` is fitted on the seed's
first ``--train`` share of episodes three times, as the study fits it: the set fit (the
scale's window, 30 % trimmed, its min_share) unchecked; checked on a fifth of those
episodes held out, replaced where its rollouts diverge (``ReadLatentConfig.select``, the
default); and the sparsest of the 18 fits within 2 of the best held-out error
(``sparsest_within=2.0``, the ``keypoints8-sparse-100k`` scale's). Each is rolled out on the
remaining episodes from every frame whose horizon is seen:
printed per fit are its active terms, the capped mean squared error over the horizon and
the share of rollouts diverged within it (``held_out_rollouts``, standardised latent), and
the fit's seconds (the reader's reading of the frames included, the same for each).

    python benchmarks/sindy_fit_choice.py --study runs/kp8_100k --seed 0
    python benchmarks/sindy_fit_choice.py --smoke --study OUT   # one thread (the tests)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from latent_sindy.errors import UserError
from latent_sindy.read_latent import ReadLatent, ReadLatentConfig, held_out_rollouts
from latent_sindy.script_args import parse_with_smoke


def compare(out: Path, seed: int, train: float) -> list[dict]:
    """The rows of the module docstring for the study in ``out`` at ``seed``."""
    from latent_sindy.study.model_based import study_latent

    _, s, make, data = study_latent(out, seed)
    n_train = round(train * data.n)
    if not 5 <= n_train < data.n:
        raise UserError(f"--train {train}: {n_train} of the seed's {data.n} episodes; fit "
                        "on at least 5 and leave some to predict")
    fitted_on = data.subset(np.arange(data.n) < n_train)
    base = ReadLatentConfig(order=s.order, window=s.window, min_share=s.min_share,
                            reward_width=s.reward_head, reader_episodes=s.seed_episodes,
                            support=s.support, horizon=s.horizon, updates=300)
    images = torch.from_numpy(np.asarray(data.images))[n_train:]
    actions = torch.from_numpy(np.asarray(data.actions, np.float64))[n_train:]
    rows = []
    for name, cfg in (("fixed", dataclasses.replace(base, select=False)),
                      ("checked", dataclasses.replace(base, select=True)),
                      ("sparsest within 2", dataclasses.replace(base, select=True,
                                                                 sparsest_within=2.0))):
        t0 = time.perf_counter()
        est = ReadLatent(make(), cfg, seed=seed).fit(fitted_on)
        seconds = time.perf_counter() - t0
        read = [est.reader.episode(images[e], actions[e], est.dt) for e in range(len(images))]
        Z = (torch.stack([z for z, _ in read]) - est.mean) / est.sd
        seen = torch.stack([v for _, v in read])
        held = held_out_rollouts(est.model, Z, actions, seen, s.horizon)
        choice = est.selection_
        setting = choice.setting if choice else None
        rows.append({"fit": name, "terms": int(np.count_nonzero(est.coefficients())),
                     "error": held.error, "diverged": held.diverged, "seconds": seconds,
                     "setting": (f"window {setting.window}, trim {setting.trim:g}, min_share "
                                 f"{setting.min_share:g}") if setting else
                                f"window {cfg.window}, trim {cfg.trim:g}, min_share "
                                f"{cfg.min_share:g}",
                     "table": choice.table() if choice else ""})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--study", type=Path, default=None, metavar="OUT",
                   help="the model-based study (a geodesic or keypoints scale's folder)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--train", type=float, default=0.8,
                   help="share of the seed's episodes the fits see (the rest are predicted)")
    p.add_argument("--threads", type=int, default=1)
    args = parse_with_smoke(p, argv, {"threads": 1})
    torch.set_num_threads(args.threads)
    if args.study is None:
        p.error("give --study OUT: a geodesic or keypoints scale's study folder")
    try:
        rows = compare(args.study, args.seed, args.train)
    except UserError as e:
        raise SystemExit(f"sindy_fit_choice: {e}") from None
    print(f"SINDy on the latent of {args.study}, seed {args.seed}: fitted on "
          f"{args.train:.0%} of its episodes, predicting the rest over the planner's horizon")
    print("| fit | setting | terms | capped error | diverged | fit s |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['fit']} | {r['setting']} | {r['terms']} | {r['error']:.4g} | "
              f"{r['diverged']:.1%} | {r['seconds']:.1f} |")
    chosen = rows[1]
    if chosen["table"]:
        print("the check (each setting tried, on the fifth of the fitted episodes held out):")
        print(chosen["table"])
    print(f"fit time checked/fixed: {chosen['seconds'] / rows[0]['seconds']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
