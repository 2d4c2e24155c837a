"""Each encoder and decoder kind is built from its own settings (models/autoencoder_parts.py),
which the autoencoder's config holds (its flat settings build them); the parts never import
the autoencoder."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig
from latent_sindy.models.autoencoder import DECODERS, ENCODERS
from latent_sindy.models.autoencoder_flags import FLAGS
from latent_sindy.models.autoencoder_parts import (
    DECODER_PARTS,
    ENCODER_PARTS,
    MaskMomentEncoderConfig,
    MlpDecoderConfig,
    MlpEncoderConfig,
    SpriteDecoderConfig,
)

MODELS = Path(__file__).parents[1] / "src" / "latent_sindy" / "models"

#: A config per kind whose settings all differ from the defaults, so a setting passed to the
#: wrong field or not at all shows.
ENCODER_SETTINGS = {
    "conv": dict(latent_dim=6, conv_channels=(3, 5), encoder_hidden=7),
    "keypoints": dict(latent_dim=6, keypoint_channels=5),
    "moments": dict(latent_dim=4, moment_order=3),
    "mask_moments": dict(latent_dim=4, moment_order=2, mask_channels=5, mask_layers=2,
                         mask_normalise=False, mask_weight="image", mask_window=2.0,
                         mask_refine=1),
    "mlp": dict(latent_dim=3, mlp_widths=(9, 5), mlp_activation="tanh"),
}
DECODER_SETTINGS = {
    "fc": dict(decoder_hidden=(11, 13)),
    "conv": dict(decoder_channels=5),
    "sprite": dict(encoder_kind="moments", latent_dim=4, moment_order=3, sprite_size=7,
                   sprite_supersample=3),
    "mlp": dict(encoder_kind="mlp", latent_dim=3, mlp_widths=(9, 5), mlp_activation="elu",
                pca_components=4),
}


def test_every_kind_has_its_settings_and_each_names_a_flat_setting() -> None:
    assert set(ENCODER_PARTS) == set(ENCODERS) and set(DECODER_PARTS) == set(DECODERS)
    own = {f.name for f in dataclasses.fields(AutoencoderConfig)}
    for cls in (*ENCODER_PARTS.values(), *DECODER_PARTS.values()):
        assert set(cls.flat) == {f.name for f in dataclasses.fields(cls)}, cls
        assert set(cls.flat.values()) <= set(FLAGS) - own, cls


@pytest.mark.parametrize("kind", sorted(ENCODER_SETTINGS))
def test_an_encoder_is_built_from_its_own_settings_as_the_autoencoders(kind: str) -> None:
    cfg = AutoencoderConfig(encoder_kind=kind, decoder_kind="mlp" if kind == "mlp" else "fc",
                            **ENCODER_SETTINGS[kind]).resolve(2, (16, 20))
    part = cfg.encoder_part()
    assert type(part) is ENCODER_PARTS[kind]
    for name, setting in part.flat.items():
        assert getattr(part, name) == getattr(cfg, setting)
    torch.manual_seed(0)
    alone = ENCODERS[kind](part, cfg.image_shape, cfg.latent_dim, **cfg.shared(part))
    torch.manual_seed(0)
    built = cfg.build().encoder
    assert type(alone) is type(built)
    a, b = alone.state_dict(), built.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    x = torch.randn(3, 2, 16, 20)
    assert torch.equal(alone(x), built(x)) and alone(x).shape == (3, cfg.latent_dim)


@pytest.mark.parametrize("kind", sorted(DECODER_SETTINGS))
def test_a_decoder_is_built_from_its_own_settings_as_the_autoencoders(kind: str) -> None:
    cfg = AutoencoderConfig(decoder_kind=kind, **DECODER_SETTINGS[kind]).resolve(2, (16, 20))
    part = cfg.decoder_part()
    assert type(part) is DECODER_PARTS[kind]
    for name, setting in part.flat.items():
        assert getattr(part, name) == getattr(cfg, setting)
    decoder = cfg.build().decoder
    assert [p.shape for p in decoder.parameters()] == [
        p.shape for p in DECODERS[kind](part, cfg.image_shape, cfg.latent_dim,
                                        **cfg.shared(part)).parameters()]
    assert decoder(torch.zeros(5, cfg.latent_dim)).shape == (5, 2, 16, 20)


def test_the_sprite_takes_the_encoders_order_and_the_resolved_side() -> None:
    cfg = AutoencoderConfig(encoder_kind="mask_moments", decoder_kind="sprite", latent_dim=4,
                            moment_order=2).resolve(1, 64)
    assert cfg.decoder == SpriteDecoderConfig(size=23, supersample=2)
    assert cfg.encoder == MaskMomentEncoderConfig(order=2)
    assert cfg.shared(cfg.decoder) == {"order": 2} and cfg.build().decoder.order == 2


def test_the_flat_keywords_build_the_parts_and_read_back() -> None:
    """Flat keywords (and ``dataclasses.replace`` with them) give the same config as the
    parts; the flat attributes read the parts, or the flat defaults where a part has none."""
    flat = AutoencoderConfig(encoder_kind="mlp", decoder_kind="mlp", latent_dim=3,
                             mlp_widths=(9, 5), mlp_activation="tanh", pca_components=4,
                             mask_channels=7)  # not the mlp's: dropped
    nested = AutoencoderConfig(latent_dim=3, encoder=MlpEncoderConfig((9, 5), "tanh"),
                               decoder=MlpDecoderConfig((9, 5), "tanh"), pca_components=4)
    assert flat == nested and flat.mlp_widths == (9, 5) and flat.mask_channels == 16
    assert (flat.encoder_kind, flat.decoder_kind, flat.moment_order) == ("mlp", "mlp", 4)
    mask = AutoencoderConfig(encoder_kind="mask_moments", decoder_kind="sprite", latent_dim=4,
                             moment_order=0)
    assert mask.order_from_data and mask.encoder == MaskMomentEncoderConfig(order=0)
    two = dataclasses.replace(mask, moment_order=2)
    assert two.encoder == MaskMomentEncoderConfig(order=2) and two.decoder == mask.decoder
    assert dataclasses.replace(mask, decoder_kind="conv").decoder_kind == "conv"
    with pytest.raises(UserError, match="encoder 'vit' is unknown"):
        AutoencoderConfig(encoder_kind="vit")
    with pytest.raises(dataclasses.FrozenInstanceError):
        mask.moment_order = 3  # type: ignore[misc]


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at any depth (also under TYPE_CHECKING and in functions)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


@pytest.mark.parametrize("name", ["encoders.py", "decoders.py", "autoencoder_parts.py"])
def test_the_parts_do_not_import_the_autoencoder(name: str) -> None:
    """The autoencoder imports its parts, never the other way round (no import circle)."""
    assert "latent_sindy.models.autoencoder" not in _imports(MODELS / name)
