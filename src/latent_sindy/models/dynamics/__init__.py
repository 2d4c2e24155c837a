"""Latent dynamics models behind one interface: SINDy, globally linear (E2C-like) and MLP,
and continuous-time SINDy.

One file per kind holds its model class and its config dataclass (its settings, its ``kind``
tag and ``build``): :mod:`.sindy`, :mod:`.linear`, :mod:`.mlp`, :mod:`.continuous`;
:mod:`.base` holds the interface (:class:`LatentDynamics`: ``step(z, u) -> z_next`` with
z (K, nz), u (K, nu), and ``rollout``) and :class:`SparseDynamics`, the kinds whose
coefficients sit under a pruned mask. Each config is registered in :data:`DYNAMICS_CONFIGS`:
a new kind is one model class, one config class and one entry there.

    >>> model = make_dynamics("sindy", nz=16, nu=3, order=2)
    >>> z = model.rollout(torch.zeros(4, 16), torch.zeros(4, 10, 3))  # (4, 11, 16)
    >>> isinstance(model, SparseDynamics), DYNAMICS_KINDS["linear"]().build(16, 3).kind
    (True, 'linear')
"""

from __future__ import annotations

from typing import Annotated, Any, Union

import tyro

from latent_sindy.models.dynamics.base import (
    LatentDynamics,
    Row,
    SparseDynamics,
    format_equations,
    project_circle,
    turn_circle,
)
from latent_sindy.models.dynamics.continuous import (
    ContinuousSindyConfig,
    ContinuousSindyDynamics,
)
from latent_sindy.models.dynamics.linear import LinearConfig, LinearDynamics
from latent_sindy.models.dynamics.mlp import MlpConfig, MlpDynamics
from latent_sindy.models.dynamics.sindy import (
    CompiledSindy,
    SindyConfig,
    SindyDynamics,
)

__all__ = [
    "DYNAMICS_CONFIGS",
    "DYNAMICS_KINDS",
    "CompiledSindy",
    "ContinuousSindyConfig",
    "ContinuousSindyDynamics",
    "DynamicsConfig",
    "LatentDynamics",
    "LinearConfig",
    "LinearDynamics",
    "MlpConfig",
    "MlpDynamics",
    "Row",
    "SindyConfig",
    "SindyDynamics",
    "SparseDynamics",
    "format_equations",
    "make_dynamics",
    "project_circle",
    "turn_circle",
]

#: The registry: every latent dynamics kind's config class (its ``kind`` names it).
DYNAMICS_CONFIGS: tuple[type, ...] = (SindyConfig, LinearConfig, MlpConfig,
                                      ContinuousSindyConfig)
DYNAMICS_KINDS: dict[str, type] = {c.kind: c for c in DYNAMICS_CONFIGS}

#: A tagged union of the registered configs; on the command line each is a subcommand
#: (``latent-sindy train sindy --order 3``, ``... train linear``).
DynamicsConfig = Union[tuple(  # noqa: UP007  (built from the registry at import time)
    Annotated[c, tyro.conf.subcommand(c.kind)] for c in DYNAMICS_CONFIGS)]


def make_dynamics(kind: str, nz: int, nu: int, **kwargs: Any) -> LatentDynamics:
    """Build a latent dynamics model by kind name (``"sindy"``, ``"linear"``, ``"mlp"``,
    ``"continuous"``).

    Extra keyword arguments go to the model's constructor (e.g. ``order=3``, ``seed=0``).
    """
    try:
        cls = DYNAMICS_KINDS[kind].model_class
    except KeyError:
        raise ValueError(
            f"unknown dynamics kind {kind!r}; valid kinds: {', '.join(sorted(DYNAMICS_KINDS))}"
        ) from None
    return cls(nz, nu, **kwargs)
