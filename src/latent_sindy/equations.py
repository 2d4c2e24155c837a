"""The discovered latent equations of a trained run, as text and as coefficient files.

For a SINDy run: one update rule per latent state with its active terms only, the number of
active coefficients and the sparsity; for a linear run: ``z[t+1] = A z + B u + c`` written out
per state. Both export their coefficients as rows ``(state, term, value)`` to
``RUN/coefficients.csv`` and ``RUN/coefficients.json`` (values at full precision, so they
read back exactly). An MLP run has no equations.

    latent-sindy equations runs/sindy2

    from latent_sindy.equations import equations_report
    print(equations_report("runs/sindy2"))
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

from latent_sindy.atomic import write_atomic
from latent_sindy.models.dynamics import LatentDynamics, LinearDynamics, SindyDynamics
from latent_sindy.training import load_run

__all__ = ["CSV_FILE", "JSON_FILE", "coefficient_rows", "equations_report"]

CSV_FILE, JSON_FILE = "coefficients.csv", "coefficients.json"

Row = tuple[str, str, float]  # (state, term, value)


def coefficient_rows(dynamics: LatentDynamics) -> list[Row]:
    """Coefficients as (state, term, value): SINDy's active ones, or all of A, B, c (linear).

    Raises TypeError for models without coefficients (MLP).
    """
    if isinstance(dynamics, SindyDynamics):
        return dynamics.coefficient_table()
    if isinstance(dynamics, LinearDynamics):
        A, B, c = (p.detach().cpu() for p in (dynamics.A, dynamics.B, dynamics.c))
        rows: list[Row] = []
        for j in range(dynamics.nz):
            rows += [(f"z{j}", f"z{k}", float(A[j, k])) for k in range(dynamics.nz)]
            rows += [(f"z{j}", f"u{k}", float(B[j, k])) for k in range(dynamics.nu)]
            rows.append((f"z{j}", "1", float(c[j])))
        return rows
    raise TypeError(f"{type(dynamics).__name__} has no coefficients")


def _linear_equations(rows: list[Row], nz: int, precision: int) -> list[str]:
    """``z0[t+1] = 0.998 z0 - 0.0123 z1 + ... + 0.05 u2 - 0.001`` per state."""
    parts: dict[str, list[str]] = {f"z{j}": [] for j in range(nz)}
    for state, term, value in rows:
        mag = f"{abs(value):.{precision}g}"
        sign = "-" if value < 0 else "+"
        parts[state].append(f"{sign} {mag}" if term == "1" else f"{sign} {mag} {term}")
    lines = []
    for state, terms in parts.items():
        rhs = " ".join(terms)
        rhs = rhs[2:] if rhs.startswith("+ ") else "-" + rhs[2:]
        lines.append(f"{state}[t+1] = {rhs}")
    return lines


def _export(run: Path, kind: str, rows: list[Row], extra: dict) -> None:
    def write_csv(f: io.TextIOBase) -> None:
        w = csv.writer(f)
        w.writerow(["state", "term", "value"])
        w.writerows((s, t, repr(v)) for s, t, v in rows)

    doc = {
        "kind": kind,
        **extra,
        "coefficients": [{"state": s, "term": t, "value": v} for s, t, v in rows],
    }
    write_atomic(run / CSV_FILE, write_csv, binary=False)
    write_atomic(run / JSON_FILE, lambda f: f.write(json.dumps(doc, indent=1)), binary=False)


def equations_report(run_dir: str | os.PathLike, export: bool = True, precision: int = 3) -> str:
    """The latent equations of a run as text; writes the coefficient files when ``export``.

    ``precision`` is the number of significant digits shown (the files keep full precision).
    """
    run = Path(run_dir)
    model = load_run(run).model
    dyn, cfg = model.dynamics, model.config
    if isinstance(dyn, SindyDynamics):
        rows = coefficient_rows(dyn)
        p, nz = dyn.mask.shape
        used = int(dyn.mask.any(dim=1).sum())
        sine = " with sin(z)" if cfg.include_sine else ""
        head = [
            f"{run}: SINDy latent dynamics, library order {cfg.order}{sine} "
            f"({p} candidate terms x {nz} states), z[t+1] = z + Θ(z, u) (M ⊙ Ψ)",
            f"active coefficients: {dyn.n_active()} of {p * nz} (sparsity "
            f"{100 * dyn.sparsity():.1f}%); terms used by some state: {used} of {p}",
        ]
        lines = head + dyn.equations(precision)
        extra = {
            "order": cfg.order,
            "include_sine": cfg.include_sine,
            "n_active": dyn.n_active(),
            "n_coefficients": p * nz,
            "sparsity": dyn.sparsity(),
            "terms": dyn.names,
        }
    elif isinstance(dyn, LinearDynamics):
        rows = coefficient_rows(dyn)
        lines = [
            f"{run}: linear latent dynamics z[t+1] = A z + B u + c "
            f"(A {dyn.nz}x{dyn.nz}, B {dyn.nz}x{dyn.nu}, c {dyn.nz}), every coefficient "
            "active",
            *_linear_equations(rows, dyn.nz, precision),
        ]
        extra = {"n_coefficients": len(rows)}
    else:
        return (
            f"{run}: {cfg.kind.upper()} latent dynamics z[t+1] = z + MLP([z, u]) "
            f"({cfg.mlp_layers} hidden layers of {cfg.mlp_hidden}): a neural network has no "
            "readable equations; nothing exported"
        )
    if export:
        _export(run, cfg.kind, rows, extra)
        lines.append(f"wrote {run / CSV_FILE} and {run / JSON_FILE}")
    return "\n".join(lines)
