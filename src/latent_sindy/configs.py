"""One serializer for every settings dataclass: JSON out, checked dataclasses back in.

Every config of the project (environment, collection, model, training, control, study) is a
frozen dataclass whose field types say what a value may be. :func:`to_json` turns one into
plain JSON values; :func:`from_json` rebuilds it from them, checking every key and type
against the dataclass, so a hand-edited or foreign file fails with one line naming the key.
A field typed as a union of dataclasses that carry a ``kind`` class variable (a *tagged
union*, like the latent dynamics configs) is written with its ``kind`` and read back as the
class of that kind.

    >>> from latent_sindy.training.config import TrainConfig
    >>> d = to_json(TrainConfig(epochs=60))
    >>> from_json(TrainConfig, d, "training") == TrainConfig(epochs=60)
    True

Why not a library: the rules we need (tagged unions by a class variable, tuples, paths,
literals, a one-line error naming the file's key) are about 100 lines; pydantic or cattrs
would each need adapters for the same rules and add a dependency to every install.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, Union

from latent_sindy.errors import UserError

__all__ = ["check_field_types", "checked_value", "from_json", "from_pairs", "to_json"]


def to_json(obj: Any) -> Any:
    """A dataclass (nested ones, tuples, paths included) as JSON values.

    A dataclass with a ``kind`` class variable gets a ``"kind"`` key first.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        kind = getattr(type(obj), "kind", None)
        if isinstance(kind, str):
            out["kind"] = kind
        for f in dataclasses.fields(obj):
            out[f.name] = to_json(getattr(obj, f.name))
        return out
    if isinstance(obj, tuple | list):
        return [to_json(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


def from_json(cls: type, data: Any, where: str) -> Any:
    """Rebuild dataclass ``cls`` from :func:`to_json` output.

    ``where`` names the source in errors (e.g. ``"runs/x/config.json: model"``). Unknown or
    mistyped keys raise :class:`UserError`; missing keys take the field's default; the
    dataclass's own checks (``__post_init__``) run as usual.
    """
    return _convert(cls, data, where)


def from_pairs(cls: type, pairs: Sequence[str], where: str) -> Any:
    """Settings dataclass ``cls`` from the ``KEY=VALUE`` pairs of a command line, the other
    fields at their defaults, checked as :func:`from_json` checks a file: each VALUE is read
    as JSON where it parses as JSON (``32``, ``true``, ``[1, 2]``), else as a string. A KEY
    given twice is refused.

        >>> from latent_sindy.training.config import TrainConfig
        >>> from_pairs(TrainConfig, ["epochs=7"], "--settings").epochs
        7
    """
    given: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise UserError(f"{where}: {pair!r} is not KEY=VALUE (e.g. size=32)")
        if key.strip() in given:
            raise UserError(f"{where}: {key.strip()} is given twice; give each setting once")
        try:
            given[key.strip()] = json.loads(text)
        except json.JSONDecodeError:
            given[key.strip()] = text
    return from_json(cls, given, where)


def checked_value(tp: Any, value: Any, name: str) -> Any:
    """A Python caller's ``value`` for a field of type ``tp`` (argument ``name``): UserError
    naming it where its type is wrong (``True`` where a number is meant, ``"2"`` or ``1.5``
    where an integer is), numpy scalars as Python ones; types other than plain numbers,
    booleans, strings, literals, optional and tuples of them pass as they are."""
    import numbers

    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return checked_value(typing.get_args(tp)[0], value, name)
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for a in (a for a in args if a is not type(None)):
            with contextlib.suppress(UserError):
                return checked_value(a, value, name)
        raise UserError(f"{name}={value!r}: give " + " or ".join(_wanted(a) for a in args))
    if origin is tuple and isinstance(value, list | tuple):
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
        if len(args) == len(value):
            return tuple(checked_value(a, v, f"{name}[{i}]")
                         for i, (a, v) in enumerate(zip(args, value, strict=True)))
    boolean = isinstance(value, bool | np_bool())
    ok = {int: not boolean and isinstance(value, numbers.Integral),
          float: not boolean and isinstance(value, numbers.Real),
          bool: boolean, str: isinstance(value, str),
          type(None): value is None}.get(tp)
    if origin is Literal:
        ok = isinstance(value, str | int) and not boolean and value in typing.get_args(tp)
    elif origin is tuple:
        ok = False
    if ok is None:
        return value
    if not ok:
        raise UserError(f"{name}={value!r}: give {_wanted(tp)}")
    if type(value).__module__ == "numpy":  # a numpy scalar: as Python's own
        return {int: int, float: float, bool: bool}.get(tp, lambda v: v)(value)
    return value


def np_bool() -> type:
    """numpy's boolean scalar type (imported only when asked)."""
    import numpy as np

    return np.bool_


def _wanted(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return _wanted(typing.get_args(tp)[0])
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return "a tuple of " + ", ".join(_wanted(a) for a in typing.get_args(tp)
                                         if a is not Ellipsis)
    return {int: "an integer (not True/False)", float: "a number (not True/False)",
            bool: "True or False", str: "a string", type(None): "None"}.get(
                tp, getattr(tp, "__name__", str(tp)))


def check_field_types(obj: Any, owner: str) -> None:
    """UserError naming the first field of the dataclass ``obj`` whose value has the wrong
    type (:func:`checked_value`); numpy scalars become Python ones (so records stay JSON)."""
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        checked = checked_value(hints[f.name], value, f"{owner}{f.name}")
        if checked is not value:
            object.__setattr__(obj, f.name, checked)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def _fail(where: str, msg: str) -> UserError:
    return UserError(f"{where}: {msg}")


def _dataclass(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise _fail(where, f"expected a mapping of settings, got {type(data).__name__}")
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    data = dict(data)
    kind = data.pop("kind", None)
    own_kind = getattr(cls, "kind", None)
    if kind is not None and kind != own_kind:
        raise _fail(where, f"kind {kind!r} is not {own_kind!r}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise _fail(where, f"unknown settings {unknown}; known: {sorted(fields)}")
    kwargs = {name: _convert(hints[name], value, f"{where}.{name}")
              for name, value in data.items()}
    try:
        return cls(**kwargs)
    except UserError as e:
        raise _fail(where, str(e)) from e
    except (TypeError, ValueError) as e:
        raise _fail(where, f"{type(e).__name__}: {e}") from e


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return _convert(typing.get_args(tp)[0], value, where)
    if dataclasses.is_dataclass(tp):
        return _dataclass(tp, value, where)
    if origin in (Union, types.UnionType):
        return _union(typing.get_args(tp), value, where)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise _fail(where, f"{value!r} is not one of {list(typing.get_args(tp))}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise _fail(where, f"expected a list, got {value!r}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise _fail(where, f"expected {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in
                     enumerate(zip(args, value, strict=True)))
    if tp is Path:
        if not isinstance(value, str):
            raise _fail(where, f"expected a path string, got {value!r}")
        return Path(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(where, f"expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(where, f"expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _fail(where, f"expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _fail(where, f"expected a string, got {value!r}")
        return value
    if tp is type(None):
        if value is not None:
            raise _fail(where, f"expected null, got {value!r}")
        return None
    if tp is Any:
        return value
    raise TypeError(f"{where}: from_json cannot read fields of type {tp!r}")


def _union(args: tuple, value: Any, where: str) -> Any:
    if value is None and type(None) in args:
        return None
    members = [a for a in args if a is not type(None)]
    bare = [typing.get_args(a)[0] if typing.get_origin(a) is typing.Annotated else a
            for a in members]
    tagged = {getattr(a, "kind", None): a for a in bare if dataclasses.is_dataclass(a)}
    if tagged and isinstance(value, dict):
        kind = value.get("kind")
        if kind not in tagged:
            raise _fail(where, f"kind {kind!r} is unknown: use one of {sorted(map(str, tagged))}")
        return _dataclass(tagged[kind], value, where)
    for a in members:  # the first member that accepts the value (int before float)
        try:
            return _convert(a, value, where)
        except UserError:
            continue
    raise _fail(where, f"{value!r} fits none of the allowed types")
