"""What ``--sweep`` and ``--seeds`` accept: the sweepable settings, sweeps and seed lists.

A sweep names one model setting (:data:`SWEEPABLE`) and its values; the study trains every
chosen model that has the setting once per value (:func:`.catalogue.study_specs`).

    latent-sindy reproduce --models sindy2 --sweep lambda_l1=1e-3,1e-2 --seeds 0..2

    >>> Sweep.parse("order=1,2").variants()
    [('order=1', 1), ('order=2', 2)]
    >>> parse_seeds(["0..2", "5"])
    (0, 1, 2, 5)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import tyro

from latent_sindy.errors import UserError

if TYPE_CHECKING:
    from latent_sindy.experiments.catalogue import ModelSpec

__all__ = ["SWEEPABLE", "Seeds", "Sweep", "Sweepable", "Sweeps", "parse_seeds",
           "parse_sweeps"]


def parse_seeds(args: list[str]) -> tuple[int, ...]:
    """Seeds from the command line: ``0 1 2``, ``0,1,2``, ranges ``0..9`` (both ends
    included), or a mix; UserError naming the bad part."""
    seeds: list[int] = []
    for arg in args:
        for part in arg.split(","):
            lo, dots, hi = part.partition("..")
            try:
                seeds.extend(range(int(lo), int(hi) + 1) if dots else [int(part)])
            except ValueError:
                raise UserError(f"--seeds {part!r}: give integers (0 1 2), a list (0,1,2) or "
                                "a range (0..9)") from None
            if dots and int(hi) < int(lo):
                raise UserError(f"--seeds {part}: a range runs from low to high (e.g. 0..9)")
    return tuple(seeds)


Seeds = Annotated[tuple[int, ...], tyro.constructors.PrimitiveConstructorSpec(
    nargs="*", metavar="SEED|A..B", instance_from_str=parse_seeds,
    is_instance=lambda v: isinstance(v, tuple), str_from_instance=lambda v: [str(s) for s in v])]


@dataclass(frozen=True)
class Sweepable:
    """A model setting a sweep may vary: its value type, where it applies, how to set it."""

    kind: type
    label: str
    applies: Callable[[ModelSpec], bool]
    apply: Callable[[ModelSpec, Any], ModelSpec]


def _loss_weight(name: str) -> Sweepable:
    return Sweepable(float, {"lambda_pred_x": "λ1", "lambda_pred_z": "λ2",
                             "lambda_l1": "λ3"}[name], lambda spec: True,
                     lambda spec, v: dataclasses.replace(
                         spec, loss=dataclasses.replace(spec.loss, **{name: v})))


def _is_sindy(spec: ModelSpec) -> bool:
    return spec.model.dynamics.kind == "sindy"


def _is_sindy_on_fixed_encoder(spec: ModelSpec) -> bool:
    return _is_sindy(spec) and spec.model.observation.fixed_encoder


def _set_order(spec: ModelSpec, order: int) -> ModelSpec:
    dyn = dataclasses.replace(spec.model.dynamics, order=order)
    return dataclasses.replace(spec, model=dataclasses.replace(spec.model, dynamics=dyn))


#: The settings ``--sweep`` may vary, by name.
SWEEPABLE: dict[str, Sweepable] = {
    "lambda_l1": _loss_weight("lambda_l1"),
    "lambda_pred_x": _loss_weight("lambda_pred_x"),
    "lambda_pred_z": _loss_weight("lambda_pred_z"),
    "order": Sweepable(int, "order", _is_sindy, _set_order),
    "window": Sweepable(int, "H", lambda spec: True,
                        lambda spec, v: dataclasses.replace(spec, window=v)),
    "threshold": Sweepable(float, "τ", _is_sindy,
                           lambda spec, v: dataclasses.replace(spec, threshold=v)),
    "init_threshold": Sweepable(float, "STLSQ threshold", _is_sindy_on_fixed_encoder,
                                lambda spec, v: dataclasses.replace(spec, init_threshold=v)),
}


@dataclass(frozen=True)
class Sweep:
    """One setting (:data:`SWEEPABLE`) and the values a study trains each model with."""

    setting: str
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        text = f"--sweep {self.setting}={','.join(map(str, self.values))}"
        if self.setting not in SWEEPABLE:
            raise UserError(f"{text}: unknown setting {self.setting!r}; sweepable: "
                            f"{', '.join(SWEEPABLE)}")
        if not self.values or len(set(self.values)) != len(self.values):
            raise UserError(f"{text}: give distinct values, e.g. {self.setting}=1,2")

    @staticmethod
    def parse(text: str) -> Sweep:
        """``SETTING=V1,V2,...``, e.g. ``lambda_l1=1e-3,1e-2``."""
        setting, eq, values = text.partition("=")
        if not eq or not values:
            raise UserError(f"--sweep {text!r}: write SETTING=V1,V2 (e.g. lambda_l1=1e-3,1e-2); "
                            f"sweepable: {', '.join(SWEEPABLE)}")
        kind = SWEEPABLE[setting].kind if setting in SWEEPABLE else float
        parsed = []
        for v in values.split(","):
            try:
                parsed.append(kind(v))
            except ValueError:
                raise UserError(f"--sweep {text}: {v!r} is not a{'n' if kind is int else ''} "
                                f"{kind.__name__}") from None
        names = [f"{v:g}" for v in parsed]
        if len(set(names)) != len(names):
            raise UserError(f"--sweep {text}: values {', '.join(values.split(','))} name the same "
                            "run twice (6 significant digits): give distinct values")
        return Sweep(setting, tuple(parsed))

    def variants(self) -> list[tuple[str, Any]]:
        """(name suffix, value) per value, e.g. ``("lambda_l1=0.001", 0.001)``."""
        return [(f"{self.setting}={v:g}", v) for v in self.values]


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
