"""The pushing world's plug-in (entry point ``push`` of ``latent_sindy.worlds``).

Loading it registers what the core looks up by name and provides :data:`WORLD`, the object the
core asks about this world's data and runs.
"""

from __future__ import annotations

from typing import Any

from latent_sindy.worlds.push import data as _data
from latent_sindy.worlds.push import library as _library  # noqa: F401  (registers the presets)
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.models import prepare_model as _prepare_model


class PushWorldPlugin:
    """What the core asks the pushing world: its settings from a record, its data checks."""

    name = "push"

    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> PushEnvConfig:
        return PushEnvConfig.from_record(record.get("env_config"), f"{where}: env_config")

    check_data = staticmethod(_data.check_data)
    read_legacy = staticmethod(_data.read_legacy)
    prepare_model = staticmethod(_prepare_model)


WORLD = PushWorldPlugin()
