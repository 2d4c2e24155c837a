"""Composition, in the manner of pysindy's ``SINDy(feature_library=..., optimizer=...)``: a
library composed from the grammar goes into the model's config and the estimator as it is,
kept in the run's record, and a sparsifier of one's choice fits it."""

from __future__ import annotations

import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.configs import from_json, to_json
from latent_sindy.errors import UserError
from latent_sindy.models import ModelConfig, SindyConfig
from latent_sindy.sindy import STLSQ, Cosine, Identity, Polynomial, SindyLibrary, Sine

SPEC = Polynomial("z", 1, bias=True) + Sine("z") + Identity("u0") * Cosine("z0")


def test_a_composed_library_is_the_models_library_and_survives_its_record() -> None:
    cfg = SindyConfig(composed=SPEC)
    assert cfg.composed == SPEC.to_dict()  # (the config keeps the spec's dict: JSON)
    model = cfg.build(2, 1)
    assert model.names == SindyLibrary(SPEC, 2, 1).names
    assert "u0 cos(z0)" in model.names
    back = from_json(ModelConfig, to_json(ModelConfig(dynamics=cfg)), "config.json: model")
    assert back.dynamics == cfg and back.dynamics.build(2, 1).names == model.names


def test_a_composed_library_and_an_optimizer_recover_known_dynamics() -> None:
    """z0' = z0 + 0.5 sin z1, z1' = z1 - 0.3 u0 cos z0: STLSQ on the composed library finds
    exactly those terms."""
    gen = torch.Generator().manual_seed(0)
    z, u = torch.randn(400, 2, generator=gen), torch.randn(400, 1, generator=gen)
    step = torch.stack([0.5 * torch.sin(z[:, 1]), -0.3 * u[:, 0] * torch.cos(z[:, 0])], -1)
    model = SindyConfig(composed=SPEC).build(2, 1).fit_state_data(
        z, u, z + step, optimizer=STLSQ(min_share=0.05))
    active = {(model.names[i], j) for i, j in model.mask.nonzero().tolist()}
    assert active == {("sin(z1)", 0), ("u0 cos(z0)", 1)}


def test_the_estimator_takes_a_composed_library() -> None:
    est = LatentSINDy(latent_dim=2, library=SPEC)
    assert est.model_config.dynamics.composed == SPEC.to_dict()
    assert LatentSINDy(latent_dim=2).model_config.dynamics.composed is None


def test_a_composed_library_replaces_a_named_one() -> None:
    with pytest.raises(UserError, match="replaces a named one"):
        SindyConfig(library="push", composed=SPEC)
    with pytest.raises(UserError, match="'kind'"):
        SindyConfig(composed={"terms": 3})
