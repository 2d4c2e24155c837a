"""The data file: HDF5 that anyone can write with h5py alone, validated on every open.

Layout (what a user writes; docs/data.md)::

    /images   (N, T+1, C, H, W)  uint8 (or float in [0, 1])   frames x_0..x_T, channels first
    /actions  (N, T, nu)         float                         actions u_0..u_{T-1}
    /states   (N, T+1, ns)       float      optional           true states (reference, probes)
    /split    (N,)               uint8      optional           0 train, 1 validation, 2 test
    /rewards  (N, T)             float      optional           the reward of each action
    attributes: action_low, action_high (nu floats; required when nu > 0);
                optional action_names, state_names (strings), state_periods (the period of
                an angle state, NaN for other states), dt (float)

A file without ``actions`` is an autonomous system (nu = 0). What latent-sindy writes adds
``format`` (``latent-sindy-sequences``), ``format_version``, ``package_version``, ``created``,
``seed``, ``world`` and ``world_record`` (the world's own JSON record, read by its plug-in),
``pixel_mean`` and ``pixel_std`` (training split). A file that latent-sindy wrote in another
format or format version is refused with one line: re-collect it (docs/compatibility.md).

A file is only ever written whole, to a temporary name that is renamed into place, so a
reader sees either nothing or a complete file.

    from latent_sindy.data import read_sequences
    data = read_sequences("data/push.h5")
    train = data.split("train")
"""

from __future__ import annotations

import json
import math
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from latent_sindy.atomic import atomic_path, check_memory
from latent_sindy.data.sequence import SPLITS, SequenceData
from latent_sindy.errors import UserError

__all__ = ["DATASETS", "FORMAT", "FORMAT_VERSION", "read_sequences", "write_sequences"]

FORMAT = "latent-sindy-sequences"
FORMAT_VERSION = 3


def write_sequences(path: str | os.PathLike, data: SequenceData) -> None:
    """Write `data` to `path` atomically (temporary file, then rename)."""
    from latent_sindy.version import __version__

    mean, std = data.pixel_stats()
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.create_dataset("images", data=data.images, chunks=(1, *data.images.shape[1:]),
                         compression="gzip", compression_opts=4, shuffle=True)
        if data.nu:
            f.create_dataset("actions", data=data.actions.astype(np.float32))
        if data.states is not None:
            f.create_dataset("states", data=data.states.astype(np.float32))
        for name in ("images_dot", "images_ddot"):
            if getattr(data, name) is not None:
                f.create_dataset(name, data=getattr(data, name).astype(np.float32),
                                 chunks=(1, *data.images.shape[1:]), compression="gzip")
        if data.executed is not None:
            f.create_dataset("executed", data=data.executed)
        if data.rewards is not None:
            f.create_dataset("rewards", data=data.rewards.astype(np.float32))
        f.create_dataset("split", data=data.split_ids.astype(np.uint8))
        f["split"].attrs["names"] = json.dumps(SPLITS)
        attrs: dict[str, Any] = {
            "format": FORMAT, "format_version": FORMAT_VERSION,
            "package_version": __version__,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "seed": -1 if data.seed is None else int(data.seed),
            "steps": data.steps, "pixel_mean": mean, "pixel_std": std,
            "world_record": json.dumps(data.record),
        }
        if data.nu:
            attrs.update(action_low=np.asarray(data.action_low, np.float64),
                         action_high=np.asarray(data.action_high, np.float64),
                         action_names=list(data.action_names))
        if data.states is not None:
            attrs.update(state_names=list(data.state_names), state_periods=np.array(
                [math.nan if p is None else p for p in data.state_periods], np.float64))
        if data.dt is not None:
            attrs["dt"] = float(data.dt)
        if data.world is not None:
            attrs["world"] = data.world
        f.attrs.update(attrs)


def _strings(value: Any) -> list[str] | None:
    if value is None:
        return None
    if isinstance(value, bytes | str):  # one name, or a JSON list of names
        text = value.decode() if isinstance(value, bytes) else value
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            return [text]
        return [str(v) for v in (value if isinstance(value, list) else [value])]
    return [v.decode() if isinstance(v, bytes) else str(v) for v in np.asarray(value).ravel()]


#: The datasets a data file may hold; anything else in it (a group of the user's own
#: metadata, another dataset) is left alone.
DATASETS = ("images", "actions", "states", "poses", "split", "images_dot", "images_ddot",
            "executed", "rewards")


def _check_sizes(f: h5py.File, path: Path) -> None:
    """Refuse from the shapes alone what would not fit in memory (before reading a byte)."""
    ours = [k for k in DATASETS if k in f]
    for k in ours:
        if not isinstance(f[k], h5py.Dataset):
            raise UserError(f"{path}: /{k} is an HDF5 group, not a dataset: write the array "
                            "itself under that name (docs/data.md)")
    total = sum(int(np.prod(f[k].shape)) * f[k].dtype.itemsize for k in ours)
    check_memory(total, f"{path} ({', '.join(f'{k} {f[k].shape}' for k in ours)})",
                 "use a smaller data set")


def _number_attr(attrs: Any, key: str, path: Path, kind: type, meaning: str,
                 example: str) -> Any:
    """The attribute ``key`` as one number of ``kind`` (None where absent); a UserError
    naming the attribute and what it holds where it is a word, a list or a bool."""
    if key not in attrs:
        return None
    value = attrs[key]
    if isinstance(value, np.ndarray) and value.shape in ((), (1,)):
        value = value.reshape(()).item()
    number = (np.integer, int) if kind is int else (np.integer, np.floating, int, float)
    if isinstance(value, bool | np.bool_) or not isinstance(value, number):
        shown = (value.decode(errors="replace") if isinstance(value, bytes)
                 else value.tolist() if isinstance(value, np.generic | np.ndarray) else value)
        raise UserError(f"{path}: the attribute {key} holds {shown!r}, not a number: set it "
                        f"to {meaning} (f.attrs[{key!r}] = {example} with h5py), or delete it")
    return kind(value)


def _executed(f: h5py.File, path: Path) -> np.ndarray | None:
    """/executed as bools: stored as bools, or as integers 0 and 1; anything else refused
    (a 7 is no answer to whether an action was carried out)."""
    if "executed" not in f:
        return None
    arr = f["executed"][()]
    if arr.dtype == np.bool_:
        return arr
    if np.issubdtype(arr.dtype, np.integer) and np.all((arr == 0) | (arr == 1)):
        return arr.astype(bool)
    found = np.unique(arr)[:5].tolist() if arr.size else []
    raise UserError(f"{path}: /executed must hold booleans (or 0 and 1), got {arr.dtype} "
                    f"values {found}: write it as a bool array")


def _read(f: h5py.File, path: Path) -> SequenceData:
    fmt = f.attrs.get("format")
    version = f.attrs.get("format_version", FORMAT_VERSION if fmt == FORMAT else None)
    if isinstance(fmt, str) and fmt.startswith("latent-sindy-") and (
            fmt != FORMAT or version != FORMAT_VERSION):
        shown = version.item() if isinstance(version, np.generic) else version
        raise UserError(f"{path} was written by another version of latent-sindy ({fmt} "
                        f"version {shown}; this one reads {FORMAT} version {FORMAT_VERSION}): "
                        "re-collect it")
    if fmt is not None and fmt != FORMAT:
        raise UserError(f"{path} is an HDF5 file but not a latent-sindy data file (format "
                        f"attribute {fmt!r}); see docs/data.md for the layout")
    if "images" not in f:
        raise UserError(f"{path} lacks the dataset 'images' (N, T+1, C, H, W); see "
                        "docs/data.md for the layout")
    a = f.attrs
    periods = a.get("state_periods")
    record = json.loads(a.get("world_record", "{}"))
    seed = _number_attr(a, "seed", path, int, "the seed the data was collected with", "0")
    dt = _number_attr(a, "dt", path, float, "the time between frames in seconds", "0.1")
    return SequenceData(
        images=f["images"][()],
        actions=f["actions"][()] if "actions" in f else None,
        action_low=a.get("action_low"), action_high=a.get("action_high"),
        action_names=_strings(a.get("action_names")),
        states=f["states"][()] if "states" in f else None,
        state_names=_strings(a.get("state_names")),
        state_periods=None if periods is None else [float(p) for p in np.ravel(periods)],
        split=f["split"][()] if "split" in f else None,
        images_dot=f["images_dot"][()] if "images_dot" in f else None,
        images_ddot=f["images_ddot"][()] if "images_ddot" in f else None,
        executed=_executed(f, path),
        rewards=f["rewards"][()] if "rewards" in f else None,
        dt=dt,
        world=_strings(a.get("world"))[0] if "world" in a else None,
        record=record, seed=None if seed is None or seed < 0 else seed, source=str(path))


def read_sequences(path: str | os.PathLike) -> SequenceData:
    """Open and validate a data file; every problem is a one-line UserError."""
    path = Path(path)
    if not path.exists() and path.is_symlink():  # (exists() follows the link)
        raise UserError(f"{path} is a symbolic link that leads to no file (a loop, or its "
                        "target is gone): point it at a data file or give the file itself")
    if not path.exists():
        raise UserError(f"{path} does not exist: collect data first with "
                        f"`latent-sindy collect --out {path}`, or write one (docs/data.md)")
    if path.is_dir():
        raise UserError(f"{path} is a directory, not a data file (.h5)")
    if not h5py.is_hdf5(path):
        raise UserError(f"{path} is not an HDF5 file (truncated, or some other format)")
    try:
        with h5py.File(path, "r") as f:
            _check_sizes(f, path)
            data = _read(f, path)
    except UserError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise UserError(f"{path} is damaged ({type(e).__name__}: {e}); re-collect it") from e
    if data.world is not None:
        from latent_sindy.plugins import get_world, hook

        check = hook(get_world(data.world), "check_data")
        if check is not None:
            check(data)
    return data
