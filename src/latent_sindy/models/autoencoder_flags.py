"""The autoencoder's settings in their flat form: one setting per name, the kinds' own
prefixed (``moment_order``, ``mlp_widths``, ...), as the command line shows them.

:class:`~latent_sindy.models.autoencoder.AutoencoderConfig` holds one settings dataclass per
part (``encoder``, ``decoder``: :mod:`.autoencoder_parts`); :func:`flat_settings` lets it
take the flat form too, from one place, each part kind's ``flat`` map:

* the constructor and ``dataclasses.replace`` take the flat keywords (``encoder_kind=``,
  ``moment_order=``, ...);
* each flat setting reads, read-only, as an attribute (the part's value, or the flat
  default where the part has no such setting);
* the command line builds the config from the flat options (:data:`CLI_REGISTRY`, given to
  tyro), so its flags are the flat settings.

    >>> from latent_sindy.models.autoencoder import AutoencoderConfig
    >>> cfg = AutoencoderConfig(encoder_kind="moments", latent_dim=4, moment_order=2)
    >>> cfg.encoder, cfg.moment_order, cfg.mask_channels
    (MomentEncoderConfig(order=2), 2, 16)
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar

import tyro
from tyro.constructors import ConstructorRegistry, StructConstructorSpec, StructTypeInfo

from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder_parts import DECODER_PARTS, ENCODER_PARTS

__all__ = ["CLI_REGISTRY", "AutoencoderFlags", "ImageSize", "flat_settings"]

#: An image size: the side S of square images, or (H, W).
ImageSize = int | tuple[int, int]

T = TypeVar("T", bound=type)

#: The tyro constructors that show the autoencoder's config as its flat options (pass it as
#: ``registry=`` to tyro).
CLI_REGISTRY = ConstructorRegistry()


@dataclass(frozen=True)
class AutoencoderFlags:
    """The autoencoder's settings, flat (the documentation of each; no checks here)."""

    channels: int | None = None
    """Image channels C (1 grayscale, 3 RGB); None: from the data file."""
    image_size: ImageSize | None = None
    """Image size in pixels: the side S of square images, or height and width (H, W); None:
    from the data file."""
    latent_dim: int = 16
    """Latent size nz (the paper: 16)."""
    conv_channels: tuple[int, int] = (4, 4)
    """Feature maps of the two 5×5 convolution stages (the course used 4 and 4)."""
    encoder_hidden: int = 100
    """Width of the encoder's fully connected layer (the course: 100)."""
    decoder_kind: Annotated[Literal["fc", "conv", "sprite", "mlp"],
                            tyro.conf.arg(name="decoder")] = "fc"
    """Decoder kind: "fc" fully connected (the course's), "conv" upsampling convolutions,
    "sprite" (moments encoder only) a learned patch of the moving object drawn at the
    latent's pose on the encoder's background, "mlp" fully connected through the reversed
    --mlp-widths with --mlp-activation (the SINDy autoencoder's)."""
    decoder_hidden: tuple[int, ...] = (500, 500)
    """fc decoder: widths of the hidden layers (the course: 500, 500)."""
    decoder_channels: int = 16
    """conv decoder: feature maps of its convolutions."""
    encoder_kind: Annotated[Literal["conv", "keypoints", "moments", "mask_moments", "mlp"],
                            tyro.conf.arg(name="encoder")] = "conv"
    """Encoder kind: "conv" (the course's: conv + pool stages, then fully connected),
    "keypoints" (a spatial softmax: the latent is the expected image position of
    latent_dim / 2 learned feature maps, so it is a position by construction) or "moments"
    (nothing learned: the latent is the centroid and the orientation of what differs from the
    background, (x, y, cos nφ, sin nφ); latent_dim 4), "mask_moments" (the same latent, the
    moments of a per-pixel weight that small convolutions learn; latent_dim 4) or "mlp"
    (fully connected through --mlp-widths with --mlp-activation: the SINDy autoencoder's, any
    image size)."""
    keypoint_channels: int = 16
    """keypoints encoder: feature maps of its two hidden 5×5 convolutions."""
    sprite_size: int | None = None
    """sprite decoder: side P of its template in pixels (odd); None: from the image's shorter
    side S, 2 ⌊5.5 S / 32⌋ + 1 (11 at 32 pixels, 23 at 64)."""
    sprite_supersample: int = 2
    """sprite decoder: draw at this many times the image's resolution, then average-pool (1:
    draw at the image's resolution)."""
    moment_order: int = 4
    """moments and mask_moments encoders: n, the order of the angular moment that gives the
    orientation: the object's visible rotational symmetry (4 for a uniform square, which
    looks alike every quarter turn; 1 for an object with none). mask_moments: 0 chooses it
    from the data at training (a short fit at order 2, then the trained encoder's
    ``symmetry_order`` on the training images; the run's record states the order chosen)."""
    mask_channels: int = 16
    """mask_moments encoder: feature maps of its hidden 3×3 convolutions."""
    mask_layers: int = 3
    """mask_moments encoder: hidden 3×3 convolutions before the one that gives the weight."""
    mask_normalise: bool = True
    """mask_moments encoder: standardise each image on its own (its median subtracted, divided
    by its standard deviation) before the convolutions."""
    mask_weight: Literal["background", "image", "mask"] = "background"
    """mask_moments encoder: a pixel's weight is the learned mask (in (0, 1)) times its
    deviation from the "background" (the per-pixel median of the training images as the
    encoder sees them) or from its "image"'s median (the mask chooses which pixels count, the
    image keeps their shape), or the "mask" alone."""
    mask_window: float = 3.0
    """mask_moments encoder: σ in pixels of the Gaussian window about the centroid that the
    angular moment is taken in (0: none, the whole image's)."""
    mask_refine: int = 3
    """mask_moments encoder: mean-shift steps of the centre: from the masked weights' centroid
    it moves this many times to the centroid of the image's own deviation (``mask_weight``'s,
    without the mask) in the window about it, and the pose is read from that deviation about
    that centre, so the mask only says where the object is, not what shape it has. 0: the
    pose of the masked weights themselves (a trained mask can drift off the object's shape:
    RESULTS.md, "The learned row"). Needs a window."""
    mlp_widths: tuple[int, ...] = (128, 64, 32)
    """mlp encoder: widths of its hidden layers (the mlp decoder: the same, reversed); the
    SINDy autoencoder's pendulum: 128, 64, 32."""
    mlp_activation: Literal["sigmoid", "relu", "elu", "tanh"] = "sigmoid"
    """mlp encoder and decoder: the activation after every hidden layer (the SINDy
    autoencoder's pendulum: sigmoid)."""
    pca_components: int = 0
    """mlp encoder and decoder: the first this many principal components of the normalised
    training frames in front of the encoder's network and behind the decoder's, a fixed
    linear map (:mod:`~latent_sindy.models.pca_front`; the frames' derivatives pass it exactly):
    the networks work on these coordinates, not on every pixel. 0: none."""


#: The flat settings, in order; their defaults; each part's flag naming its kind.
FLAGS = tuple(f.name for f in dataclasses.fields(AutoencoderFlags))
_DEFAULTS = {f.name: f.default for f in dataclasses.fields(AutoencoderFlags)}
_KINDS = {"encoder": ("encoder_kind", ENCODER_PARTS), "decoder": ("decoder_kind", DECODER_PARTS)}


def _flat_of(part: Any) -> dict[str, Any]:
    """A part's settings under their flat names."""
    return {flat: getattr(part, name) for name, flat in part.flat.items()}


def replaced_from() -> Any:
    """The dataclass that ``dataclasses.replace`` is copying, where the constructor runs inside
    it (it passes every field it is not given, so the part beside a flat setting the caller
    gave); else None. For a decorated ``__init__``'s helper: the frames are this function,
    the helper, the decorated ``__init__``, then its caller."""
    frame = sys._getframe(3)
    if frame.f_code is dataclasses.replace.__code__ or (
            frame.f_code.co_name == "_replace" and frame.f_globals is vars(dataclasses)):
        return frame.f_locals.get("obj")
    return None


def _nested(kwargs: dict[str, Any], own: set[str]) -> dict[str, Any]:
    """Constructor keywords with the flat ones (names outside ``own``, the nested config's
    fields) turned into the parts; a flat setting wins over the part's
    (``dataclasses.replace(cfg, moment_order=n)`` passes both)."""
    for which, (kind_flag, parts) in _KINDS.items():
        part = kwargs.get(which)
        if part is not None and not isinstance(part, tuple(parts.values())):
            names = ", ".join(c.__name__ for c in parts.values())
            raise UserError(f"AutoencoderConfig(...): {which}={part!r} is none of the {which}'s "
                            f"configs ({names}): give one, or its kind as {kind_flag}=")
    flat = {k: kwargs[k] for k in kwargs if k in FLAGS and k not in own}
    if not flat:
        return kwargs
    _one_form_each(kwargs, flat, replaced_from())
    out = {k: v for k, v in kwargs.items() if k not in flat}
    for which, (kind_flag, parts) in _KINDS.items():
        part = out.get(which)
        base = {} if part is None else {kind_flag: part.kind, **_flat_of(part)}
        base.update(flat)
        kind = base.get(kind_flag, _DEFAULTS[kind_flag])
        if kind not in parts:
            raise UserError(f"{which} {kind!r} is unknown: use one of " + ", ".join(parts))
        cls = parts[kind]
        out[which] = cls(**{name: base[f] for name, f in cls.flat.items() if f in base})
    return out


def _one_form_each(kwargs: dict[str, Any], flat: dict[str, Any], copied: Any) -> None:
    """UserError where a setting is given twice: a part (``encoder=MomentEncoderConfig(...)``)
    with a flat setting of its own (``moment_order=``). ``dataclasses.replace(cfg,
    moment_order=n)`` passes the ``copied`` config's part too: that one is not counted."""
    for which, (kind_flag, _) in _KINDS.items():
        part = kwargs.get(which)
        if part is None or (copied is not None and part is getattr(copied, which, None)):
            continue
        twice = [k for k in flat if k == kind_flag or k in part.flat.values()]
        if twice:
            raise UserError(f"AutoencoderConfig(...): {which}={part!r} and {twice[0]}= both "
                            f"set the {which}'s {twice[0]}: give the part, or its flat "
                            "settings, not both")


def _flat_property(name: str) -> property:
    def read(self: Any) -> Any:
        for which, (kind_flag, _) in _KINDS.items():
            part = getattr(self, which)
            if name == kind_flag:
                return part.kind
            for field, flat in part.flat.items():
                if flat == name:
                    return getattr(part, field)
        return _DEFAULTS[name]

    return property(read, doc=f"The flat setting ``{name}``: its part's (read-only).")


def flat_settings(cls: T) -> T:
    """Class decorator: the nested autoencoder config ``cls`` takes and shows the flat
    settings of :class:`AutoencoderFlags` (see the module's documentation)."""
    own = {f.name for f in dataclasses.fields(cls)}
    init = cls.__init__

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **_nested(kwargs, own))

    cls.__init__ = __init__
    for name in FLAGS:
        if name not in own:
            setattr(cls, name, _flat_property(name))

    @CLI_REGISTRY.struct_rule
    def flat_options(info: StructTypeInfo) -> StructConstructorSpec | None:
        if info.type is not cls:
            return None
        default = info.default if isinstance(info.default, cls) else cls()
        flags = AutoencoderFlags(**{k: getattr(default, k) for k in FLAGS})
        spec = ConstructorRegistry.get_struct_spec(
            StructTypeInfo.make(AutoencoderFlags, flags, info.in_union_context))
        assert isinstance(spec, StructConstructorSpec)
        return StructConstructorSpec(instantiate=cls, fields=spec.fields)

    return cls
