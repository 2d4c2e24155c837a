"""World plug-ins, found by name through Python entry points (group ``latent_sindy.worlds``).

The core never imports a world. A world package declares itself in its distribution's
metadata, as this project does for its own worlds in ``pyproject.toml``::

    [project.entry-points."latent_sindy.worlds"]
    mine = "my_package.world:WORLD"

Loading a plug-in runs its module, which may register what the core looks up by name:
named libraries and derived library variables (:mod:`latent_sindy.sindy`), encoders. The core
calls :func:`load_plugins` when a name it is asked for is not registered yet, so a run folder
that names a world's library loads without the user importing the world first.

    >>> from latent_sindy.plugins import world_names
    >>> "push" in world_names()
    True
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from typing import Any, Protocol

from latent_sindy.errors import UserError

GROUP = "latent_sindy.worlds"

__all__ = ["CONFIG_GIVEN", "GROUP", "HOOKS", "Command", "WorldPlugin", "default_world",
           "get_world", "hook", "load_plugins", "world_names"]


class WorldPlugin(Protocol):
    """The whole contract of a world plug-in: what the core reads of the object a plug-in's
    entry point names. A world for closed-loop control has the members of
    :class:`~latent_sindy.control.world.World` (``make_env``, ``sample_task``, ``reset``,
    ``image``, ``goal_image``, ``state``, ``success``) besides these; a world that only
    describes data (a study of recorded video) may have none of them. Everything else is an
    optional hook named in :data:`HOOKS` and read through :func:`hook`, which refuses any
    other name: the contract cannot grow unseen."""

    name: str
    action_low: Sequence[float]
    action_high: Sequence[float]
    action_names: Sequence[str]
    config: Any
    """The world's settings (a frozen dataclass), where it has any."""


#: The attribute the core sets on a world it rebuilt on a user's settings (``--world-config
#: KEY=VALUE``): the names of the fields given, as a tuple. A world's study takes those
#: fields over its scale's settings (a value equal to the field's default included) and
#: keys its results on them; the installed world, built on no settings, has none (read it
#: as ``getattr(world, CONFIG_GIVEN, ())``).
CONFIG_GIVEN = "config_given"


#: The optional hooks of a world plug-in, with what the core does with each; where a world
#: lacks one the core does without (the default in brackets).
HOOKS: dict[str, str] = {
    "config_from_record": "(record, where) -> the world's settings, from the record its data "
                          "or runs carry [no settings: data and runs of the world are refused]",
    "check_data": "(data) -> None: UserError unless the data fit the world [any data]",
    "prepare_model": "(model config, data) -> the model config the world adjusts to its data, "
                     "e.g. a named library's options [as given]",
    "feasible": "(states, actions) -> bool per action: which the world can carry out [all]",
    "planner": "() -> the MPPI settings control uses in this world [MPPIConfig()]",
    "collect": "(sequences, steps, seed) -> SequenceData of random actions [collect_random]",
    "about": "a line on the world's own study, for --help [none]",
    "scales": "{scale: what it runs} of the world's own study [no study of its own]",
    "reproduce": "(scale, out, seeds, device, threads, say, **study options) -> the world's "
                 "own study, a latent_sindy.world_study.WorldStudy; `latent-sindy reproduce` "
                 "runs it through latent_sindy.study.runner.run_study [none]",
    "study_options": "names of the options its study takes besides the six every study "
                     "does, passed to the reproduce hook by name: settings every study may "
                     "take (latent_sindy.study.settings.OPTIONS, e.g. 'workers') and the "
                     "fields of its study_flags [none: those options are refused when given]",
    "study_flags": "a dataclass of its study's own options (fields with defaults and "
                   "docstrings): where this is the CLI's default world, its fields are flags "
                   "of reproduce, and those given reach the reproduce hook by name [none]",
    "named_worlds": "{name: the world's settings} ready-made settings its study runs on "
                    "as `reproduce --world NAME` (the world's class built on them; "
                    "--world-config changes fields of them; its about names them) [none]",
    "data": "(**settings) -> SequenceData the world's study is made of [none]",
    "default": "True: this world is the CLI's default world, whose commands hook gives "
               "collect and control their flags and whose study reproduce runs without "
               "--world, with its study_flags as flags (one installed world at most) "
               "[the first installed world, by name, with a commands hook]",
    "commands": "{'collect' | 'control': Command} the CLI's commands as this world runs "
                "them, with settings of its own (a Command's settings type: its fields are "
                "the command's flags where this is the CLI's default world); collect: "
                "run(settings, out, workers, progress) for --world of this world; control: "
                "run(run folder, loaded run, settings, out, progress) for its runs "
                "[collect: the collect hook; control: the closed loop of control.episodes]",
}


@dataclass(frozen=True)
class Command:
    """One CLI command as a world runs it (the ``commands`` hook): its settings, a dataclass
    whose fields become the command's flags, and what runs it (:data:`HOOKS` says with
    which arguments)."""

    settings: type
    run: Callable[..., Any]


def hook(world: Any, name: str) -> Any | None:
    """The optional hook ``name`` of ``world`` (:data:`HOOKS`), or None where the world has
    none. A name outside :data:`HOOKS` is a programming error (KeyError): declare it there."""
    if name not in HOOKS:
        raise KeyError(f"{name!r} is not a declared world hook: add it to plugins.HOOKS")
    return getattr(world, name, None)


def world_names() -> list[str]:
    """The names of the installed world plug-ins."""
    return sorted(ep.name for ep in entry_points(group=GROUP))


@cache
def get_world(name: str) -> Any:
    """The world object the plug-in ``name`` provides (loading its package once)."""
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        raise UserError(f"world {name!r} is not installed: use one of "
                        f"{', '.join(world_names()) or '(none)'}")
    return found[0].load()


@cache
def default_world() -> str:
    """The name of the CLI's default world: the installed world whose plug-in says it is
    (its ``default`` hook), else the first, by name, with a ``commands`` hook. UserError where
    two say so or none has commands."""
    worlds = {name: get_world(name) for name in world_names()}
    said = [name for name, world in worlds.items() if hook(world, "default")]
    if len(said) > 1:
        raise UserError(f"worlds {', '.join(said)} each say they are the default world: "
                        "uninstall all but one")
    found = [name for name in said or worlds if hook(worlds[name], "commands") is not None]
    if not found:
        raise UserError("no installed world offers the commands collect and control (a "
                        "commands hook): install a world plug-in that does")
    return found[0]


@cache
def load_plugins() -> tuple[str, ...]:
    """Load every installed world plug-in (once), so that what they register is known."""
    for name in world_names():
        get_world(name)
    return tuple(world_names())
