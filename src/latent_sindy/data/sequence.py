"""Sequences of images and actions: the one data type every model, trainer and command reads.

A data set is N sequences of T+1 camera frames x_0..x_T and the T actions u_0..u_{T-1}
between them, with the box the actions live in. Everything else is optional: true states
(reference rows, probes, privileged heads) with their names, which of them are angles
(``state_periods``), the reward each action earned, split labels (else a seeded split), the
time step, and the record of the world that produced the data (metadata that world's plug-in
owns and reads).

    >>> import numpy as np
    >>> from latent_sindy import SequenceData
    >>> images = np.zeros((6, 5, 3, 20, 28), np.uint8)     # (N, T+1, C, H, W)
    >>> actions = np.zeros((6, 4, 2), np.float32)          # (N, T, nu)
    >>> data = SequenceData(images, actions, action_low=[-1, -1], action_high=[1, 1])
    >>> data.n, data.steps, data.nu, data.split_counts()
    (6, 4, 2, {'train': 4, 'val': 1, 'test': 1})
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Sequence
from dataclasses import InitVar, dataclass, field
from typing import Any

import numpy as np

from latent_sindy.data.checks import check_action_names, check_dt, check_pixels
from latent_sindy.errors import UserError

__all__ = ["SPLITS", "SequenceData", "check_action_names", "check_pixels", "concatenate",
           "seeded_split"]

SPLITS = ("train", "val", "test")
_SLACK = 1e-4


def seeded_split(n: int, seed: int = 0, val: float = 0.1, test: float = 0.1) -> np.ndarray:
    """Split labels (n,) uint8 (0 train, 1 val, 2 test): a seeded permutation, at least one
    validation and one test sequence once there are three or more."""
    n_val = max(1, round(val * n)) if n >= 3 else 0
    n_test = max(1, round(test * n)) if n >= 3 else 0
    labels = np.zeros(n, np.uint8)
    order = np.random.default_rng(seed).permutation(n)
    labels[order[:n_val]] = 1
    labels[order[n_val:n_val + n_test]] = 2
    return labels


def _names(given: Sequence[str] | None, n: int, stem: str, what: str, where: str) -> tuple:
    if given is None:
        return tuple(f"{stem}{i}" for i in range(n))
    names = tuple(str(s) for s in given)
    if len(names) != n:
        raise UserError(f"{where}: {what} has {len(names)} name(s) for {n} column(s)")
    return names


def _float_array(name: str, value: np.ndarray, lead: tuple[int, int], last: str,
                 where: str) -> np.ndarray:
    """``value`` as a finite floating-point array of shape (*lead, any); UserError if not."""
    arr = np.asarray(value)
    if arr.ndim != 3 or arr.shape[:2] != lead:
        raise UserError(f"{where}: {name} have shape {arr.shape}, expected "
                        f"({lead[0]}, {lead[1]}, {last})")
    if not np.issubdtype(arr.dtype, np.floating):
        raise UserError(f"{where}: {name} must be floating point, got {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        i = int(np.argwhere(~np.isfinite(arr))[0][0])
        raise UserError(f"{where}: {name} of sequence {i} contain NaN or inf values")
    return arr


@dataclass
class SequenceData:
    """N sequences of images (N, T+1, C, H, W) and actions (N, T, nu), with their context.

    ``images`` are uint8 (0..255) or floating point in [0, 1]; any C (1 gray, 3 colour, or
    stacked frames), H and W.
    ``actions=None`` means an autonomous system (nu = 0). ``split`` labels each sequence
    0 (train), 1 (validation) or 2 (test); without it a split seeded by ``split_seed`` is made.
    ``state_periods`` gives, per state, the period of an angle (None for other states).
    ``images_dot`` and ``images_ddot`` are optional exact time derivatives of the images (same
    shape, floating point, in the images' pixel scale per unit time) for continuous-time models.
    ``executed`` (N, T) bool says whether each action was carried out (a world may skip one it
    cannot make, e.g. out of a robot's reach); absent means all were.
    ``rewards`` (N, T) float: the reward the world gave for each action (the sum over an
    action repeat), for models that learn to predict it; absent where the world gives none.
    ``world`` names the world plug-in whose ``record`` travels with the data.
    """

    images: np.ndarray
    actions: np.ndarray | None = None
    action_low: Sequence[float] | np.ndarray | None = None
    action_high: Sequence[float] | np.ndarray | None = None
    action_names: Sequence[str] | None = None
    states: np.ndarray | None = None
    state_names: Sequence[str] | None = None
    state_periods: Sequence[float | None] | None = None
    split: InitVar[np.ndarray | None] = None
    dt: float | None = None
    world: str | None = None
    images_dot: np.ndarray | None = None
    images_ddot: np.ndarray | None = None
    executed: np.ndarray | None = None
    rewards: np.ndarray | None = None
    record: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None
    source: str = "<memory>"
    split_seed: int = 0
    split_ids: np.ndarray = field(init=False)  # (N,) uint8, index into SPLITS

    def __post_init__(self, split: np.ndarray | None) -> None:
        where = self.source
        images = np.asarray(self.images)
        if images.ndim != 5:
            raise UserError(f"{where}: images must be (N, T+1, C, H, W), got shape "
                            f"{images.shape}")
        n, t1, c = images.shape[:3]
        if c < 1:
            raise UserError(f"{where}: images need at least one channel (axis 2), shape "
                            f"{images.shape}")
        if min(images.shape[3:]) < 1:
            raise UserError(f"{where}: images need at least one pixel of height and width "
                            f"(axes 3 and 4), shape {images.shape}")
        if t1 < 2:
            raise UserError(f"{where}: sequences need at least one step, images have {t1} "
                            "frame(s)")
        if images.dtype != np.uint8:
            if not np.issubdtype(images.dtype, np.floating):
                raise UserError(f"{where}: images must be uint8 or floating point in [0, 1], "
                                f"got {images.dtype}")
            if images.size and not (np.all(np.isfinite(images)) and images.min() >= 0
                                    and images.max() <= 1):
                raise UserError(f"{where}: floating-point images must lie in [0, 1] "
                                "(scale uint8 pixels by 1/255, or pass them as uint8)")
        self.images = images
        self._check_actions(n, t1 - 1, where)
        self._check_states(n, t1, where)
        self._check_extras(n, t1, where)
        if split is None or callable(split):  # (the class's split method shadows the default)
            split = seeded_split(n, self.split_seed)
        split = np.asarray(split)
        if split.shape != (n,):
            raise UserError(f"{where}: split has shape {split.shape}, expected {(n,)}")
        if split.size and (not np.issubdtype(split.dtype, np.integer) or split.min() < 0
                           or split.max() >= len(SPLITS)):
            raise UserError(f"{where}: split labels must be the integers 0 (train), 1 (val) "
                            f"or 2 (test), found {sorted(set(split.tolist()))[:5]}")
        self.split_ids = split.astype(np.uint8)
        self.dt = check_dt(self.dt, where)

    def _check_actions(self, n: int, steps: int, where: str) -> None:
        if self.actions is None:
            self.actions = np.zeros((n, steps, 0), np.float32)
        actions = _float_array("actions", self.actions, (n, steps), "nu", where)
        nu = actions.shape[2]
        self.actions = actions
        if self.action_names is not None:
            check_action_names(self.action_names, nu, f"{where}: action_names")
        self.action_names = _names(self.action_names, nu, "u", "action_names", where)
        if nu and (self.action_low is None or self.action_high is None):
            raise UserError(f"{where}: give the action box (action_low and action_high, "
                            f"{nu} value(s) each): the planner samples within it")
        low = np.zeros(0) if self.action_low is None else np.asarray(self.action_low, float)
        high = np.zeros(0) if self.action_high is None else np.asarray(self.action_high, float)
        if low.shape != (nu,) or high.shape != (nu,):
            raise UserError(f"{where}: action_low and action_high need {nu} value(s) each, "
                            f"got {low.shape[0] if low.ndim else low} and "
                            f"{high.shape[0] if high.ndim else high}")
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low < high)):
            raise UserError(f"{where}: the action box needs finite action_low < action_high, "
                            f"got {low.tolist()} and {high.tolist()}")
        self.action_low = tuple(low.tolist())
        self.action_high = tuple(high.tolist())
        out = (actions < low - _SLACK) | (actions > high + _SLACK)
        if np.any(out):
            i, k, j = (int(v) for v in np.argwhere(out)[0])
            raise UserError(f"{where}: action {j} ({self.action_names[j]}) of step {k} of "
                            f"sequence {i} is {float(actions[i, k, j]):.4g}, outside "
                            f"[{low[j]:.4g}, {high[j]:.4g}]")

    def _check_states(self, n: int, t1: int, where: str) -> None:
        if self.states is None:
            if self.state_names or self.state_periods:
                raise UserError(f"{where}: state_names or state_periods given without states")
            self.state_names = ()
            self.state_periods = ()
            return
        states = _float_array("states", self.states, (n, t1), "ns", where)
        ns = states.shape[2]
        self.states = states
        self.state_names = _names(self.state_names, ns, "s", "state_names", where)
        periods = (None,) * ns if self.state_periods is None else tuple(
            None if p is None or (isinstance(p, float) and math.isnan(p)) else float(p)
            for p in self.state_periods)
        if len(periods) != ns or any(p is not None and not (math.isfinite(p) and p > 0)
                                     for p in periods):
            raise UserError(f"{where}: state_periods needs {ns} value(s), each a positive "
                            f"finite period or None (NaN in a file), got "
                            f"{list(self.state_periods)}")
        self.state_periods = periods

    def _check_extras(self, n: int, t1: int, where: str) -> None:
        if self.images_ddot is not None and self.images_dot is None:
            raise UserError(f"{where}: images_ddot without images_dot: a second-order model "
                            "needs the images' first derivatives as well (give both, or "
                            "neither: the frames' differences estimate them)")
        for name in ("images_dot", "images_ddot"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value)
            if arr.shape != self.images.shape:
                raise UserError(f"{where}: {name} has shape {arr.shape}, expected the images' "
                                f"{self.images.shape}")
            if not np.issubdtype(arr.dtype, np.floating) or not np.all(np.isfinite(arr)):
                raise UserError(f"{where}: {name} must be finite floating-point values")
            setattr(self, name, arr)
        if self.executed is not None:
            arr = np.asarray(self.executed)
            if arr.shape != (n, t1 - 1) or arr.dtype != np.bool_:
                raise UserError(f"{where}: executed must be a bool array of shape "
                                f"{(n, t1 - 1)} (one flag per action), got {arr.dtype} "
                                f"{arr.shape}")
            self.executed = arr
        if self.rewards is not None:
            arr = np.asarray(self.rewards)
            if arr.shape != (n, t1 - 1) or not np.issubdtype(arr.dtype, np.floating):
                raise UserError(f"{where}: rewards must be a floating-point array of shape "
                                f"{(n, t1 - 1)} (one reward per action), got {arr.dtype} "
                                f"{arr.shape}")
            if not np.all(np.isfinite(arr)):
                i = int(np.argwhere(~np.isfinite(arr))[0][0])
                raise UserError(f"{where}: rewards of sequence {i} contain NaN or inf values")
            self.rewards = arr

    # ------------------------------------------------------------------ views

    @property
    def n(self) -> int:
        return len(self.images)

    @property
    def steps(self) -> int:
        return self.images.shape[1] - 1

    @property
    def nu(self) -> int:
        return self.actions.shape[2]

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """(C, H, W)"""
        return tuple(self.images.shape[2:])

    def replace(self, **changes: Any) -> SequenceData:
        """A copy with ``changes`` (the split labels kept unless given)."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}
        fields.update(split=self.split_ids, state_names=self.state_names or None,
                      state_periods=self.state_periods or None)
        fields.update(changes)
        return SequenceData(**fields)

    def subset(self, keep: np.ndarray) -> SequenceData:
        """The sequences selected by ``keep`` (a boolean mask or indices), same context."""
        def part(arr: np.ndarray | None) -> np.ndarray | None:
            return None if arr is None else arr[keep]

        return self.replace(images=self.images[keep], actions=self.actions[keep],
                            states=part(self.states), images_dot=part(self.images_dot),
                            images_ddot=part(self.images_ddot), executed=part(self.executed),
                            rewards=part(self.rewards), split=self.split_ids[keep])

    def split(self, name: str) -> SequenceData:  # noqa: F811  (the constructor takes split=)
        """The sequences of one split ('train', 'val' or 'test')."""
        if name not in SPLITS:
            raise UserError(f"split {name!r} does not exist: use one of {', '.join(SPLITS)}")
        return self.subset(self.split_ids == SPLITS.index(name))

    def split_counts(self) -> dict[str, int]:
        return {s: int(np.sum(self.split_ids == i)) for i, s in enumerate(SPLITS)}

    def fingerprint(self) -> str:
        """SHA-256 of the arrays (images, actions, states, split): equal data, equal print."""
        h = hashlib.sha256()
        arrays = [self.images, self.actions]
        if self.states is not None:
            arrays.append(self.states)
        for arr in (*arrays, self.split_ids):
            a = np.ascontiguousarray(arr)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def extras_fingerprint(self) -> str:
        """SHA-256 of the optional arrays :meth:`fingerprint` leaves out: the exact
        derivatives (``images_dot``, ``images_ddot``), which actions were ``executed`` and,
        where there are any, the ``rewards`` (data without rewards print as they did before
        rewards existed; the time step and the action box are compared as they are)."""
        h = hashlib.sha256()
        names = ("images_dot", "images_ddot", "executed")
        for name in names + (("rewards",) if self.rewards is not None else ()):
            arr = getattr(self, name)
            h.update(f"{name}:".encode())
            if arr is not None:
                a = np.ascontiguousarray(arr)
                h.update(f"{a.dtype.str}{a.shape}".encode())
                h.update(a.tobytes())
        return h.hexdigest()

    def pixel_stats(self) -> tuple[float, float]:
        """Scalar mean and std of the training split's pixels, in the images' own scale.

        A sequence at a time in float64 (two passes: the mean, then the squared deviations),
        so the memory is one sequence's, not the whole split's in float64 (BENCHMARKS.md)."""
        train = np.flatnonzero(self.split_ids == 0)
        n = train.size * int(np.prod(self.images.shape[1:]))
        if n == 0:
            raise UserError(f"{self.source} has no training sequences to normalise with")
        mean = sum(float(np.asarray(self.images[i], np.float64).sum()) for i in train) / n
        squares = sum(float(np.square(np.asarray(self.images[i], np.float64) - mean).sum())
                      for i in train)
        return float(mean), float(np.sqrt(squares / n))

    def pixel_scale(self) -> float:
        """255 for uint8 images, 1 for floating-point ones."""
        return 255.0 if self.images.dtype == np.uint8 else 1.0

    def describe(self) -> dict[str, Any]:
        """What a model trained on this data must know of it (stored in its run folder)."""
        return {"frame_shape": list(self.frame_shape), "pixel_dtype": str(self.images.dtype),
                "action_low": list(self.action_low), "action_high": list(self.action_high),
                "action_names": list(self.action_names), "state_names": list(self.state_names),
                "state_periods": list(self.state_periods), "dt": self.dt, "world": self.world}

    @property
    def poses(self) -> np.ndarray:
        """The states, for code that reads them as poses; refused when there are none."""
        if self.states is None:
            raise UserError(f"{self.source} has no states: this needs data with true states "
                            "(write them as the dataset 'states')")
        return self.states

    @property
    def world_config(self) -> Any:
        """The settings of the world that recorded the data, read by that world's plug-in
        from ``record``; refused for data of no world."""
        if self.world is None:
            raise UserError(f"{self.source} was not recorded in a world of latent-sindy: this "
                            "needs a world's data (e.g. `latent-sindy collect`)")
        from latent_sindy.plugins import get_world

        return get_world(self.world).config_from_record(self.record, self.source)


#: The optional per-sequence arrays, which every part of a concatenation has or none does.
_OPTIONAL = ("states", "images_dot", "images_ddot", "executed", "rewards")


def concatenate(parts: Sequence[SequenceData]) -> SequenceData:
    """The sequences of ``parts`` one after another, with their split labels; the context
    (action box and names, state names and periods, dt, world and its record) is the first
    part's, and the others must agree with it (UserError naming what differs)."""
    if not parts:
        raise UserError("concatenate needs at least one SequenceData")
    first = parts[0]
    for k, part in enumerate(parts[1:], 1):
        differs = [name for name, a, b in (
            ("frame shape", first.frame_shape, part.frame_shape),
            ("pixel type", first.images.dtype, part.images.dtype),
            ("steps", first.steps, part.steps), ("action box", (first.action_low,
             first.action_high), (part.action_low, part.action_high)),
            ("state names", first.state_names, part.state_names),
            ("dt", first.dt, part.dt), ("world", first.world, part.world))
            if a != b]
        differs += [name for name in _OPTIONAL
                    if (getattr(first, name) is None) != (getattr(part, name) is None)]
        if differs:
            raise UserError(f"concatenate: part {k} ({part.source}) differs from part 0 "
                            f"({first.source}) in {', '.join(differs)}")
    joined = {name: np.concatenate([getattr(p, name) for p in parts])
              for name in ("images", "actions", *_OPTIONAL) if getattr(first, name) is not None}
    return first.replace(**joined, split=np.concatenate([p.split_ids for p in parts]))
