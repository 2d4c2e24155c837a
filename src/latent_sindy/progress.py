"""Progress reporting, passed in as an object so library code never prints by itself.

:class:`Progress` is what long work (training epochs) reports to; :class:`TqdmProgress` draws
a bar, :class:`Milestones` prints a few lines (for logs of worker processes), :class:`Silent`
shows nothing. :func:`bar` wraps an iterable (trajectories collected, episodes run) in a tqdm
bar on stderr, so stdout stays free for results.

    from latent_sindy.progress import TqdmProgress, bar
    train(cfg, TqdmProgress("train"))
    for item in bar(items, total=len(items), desc="collect", unit="traj"): ...
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Mapping
from typing import Any, Protocol, TypeVar

__all__ = ["Milestones", "Progress", "Silent", "TqdmProgress", "bar", "say_stderr"]

T = TypeVar("T")


def say_stderr(text: str) -> None:
    """A progress line on stderr (stdout stays free for results)."""
    print(text, file=sys.stderr, flush=True)


def bar(iterable: Iterable[T], total: int | None = None, initial: int = 0, desc: str = "",
        unit: str = "it", leave: bool = True) -> Iterable[T]:
    """``iterable`` wrapped in a tqdm progress bar on stderr."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, initial=initial, desc=desc, unit=unit, leave=leave,
                dynamic_ncols=True, file=sys.stderr)


class Progress(Protocol):
    """What training reports to: a progress bar, a logger, a test recorder."""

    def start(self, total: int, initial: int) -> None:
        """Work will run steps initial+1..total."""

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        """Step `epoch` finished with this metrics row."""

    def note(self, text: str) -> None:
        """Something the user should know (e.g. no validation split)."""

    def close(self) -> None:
        """The work ended (normally or not)."""


class Silent:
    """Shows nothing."""

    def start(self, total: int, initial: int) -> None: ...
    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None: ...
    def note(self, text: str) -> None: ...
    def close(self) -> None: ...


class TqdmProgress:
    """A tqdm bar over epochs showing the current train/val objective and SINDy's terms."""

    def __init__(self, desc: str = "train") -> None:
        self.desc = desc
        self.bar: Any = None
        self.val: float | None = None  # the last validation loss (not every epoch has one)

    def start(self, total: int, initial: int) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=total, initial=initial, desc=self.desc, unit="epoch",
                        dynamic_ncols=True, file=sys.stderr)

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        if metrics.get("val/objective") is not None:
            self.val = metrics["val/objective"]
        shown = {"train": metrics.get("train/objective"), "val": self.val,
                 "active": metrics.get("sindy/active")}
        self.bar.set_postfix({k: f"{v:.4g}" for k, v in shown.items() if v is not None},
                             refresh=False)
        self.bar.update(1)

    def note(self, text: str) -> None:
        from tqdm import tqdm

        tqdm.write(text, file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class Milestones:
    """Training progress as a few lines (every 20% of the epochs), for logs from workers."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.every = self.total = 1

    def start(self, total: int, initial: int) -> None:
        self.total = total
        self.every = max(1, total // 5)

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        if epoch % self.every == 0 or epoch == self.total:
            val = metrics.get("val/objective")
            say_stderr(f"    {self.label}: epoch {epoch}/{self.total}, train "
                       f"{metrics['train/objective']:.4g}"
                       + ("" if val is None else f", val {val:.4g}"))

    def note(self, text: str) -> None:
        say_stderr(f"    {self.label}: {text}")

    def close(self) -> None: ...
