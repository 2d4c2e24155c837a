"""What two runs of a study must share when they ran the same seeds: every measured number of
summary.json (timings left out), the data, and the trained weights of every run folder."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import torch

#: Metrics that measure time, not the model: they differ between any two runs.
TIMED = re.compile(r"(plan_ms_mean|warmup_ms|train/seconds)$")


def _untimed(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if not TIMED.search(k)}
    return obj


def summary_numbers(out: Path) -> dict[str, Any]:
    """The parts of OUT/summary.json that depend only on the data, seeds and settings."""
    s = json.loads((out / "summary.json").read_text())
    study, results = s["study"], s["results"]
    record = {k: _untimed(study[k]) for k in ("scale", "models", "control")}
    record.update({k: _untimed(results[k]) for k in (
        "train_status", "failures", "baselines", "aggregate", "per_seed", "losses_per_seed")})
    record["seeds"] = s["seeds"]
    record["data"] = {k: v for k, v in study["data"].items() if k != "path"}
    return record


def weights(out: Path) -> dict[str, dict[str, torch.Tensor]]:
    """runs/seed<S>/<model> -> every tensor of its model.pt (by key path)."""
    found: dict[str, dict[str, torch.Tensor]] = {}
    for path in sorted(out.glob("runs/seed*/*/model.pt")):
        flat: dict[str, torch.Tensor] = {}

        def walk(obj: Any, key: str, flat: dict[str, torch.Tensor] = flat) -> None:
            if isinstance(obj, torch.Tensor):
                flat[key] = obj
            elif isinstance(obj, dict):
                for k, v in obj.items():
                    walk(v, f"{key}/{k}")

        walk(torch.load(path, map_location="cpu", weights_only=True), "")
        found[str(path.parent.relative_to(out))] = flat
    return found


def assert_same_study(a: Path, b: Path) -> None:
    """The two study folders hold the same numbers and bit-identical trained weights."""
    assert summary_numbers(a) == summary_numbers(b)
    wa, wb = weights(a), weights(b)
    assert wa and sorted(wa) == sorted(wb)
    for run, tensors in wa.items():
        assert sorted(tensors) == sorted(wb[run]), run
        for key, t in tensors.items():
            assert torch.equal(t, wb[run][key]), f"{run}: {key} differs"
