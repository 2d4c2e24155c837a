"""The DeepMind Control suite, imported only when a task is loaded.

:func:`load` builds one task's environment (its episodes never time out: the caller decides
their length), choosing MuJoCo's headless EGL renderer where the user has not chosen one
(``MUJOCO_GL``; set ``MUJOCO_GL=osmesa`` on a machine without EGL). Without the ``dmc`` extra
every use is a UserError that says how to install it.

    env = load(DmcConfig(task="cartpole-swingup"), seed=0)
"""

from __future__ import annotations

import os
from typing import Any

from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.config import DmcConfig

__all__ = ["INSTALL", "check_task", "load", "suite", "task_names"]

INSTALL = ("the dmc world needs the DeepMind Control suite: install latent-sindy[dmc] "
           "(pip install 'latent-sindy[dmc]', i.e. dm-control 1.0.50 with mujoco 3.17.0)")


def suite() -> Any:
    """``dm_control.suite``, with ``MUJOCO_GL=egl`` unless the user set a renderer."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        from dm_control import suite as dm_suite
    except ImportError as e:
        raise UserError(f"{INSTALL} ({type(e).__name__}: {e})") from e
    return dm_suite


def task_names() -> list[str]:
    """Every task of the suite as DOMAIN-TASK."""
    return [f"{domain}-{task}" for domain, task in suite().ALL_TASKS]


def check_task(config: DmcConfig) -> Any:
    """``dm_control.suite``, once it is found to hold ``config.task``: UserError if the suite
    is not installed (saying how to install it) or has no such task (naming those it has)."""
    dm_suite = suite()
    if (config.domain, config.task_name) not in dm_suite.ALL_TASKS:
        raise UserError(f"dmc task {config.task!r} is not in the DeepMind Control suite: use "
                        f"one of {', '.join(task_names())}")
    return dm_suite


def load(config: DmcConfig, seed: int = 0) -> Any:
    """The dm_control environment of ``config.task``, its random starts seeded by ``seed``."""
    dm_suite = check_task(config)
    env = dm_suite.load(config.domain, config.task_name,
                        task_kwargs={"random": seed, "time_limit": float("inf")})
    if config.camera >= env.physics.model.ncam:
        raise UserError(f"dmc camera {config.camera}: the {config.domain} model has "
                        f"{env.physics.model.ncam} camera(s), 0..{env.physics.model.ncam - 1}")
    return env
