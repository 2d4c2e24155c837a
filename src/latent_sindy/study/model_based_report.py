"""The report of a model-based study (:func:`.model_based.run_loops`'s runs) as ``latent-sindy
reproduce`` writes it: the :class:`~latent_sindy.world_study.WorldStudy` of tables of return
against environment steps per model with intervals over seeds, the test episodes, published
reference rows where the world has them, costs, active terms; the last SINDy equations; a
figure. It knows no world: the world's study names its task and its published lines.

    study = model_based_study(run_loops(...), "tiny", out, "gym from pixels: Pendulum-v1",
                              "Pendulum-v1")
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from latent_sindy.atomic import atomic_path
from latent_sindy.study.model_based import MODELS, mean_interval
from latent_sindy.world_study import Table, WorldStudy

__all__ = ["Reference", "model_based_study"]


@dataclass(frozen=True)
class Reference:
    """Published returns of one task at a number of environment steps, to show beside a
    study's: per method (mean, sd over seeds) and where each was published."""

    task: str
    steps: int
    returns: dict[str, tuple[float, float]]
    sources: dict[str, str]


def _fmt(mean: float, half: float | None) -> str:
    return f"{mean:.1f}" if half is None else f"{mean:.1f} ± {half:.1f}"


def _curves(runs: dict[str, dict[int, dict[str, Any]]]) -> dict[str, list[dict[str, Any]]]:
    """Per model, per planned iteration: environment steps, each seed's return (mean of the
    iteration's episodes), their mean, 95% half-width and sd."""
    curves: dict[str, list[dict[str, Any]]] = {}
    for model, by_seed in runs.items():
        points: dict[int, dict[str, Any]] = {}
        for seed, run in by_seed.items():
            for e in run["log"]["episodes"]:
                it = e["iteration"]
                p = points.setdefault(it, {"iteration": it, "env_steps": 0, "by_seed": {}})
                p["env_steps"] = max(p["env_steps"], e["env_steps"])
                p["by_seed"].setdefault(seed, []).append(e["return"])
        rows = []
        for it in sorted(points):
            p = points[it]
            per_seed = [sum(v) / len(v) for v in p["by_seed"].values()]
            mean, half, sd = mean_interval(per_seed)
            rows.append({"iteration": it, "env_steps": p["env_steps"], "mean": mean,
                         "half_width": half, "sd": sd, "seeds": len(per_seed),
                         "returns": per_seed})
        curves[model] = rows
    return curves


def _tests(runs: dict[str, dict[int, dict[str, Any]]]) -> dict[str, list[dict[str, Any]]]:
    """Per model, per iteration with test episodes: the environment steps its fit saw, each
    seed's mean test return, their mean, 95% half-width and sd (empty without tests)."""
    tests: dict[str, list[dict[str, Any]]] = {}
    for model, by_seed in runs.items():
        points: dict[int, dict[str, Any]] = {}
        for seed, run in by_seed.items():
            for it in run["log"]["iterations"]:
                if it.get("evaluation"):
                    p = points.setdefault(it["iteration"], {"steps": 0, "by_seed": {}})
                    p["steps"] = max(p["steps"], it["fit_env_steps"])
                    p["by_seed"][seed] = sum(it["evaluation"]) / len(it["evaluation"])
        rows = []
        for it in sorted(points):
            per_seed = list(points[it]["by_seed"].values())
            mean, half, sd = mean_interval(per_seed)
            rows.append({"iteration": it, "env_steps": points[it]["steps"], "mean": mean,
                         "half_width": half, "sd": sd, "seeds": len(per_seed),
                         "returns": per_seed})
        tests[model] = rows
    return tests


def _test_finding(tests: dict[str, list[dict[str, Any]]],
                  numbers: dict[str, dict[str, Any]]) -> list[str]:
    """One sentence on the last fit's test episodes per model (what published tables
    report), with SINDy's active terms over seeds; none without test episodes."""
    terms = [v["active_terms"] for k, v in numbers.items()
             if k.startswith("sindy/") and v["active_terms"] is not None]
    parts = []
    for m in (m for m in MODELS if tests.get(m)):
        r = tests[m][-1]
        sd = "" if r["sd"] is None else f" (sd {r['sd']:.1f})"
        extra = f", {min(terms)}–{max(terms)} active terms" if m == "sindy" and terms else ""
        parts.append(f"{m} {r['mean']:.1f}{sd}{extra}")
    if not parts:
        return []
    r0 = next(tests[m][-1] for m in MODELS if tests.get(m))
    return [f"Test episodes of the last fit (no noise; the fit saw {r0['env_steps']:,} "
            f"environment steps), mean over {r0['seeds']} seed(s): " + "; ".join(parts) + "."]


def _figure(curves: dict[str, list[dict[str, Any]]], reference: dict[str, list[float]],
            show_reference: bool, path: Path,
            tests: dict[str, list[dict[str, Any]]] | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for model, rows in curves.items():
        x = [r["env_steps"] for r in rows]
        y = [r["mean"] for r in rows]
        ax.plot(x, y, marker="o", label=model)
        if any(r["half_width"] is not None for r in rows):
            h = [r["half_width"] or 0.0 for r in rows]
            ax.fill_between(x, [a - b for a, b in zip(y, h, strict=True)],
                            [a + b for a, b in zip(y, h, strict=True)], alpha=0.2)
    for model, rows in (tests or {}).items():
        if rows:
            ax.plot([r["env_steps"] for r in rows], [r["mean"] for r in rows], ls="--",
                    marker="x", label=f"{model}, test (no noise)")
    if show_reference:
        for name, (mean, _) in reference.items():
            ax.axhline(mean, ls=":", lw=0.8, color="gray")
            ax.annotate(name, (ax.get_xlim()[1], mean), fontsize=6, ha="right", va="bottom")
    ax.set(xlabel="environment steps", ylabel="episode return",
           title="return against environment steps (iteration 0: random seed episodes)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    return path


def _rows(runs: dict[str, dict[int, dict[str, Any]]]) -> list[dict[str, Any]]:
    """A row per model and seed: the mean test return of its last fit with test episodes,
    the mean return of the random seed episodes, the environment steps that fit saw, its
    active terms, the loop's wall seconds."""
    rows = []
    for model, by_seed in runs.items():
        for seed, run in sorted(by_seed.items()):
            tested = [it for it in run["log"]["iterations"] if it.get("evaluation")]
            last = tested[-1] if tested else None
            random = [e["return"] for e in run["log"]["episodes"] if e["kind"] == "random"]
            rows.append({"model": model, "seed": seed,
                         "test_return": None if last is None
                         else sum(last["evaluation"]) / len(last["evaluation"]),
                         "random_return": sum(random) / len(random) if random else None,
                         "env_steps": None if last is None else last["fit_env_steps"],
                         "active_terms": None if last is None else last["active_terms"],
                         "wall_s": run["wall_s"]})
    return rows


def model_based_study(result: dict[str, Any], scale: str, out: Path, title: str, task: str,
                      reference: Reference | None = None) -> WorldStudy:
    """The WorldStudy of a model-based study's ``result`` (:func:`.model_based.run_loops`)
    at ``scale`` in ``out`` (its figure written there), of the world's ``task``, with the
    ``reference`` lines where the world has any."""
    runs = result["runs"]
    curves, tests = _curves(runs), _tests(runs)
    is_reference = reference is not None and task == reference.task
    rows = [[m, str(r["iteration"]), str(r["env_steps"]), _fmt(r["mean"], r["half_width"]),
             str(r["seeds"])] for m in MODELS for r in curves[m]]
    last = {m: curves[m][-1] for m in MODELS}
    final = [[m, str(last[m]["env_steps"]), _fmt(last[m]["mean"], last[m]["sd"]),
              "this study, collected episodes"] for m in MODELS]
    final += [[m, str(tests[m][-1]["env_steps"]), _fmt(tests[m][-1]["mean"], tests[m][-1]["sd"]),
               "this study, test episodes of the last fit"] for m in MODELS if tests[m]]
    if reference is not None:
        final += [[name, f"{reference.steps:,}", f"{mean} ± {sd}",
                   "published: " + reference.sources[name]]
                  for name, (mean, sd) in reference.returns.items()]
    costs = []
    equations = {}
    numbers = {}
    for m in MODELS:
        for seed, run in sorted(runs[m].items()):
            its = run["log"]["iterations"]
            fit = [it["fit_seconds"] for it in its]
            plan = [it["plan_seconds"] for it in its]
            active = its[-1]["active_terms"] if its else None
            per_fit = [it["active_terms"] for it in its]
            costs.append([m, str(seed), f"{fit[0]:.1f}" if fit else "-",
                          f"{sum(fit[1:]) / len(fit[1:]):.1f}" if fit[1:] else "-",
                          f"{sum(plan) / len(plan):.1f}" if plan else "-",
                          f"{run['wall_s']:.0f}", "-" if active is None else
                          " → ".join(map(str, per_fit))])
            if m == "sindy" and its and its[-1]["equations"]:
                equations[f"sindy_seed{seed}"] = "\n".join(its[-1]["equations"])
            numbers[f"{m}/seed{seed}"] = {
                "returns": [e["return"] for e in run["log"]["episodes"]],
                "env_steps": [e["env_steps"] for e in run["log"]["episodes"]],
                "kinds": [e["kind"] for e in run["log"]["episodes"]],
                "fit_seconds": fit, "plan_seconds": plan, "active_terms": active,
                "active_terms_per_fit": per_fit,
                "wall_s": run["wall_s"]}
    lines = {} if reference is None else reference.returns
    figure = _figure(curves, lines, is_reference, out / "returns.png", tests)
    best = max(MODELS, key=lambda m: last[m]["mean"])
    findings = [
        f"{task} from {result['settings']['world']['size']}-pixel images, {scale} scale: "
        f"after {last[best]['env_steps']:,} environment steps the best mean return of the "
        f"collected episodes (exploration noise included) is {best}'s "
        f"{last[best]['mean']:.1f} over {last[best]['seeds']} seed(s) (random seed "
        f"episodes: {curves[best][0]['mean']:.1f}).",
        *_test_finding(tests, numbers),
        "Each model ran its own loop from the same seed episodes with the same planner and "
        "seeds; refits after the first are warm-started (the last model and optimiser, a "
        "fixed budget of updates in batches of a fixed size, the first fit's normaliser), "
        "and each prunes SINDy's smallest terms first."]
    if reference is not None and is_reference:
        findings.append(f"The published rows are at {reference.steps:,} steps; "
                        "compare only at equal steps (this scale's steps are in the table).")
    elif reference is not None:
        findings.append(f"The published rows are {reference.task}'s, not {task}'s: shown "
                        "for scale only.")
    tables = [
        Table("Return against environment steps", ["model", "iteration", "env steps",
              "mean return (95% interval over seeds)", "seeds"], rows,
              "Iteration 0: the seed episodes of random actions; then each iteration's "
              "planned episodes (with exploration noise). Interval: " + result["interval"]
              + "."),
        Table("Test episodes, without exploration noise", ["model", "iteration",
              "env steps the fit saw", "mean test return (95% interval over seeds)", "seeds"],
              [[m, str(r["iteration"]), str(r["env_steps"]), _fmt(r["mean"], r["half_width"]),
                str(r["seeds"])] for m in MODELS for r in tests[m]],
              "After each fit, episodes planned from the same starts without noise and kept "
              "out of the data: what published tables report."),
        Table("Last return" + ("" if reference is None else " and the published lines"),
              ["model", "env steps",
              "return (mean ± sd over seeds)", "source"], final),
        Table("Costs and sparsity", ["model", "seed", "first fit s", "refit s (mean)",
              "planned episodes s (an iteration's, mean)", "wall s",
              "active terms per fit"], costs,
              "Wall: the loop's episodes (test episodes included) and fits as its log "
              "records them (resumed runs included). Active terms: each fit's nonzero "
              "coefficients, first to last (SINDy's after pruning: each warm refit prunes "
              "first; the linear model's A, B, c; none for the MLP).")]
    return WorldStudy(
        title=title,
        settings=result["settings"], seeds=result["seeds"],
        numbers={"curves": curves, "tests": tests, "runs": numbers,
                 "reference": None if reference is None else {
                     "task": reference.task, "steps": reference.steps,
                     "returns": {k: list(v) for k, v in reference.returns.items()}}},
        findings=findings, tables=tables, figures=[(figure, "Mean return per model against "
                                                    "environment steps (band: 95% interval "
                                                    "over seeds)")],
        equations=equations, rows=_rows(runs))
