"""The core names no world: its settings, its errors and the command line's defaults speak
of libraries, latents and worlds in general; a world's vocabulary (the pushing world's push,
face and frame libraries, its block and faces) comes from the world's plug-in.

These tests read what a user meets, not the source: the fields of every settings dataclass
the core defines (names, defaults, Literal choices), the messages of the core's errors
(raised here, with a neutral library registered in place of the worlds'), and the command
line's defaults with the plug-ins telling it another default world."""

from __future__ import annotations

import dataclasses
import importlib
import json
import pkgutil
import re
import subprocess
import sys
import typing
from dataclasses import dataclass

import pytest

import latent_sindy
from latent_sindy.errors import UserError
from latent_sindy.models import ModelConfig, SindyConfig
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.state import StateConfig
from latent_sindy.plugins import load_plugins
from latent_sindy.sindy import NamedLibrary, Polynomial, library_spec, register_library
from latent_sindy.sindy import named_libraries as registry
from latent_sindy.training.config import TrainConfig

#: What names a world (the pushing world's concepts, its simulator), as whole words.
WORLD_WORDS = {"push", "pushes", "pushing", "pushed", "face", "faces", "frame", "block",
               "blocks", "panda", "franka", "pybullet"}


def world_words(text: object) -> set[str]:
    """The words of ``text`` that name a world's concepts."""
    return set(re.findall(r"[a-z]+", str(text).lower().replace("_", " "))) & WORLD_WORDS


def test_the_word_check_sees_a_world_and_passes_the_generic() -> None:
    assert world_words("--library frame_sense: a block whose symmetry is its faces") == {
        "frame", "block", "faces"}
    assert not world_words("frames of a video, the pose latent's angle frequency")


def core_modules() -> list[str]:
    return [m.name for m in pkgutil.walk_packages(latent_sindy.__path__, "latent_sindy.")
            if not m.name.startswith("latent_sindy.worlds")]


def field_findings(cls: type) -> list[str]:
    """The fields of dataclass ``cls`` whose name, default or Literal choices name a world."""
    hints = typing.get_type_hints(cls, include_extras=True)

    def literals(tp: object) -> list[object]:
        found = list(typing.get_args(tp)) if typing.get_origin(tp) is typing.Literal else []
        return found + [v for a in typing.get_args(tp) for v in literals(a)]

    out = []
    for f in dataclasses.fields(cls):
        said = [f.name, *literals(hints.get(f.name))]
        if f.default is not dataclasses.MISSING:
            said.append(f.default)
        if world_words(said):
            out.append(f"{cls.__module__}.{cls.__qualname__}.{f.name}: {world_words(said)}")
    return out


def test_no_core_settings_field_names_a_world() -> None:
    found, seen = [], 0
    for name in core_modules():
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if (isinstance(obj, type) and dataclasses.is_dataclass(obj)
                    and obj.__module__ == name and name != "latent_sindy.cli"):
                seen += 1
                found += field_findings(obj)
    assert seen > 30  # (the walk reached the configs: training, models, control, data, ...)
    assert not found, found


# ------------------------------------------------------------------ errors, with a neutral library
@dataclass(frozen=True)
class _Options:
    frequency: float = 2.0


def _neutral(order: int, include_sine: bool, options: _Options):
    return Polynomial(("z", "u"), order, bias=True)


@pytest.fixture
def neutral_library(monkeypatch):
    """The registry holding only the core's library and a neutral one that needs what the
    worlds' libraries need (one order, actions, a pose latent, a frequency from the latent):
    the messages then show nothing but the core's own words."""
    load_plugins()  # (the worlds register theirs first; the registry below replaces them)
    monkeypatch.setattr(registry, "NAMED_LIBRARIES", {"poly": registry.NAMED_LIBRARIES["poly"]})
    register_library("lib", NamedLibrary(_neutral, _Options, orders=(1,), actions=2,
                                         pose_latent=True, latent_frequency="frequency"))
    return "lib"


def _message(make) -> str:
    with pytest.raises((UserError, ValueError)) as e:
        make()
    return str(e.value)


CORE_ERRORS = {
    "unknown library": lambda: SindyConfig(library="elsewhere"),
    "an order it does not take": lambda: SindyConfig(library="lib", order=2),
    "cosine": lambda: SindyConfig(library="lib", order=1, include_cosine=True),
    "unknown option": lambda: SindyConfig(library="lib", order=1, library_options=("x=1",)),
    "too few actions": lambda: SindyConfig(library="lib", order=1).build(4, 1),
    "too small a pose latent": lambda: SindyConfig(library="lib", order=1).build(2, 3),
    "not a pose latent": lambda: ModelConfig(observation=AutoencoderConfig(),
                                             dynamics=SindyConfig(library="lib", order=1)),
    "frequency from no encoder": lambda: ModelConfig(
        observation=StateConfig(),
        dynamics=SindyConfig(library="lib", order=1, library_options={"frequency": 0})),
    "spec at another order": lambda: library_spec("lib", order=3),
    "order": lambda: SindyConfig(order=9),
    "taken name": lambda: register_library("poly", NamedLibrary(_neutral)),
    "turn": lambda: ModelConfig(turn=True),
    "window": lambda: TrainConfig(window=0),
}


@pytest.mark.parametrize("case", sorted(CORE_ERRORS))
def test_the_cores_errors_name_no_world(neutral_library, case: str) -> None:
    message = _message(CORE_ERRORS[case])
    assert message and not world_words(message), message


def test_a_named_library_is_what_its_world_registered(neutral_library) -> None:
    cfg = SindyConfig(library="lib", order=1, library_options={"frequency": 0})
    assert cfg.pose_library and cfg.follows_latent and cfg.options == _Options(0.0)
    assert cfg.library_options == ("frequency=0.0",)  # (the pairs that differ from defaults)
    resolved = cfg.with_latent_frequency(3)
    assert resolved.options.frequency == 3.0 and not resolved.follows_latent
    assert SindyConfig(library="lib", order=1).library_options == ()
    model = SindyConfig(library="lib", order=1, include_sine=False).build(4, 2)
    assert model.names == ["1", "z0", "z1", "z2", "z3", "u0", "u1"]


# ------------------------------------------------------------------ the command line's defaults
CLI_PROBE = r"""
import dataclasses, json, sys
import latent_sindy.plugins as plugins

real = plugins.get_world(plugins.default_world())


class Elsewhere:
    '''Another default world: the real one's commands under another name.'''
    name = "elsewhere"
    default = True
    commands = real.commands


def get_world(name):
    return Elsewhere if name == "elsewhere" else real_get(name)


real_get = plugins.get_world
plugins.get_world = get_world
plugins.default_world = lambda: "elsewhere"

from latent_sindy import cli  # noqa: E402  (reads the plug-ins' default world)

defaults = {}
for command, cls in cli.COMMANDS.items():
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
            if type(value).__module__.startswith("latent_sindy.worlds."):
                continue  # (the default world's own settings: its flags, its words)
        else:
            continue
        defaults[f"{command}.{f.name}"] = repr(value)
errors = {}
for argv in (["collect", "--world-config", "a=1"],):
    import contextlib, io
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        cli.main(argv)
    errors[" ".join(argv)] = err.getvalue()
print(json.dumps({"world": cli.Collect().world, "defaults": defaults, "errors": errors}))
"""


def test_the_command_lines_defaults_come_from_the_plugins() -> None:
    """With the plug-ins naming another default world, the CLI's defaults follow it and name
    no world of their own (the default world's settings, its own flags, are skipped)."""
    out = subprocess.run([sys.executable, "-c", CLI_PROBE], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    probe = json.loads(out.stdout.splitlines()[-1])
    assert probe["world"] == "elsewhere"
    assert "elsewhere.h5" in probe["defaults"]["collect.out"]
    assert "elsewhere.h5" in probe["defaults"]["train.config"]
    found = {k: world_words(v) for k, v in {**probe["defaults"], **probe["errors"]}.items()
             if world_words(v)}
    assert not found, found
    assert all("elsewhere world" in e for e in probe["errors"].values()), probe["errors"]


def test_the_default_world_is_the_one_its_plugin_names(monkeypatch) -> None:
    """The world whose plug-in says ``default = True``; else the first with commands; two
    that say so, or none with commands, are refused."""
    from latent_sindy import plugins

    class World:
        def __init__(self, default: bool = False, commands: bool = True) -> None:
            if default:
                self.default = True
            if commands:
                self.commands = {}

    def installed(**worlds: World) -> str:
        monkeypatch.setattr(plugins, "world_names", lambda: sorted(worlds))
        monkeypatch.setattr(plugins, "get_world", worlds.__getitem__)
        return plugins.default_world.__wrapped__()

    assert installed(a=World(commands=False), b=World(), c=World(default=True)) == "c"
    assert installed(a=World(commands=False), b=World(), c=World()) == "b"
    with pytest.raises(UserError, match="each say they are the default"):
        installed(a=World(default=True), b=World(default=True))
    with pytest.raises(UserError, match="no installed world offers"):
        installed(a=World(commands=False))


NO_DEFAULT_PROBE = r"""
import contextlib, io, json, sys
import latent_sindy.plugins as plugins
from latent_sindy.errors import UserError


def no_default_world():
    raise UserError("no installed world offers the commands collect and control (a commands "
                    "hook): install a world plug-in that does")


plugins.default_world = no_default_world
from latent_sindy import cli  # noqa: E402  (must not fail: the commands that need it say so)

said = {}
for argv in (["collect", "--out", sys.argv[1] + "/c.h5"],
             ["reproduce", "--scale", "tiny", "--out", sys.argv[1] + "/s"],
             ["collect", "--world", "pendulum", "--trajectories", "2", "--steps", "2",
              "--out", sys.argv[1] + "/p.h5"]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(argv)
    said[argv[0] + (" --world" if "--world" in argv else "")] = [code, err.getvalue()]
print(json.dumps(said))
"""


def test_without_a_default_world_the_commands_that_need_one_say_so(tmp_path) -> None:
    """No installed world offers commands: the command line still loads; collect and
    reproduce without --world end with the one line saying what to install, and another
    world's collection still runs."""
    out = subprocess.run([sys.executable, "-c", NO_DEFAULT_PROBE, str(tmp_path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    said = json.loads(out.stdout.splitlines()[-1])
    for command in ("collect", "reproduce"):
        code, err = said[command]
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith("latent-sindy: error: no installed world offers"), err
    assert said["collect --world"][0] == 0 and (tmp_path / "p.h5").exists()
