"""The CLI's collect and control as the pushing world runs them (its ``commands`` hook,
:data:`latent_sindy.plugins.HOOKS`): each with settings of its own, whose fields are the
command's flags while push is the CLI's default world. Its study, ``reproduce``, enters
through the plug-in's ``reproduce`` hook as every world's does (:mod:`.plugin`).

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
    latent-sindy control runs/sindy2 --task paper --episodes 1
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.plugins import Command
from latent_sindy.worlds.push.collect import CollectionPlan, collect
from latent_sindy.worlds.push.episodes import (
    ControlConfig,
    check_space,
    format_summary,
    run_control,
)
from latent_sindy.worlds.push.planner import world_planner

__all__ = ["COMMANDS", "collect_command", "control_command"]


def collect_command(plan: CollectionPlan, out: Path, workers: int, progress: Any) -> None:
    """Random pushes into ``out`` (resumable: re-run to finish), ``workers`` processes."""
    existed = out.exists()
    t0 = time.perf_counter()
    path = collect(out, plan, workers, progress)
    if existed:
        print(f"{path} is already complete with these settings; nothing to do")
    else:
        print(f"wrote {path} ({plan.trajectories} trajectories x {plan.steps} pushes, "
              f"splits {plan.split_counts()}) in {time.perf_counter() - t0:.1f} s")


def control_command(run_dir: Path, run: Any, s: ControlConfig, out: Path, progress: Any
                    ) -> None:
    """Closed-loop pushes of the loaded run ``run`` (of ``run_dir``) into ``out``; without a
    planner option, the planner of the run's world."""
    check_space(run.model, s.space)  # before the planner's note: the refusal alone
    if s.mppi == MPPIConfig():  # no planner option given: the planner of the run's world
        s = replace(s, mppi=world_planner(run.world_config))
        m = s.mppi
        print(f"planner: the {run.world_config.push} push's default, K={m.samples} "
              f"H={m.horizon} sigma={m.sigma} lambda={m.lambda_} (options choose another)",
              file=sys.stderr)
    _, summary = run_control(run.model, run.normalizer, run.world_config, s, out, progress)
    print(format_summary(summary, f"{run_dir} ({run.config.model.dynamics_kind}), "
                                  f"{s.task} task, {s.space}-space MPPI:"))
    print(f"wrote {out}/results.json, results.csv"
          + (", episode GIFs" if s.gif_episodes else ""))


COMMANDS = {"collect": Command(CollectionPlan, collect_command),
            "control": Command(ControlConfig, control_command)}
