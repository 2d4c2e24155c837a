"""Settings renamed since run folders were written: their old names still read.

A config dataclass decorated with ``@renamed(old="new", ...)`` records the map in its
``renamed_settings`` class variable, the one place that knows the old names. From it

* :func:`latent_sindy.configs.from_json` reads a record (a run folder's ``config.json``)
  written with an old key as the new setting (it applies ``renamed_settings``);
* the constructor and ``dataclasses.replace`` take the old keyword; an old name and its
  new one given together are refused (a :class:`~latent_sindy.errors.UserError` naming
  both), whatever their values;
* the old attribute reads the new one (read-only).

Records are written with the new names (:func:`latent_sindy.configs.to_json` writes fields).

    >>> from dataclasses import dataclass
    >>> @renamed(encoder="encoder_kind")
    ... @dataclass(frozen=True)
    ... class Config:
    ...     encoder_kind: str = "conv"
    >>> Config(encoder="moments").encoder_kind, Config().encoder
    ('moments', 'conv')
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from latent_sindy.configs import one_name_each
from latent_sindy.errors import UserError

__all__ = ["flag_aliases", "one_flag_each", "one_name_each", "renamed", "replaced_from"]

T = TypeVar("T", bound=type)


def renamed(**old_to_new: str) -> Callable[[T], T]:
    """Class decorator for a dataclass whose settings ``old`` are now named ``new``."""

    def decorate(cls: T) -> T:
        names = {f.name for f in dataclasses.fields(cls)}
        for old, new in old_to_new.items():
            if new not in names or old in names:
                raise TypeError(f"{cls.__name__}: renamed {old!r} -> {new!r} needs a field "
                                f"{new!r} and no field {old!r}")
        cls.renamed_settings = {**getattr(cls, "renamed_settings", {}), **old_to_new}
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
            init(self, *args, **_new_names(old_to_new, kwargs, cls.__name__))

        cls.__init__ = __init__
        for old, new in old_to_new.items():
            setattr(cls, old, property(lambda self, new=new: getattr(self, new),
                                       doc=f"The setting now named ``{new}`` (read-only)."))
        return cls

    return decorate


def replaced_from() -> Any:
    """The dataclass that ``dataclasses.replace`` is copying, where the constructor runs inside
    it (it passes every field it is not given, so the new name beside an old one the caller
    gave); else None. For a decorated ``__init__``'s helper: the frames are this function,
    the helper, the decorated ``__init__``, then its caller."""
    frame = sys._getframe(3)
    if frame.f_code is dataclasses.replace.__code__ or (
            frame.f_code.co_name == "_replace" and frame.f_globals is vars(dataclasses)):
        return frame.f_locals.get("obj")
    return None


def _new_names(old_to_new: dict[str, str], kwargs: dict[str, Any], owner: str
               ) -> dict[str, Any]:
    """``kwargs`` with the old names as the new ones; an old name with its new one is refused
    (``dataclasses.replace(c, old=v)`` passes the new one too, the copied config's own: that
    one is not counted as given)."""
    if not any(old in kwargs for old in old_to_new):
        return kwargs
    copied = replaced_from()
    given = kwargs if copied is None else {  # replace filled in the fields it was not given
        k: v for k, v in kwargs.items()
        if k not in old_to_new.values() or v is not getattr(copied, k, None)}
    one_name_each(old_to_new, given, f"{owner}(...)")
    out = dict(kwargs)
    for old, new in old_to_new.items():
        if old in out:
            out[new] = out.pop(old)
    return out


def flag_aliases(cls: type) -> dict[str, str]:
    """The command-line aliases among ``cls``'s settings and every settings dataclass within
    it: ``--old-flag`` -> the flag it stands for (``tyro.conf.arg(aliases=...)``)."""
    import typing

    out: dict[str, str] = {}
    seen: set[type] = set()

    def visit(tp: Any) -> None:
        if typing.get_origin(tp) is typing.Annotated:
            visit(typing.get_args(tp)[0])
            return
        for arg in typing.get_args(tp):  # unions, tuples, Optional
            visit(arg)
        if not (isinstance(tp, type) and dataclasses.is_dataclass(tp)) or tp in seen:
            return
        seen.add(tp)
        try:
            hints = typing.get_type_hints(tp, include_extras=True)
        except Exception:  # a type tyro resolves its own way: no aliases read there
            return
        for f in dataclasses.fields(tp):
            hint = hints.get(f.name)
            for meta in getattr(hint, "__metadata__", ()):
                aliases = getattr(meta, "aliases", None) or ()
                flag = "--" + (getattr(meta, "name", None) or f.name).replace("_", "-")
                out.update({alias: flag for alias in aliases})
            visit(hint)

    visit(cls)
    return out


def one_flag_each(cls: type, args: Sequence[str], where: str) -> None:
    """UserError where ``args`` (a command line of ``cls``) give an old flag and the flag it
    stands for together (``--threshold 0.25 --prune-below 0.5``): whatever their values, which
    one is meant is not guessed."""
    given = {a.split("=", 1)[0] for a in args if a.startswith("--")}
    for alias, flag in flag_aliases(cls).items():
        if alias in given and flag in given:
            raise UserError(f"{where}: {alias} and {flag} are the same setting ({alias} is its "
                            f"old name) and both are given: keep {flag} only")
