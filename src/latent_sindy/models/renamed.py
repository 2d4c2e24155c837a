"""Settings renamed since run folders were written: their old names still read.

A config dataclass decorated with ``@renamed(old="new", ...)`` records the map in its
``renamed_settings`` class variable, the one place that knows the old names. From it

* :func:`latent_sindy.configs.from_json` reads a record (a run folder's ``config.json``)
  written with an old key as the new setting (it applies ``renamed_settings``);
* the constructor and ``dataclasses.replace`` take the old keyword;
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
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["renamed"]

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
            init(self, *args, **_new_names(old_to_new, kwargs))

        cls.__init__ = __init__
        for old, new in old_to_new.items():
            setattr(cls, old, property(lambda self, new=new: getattr(self, new),
                                       doc=f"The setting now named ``{new}`` (read-only)."))
        return cls

    return decorate


def _new_names(old_to_new: dict[str, str], kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` with the old names as the new ones; an old name wins over its new one
    (``dataclasses.replace(c, old=v)`` passes the new one too)."""
    if not any(old in kwargs for old in old_to_new):
        return kwargs
    out = dict(kwargs)
    for old, new in old_to_new.items():
        if old in out:
            out[new] = out.pop(old)
    return out
