"""The discovered latent equations of a trained run, as text and as coefficient files.

Every dynamics model describes itself (``summary``, ``equations``, ``coefficient_rows``): a
SINDy run prints one update rule per latent state with its active terms only, the number of
active coefficients and the sparsity; a linear run ``z[t+1] = A z + B u + c`` written out per
state. Both export their coefficients as rows ``(state, term, value)`` to
``RUN/coefficients.csv`` and ``RUN/coefficients.json`` (values at full precision, so they
read back exactly). A model without coefficients (MLP) prints its summary only.

    latent-sindy equations runs/sindy2

    from latent_sindy.equations import equations_report
    print(equations_report("runs/sindy2"))
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Sequence
from typing import Any

from latent_sindy.atomic import write_atomic
from latent_sindy.training.manifold_start import SETTLED
from latent_sindy.training.runs import RunDir

__all__ = ["coefficient_table", "equations_report", "name_actions", "pruned_note"]


def coefficient_table(dyn: Any) -> tuple[list[str], Any]:
    """A model's coefficients as pysindy lays them out: the term names and an array (terms,
    states), pruned entries 0; UserError for dynamics without coefficients (an MLP)."""
    import numpy as np

    from latent_sindy.errors import UserError

    rows = dyn.coefficient_rows()
    if rows is None:
        raise UserError(f"{dyn.kind} dynamics have no coefficients to show")
    if hasattr(dyn, "coefficients"):
        return list(dyn.names), dyn.coefficients().detach().numpy().copy()

    def natural(name: str) -> tuple:
        return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))

    states = sorted({s for s, _, _ in rows}, key=natural)
    terms = list(dict.fromkeys(t for _, t, _ in rows))
    out = np.zeros((len(terms), len(states)))
    for s, t, v in rows:
        out[terms.index(t), states.index(s)] = v
    return terms, out


def name_actions(lines: list[str], names: Sequence[str]) -> list[str]:
    """Equations with the action variables u0, u1, ... written as ``names``."""
    if not names:
        return lines
    return [re.sub(r"\bu(\d+)\b", lambda m: names[int(m[1])] if int(m[1]) < len(names)
                   else m[0], line) for line in lines]


def _export(run: RunDir, kind: str, rows: list[tuple[str, str, float]], extra: dict) -> None:
    def write_csv(f: io.TextIOBase) -> None:
        w = csv.writer(f)
        w.writerow(["state", "term", "value"])
        w.writerows((s, t, repr(v)) for s, t, v in rows)

    doc = {
        "kind": kind,
        **extra,
        "coefficients": [{"state": s, "term": t, "value": v} for s, t, v in rows],
    }
    write_atomic(run / run.COEFFICIENTS_CSV, write_csv, binary=False)
    write_atomic(run / run.COEFFICIENTS_JSON, lambda f: f.write(json.dumps(doc, indent=1)),
                 binary=False)


def pruned_note(dynamics: Any) -> str | None:
    """One line saying that sparse ``dynamics`` lost every term (their equations would be
    identities, z[t+1] = z: nothing moves), with what to try; None where a term is left."""
    if not getattr(dynamics, "sparse", False) or dynamics.n_active() > 0:
        return None
    if getattr(dynamics, "continuous", False):
        k = getattr(dynamics, "derivative_order", 1)
        said = "z'' = 0: nothing accelerates" if k == 2 else "z' = 0: nothing moves"
        return (f"every SINDy term was pruned: the model says {said}; try more starts "
                "(fit(..., restarts=Restarts(count=4, agree=2))), more epochs, or a lower "
                "prune_below (TrainConfig), and check that the frames show the motion")
    return ("every SINDy term was pruned: the model predicts that nothing moves (z[t+1] = z); "
            "lower --prune-below, train longer, or try more starts")


#: A continuous-time law that leaves more than this share of the latent's derivative
#: unexplained on the validation frames is reported with a warning.
UNEXPLAINED_LIMIT = 0.05


def doubt_notes(kept: dict[str, Any]) -> list[str]:
    """Why a fit's law may be wrong, one line each, from what its training kept (``kept``:
    the estimator's ``kept_``): starts that wrote different laws and no two agreed, a law
    written at the start whose terms were a close call (a term more took away a share of
    the held-out error near the search's margin) or with no rate term over sequences
    shorter than a quarter of its oscillation, a start whose coordinates settled no law
    (the law kept is the main fit's), or a law that leaves over
    :data:`UNEXPLAINED_LIMIT` of the latent's derivative unexplained on the validation
    frames. Empty where none."""
    notes = []
    starts = kept.get("restarts") or {}
    if starts.get("agreed") is False:
        laws = "; ".join(" | ".join(" + ".join(t) or "0" for t in law["law"]) or "no term"
                         for law in starts.get("laws", []))
        notes.append(f"no two of the {starts.get('starts')} starts wrote the same law (those "
                     f"trained through: {laws}): the law kept may be wrong; try more starts "
                     "(fit(..., restarts=Restarts(count=5, agree=2))) or more data")
    start = kept.get("start") or {}
    if start.get("settled") and start.get("close"):
        terms, gain = max(start["close"], key=lambda c: c[1])
        notes.append(f"the law's terms were a close call: {' + '.join(terms)} took away only "
                     f"{100 * gain:.0f} % of the held-out error of the law one term smaller "
                     "(a true term took away 98 % or more on the project's drawn videos): a "
                     "term may be missing or stand for a warp of the latent; more or longer "
                     "sequences tell them apart")
    if not start.get("settled") and start.get("law_fvu") is not None:
        notes.append(f"the frames' own coordinates settled no law (the best one searched on "
                     f"them left {100 * max(start['law_fvu']):.0f} % of the held-out "
                     f"second derivative unexplained, over the {100 * SETTLED:.0f} % a "
                     "settled start may): this law was found by training the autoencoder "
                     "further, and a latent it warps can take a law of its own; more or "
                     "longer sequences, less noise or exact derivatives would tell")
    for name, span in start.get("short", []) if start.get("settled") else ():
        notes.append(f"{name}'s law has no term in {name}' and each sequence spans only "
                     f"{span:.1f} rad ({span / (2 * math.pi):.2f} of a period) of its "
                     "oscillation: a weak damping may be missing (it cannot show over so "
                     "short stretches); longer sequences would tell")
    share = kept.get("unexplained")
    if share is not None and not share <= UNEXPLAINED_LIMIT:
        notes.append(f"the law leaves {100 * share:.0f} % of the latent's derivative "
                     "unexplained on the validation frames: it may be wrong or miss a term "
                     "(derivatives taken from noisy frames make this share larger; give "
                     "exact derivatives where you have them)")
    return notes


def equations_report(run_dir: str | os.PathLike, export: bool = True, precision: int = 3) -> str:
    """The latent equations of a run as text; writes the coefficient files when ``export``.

    ``precision`` is the number of significant digits shown (the files keep full precision).
    """
    run = RunDir(run_dir)
    loaded = run.load()
    dyn = loaded.model.dynamics
    rows = dyn.coefficient_rows()
    head = dyn.summary()
    lines = [f"{run.path}: {head[0]}", *head[1:]]
    if rows is None:
        return "\n".join([*lines, "nothing exported"])
    note = pruned_note(dyn)
    lines += [note] if note else name_actions(dyn.equations(precision),
                                              loaded.description.get("action_names", []))
    if export:
        _export(run, dyn.kind, rows, dyn.export_info())
        lines.append(f"wrote {run / run.COEFFICIENTS_CSV} and {run / run.COEFFICIENTS_JSON}")
    return "\n".join(lines)
