"""The per-epoch metrics a fit records, with grouped names (``train/…``, ``val/…``, ``sindy/…``)."""

from latent_sindy.models.latent_model import LOSS_TERMS

__all__ = ["METRIC_COLUMNS"]

METRIC_COLUMNS = (
    "epoch",
    *(f"train/{t}" for t in LOSS_TERMS),
    *(f"val/{t}" for t in LOSS_TERMS),
    "sindy/active",
    "sindy/sparsity",
    "sindy/pruned",
    "time_s",
)
