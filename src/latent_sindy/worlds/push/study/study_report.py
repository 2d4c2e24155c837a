"""The study's report.html, built with :class:`~.report.Report`. Its first screen answers
"which model, how well": a figure (success under both criteria with intervals; active terms
against prediction error) and a short table of the models (:mod:`.overview`). How the numbers
reproduce, the setting, then Table I, control results, findings beyond the paper, figures,
GIFs, equations, configuration and versions.

Made by :func:`latent_sindy.worlds.push.study.pipeline.push_study` (:func:`study_page`, with
the tables and figures the study hands on: :func:`study_tables`, :func:`study_figures`) and
written by ``latent-sindy reproduce``; the findings are sentences computed from the measured
numbers, never fixed text.

    latent-sindy reproduce --scale demo --out results   # writes results/report.html
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from latent_sindy.study.evaluation import Stat
from latent_sindy.study.report import Report
from latent_sindy.world_study import Table
from latent_sindy.worlds.push.config import WORLD_ABOUT
from latent_sindy.worlds.push.study import figures
from latent_sindy.worlds.push.study.overview import overview, overview_table, reproduction_notes
from latent_sindy.worlds.push.study.results import Study
from latent_sindy.worlds.push.study.scales import SCALES
from latent_sindy.worlds.push.study.table import format_stat, table1_rows

__all__ = ["findings", "study_figures", "study_page", "study_tables"]

#: Equations longer than this are cut in the report (the .txt files hold them whole).
MAX_EQUATION_CHARS = 6000


def _get(study: Study, model: str, key: str) -> Stat | None:
    return study.stats.get(model, {}).get(key)


def _fmt(study: Study, model: str, key: str, fmt: str) -> str:
    return format_stat(_get(study, model, key), fmt, len(study.config.seeds))


def _mean(study: Study, model: str, key: str) -> float:
    s = _get(study, model, key)
    return math.nan if s is None or s.mean is None else s.mean


def findings(study: Study) -> list[str]:
    """The comparisons beyond the paper, as sentences with the measured numbers."""
    out = []
    multi, single = study.multistep, study.single_step
    if multi and single and single.name in study.stats and multi.name in study.stats:
        a, b = multi.name, single.name
        ea, eb = _mean(study, a, "pred_err/hmax"), _mean(study, b, "pred_err/hmax")
        rnd = "control/random/latent/success_rate"
        pap = "control/paper/latent/success_rate"
        if math.isfinite(ea) and ea < eb:
            verdict = (f"more accurate: {eb / ea:.2f}x lower error" if math.isfinite(eb)
                       else "more accurate: the single-step rollout diverged")
        else:
            verdict = "not more accurate: its error is not lower"
        out.append(
            f"Multi-step vs single-step SINDy: trained on H={multi.window} windows, "
            f"{multi.label}'s open-loop prediction error on test trajectories is "
            f"{_fmt(study, a, 'pred_err/h1', 'loss')} after 1 push and "
            f"{_fmt(study, a, 'pred_err/hmax', 'loss')} at the longest horizon, against "
            f"{_fmt(study, b, 'pred_err/h1', 'loss')} and {_fmt(study, b, 'pred_err/hmax', 'loss')}"
            f" for single-step SINDy-2: its long rollouts are {verdict} (sharpness: Fig. 8)."
            + f" Latent-MPPI success on random tasks: {_fmt(study, a, rnd, 'pct')} vs "
            f"{_fmt(study, b, rnd, 'pct')}; on the paper task: {_fmt(study, a, pap, 'pct')} vs "
            f"{_fmt(study, b, pap, 'pct')}.")
    for m in ("sindy3", "sindy4"):
        if m in study.stats:
            episodes = sum(_mean(study, m, k) for k in study.stats[m]
                           if k.startswith("control/") and k.endswith("/episodes"))
            out.append(
                f"NaN safety, {study.labels[m]}: {episodes:.0f} closed-loop episodes per seed "
                f"(latent and image space); MPPI discarded "
                f"{_fmt(study, m, 'control/discarded_total', 'int')} sampled rollouts whose "
                "prediction or cost was NaN or infinite (zero weight), and executed "
                f"{_fmt(study, m, 'control/nonfinite_actions', 'int')} non-finite pushes "
                "(the paper's order-3/4 controllers produced NaN).")
    if "linear" in study.stats:
        lin = _mean(study, "linear", "control/latent/plan_ms_mean")
        parts = []
        for k in (1, 2, 3, 4):
            m = f"sindy{k}"
            ms = _mean(study, m, "control/latent/plan_ms_mean")
            if math.isfinite(ms) and math.isfinite(lin) and lin > 0:
                parts.append(f"{study.labels[m]} {ms:.2f} ms ({ms / lin:.2f}x)")
        if parts:
            out.append(
                f"Planning time per control step with latent MPPI (K, H as configured): linear "
                f"{lin:.2f} ms; " + ", ".join(parts) + ". SINDy steps evaluate only the active "
                "library terms (the paper's stated future work was a faster SINDy model).")
    knows = _latent_knows(study)
    if knows:
        out.append(knows)
    image = [f"{study.labels[m]} {_fmt(study, m, 'control/paper/image/success_rate', 'pct')}"
             for m in study.models if _get(study, m, "control/paper/image/success_rate")]
    if image:
        out.append("Image-space MPPI on the paper task (the paper: 7 of 10 runs succeeded): "
                   + ", ".join(image) + ".")
    return out


def _latent_knows(study: Study) -> str | None:
    """What the image models' latents know of the pose, and where their predictions put the
    block, against "nothing moves"; None without image models."""
    models = [m for m in study.models if _get(study, m, "probe/x") is not None]
    if not models:
        return None

    def probe(m: str) -> str:
        linear = "/".join(_fmt(study, m, f"probe/{k}", "r2") for k in ("x", "y", "angle"))
        if _get(study, m, "probe/kernel/angle") is None:
            return linear
        kernel = "/".join(_fmt(study, m, f"probe/kernel/{k}", "r2") for k in ("x", "y", "angle"))
        return f"{linear} (kernel ridge {kernel})"

    def cm(m: str, key: str) -> str:
        return _fmt(study, m, key, "num2")

    horizons = [h for h in (1, 5, 10) if _get(study, models[0], f"pos_err/h{h}") is not None]
    parts = [f"{study.labels[m]} " + " / ".join(cm(m, f"pos_err/h{h}") for h in horizons)
             for m in models]
    still = " / ".join(cm(models[0], f"pos_err/still/h{h}") for h in horizons)
    reader = study.baselines.position.get("reader")
    floor = (f" Reading the true test images gives {reader:.2f} cm (the measure's own error)."
             if reader is not None else "")
    states = [m for m in study.models if _get(study, m, "probe/x") is None
              and _get(study, m, "pos_err/h1") is not None]
    if states:
        floor += (" The state-space models, which see the true pose, predict it "
                  + "; ".join(f"{study.labels[m]} " + " / ".join(
                      cm(m, f"pos_err/h{h}") for h in horizons) for m in states)
                  + " cm off: the bound for the image models.")
    return ("What the latent knows (image models, test images): a linear probe from the latent "
            "to the block's pose reaches R² (x / y / angle features; in brackets a kernel ridge "
            "probe, which also sees what the latent holds nonlinearly) "
            + ", ".join(f"{study.labels[m]} {probe(m)}" for m in models)
            + ". Block position read from the decoded open-loop predictions after "
            + " / ".join(map(str, horizons)) + " pushes, error in cm: " + "; ".join(parts)
            + f"; nothing moves: {still}." + floor)


def _control_rows(study: Study) -> list[list[str]]:
    rows = []
    n = len(study.config.seeds)
    for m in study.models:
        for cond in study.scale.all_conditions():
            key = f"control/{cond.name}"
            if _get(study, m, f"{key}/episodes") is None:
                continue

            def f(k: str, fmt: str, m: str = m, key: str = key) -> str:
                return format_stat(_get(study, m, f"{key}/{k}"), fmt, n)

            dist = _get(study, m, f"{key}/final_distance_mean")
            cm = format_stat(None if dist is None else Stat(
                None if dist.mean is None else 100 * dist.mean,
                None if dist.std is None else 100 * dist.std, dist.n), "num", n)
            rows.append([study.labels[m], cond.task, cond.space, f("episodes", "int"),
                         f("success_rate", "pct"), _ci(study, m, key, "success"),
                         f("strict_success_rate", "pct"), _ci(study, m, key, "strict"),
                         f("steps_to_goal_mean", "num"), cm,
                         f("final_angle_error_deg_mean", "num"), f("executed_rate", "pct"),
                         f("plan_ms_mean", "num"), f("discarded_total", "int"),
                         f("left_workspace", "int")])
    return rows


def _ci(study: Study, model: str, key: str, which: str) -> str:
    """The Wilson interval of the first seed, e.g. "22–48%" ("—" where not measured)."""
    first = study.per_seed.get(study.config.seeds[0], {}).get(model, {})
    lo, hi = first.get(f"{key}/{which}_ci_low"), first.get(f"{key}/{which}_ci_high")
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return "—"
    return f"{100 * lo:.0f}–{100 * hi:.0f}%"


def _first_screen(r: Report, study: Study, figure: Path) -> None:
    """The overview figure and the short table (best first), then how the numbers reproduce."""
    view = overview(study)
    seeds = len(study.config.seeds)
    r.image(figures.overview_figure(view, figure),
            "Which model, how well: closed-loop success on random tasks, and active dynamics "
            "terms against prediction error (numbers as in the table below).", cls="overview")
    header, rows = overview_table(view, seeds)
    r.table(header, rows, cls="overview")
    ours = "mean ± std over seeds" if seeds > 1 else "one seed"
    r.paragraph(f"Best first (strict success, then the 0.1 m one); {ours}. Success on the random "
                "tasks with latent MPPI: within 0.1 m (the course's criterion; figure: open "
                "circles) and within 2 cm and 10° (filled), with the 95% Wilson interval of all "
                "seeds' episodes together. Active terms: non-zero dynamics coefficients of all "
                "candidates (sparsity: the share that is zero); a dense network counts its "
                f"parameters. Error: the {view.error_label} of open-loop predictions on the test "
                "trajectories. State rows see the block's true pose: the bound for the image "
                "models.", cls="note")
    r.heading("How these numbers reproduce")
    for text in reproduction_notes(view):
        r.paragraph(text, cls="note")


#: What Table I's figures are, under the table.
TABLE1_NOTE = ("Losses: the objective without the L1 term (reconstruction + image prediction "
               "+ latent prediction, mean squared error per normalised pixel or latent "
               "coordinate) on the single-step windows of each split, for every model alike. "
               "Steps to goal: mean over successful episodes (course criterion: within 0.1 m); "
               "strict criterion: within 0.02 m and 10°. Ours: mean ± sample std over seeds; "
               "n/a: does not apply; —: no value.")

#: The closed-loop table's columns and what its figures are.
CONTROL_HEADER = ["model", "task", "MPPI", "episodes", "success (course)", "95% CI",
                  "success (strict)", "95% CI", "steps to goal", "final distance (cm)",
                  "final angle error (°)", "pushes executed", "plan ms/step",
                  "discarded samples", "left workspace"]
CONTROL_NOTE = ("95% CI: the Wilson score interval of the first seed's success rate over its "
                "episodes. The strict criterion (2 cm, 10°) compares orientations modulo the "
                "block's visible symmetry. Planning time excludes the one-time warm-up (numba "
                "compiling the SINDy kernel). State rows see the block's true pose: they are "
                "the upper bound of what the image models could reach.")


def study_tables(study: Study) -> list[Table]:
    """Table I beside the paper's and the closed-loop table, as table.md holds them."""
    header = ["metric", *(study.labels[m] for m in study.models)]
    return [Table("Table I: the paper's values beside ours", header,
                  table1_rows(study.models, study.stats, len(study.config.seeds)), TABLE1_NOTE),
            Table("Closed-loop control", CONTROL_HEADER, _control_rows(study), CONTROL_NOTE)]


def study_figures(files: dict[str, Any]) -> list[tuple[Path, str]]:
    """The study's figures (PNG) among its output files, with captions."""
    captions = {"loss": "training and validation loss per epoch",
                "horizon": "open-loop prediction error against horizon",
                "position": "block position error of the decoded predictions against horizon",
                "control": "success rate per condition and planning time",
                "rollouts": "a test trajectory and open-loop rollouts"}
    found = [(files[k], caption) for k, caption in captions.items() if k in files]
    return found + [(p, f"active coefficients of {m}")
                    for m, p in files.get("coefficients", {}).items()]


def study_page(study: Study, files: dict[str, Any], summary: dict[str, Any]) -> Report:
    """The study's page (report.html, self-contained; not yet written) from the study, its
    output files and its record (:func:`~.pipeline.study_record`)."""
    cfg = study.config
    scale = study.config.preset
    seeds = ", ".join(map(str, cfg.seeds))
    data = summary["data"]
    r = Report(f"latent-sindy: the paper's study, reproduced ({cfg.scale} scale)")
    _first_screen(r, study, cfg.out / "figures" / "overview.png")
    train_s = sum(m.get("train/seconds") or 0.0 for d in study.per_seed.values()
                  for m in d.values())
    load = ", ".join(f"{v:.1f}" for v in summary["machine"]["load_average"])
    planner = scale.planner(cfg.world)
    headline = ", ".join(s.label for s in study.specs if s.headline)
    image = ", ".join(s.label for s in study.specs if s.image_space)
    control_note = (f"closed loop per model and seed, on one fixed list of random tasks: "
                    f"{scale.paper_episodes} paper-task episodes (one controller seed each) and "
                    f"{scale.random_episodes} random tasks with latent MPPI for {headline}, "
                    f"{scale.other_random_episodes} for the other rows (at most "
                    f"{scale.max_steps} pushes); {scale.image_paper_episodes} + "
                    f"{scale.image_random_episodes} with image-space MPPI for {image} (at most "
                    f"{scale.image_max_steps}); MPPI K={planner.samples}, "
                    f"H={planner.horizon}, Σ={planner.sigma}")
    world = WORLD_ABOUT.get(cfg.world, "a pushing world")
    r.heading("The study")
    r.paragraph(f"World: {cfg.world} ({world}). The strict criterion compares orientations "
                "modulo the block's visible symmetry (90° for the uniform block, 360° for the "
                "marked one).")
    r.paragraph(
        f"Data: {data['trajectories']} trajectories of {data['steps']} pushes (splits "
        f"{data['splits']}). Every model trained {scale.epochs} epochs, batch "
        f"{scale.batch_size}, SINDy pruning every {scale.prune_every} epochs at "
        f"{scale.prune_below:g}; seeds {seeds}; {control_note}. Training took "
        f"{train_s:.0f} s summed over all models and seeds; this invocation took "
        f"{study.timings.get('total', math.nan):.0f} s of wall time on "
        f"{summary['machine']['cpus']} CPUs (load average {load}; finished pieces of "
        "earlier invocations are reused, not redone).")
    if cfg.scale != "paper":
        r.paragraph(
            f"This is the {cfg.scale} scale: {scale.trajectories} trajectories (the paper: "
            f"100/50/50), {scale.epochs} epochs (the paper: 3000) and fewer control episodes "
            f"than the paper scale's ({SCALES['paper'].random_episodes} random tasks for the "
            "headline rows); the numbers show the pipeline and the trends, not the "
            "paper-scale result. Run --scale paper for that.")
    if failures := study.evaluations.failures:
        r.paragraph("Failed runs (left out of the averages): " + "; ".join(failures))

    table1, control = study_tables(study)
    r.heading(table1.heading)
    r.table(table1.header, table1.rows, cls="wide")
    r.paragraph(table1.note)

    r.heading(control.heading)
    r.table(control.header, control.rows)
    r.paragraph(control.note)
    r.image(files["control"], "Success rate per condition and latent-MPPI planning time")

    r.heading("Beyond the paper")
    for text in findings(study):
        r.paragraph(text)

    r.heading("Figures")
    r.image(files["loss"], "Fig. 6/7: training and validation loss per epoch (seed "
            f"{cfg.seeds[0]})")
    if "rollouts" in files:
        r.image(files["rollouts"], "Fig. 8: a test trajectory (top) and open-loop rollouts "
                "from its first image and actions: the single-step and the multi-step SINDy-2, "
                "then the other headline image models")
    r.image(files["horizon"], "Open-loop prediction error against horizon on the test "
            "trajectories (mean ± std over seeds); dashed: predictors that learn nothing")
    if baselines := study.baselines.pred_err:
        still = baselines["still"]
        mean = baselines["mean_image"]
        r.paragraph(
            "For scale, on the same test trajectories: predicting that nothing moves scores "
            f"{still[0]:.4f} one push ahead and {still[-1]:.4f} at the longest horizon; the "
            f"mean training image scores {mean[0]:.4f} (so about {2 * mean[0]:.2f} on the "
            "objective's reconstruction plus image prediction).")
    if "position" in files:
        r.image(files["position"], "Block position error of the decoded open-loop predictions "
                "against horizon on the test trajectories (mean ± std over seeds): the centroid "
                "of the block's pixels, back-projected through the camera; dashed: nothing "
                "moves; dotted: reading the true images (the measure's own error)")
    for m, p in files["coefficients"].items():
        r.image(p, f"Fig. 9/10: active coefficients of {study.labels[m]} (rows latent states, "
                "columns candidate terms; grey: pruned; a turning model's row ω is the angle "
                "by which its orientation features turn)")

    if files["gifs"]:
        r.heading(f"Closed-loop episodes (seed {cfg.seeds[0]}, first episode of each condition)")
        for cond in study.scale.all_conditions():
            items = [(p, f"{study.labels[m]}, {cond.label}")
                     for m, c, p in files["gifs"] if c == cond]
            if items:
                r.gallery(items)

    r.heading("Discovered equations")
    for m, p in files["equations"].items():
        text = p.read_text()
        if len(text) > MAX_EQUATION_CHARS:
            text = (text[:MAX_EQUATION_CHARS] + f"\n… ({len(text) - MAX_EQUATION_CHARS} more "
                    f"characters in {p.name})")
        r.heading(study.labels[m], level=3)
        r.preformatted(text)

    r.heading("Configuration, versions and seeds")
    r.preformatted(json.dumps({k: summary[k] for k in (
        "config", "scale", "seeds", "models", "data", "versions", "machine", "timings_s",
        "train_status")}, indent=1))
    return r
