"""What ``--sweep`` accepts: the sweepable settings and sweeps (``--seeds``:
:mod:`latent_sindy.study.settings`).

A sweep names one model setting (:data:`SWEEPABLE`) and its values; the study trains every
chosen model that has the setting once per value (:func:`.catalogue.study_specs`). Every
value is checked when the sweep is read, before anything runs; :data:`SWEEPABLE` is also
what ``reproduce --help`` lists (:func:`sweep_help`).

    latent-sindy reproduce --models sindy2 --sweep lambda_l1=1e-3,1e-2 --seeds 0..2

    >>> Sweep.parse("order=1,2").variants()
    [('order=1', 1), ('order=2', 2)]
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import tyro

from latent_sindy.errors import UserError
from latent_sindy.sindy import VALID_ORDERS

if TYPE_CHECKING:
    from latent_sindy.worlds.push.study.spec import ModelSpec

__all__ = ["SWEEPABLE", "Sweep", "Sweepable", "Sweeps", "check_windows", "parse_sweeps",
           "sweep_help", "sweepable"]


@dataclass(frozen=True)
class Sweepable:
    """A model setting a sweep may vary: its value type and label, what it is and which
    models have it (the help's words), where it applies, how to set it, which values it
    takes."""

    kind: type
    label: str
    """Its name in tables and figures, e.g. λ3."""
    meaning: str
    """What it is, e.g. "the L1 weight of SINDy's coefficients"."""
    models: str
    """Which models have it, in words, e.g. "SINDy models"."""
    applies: Callable[[ModelSpec], bool]
    apply: Callable[[ModelSpec, Any], ModelSpec]
    valid: Callable[[Any], bool]
    rule: str
    """The values it takes, in words: what a refused value is told to be."""


def _non_negative(v: float) -> bool:
    return math.isfinite(v) and v >= 0


def _every_model(spec: ModelSpec) -> bool:
    return True


def _is_sindy(spec: ModelSpec) -> bool:
    return spec.model.dynamics.kind == "sindy"


def _has_order(spec: ModelSpec) -> bool:
    """SINDy whose library takes more than one order: the face and frame libraries are
    order 1 by construction (their push terms hold the higher products)."""
    return _is_sindy(spec) and len(spec.model.dynamics.named.orders) > 1


def _is_sindy_on_fixed_encoder(spec: ModelSpec) -> bool:
    return _is_sindy(spec) and spec.model.observation.fixed_encoder


def _loss_weight(name: str, label: str, meaning: str, applies: Callable[[ModelSpec], bool],
                 models: str) -> Sweepable:
    return Sweepable(float, label, meaning, models, applies,
                     lambda spec, v: dataclasses.replace(
                         spec, loss=dataclasses.replace(spec.loss, **{name: v})),
                     _non_negative, "a finite number >= 0")


def _set_order(spec: ModelSpec, order: int) -> ModelSpec:
    dyn = dataclasses.replace(spec.model.dynamics, order=order)
    return dataclasses.replace(spec, model=dataclasses.replace(spec.model, dynamics=dyn))


#: The settings ``--sweep`` may vary, by name.
SWEEPABLE: dict[str, Sweepable] = {
    "lambda_l1": _loss_weight("lambda_l1", "λ3", "the L1 weight of SINDy's coefficients",
                              _is_sindy, "SINDy models"),
    "lambda_pred_x": _loss_weight("lambda_pred_x", "λ1", "the image prediction weight",
                                  _every_model, "every model"),
    "lambda_pred_z": _loss_weight("lambda_pred_z", "λ2", "the latent prediction weight",
                                  _every_model, "every model"),
    "order": Sweepable(int, "order", "the library's polynomial order",
                       "SINDy models but those of the face and frame libraries (order 1)",
                       _has_order, _set_order, lambda v: v in VALID_ORDERS,
                       f"one of {', '.join(map(str, VALID_ORDERS))}"),
    "window": Sweepable(int, "H", "the training window in pushes", "every model",
                        _every_model, lambda spec, v: dataclasses.replace(spec, window=v),
                        lambda v: v >= 1, "1 or more pushes"),
    "prune_below": Sweepable(float, "τ", "the pruning cut, |Ψ| < τ pruned", "SINDy models",
                             _is_sindy, lambda spec, v: dataclasses.replace(spec, prune_below=v),
                             _non_negative, "a finite number >= 0"),
    "init_share": Sweepable(float, "STLSQ share",
                            "the smallest share a term may contribute in the sparse regression "
                            "the coefficients start from",
                            "SINDy models on a fixed encoder (moments, state)",
                            _is_sindy_on_fixed_encoder,
                            lambda spec, v: dataclasses.replace(spec, init_share=v),
                            _non_negative, "a finite number >= 0"),
}

def sweepable(setting: str) -> Sweepable:
    """The :data:`SWEEPABLE` entry of ``setting``."""
    return SWEEPABLE[setting]


def sweep_help() -> str:
    """The ``--sweep`` help of ``reproduce``: every setting of :data:`SWEEPABLE`."""
    settings = "; ".join(f"{name} ({'' if s.label == name else f'{s.label}, '}{s.meaning}: "
                         f"{s.models})" for name, s in SWEEPABLE.items())
    return ("Train every chosen model that has a setting with each value of it, e.g. "
            "lambda_l1=1e-3,1e-2 or order=1,2,3 (several: every combination); the other "
            f"models train once. Sweepable: {settings}. Each variant is a model of its own "
            "(NAME.SETTING=VALUE) in the tables, sweep.md and every figure.")


def _check_values(setting: str, values: tuple[Any, ...], text: str) -> None:
    """UserError, named as the sweep ``text``, for an unknown setting or a value it
    does not take."""
    if setting not in SWEEPABLE:
        raise UserError(f"{text}: unknown setting {setting!r}; sweepable: "
                        f"{', '.join(SWEEPABLE)}")
    if not values or len(set(values)) != len(values):
        raise UserError(f"{text}: give distinct values, e.g. {setting}=1,2")
    s = sweepable(setting)
    bad = [v for v in values if not s.valid(v)]
    if bad:
        raise UserError(f"{text}: {setting} {', '.join(f'{v:g}' for v in bad)}: use "
                        f"{s.rule} ({s.label}, {s.meaning})")


@dataclass(frozen=True)
class Sweep:
    """One setting (:data:`SWEEPABLE`) and the values a study trains each model with."""

    setting: str
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        _check_values(self.setting, self.values, self.text)

    @property
    def text(self) -> str:
        """As written on the command line, e.g. ``--sweep lambda_l1=0.001,0.01``."""
        return f"--sweep {self.setting}={','.join(f'{v:g}' for v in self.values)}"

    @staticmethod
    def parse(text: str) -> Sweep:
        """``SETTING=V1,V2,...``, e.g. ``lambda_l1=1e-3,1e-2``."""
        setting, eq, values = text.partition("=")
        if not eq or not values:
            raise UserError(f"--sweep {text!r}: write SETTING=V1,V2 (e.g. lambda_l1=1e-3,1e-2); "
                            f"sweepable: {', '.join(SWEEPABLE)}")
        kind = sweepable(setting).kind if setting in SWEEPABLE else float
        parsed = []
        for v in values.split(","):
            try:
                parsed.append(kind(v))
            except ValueError:
                raise UserError(f"--sweep {text}: {v!r} is not a{'n' if kind is int else ''} "
                                f"{kind.__name__}") from None
        _check_values(setting, tuple(parsed), f"--sweep {text}")
        names = [f"{v:g}" for v in parsed]
        if len(set(names)) != len(names):
            raise UserError(f"--sweep {text}: values {', '.join(values.split(','))} name the same "
                            "run twice (6 significant digits): give distinct values")
        return Sweep(setting, tuple(parsed))

    def variants(self) -> list[tuple[str, Any]]:
        """(name suffix, value) per value, e.g. ``("lambda_l1=0.001", 0.001)``."""
        return [(f"{self.setting}={v:g}", v) for v in self.values]


def check_windows(sweeps: tuple[Sweep, ...], steps: int, trajectories: str) -> None:
    """UserError, named as the sweep's, for a swept window longer than the ``steps`` pushes
    of the study's ``trajectories`` (words naming them)."""
    for sweep in sweeps:
        if sweep.setting == "window" and max(sweep.values) > steps:
            long = ", ".join(f"{v:g}" for v in sweep.values if v > steps)
            raise UserError(f"{sweep.text}: window {long} is longer than {trajectories} "
                            f"({steps} pushes): use 1 to {steps}")


def parse_sweeps(args: list[str]) -> tuple[Sweep, ...]:
    sweeps = tuple(Sweep.parse(a) for a in args)
    names = [s.setting for s in sweeps]
    if len(set(names)) != len(names):
        raise UserError(f"--sweep {' '.join(args)}: name each setting once")
    return sweeps


Sweeps = Annotated[tuple[Sweep, ...], tyro.constructors.PrimitiveConstructorSpec(
    nargs="*", metavar="SETTING=V1,V2", instance_from_str=parse_sweeps,
    is_instance=lambda v: isinstance(v, tuple),
    str_from_instance=lambda v: [f"{s.setting}={','.join(map(str, s.values))}" for s in v])]
