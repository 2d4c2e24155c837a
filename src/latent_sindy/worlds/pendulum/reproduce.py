"""The pendulum studies as ``latent-sindy reproduce`` runs them: their scales, and what each
hands back for the common report (tables, figures, equations, every number).

``reproduce --world pendulum-video`` runs :func:`.video_study.run_video_study` and
``reproduce --world pendulum`` runs :func:`.study.compare_swing_ups`, at a scale named here; the
plug-ins (:mod:`.plugin`) call :func:`pendulum_video_study` and :func:`pendulum_study`, and the
command writes summary.json, table.md, report.html and equations_*.txt from the
:class:`WorldStudy` they return (it knows nothing of pendulums).

    latent-sindy reproduce --world pendulum-video --scale tiny --out /tmp/pv
    latent-sindy reproduce --world pendulum --scale demo --out results/pendulum
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from latent_sindy.atomic import atomic_path, write_atomic
from latent_sindy.configs import to_json
from latent_sindy.errors import UserError
from latent_sindy.training.config import resolve_device
from latent_sindy.world_study import Table, WorldStudy

__all__ = ["PENDULUM_SCALES", "VIDEO_SCALES", "Table", "WorldStudy", "pendulum_config",
           "pendulum_study", "pendulum_video_study", "video_config"]

Say = Callable[[str], None]

VIDEO_SCALES = {
    "tiny": "seconds, for tests: 4/2/2 trajectories of 50 frames, 8 components, 3 epochs of "
            "the uncalibrated schedule, seed 0",
    "demo": "the scalefree schedule (250 + 50 + 300 epochs, every 5th frame, 48 "
            "components) on seeds 0..2; about 10 minutes a seed on a CPU core",
    "recovery": "the scalefree schedule on seeds 0..9: the ten-seed recovery rate on a CPU",
    "recovery-frames": "as recovery, with the image derivatives taken by central differences "
                       "of the frames instead of exactly",
    "published": "the published schedule (6002 epochs, batch 1000, every frame) on seeds "
                 "0..9, 48 components: for a CUDA device",
}
PENDULUM_SCALES = {
    "tiny": "seconds, for tests: 12 sequences of 3 steps at 16x16, 1 epoch, 2 swing-ups of 4 "
            "steps; seed 0 unless --seeds (each seed a whole study)",
    "demo": "the study's defaults: 400 sequences of 12 steps at 16x16, 40 epochs, 50 swing-ups "
            "of 100 steps",
    "published": "48x48 images as E2C: 1000 sequences of 12 steps, 100 epochs, 50 swing-ups "
                 "of 100 steps",
    "published-cpu": "the published camera and data without the autoencoder rows (hours "
                     "of training on a CPU): the state row and the centroid-latent rows, "
                     "about 10 minutes a seed on a CPU core",
    "geodesic": "as demo, the SINDy, MLP and linear rows planning on a latent learned from "
                "the training frames alone (each frame's angle of its geodesic coordinates) "
                "in the place of the intensity centroid, the cost's graph with 16 neighbours; "
                "no autoencoder or state rows",
    "geodesic-published": "as published-cpu, on the latent learned from the frames alone "
                          "(geodesic) in the place of the centroid",
}


def _scale(scale: str, scales: dict[str, str], world: str) -> None:
    if scale not in scales:
        raise UserError(f"--scale {scale}: the {world} world's scales are "
                        f"{', '.join(scales)}")


def _figure(rows: int, cols: int, size: tuple[float, float]):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    return path


# ----------------------------------------------------------------------------- the video
def video_config(scale: str, seeds: tuple[int, ...] | None, device: str, threads: int,
                 omega2: float = 1.0, starts: str = "own_time"):
    """The :class:`~.video_study.VideoStudyConfig` of a scale (``seeds`` None: the scale's)
    for the video at ``omega2`` with its ``starts``."""
    from latent_sindy.worlds.pendulum.video_study import VideoStudyConfig

    _scale(scale, VIDEO_SCALES, "pendulum-video")
    base = {"tiny": dict(seeds=(0,), schedule="uncalibrated", components=8, epochs=3,
                         splits=(4, 2, 2), steps=50),
            "demo": dict(seeds=(0, 1, 2), schedule="scalefree"),
            "recovery": dict(seeds=tuple(range(10)), schedule="scalefree"),
            "recovery-frames": dict(seeds=tuple(range(10)), schedule="scalefree",
                                    derivatives="central"),
            "published": dict(seeds=tuple(range(10)), schedule="published")}[scale]
    if seeds:
        base["seeds"] = tuple(seeds)
    return VideoStudyConfig(**base, device=device, threads=threads, omega2=omega2,
                            starts=starts)


def _video_figure(rows: list[dict[str, Any]], path: Path) -> Path:
    """Left: each seed's test z̈ FVU (log), the published and replicated lines; right: each
    seed's coefficients (sin z's at -1 when recovered)."""
    from latent_sindy.worlds.pendulum.video_study import PUBLISHED, REPLICATED

    fig, axes = _figure(1, 2, (11, 3.8))
    ax, ax2 = axes[0]
    seeds = [str(r["seed"]) for r in rows]
    colours = ["tab:green" if r["recovered"] else "tab:red" for r in rows]
    ax.bar(seeds, [max(r["fvu_ddz"], 1e-12) for r in rows], color=colours)
    ax.axhline(PUBLISHED["fvu_ddz"], color="k", ls="--", lw=1, label="published (best of 10)")
    ax.axhline(REPLICATED["fvu_ddz"][0], color="gray", ls=":", lw=1,
               label="replication (mean of 10)")
    ax.set(yscale="log", xlabel="seed", ylabel="test FVU of z̈",
           title="z̈ error per seed (green: recovered)")
    ax.legend(fontsize=7)
    names = list(rows[0]["coefficients"])
    coef = np.array([[r["coefficients"][n] for n in names] for r in rows])  # (seeds, terms)
    lim = max(float(np.abs(coef).max()), 1e-9)
    im = ax2.imshow(coef, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    ax2.set_xticks(range(len(names)), names, rotation=60, fontsize=7)
    ax2.set_yticks(range(len(rows)), seeds)
    ax2.set(ylabel="seed", title="z'' coefficients per seed (0: pruned)")
    fig.colorbar(im, ax=ax2)
    return _save(fig, path)


def pendulum_video_study(scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                         device: str = "auto", threads: int = 1, say: Say = print,
                         omega2: float = 1.0, starts: str = "own_time") -> WorldStudy:
    """The pendulum-video recovery study at ``scale`` in ``out`` (finished seeds reused), of
    the video at ``omega2`` (θ̈ = −ω² sin θ) with its ``starts``."""
    from latent_sindy.worlds.pendulum.video_study import run_video_study, to_record

    cfg = video_config(scale, seeds, device, threads, omega2, starts)
    video = "" if omega2 == 1 else f" at ω² = {omega2:g} ({starts} starts)"
    say(f"pendulum video{video}, {scale} scale: schedule {cfg.schedule}, seeds "
        f"{', '.join(map(str, cfg.seeds))}, {cfg.components} components, derivatives "
        f"{cfg.derivatives}, device {resolve_device(cfg.device)}")
    result = run_video_study(cfg, out, say)
    record = to_record(result)
    s = record["summary"]
    med = record["summary"]["median"]
    pub, rep = s["published"], s["replicated"]

    def e(v: float | None) -> str:
        return "-" if v is None or not math.isfinite(v) else f"{v:.1e}"

    per_seed = [[str(r["seed"]), r["equation"], "yes" if r["exact_sin"] else "no",
                 "-" if r["coefficient"] is None else f"{r['coefficient']:+.4f}",
                 "yes" if r["recovered"] else "no", e(r["fvu_x"]), e(r["fvu_ddx"]),
                 e(r["fvu_ddz"]), f"{r['time_s']:.0f}"] for r in result.rows]
    summary = [[f"this run ({cfg.schedule}, {len(result.rows)} seeds, median)",
                f"{s['recovered']} of {s['seeds']}", e(med["fvu_x"]), e(med["fvu_ddx"]),
                e(med["fvu_ddz"])],
               ["published (best of 10)", "-", e(pub["fvu_x"]), e(pub["fvu_ddx"]),
                e(pub["fvu_ddz"])],
               ["replication (mean ± std of 10)", "-",
                *(f"{rep[k]['mean']:.1e} ± {rep[k]['std']:.1e}"
                  for k in ("fvu_x", "fvu_ddx", "fvu_ddz"))]]
    figure = _video_figure(result.rows, out / "figures" / "pendulum_video_seeds.png")
    return WorldStudy(
        title=f"latent-sindy: the pendulum video ({scale} scale)",
        settings={"scale": scale, **to_json(cfg), "schedule_settings": record["schedule"]},
        seeds=list(cfg.seeds), numbers=record,
        findings=[*result.lines(),
                  "recovered: the active set exactly {sin z}, its coefficient -1 ± 2 %. Seeds "
                  f"reused from an earlier run in this folder: {result.reused or 'none'}."],
        tables=[Table("Summary beside the published and replicated figures",
                      ["run", "recovered", "FVU x", "FVU ẍ", "FVU z̈"], summary),
                Table("Per seed", ["seed", "equation", "exactly {sin z}", "coefficient",
                                   "recovered", "FVU x", "FVU ẍ", "FVU z̈", "time s"],
                      per_seed, note="FVU: test fraction of unexplained variance; x and ẍ "
                                     "in pixel space, z̈ the encoder's against the library's")],
        figures=[(figure, "Per seed: the test FVU of z̈ (log scale, the published and "
                          "replicated lines) and the coefficients of z''")],
        equations={"pendulum-video": "\n".join(f"seed {r['seed']}: {r['equation']}"
                                               for r in result.rows)},
        rows=[{"model": cfg.schedule, "seed": r["seed"], "recovered": r["recovered"],
               "exact_sin": r["exact_sin"], "coefficient": r["coefficient"],
               "equation": r["equation"], "fvu_x": r["fvu_x"], "fvu_ddx": r["fvu_ddx"],
               "fvu_ddz": r["fvu_ddz"], "starts": r.get("starts"), "time_s": r["time_s"]}
              for r in result.rows])


# ----------------------------------------------------------------------------- the pendulum
#: The controlled pendulum's settings (``--world-config``) and the study's field each sets.
WORLD_TO_STUDY = {"image_size": "image_size", "start": "start", "perturbation": "perturbation"}


def pendulum_config(scale: str, seed: int, device: str,
                    world: Mapping[str, Any] | None = None):
    """The :class:`~.study.StudyConfig` of a scale, for one seed; ``world``: settings of the
    pendulum world (:class:`~.config.PendulumConfig` fields, ``--world-config``) that replace
    the scale's camera and the tasks' starts."""
    from latent_sindy.worlds.pendulum.study import StudyConfig

    _scale(scale, PENDULUM_SCALES, "pendulum")
    base = {"tiny": dict(image_size=16, sequences=12, steps=3, epochs=1, window=2,
                         episodes=2, episode_steps=4, last=2, samples=16, horizon=3,
                         nodes=20, neighbours=4, cost_check=1, centroid_models=()),
            "demo": {},
            "published": dict(image_size=48, sequences=1000, epochs=100),
            "published-cpu": dict(image_size=48, sequences=1000, models=()),
            # 16 graph neighbours: with 8, seed 4's cost graph breaks just beside upright
            # (from one side the distance ran the long way round, 8.8 against 4.7 hanging)
            "geodesic": dict(models=(), centroid_latent="geodesic", state_control=False,
                             cost_check=0, neighbours=16),
            "geodesic-published": dict(image_size=48, sequences=1000, models=(),
                                       centroid_latent="geodesic")}[scale]
    for key, value in (world or {}).items():
        if key not in WORLD_TO_STUDY:
            raise UserError(f"--world-config {key}: the pendulum study takes "
                            f"{', '.join(WORLD_TO_STUDY)}")
        base[WORLD_TO_STUDY[key]] = value
    return StudyConfig(**base, seed=seed, device=device)


def _row_record(row) -> dict[str, Any]:
    lo, hi = row.success_interval
    f, flo, fhi = row.upright
    return {"model": row.name, "successes": row.successes, "episodes": len(row.episodes),
            "success_wilson95": [lo, hi], "upright_fraction": f, "upright_95": [flo, fhi],
            "r2": row.r2, "sparsity": row.sparsity, "fit_s": row.fit_seconds,
            "control_s": row.control_seconds,
            "cost_check_successes": sum(e.success for e in row.cost_check),
            "cost_check_episodes": len(row.cost_check),
            "episode_success": [bool(e.success) for e in row.episodes],
            "episode_upright": [float(e.upright_fraction) for e in row.episodes],
            "equations": list(row.equations)}


def _pendulum_figure(per_seed: dict[int, list[dict[str, Any]]], path: Path) -> Path:
    """Swing-up success per model with its 95 % Wilson interval, a bar per seed."""
    fig, axes = _figure(1, 1, (8, 3.8))
    ax = axes[0][0]
    models = [r["model"] for r in next(iter(per_seed.values()))]
    width = 0.8 / len(per_seed)
    x = np.arange(len(models))
    for k, (seed, rows) in enumerate(per_seed.items()):
        rate = np.array([r["successes"] / r["episodes"] for r in rows])
        lo = np.array([r["success_wilson95"][0] for r in rows])
        hi = np.array([r["success_wilson95"][1] for r in rows])
        ax.bar(x + (k - (len(per_seed) - 1) / 2) * width, 100 * rate, width,
               yerr=100 * np.stack([rate - lo, hi - rate]).clip(0),  # (rounding at 0 and n)
               capsize=3, label=f"seed {seed}")
    ax.set_xticks(x, models, rotation=15, fontsize=8)
    ax.set(ylabel="swing-up success (%)", ylim=(0, 105),
           title="swing-up success with 95 % Wilson intervals")
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def _seed_record(cfg, out: Path, say: Say) -> dict[str, Any]:
    """One seed's study: read back from OUT/pendulum_seed<S>.json when it was run there with
    these settings (the device aside), else run and kept there (atomically)."""
    from latent_sindy.worlds.pendulum.study import compare_swing_ups

    path = out / f"pendulum_seed{cfg.seed}.json"
    # (the hanging starts' perturbation keys a seed only where it is not the default, so a
    # seed run before it was a setting is still read back)
    key = {k: v for k, v in to_json(cfg).items() if k != "device" and not (
        k == "perturbation" and v == type(cfg)().perturbation)}
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
        if isinstance(saved, dict) and saved.get("settings") == key:
            say(f"seed {cfg.seed}: reused from {path} (same settings)")
            return saved
    except (OSError, ValueError):
        pass  # none yet, or unreadable: run it
    result = compare_swing_ups(cfg, report=say)
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in result.table().splitlines()]
    record = {"settings": key, "rows": [_row_record(r) for r in result.rows],
              "header": cells[0], "table": cells[2:], "data_s": result.data_seconds}
    text = json.dumps(record)
    write_atomic(path, lambda f: f.write(text), binary=False)
    return record


def pendulum_study(scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                   device: str = "auto", threads: int = 1,
                   say: Say = print, world: Mapping[str, Any] | None = None) -> WorldStudy:
    """The controlled-pendulum study at ``scale``, once per seed, in ``out`` (a seed run
    there before with the same settings is read back); ``world``: the pendulum world's
    settings given (:func:`pendulum_config`)."""
    import torch

    from latent_sindy.stats import wilson_interval

    seeds = tuple(seeds) if seeds else (0,)
    configs = {s: pendulum_config(scale, s, device, world) for s in seeds}
    threads_before = torch.get_num_threads()
    torch.set_num_threads(threads)
    per_seed: dict[int, list[dict[str, Any]]] = {}
    tables = []
    equations = {}
    data_s = {}
    try:
        for seed, cfg in configs.items():
            trained = (f"{cfg.epochs} epochs of {', '.join(cfg.models)}" if cfg.models
                       else "no autoencoder rows")
            say(f"pendulum, {scale} scale, seed {seed}: {cfg.sequences} sequences at "
                f"{cfg.image_size}x{cfg.image_size}, {trained}, {cfg.episodes} swing-ups "
                f"from {cfg.start} starts, device {resolve_device(device)}")
            record = _seed_record(cfg, out, say)
            per_seed[seed] = record["rows"]
            data_s[seed] = record["data_s"]
            tables.append(Table(f"Seed {seed}", record["header"], record["table"]))
            for r in record["rows"]:
                name = _model_id(r["model"])
                equations[name] = (equations.get(name, "") + f"seed {seed}:\n  "
                                   + "\n  ".join(r["equations"]) + "\n")
    finally:
        torch.set_num_threads(threads_before)
    pooled = []
    for i, first in enumerate(next(iter(per_seed.values()))):
        k = sum(rows[i]["successes"] for rows in per_seed.values())
        n = sum(rows[i]["episodes"] for rows in per_seed.values())
        lo, hi = wilson_interval(k, n)
        pooled.append({"model": first["model"], "successes": k, "episodes": n,
                       "success_wilson95": [lo, hi]})
    figure = _pendulum_figure(per_seed, out / "figures" / "pendulum_success.png")
    first = configs[seeds[0]]
    return WorldStudy(
        title=f"latent-sindy: the controlled pendulum from images ({scale} scale)",
        settings={"scale": scale, "study": to_json(first),
                  "per_seed": {str(s): dataclasses.asdict(c) for s, c in configs.items()}},
        seeds=list(seeds), numbers={"per_seed": {str(s): v for s, v in per_seed.items()},
                                    "pooled": pooled, "data_s": {str(s): v for s, v in
                                                                 data_s.items()}},
        findings=[f"{p['model']}: {p['successes']} of {p['episodes']} swing-ups (95 % Wilson "
                  f"{100 * p['success_wilson95'][0]:.0f}–{100 * p['success_wilson95'][1]:.0f} %)"
                  for p in pooled],
        tables=[Table("Pooled over seeds", ["model", "swing-ups", "95 % Wilson"],
                      [[p["model"], f"{p['successes']} of {p['episodes']}",
                        f"{100 * p['success_wilson95'][0]:.0f}–"
                        f"{100 * p['success_wilson95'][1]:.0f} %"] for p in pooled]),
                *tables],
        figures=[(figure, "Swing-up success per model (upright within 10° over the last "
                          f"{first.last} of {first.episode_steps} steps), 95 % Wilson "
                          "intervals, a bar per seed")],
        equations=equations,
        rows=[{"model": _model_id(r["model"]), "seed": seed, "successes": r["successes"],
               "episodes": r["episodes"], "upright": r["upright_fraction"],
               "upright_low": r["upright_95"][0], "upright_high": r["upright_95"][1],
               "sparsity": r["sparsity"], "fit_s": r["fit_s"], "control_s": r["control_s"]}
              for seed, rows in per_seed.items() for r in rows])


def _model_id(label: str) -> str:
    """A row's name for its label: ``state_sindy``, or the model and the fixed latent it
    plans on (``sindy_centroid``, ``sindy_geodesic``)."""
    if label.startswith("state"):
        return "state_sindy"
    for latent in ("centroid", "geodesic"):
        if f"{latent} latent" in label:
            return f"{label.split(' ')[0]}_{latent}"
    return label.split(" ")[0]
