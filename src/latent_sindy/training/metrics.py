"""The per-epoch metrics a fit records, with grouped names (``train/…``, ``val/…``, ``sindy/…``).

Loss terms added since metrics.csv was first written (:data:`ADDED_TERMS`) come last, so that
an older file's columns keep their places: it reads as before, its rows without those terms
(a resumed run rewrites its file, these columns empty in the rows from before)."""

from latent_sindy.models.latent_model import LOSS_TERMS

__all__ = ["ADDED_TERMS", "METRIC_COLUMNS"]

#: Loss terms newer than the file format, in the order they were added.
ADDED_TERMS = ("reward",)
_FIRST_TERMS = tuple(t for t in LOSS_TERMS if t not in ADDED_TERMS)

METRIC_COLUMNS = (
    "epoch",
    *(f"train/{t}" for t in _FIRST_TERMS),
    *(f"val/{t}" for t in _FIRST_TERMS),
    "sindy/active",
    "sindy/sparsity",
    "sindy/pruned",
    "time_s",
    *(f"{part}/{t}" for t in ADDED_TERMS for part in ("train", "val")),
)
