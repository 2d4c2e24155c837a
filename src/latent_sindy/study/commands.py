"""What the CLI's commands do with any world plug-in rather than its default one: a world
rebuilt on ``--world-config KEY=VALUE`` settings (collect, reproduce), and ``latent-sindy
control`` of another world's run (its own tasks and success criteria, MPPI in the run's
latent or image space, results in RUN/control-SPACE/results.json). It knows no world: it
asks the plug-ins.

    latent-sindy collect --world dmc --world-config task=reacher-easy --out data/r.h5
    latent-sindy reproduce --world dmc --world-config task=cartpole-swingup --scale tiny
    latent-sindy control runs/pendulum --episodes 5 --space latent
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from latent_sindy.configs import from_pairs
from latent_sindy.errors import UserError
from latent_sindy.plugins import CONFIG_GIVEN, get_world, hook

__all__ = ["configured_world", "control_world"]


def configured_world(name: str, pairs: Sequence[str], flag: str = "--world-config") -> Any:
    """The world plug-in ``name``, rebuilt on the settings of the ``KEY=VALUE`` ``pairs``
    (fields of its config dataclass, the others at their defaults) where any are given: a
    world is its class built on its settings. The rebuilt world's ``config_given`` names the
    fields given (:data:`~latent_sindy.plugins.CONFIG_GIVEN`), so that its study takes
    them over its scale's settings, even where a value equals the field's default.
    UserError for a world without settings, or a KEY given twice."""
    from dataclasses import is_dataclass

    world = get_world(name)
    if not pairs:
        return world
    if not is_dataclass(getattr(world, "config", None)):
        raise UserError(f"--world {name} has no settings for {flag}")
    rebuilt = type(world)(from_pairs(type(world.config), pairs, flag))
    setattr(rebuilt, CONFIG_GIVEN, tuple(p.partition("=")[0].strip() for p in pairs))
    return rebuilt


def control_world(run_dir: Path, run: Any, s: Any, out: Path, default: Any,
                  generic: tuple[str, ...], default_world: str) -> None:
    """``latent-sindy control`` of a run of another world than the CLI's default one: its
    own tasks and criteria, MPPI in the run's space. ``s``: the control settings (the
    default world's dataclass, ``default`` its defaults), of which only ``generic`` apply."""
    import json

    from latent_sindy.api import LatentSINDy
    from latent_sindy.atomic import write_atomic
    from latent_sindy.control import ImagePolicy, run_closed_loop, success_rates
    from latent_sindy.control.mppi import MPPIConfig

    own = [f"--{k.replace('_', '-')}" for k in vars(default) if k not in generic
           and getattr(s, k) != getattr(default, k)]
    if own or s.space not in ("latent", "image"):
        raise UserError(f"{', '.join(own) or f'--space {s.space}'}: the "
                        f"{default_world} world's; a "
                        f"{run.world} run takes --episodes, --max-steps, --seed, --space "
                        "latent or image and the planner's options")
    if not callable(getattr(plugin := get_world(run.world), "make_env", None)):
        raise UserError(f"the {run.world} world has no closed loop: plan with the estimator")
    world = type(plugin)(run.world_config)
    mppi = world.planner() if s.mppi == MPPIConfig() and hook(world, "planner") else s.mppi
    planner = LatentSINDy.load(run_dir).planner(mppi, space=s.space, seed=s.seed)
    results = run_closed_loop(world, ImagePolicy(planner), s.episodes, s.max_steps, s.seed)
    rates = success_rates(results)
    out.mkdir(parents=True, exist_ok=True)
    record = {"world": run.world, **{k: getattr(s, k) for k in ("episodes", "max_steps",
              "seed", "space")}, "success": rates,
              "results": [{"steps": r.steps, "reached": r.reached, "actions": r.actions}
                          for r in results]}
    write_atomic(out / "results.json", lambda f: f.write(json.dumps(record, indent=1)),
                 binary=False)
    print(f"{run_dir} in the {run.world} world, {s.episodes} episode(s) of at most "
          f"{s.max_steps} steps, {s.space}-space MPPI: "
          + ", ".join(f"{k} {100 * v:.0f} %" for k, v in rates.items()))
    print(f"wrote {out}/results.json")
