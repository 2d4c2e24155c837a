"""The plug-in contract is declared whole: every public member of an installed world is in
the World protocol, the WorldPlugin protocol or the declared hooks, and the core reads hooks
only by their declared names."""

from __future__ import annotations

import pytest

from latent_sindy.control.world import World
from latent_sindy.plugins import HOOKS, WorldPlugin, get_world, hook, world_names

DECLARED = (set(HOOKS) | {n for n in vars(World) if not n.startswith("_")}
            | set(WorldPlugin.__annotations__) | set(World.__annotations__))


@pytest.mark.parametrize("name", world_names())
def test_every_public_member_of_a_world_is_declared(name: str) -> None:
    world = get_world(name)
    public = {n for n in dir(world) if not n.startswith("_")}
    assert public - DECLARED == set(), f"{name} has undeclared members"


def test_an_undeclared_hook_is_refused_and_a_missing_one_is_none() -> None:
    world = get_world("pendulum")
    with pytest.raises(KeyError, match="not a declared world hook"):
        hook(world, "something_new")
    assert hook(world, "feasible") is None
    assert callable(hook(world, "collect"))

