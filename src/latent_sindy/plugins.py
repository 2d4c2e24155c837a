"""World plug-ins, found by name through Python entry points (group ``latent_sindy.worlds``).

The core never imports a world. A world package declares itself in its distribution's
metadata, as this project does for its own worlds in ``pyproject.toml``::

    [project.entry-points."latent_sindy.worlds"]
    push = "latent_sindy.worlds.push.plugin:WORLD"

Loading a plug-in runs its module, which may register what the core looks up by name:
library presets and derived library variables (:mod:`latent_sindy.sindy`), encoders. The core
calls :func:`load_plugins` when a name it is asked for is not registered yet, so a run folder
that names a world's library loads without the user importing the world first.

    >>> from latent_sindy.plugins import world_names
    >>> "push" in world_names()
    True
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import Any

from latent_sindy.errors import UserError

GROUP = "latent_sindy.worlds"

__all__ = ["GROUP", "get_world", "load_plugins", "world_names"]


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
def load_plugins() -> tuple[str, ...]:
    """Load every installed world plug-in (once), so that what they register is known."""
    for name in world_names():
        get_world(name)
    return tuple(world_names())
