"""Autoencoder shapes, the latent model's loss terms (eq. 1-4) and its configuration."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from latent_sindy.configs import from_json, to_json
from latent_sindy.errors import UserError
from latent_sindy.models import (
    DYNAMICS_KINDS,
    LOSS_TERMS,
    Autoencoder,
    AutoencoderConfig,
    LatentModel,
    LossWeights,
    MlpConfig,
    ModelConfig,
    SindyConfig,
)
from latent_sindy.models.autoencoder_parts import (
    MomentEncoderConfig,
    SpriteDecoderConfig,
)

KINDS = ("sindy", "linear", "mlp")


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def tiny(kind: str, **kw) -> LatentModel:
    torch.manual_seed(0)
    if kind == "mlp":  # an MLP has no coefficient scale
        kw.pop("init_scale", None)
    dyn = {"mlp": {"hidden": 16}}.get(kind, {}) | kw
    cfg = ModelConfig(
        observation=AutoencoderConfig(latent_dim=4, channels=1, image_size=32,
                                      encoder_hidden=16, decoder_hidden=(32,)),
        dynamics=DYNAMICS_KINDS[kind](**dyn),
        action_dim=3,
    )
    return LatentModel(cfg)


def batch(b: int = 5, h: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, h + 1, 1, 32, 32, generator=g), torch.rand(b, h, 3, generator=g)


@pytest.mark.parametrize(("channels", "size"), [(1, 32), (3, 32), (1, 64)])
def test_autoencoder_shapes(channels: int, size: int) -> None:
    ae = Autoencoder(AutoencoderConfig(channels=channels, image_size=size, latent_dim=16))
    x = torch.randn(2, 3, channels, size, size)
    z = ae.encode(x)
    assert z.shape == (2, 3, 16)
    assert ae.decode(z).shape == x.shape
    # Leading dimensions are only folded: encoding per frame gives the same latents.
    torch.testing.assert_close(z[1, 2], ae.encode(x[1, 2][None])[0])


@pytest.mark.parametrize(("channels", "size"), [(1, 32), (3, 32), (1, 64), (1, 20)])
def test_conv_decoder_shapes_and_batching(channels: int, size: int) -> None:
    cfg = AutoencoderConfig(channels=channels, image_size=size, decoder_kind="conv")
    ae = Autoencoder(cfg)
    z = torch.randn(2, 3, 16)
    x = ae.decode(z)
    assert x.shape == (2, 3, channels, size, size)
    torch.testing.assert_close(x[1, 2], ae.decode(z[1, 2][None])[0])  # no mixing across samples
    # Fewer parameters than the course's fully connected decoder, for the same images.
    fc = Autoencoder(AutoencoderConfig(channels=channels, image_size=size))
    n_params = [sum(p.numel() for p in m.decoder.parameters()) for m in (ae, fc)]
    assert n_params[0] < n_params[1]


def test_conv_decoder_rejects_sizes_it_cannot_draw() -> None:
    with pytest.raises(UserError, match="divisible by 4"):
        AutoencoderConfig(image_size=30, decoder_kind="conv")
    with pytest.raises(UserError, match="unknown"):
        AutoencoderConfig(decoder_kind="deconv")
    with pytest.raises(UserError, match="divisible by 4"):
        ModelConfig(observation=AutoencoderConfig(decoder_kind="conv")).resolve(1, 30, 3)


@pytest.mark.parametrize(("channels", "size"), [(1, 32), (3, 32), (1, 20)])
def test_keypoints_encoder_shapes_and_range(channels: int, size: int) -> None:
    cfg = AutoencoderConfig(channels=channels, image_size=size, latent_dim=6,
                            encoder_kind="keypoints", keypoint_channels=4)
    ae = Autoencoder(cfg)
    x = 5 * torch.randn(2, 3, channels, size, size)
    z = ae.encode(x)
    assert z.shape == (2, 3, 6) and ae.decode(z).shape == x.shape
    assert z.abs().max() <= 1.0  # expected positions on a [-1, 1] grid
    torch.testing.assert_close(z[1, 2], ae.encode(x[1, 2][None])[0])


def test_keypoints_are_where_their_feature_maps_peak() -> None:
    """A map peaked at (row 5, col 12) of 17 puts its keypoint at x = 0.5, y = -0.375; the
    keypoint moves with the peak (x with the column, y with the row)."""
    ae = Autoencoder(AutoencoderConfig(channels=1, image_size=17, latent_dim=4,
                                       encoder_kind="keypoints"))
    enc = ae.encoder
    enc.net = torch.nn.Identity()  # the image itself is the feature map of keypoint 1 ...
    enc.log_temperature.data.fill_(-3.0)  # ... sharpened by a low temperature
    x = torch.zeros(1, 2, 17, 17)
    x[0, 0, 5, 12] = 1.0
    x[0, 1, 16, 0] = 1.0
    z = enc(x)[0]
    torch.testing.assert_close(z, torch.tensor([0.5, -0.375, -1.0, 1.0]), atol=1e-3, rtol=0)


def test_keypoints_encoder_needs_an_even_latent() -> None:
    with pytest.raises(UserError, match="even latent_dim"):
        AutoencoderConfig(latent_dim=5, encoder_kind="keypoints")
    with pytest.raises(UserError, match="unknown"):
        AutoencoderConfig(encoder_kind="vit")


def test_course_encoder_sizes() -> None:
    cfg = AutoencoderConfig(channels=1, image_size=32)
    assert cfg.conv_shape() == (5, 5)  # 32 -> 28 -> 14 -> 10 -> 5: 4 maps x 5 x 5 = 100
    fc = Autoencoder(cfg).encoder.net[7]
    assert (fc.in_features, fc.out_features) == (100, 100)
    with pytest.raises(UserError, match="too small"):
        AutoencoderConfig(image_size=12)


@pytest.mark.parametrize("kind", KINDS)
def test_loss_matches_equations(kind: str) -> None:
    """Each term recomputed by hand from encode / rollout / decode, and the weighted sums."""
    model = tiny(kind)
    x, u = batch(h=3)
    w = LossWeights(lambda_pred_x=0.7, lambda_pred_z=0.3, lambda_l1=0.05)
    terms = model.loss(x, u, w)
    assert set(terms) == set(LOSS_TERMS)
    assert all(torch.isfinite(v) and v.ndim == 0 for v in terms.values())
    z = model.encode(x)  # (B, 4, nz)
    z_hat = model.rollout_latent(z[:, 0], u)  # (B, 4, nz)
    torch.testing.assert_close(terms["recon"], ((model.decode(z) - x) ** 2).mean())
    pred = model.decode(z_hat[:, 1:])
    torch.testing.assert_close(terms["pred_x"], ((pred - x[:, 1:]) ** 2).mean())
    torch.testing.assert_close(terms["pred_z"], ((z_hat[:, 1:] - z[:, 1:]) ** 2).mean())
    objective = terms["recon"] + 0.7 * terms["pred_x"] + 0.3 * terms["pred_z"]
    torch.testing.assert_close(terms["objective"], objective)
    torch.testing.assert_close(terms["total"], objective + 0.05 * terms["l1"])
    if kind == "sindy":
        torch.testing.assert_close(terms["l1"], model.dynamics.coefficients().abs().sum())
        assert terms["l1"] > 0
    else:
        assert terms["l1"] == 0


@pytest.mark.parametrize("kind", KINDS)
def test_loss_terms_depend_on_the_right_parts(kind: str) -> None:
    """recon ignores actions and dynamics; pred_z ignores the decoder; pred_x needs all three."""
    model = tiny(kind, init_scale=0.1)
    x, u = batch()
    u.requires_grad_(True)
    dec = list(model.autoencoder.decoder.parameters())
    dyn = list(model.dynamics.parameters())
    enc = list(model.autoencoder.encoder.parameters())

    def grads(term: str, params: list[torch.Tensor]) -> list[torch.Tensor | None]:
        out = model.loss(x, u)[term]
        return torch.autograd.grad(out, params, allow_unused=True)

    def nonzero(gs) -> bool:
        return any(g is not None and g.abs().sum() > 0 for g in gs)

    assert not nonzero(grads("recon", [u, *dyn]))
    assert nonzero(grads("recon", enc)) and nonzero(grads("recon", dec))
    assert nonzero(grads("pred_x", [u])) and nonzero(grads("pred_x", dyn))
    assert nonzero(grads("pred_x", dec)) and nonzero(grads("pred_x", enc))
    assert not nonzero(grads("pred_z", dec))
    assert nonzero(grads("pred_z", [u])) and nonzero(grads("pred_z", enc))
    if kind == "sindy":
        assert nonzero(grads("l1", dyn)) and not nonzero(grads("l1", [*enc, *dec]))


def test_foreground_weight_weights_only_the_block_pixels_in_the_trained_total() -> None:
    model = tiny("sindy")
    x, u = batch(b=3, h=2)
    x = 0.1 * x  # the table: within 1 of its median everywhere
    plain = model.loss(x, u, LossWeights())
    weighted = model.loss(x, u, LossWeights(foreground_weight=9.0))
    assert weighted["total"] == plain["total"]  # no block, no extra weight
    x[..., 10:14, 10:14] = -4.0  # a block: 16 pixels far below the table
    plain = model.loss(x, u, LossWeights())
    weighted = model.loss(x, u, LossWeights(foreground_weight=9.0))
    for term in ("recon", "pred_x", "pred_z", "objective"):  # reported terms stay unweighted
        assert weighted[term] == plain[term], term
    with torch.no_grad():
        z = model.encode(x)
        z_hat = model.rollout_latent(z[:, 0], u)[:, 1:]
        err = (model.decode(torch.cat([z, z_hat], 1))
               - torch.cat([x, x[:, 1:]], 1)).square()  # (B, 2H+1, C, S, S)
    block = err[..., 10:14, 10:14].sum(dim=(-1, -2, -3))  # (B, 2H+1)
    extra = 9.0 * (block[:, :3].sum() / err[:, :3].numel() + block[:, 3:].sum()
                   / err[:, 3:].numel())
    torch.testing.assert_close(weighted["total"] - plain["total"], extra)


def windows_of(x: torch.Tensor, u: torch.Tensor, h: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every window of h pushes of sequences x (B, T+1, ...), u (B, T, nu), sequence-major:
    (B (T-h+1), h+1, ...), (B (T-h+1), h, nu)."""
    starts = range(u.shape[1] - h + 1)
    return (torch.stack([x[:, s : s + h + 1] for s in starts], 1).flatten(0, 1),
            torch.stack([u[:, s : s + h] for s in starts], 1).flatten(0, 1))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("h", [1, 2])
def test_trajectory_loss_equals_the_windows_loss(kind: str, h: int) -> None:
    """Sequences of 4 pushes with window h: the prediction terms (and l1) are those of the
    3 or 4 windows per sequence passed one by one; recon is the mean over the distinct frames,
    which the windows count once per window holding them."""
    model = tiny(kind, init_scale=0.1)
    x, u = batch(b=3, h=4, seed=1)
    w = LossWeights(lambda_pred_x=0.7, lambda_pred_z=0.3)
    seq = model.loss(x, u, w, window=h)
    xw, uw = windows_of(x, u, h)
    assert xw.shape[:2] == (3 * (5 - h), h + 1)
    win = model.loss(xw, uw, w)
    for term in ("pred_x", "pred_z", "l1"):
        torch.testing.assert_close(seq[term], win[term], rtol=1e-5, atol=0)
    per_frame = (model.decode(model.encode(x)) - x).square().mean()
    torch.testing.assert_close(seq["recon"], per_frame, rtol=1e-6, atol=0)
    if h == 1:  # the windows count the interior frames twice: a different mean
        assert not torch.isclose(seq["recon"], win["recon"], rtol=1e-4)
    torch.testing.assert_close(
        seq["objective"], seq["recon"] + 0.7 * seq["pred_x"] + 0.3 * seq["pred_z"])
    # The gradients of the prediction terms are those of the windows too.
    params = list(model.parameters())
    for term in ("pred_x", "pred_z"):
        ga = torch.autograd.grad(model.loss(x, u, w, window=h)[term], params, allow_unused=True)
        gb = torch.autograd.grad(model.loss(xw, uw, w)[term], params, allow_unused=True)
        for a, b in zip(ga, gb, strict=True):
            assert (a is None) == (b is None)
            if a is not None:
                torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-7)


def test_trajectory_loss_weights_the_block_like_the_windows() -> None:
    """With a foreground weight, the trained total of the sequences is their weighted
    reconstruction (each frame once) + the windows' weighted prediction part."""
    model = tiny("sindy", init_scale=0.1)
    x, u = batch(b=2, h=3, seed=2)
    x = 0.1 * x  # the table: within 1 of its median
    x[..., 10:14, 10:14] = -4.0  # the block
    fg = torch.ones_like(x[0, 0])
    fg[..., 10:14, 10:14] = 10.0  # 1 + the foreground weight
    w = LossWeights(foreground_weight=9.0, lambda_pred_z=0.3)
    seq = model.loss(x, u, w, window=1)
    xw, uw = windows_of(x, u, 1)
    win = model.loss(xw, uw, w)

    def weighted_recon(v: torch.Tensor) -> torch.Tensor:
        return (fg * (model.decode(model.encode(v)) - v).square()).mean()

    pred_part = win["total"] - weighted_recon(xw)  # λ1 pred_x + λ2 pred_z + λ3 l1, weighted
    torch.testing.assert_close(seq["total"], weighted_recon(x) + pred_part, rtol=1e-5, atol=0)
    assert seq["total"] > model.loss(x, u, dataclasses.replace(w, foreground_weight=0),
                                     window=1)["total"]


def test_trajectory_loss_pose_term_counts_frames_once_and_windows_alike() -> None:
    """A pose head's term: its encoded-frame part is the per-frame mean, its prediction part
    that of the windows."""
    torch.manual_seed(0)
    cfg = ModelConfig(observation=AutoencoderConfig(latent_dim=4, channels=1, image_size=32,
                                                encoder_hidden=16, decoder_hidden=(32,)),
                      dynamics=SindyConfig(init_scale=0.1), action_dim=3, pose_head="linear")
    model = LatentModel(cfg)
    x, u = batch(b=3, h=4, seed=3)
    poses = torch.randn(3, 5, 4, generator=torch.Generator().manual_seed(4))
    model.pose_head.fit_statistics(poses.flatten(0, 1))
    xw, uw = windows_of(x, u, 2)
    sw = torch.stack([poses[:, s : s + 3] for s in range(3)], 1).flatten(0, 1)  # (9, 3, 4)
    head, std = model.pose_head.standardized, model.pose_head.standardize

    def frame_part(v: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return (head(model.encode(v)) - std(s)).square().mean()

    seq = model.loss(x, u, poses=poses, window=2)["pose"]
    win = model.loss(xw, uw, poses=sw)["pose"]
    torch.testing.assert_close(seq - frame_part(x, poses), win - frame_part(xw, sw),
                               rtol=1e-5, atol=1e-6)
    assert seq > 0


def test_loss_rejects_a_window_longer_than_the_sequences() -> None:
    x, u = batch(h=2)
    with pytest.raises(ValueError, match="window 3 does not fit"):
        tiny("linear").loss(x, u, window=3)


def test_loss_rejects_bad_shapes() -> None:
    x, u = batch(h=2)
    with pytest.raises(ValueError, match="loss expects"):
        tiny("linear").loss(x, u[:, :1])


def test_model_config_round_trip_and_resolve() -> None:
    cfg = ModelConfig(observation=AutoencoderConfig(decoder_hidden=(64, 32)),
                      dynamics=MlpConfig(layers=3))
    back = from_json(ModelConfig, json.loads(json.dumps(to_json(cfg))), "model")
    assert back == cfg and isinstance(back.dynamics, MlpConfig)
    resolved = cfg.resolve(3, 32, 3)
    assert (resolved.observation.channels, resolved.observation.image_size) == (3, 32)
    assert cfg.observation.channels is None and resolved.action_dim == 3
    assert dataclasses.replace(resolved) == resolved.resolve(3, 32, 3)
    with pytest.raises(UserError, match=r"channels is 1 but data\.h5 has channels 3"):
        ModelConfig(observation=AutoencoderConfig(channels=1)).resolve(3, 32, 3, "data.h5")
    with pytest.raises(UserError, match=r"--action-dim 5 but data\.h5 has actions of size 3"):
        ModelConfig(action_dim=5).resolve(1, 32, 3, "data.h5")
    with pytest.raises(ValueError, match="resolve"):
        LatentModel(cfg)


@pytest.mark.parametrize(
    ("build", "message"),
    [(lambda: SindyConfig(order=5), "order 5"),
     (lambda: AutoencoderConfig(latent_dim=0), "latent_dim"),
     (lambda: MlpConfig(hidden=0), "hidden"),
     (lambda: SindyConfig(init_scale=float("nan")), "init_scale"),
     (lambda: LossWeights(lambda_l1=float("inf")), "lambda-l1"),
     (lambda: ModelConfig(action_dim=-1), "action_dim")],
)
def test_model_config_rejects(build, message: str) -> None:
    with pytest.raises(UserError, match=message):
        build()


def test_unknown_dynamics_kind_is_one_clear_error() -> None:
    d = to_json(ModelConfig())
    d["dynamics"]["kind"] = "transformer"
    with pytest.raises(UserError, match=r"model\.dynamics: kind 'transformer' is unknown"):
        from_json(ModelConfig, d, "model")


@pytest.mark.parametrize("channels", [1, 3])
def test_conv_decoder_last_layer_is_a_transposed_convolution(channels: int) -> None:
    """The last layer computes what nn.ConvTranspose2d computes, values and gradients, with
    its parameters: for one channel on the CPU's native forward and oneDNN's backward."""
    torch.manual_seed(0)
    cfg = AutoencoderConfig(channels=channels, image_size=32, decoder_kind="conv")
    dec = Autoencoder(cfg).decoder
    layer = dec.conv[2]
    plain = torch.nn.ConvTranspose2d(16, channels, 4, stride=2, padding=1)
    plain.load_state_dict(layer.state_dict())
    x = torch.randn(7, 16, 16, 16).contiguous(memory_format=torch.channels_last)
    xa, xb = x.clone().requires_grad_(), x.clone().requires_grad_()
    ya, yb = layer(xa), plain(xb)
    assert ya.shape == yb.shape == (7, channels, 32, 32)
    assert ("NativeForward" in type(ya.grad_fn).__name__) == (channels == 1)
    torch.testing.assert_close(ya, yb, rtol=1e-5, atol=1e-5)
    g = torch.randn_like(ya)
    ya.backward(g)
    yb.backward(g)
    torch.testing.assert_close(xa.grad, xb.grad, rtol=1e-5, atol=1e-5)
    for name, p in layer.named_parameters():
        torch.testing.assert_close(p.grad, dict(plain.named_parameters())[name].grad,
                                   rtol=1e-4, atol=1e-4)
    with torch.inference_mode():
        torch.testing.assert_close(layer(x), plain(x), rtol=1e-5, atol=1e-5)
    assert set(dec.state_dict()) == {"net.0.weight", "net.0.bias", "net.2.weight",
                                     "net.2.bias", "conv.0.weight", "conv.0.bias",
                                     "conv.2.weight", "conv.2.bias"}


def test_encoder_pools_before_its_relus_with_the_course_layout() -> None:
    """Pool-then-ReLU gives the course's ReLU-then-pool values and gradients exactly, and the
    state dict keeps the course's layer indices (older runs load)."""
    torch.manual_seed(0)
    enc = Autoencoder(AutoencoderConfig(channels=1, image_size=32)).encoder
    course = torch.nn.Sequential(*enc.net)
    course[1], course[2] = torch.nn.ReLU(), torch.nn.MaxPool2d(2)
    course[4], course[5] = torch.nn.ReLU(), torch.nn.MaxPool2d(2)
    assert [type(m).__name__ for m in enc.net[:6]] == ["Conv2d", "MaxPool2d", "ReLU"] * 2
    x = torch.randn(9, 1, 32, 32).contiguous(memory_format=torch.channels_last)
    za = enc(x)
    zb = course(x)
    assert torch.equal(za, zb)
    g = torch.randn_like(za)
    grads_a = torch.autograd.grad(za, list(enc.parameters()), g)
    grads_b = torch.autograd.grad(zb, list(course.parameters()), g)
    for a, b in zip(grads_a, grads_b, strict=True):
        assert torch.equal(a, b)
    assert {k.rsplit(".", 1)[0] for k in enc.state_dict()} == {"net.0", "net.3", "net.7",
                                                               "net.9"}


# ----------------------------------------------------------------------------- any image shape
SHAPE = (3, 20, 28)  # (C, H, W): neither square nor a multiple of 8


@pytest.mark.parametrize(("encoder", "decoder", "nz"),
                         [("conv", "fc", 6), ("conv", "conv", 6), ("keypoints", "conv", 6),
                          ("moments", "conv", 4), ("moments", "sprite", 4)])
def test_every_kind_takes_a_non_square_image(encoder: str, decoder: str, nz: int) -> None:
    cfg = AutoencoderConfig(latent_dim=nz, encoder_kind=encoder, decoder_kind=decoder,
                            keypoint_channels=4).resolve(SHAPE[0], SHAPE[1:])
    assert cfg.image_size == (20, 28) and cfg.image_shape == SHAPE
    ae = Autoencoder(cfg)
    x = torch.randn(2, 3, *SHAPE)
    ae.fit_statistics(x.flatten(0, 1))
    z = ae.encode(x)
    assert z.shape == (2, 3, nz) and torch.isfinite(z).all()
    assert ae.decode(z).shape == x.shape


def test_a_conv_autoencoder_on_rgb_20x28_images_learns() -> None:
    """Shapes round-trip and a few Adam steps lower the reconstruction loss."""
    torch.manual_seed(0)
    ae = Autoencoder(AutoencoderConfig(channels=3, image_size=(20, 28), latent_dim=8,
                                       decoder_kind="conv"))
    conv = ae.encoder.net[7]
    assert conv.in_features == 4 * 2 * 4  # 20 -> 16 -> 8 -> 4 -> 2, 28 -> 24 -> 12 -> 8 -> 4
    g = torch.Generator().manual_seed(1)
    x = torch.randn(16, 1, 1, 1, generator=g) * torch.randn(1, *SHAPE, generator=g)
    assert ae(x).shape == (16, *SHAPE)
    opt = torch.optim.Adam(ae.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        opt.zero_grad()
        loss = (ae(x) - x).square().mean()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.7 * losses[0], losses


def test_a_latent_model_on_non_square_images_takes_the_data_shape() -> None:
    cfg = ModelConfig(observation=AutoencoderConfig(latent_dim=4, encoder_hidden=16,
                                                    decoder_hidden=(32,)),
                      dynamics=SindyConfig(order=1)).resolve(3, (20, 28), 2)
    x, u = torch.randn(4, 3, *SHAPE), torch.rand(4, 2, 2)
    terms = LatentModel(cfg).loss(x, u)
    assert all(torch.isfinite(v) for v in terms.values())


def test_non_square_images_a_kind_cannot_take_are_one_clear_error() -> None:
    with pytest.raises(UserError, match=r"conv decoder needs image sides divisible by 4 "
                                         r"\(got 20x30\)"):
        AutoencoderConfig(decoder_kind="conv").resolve(3, (20, 30))
    with pytest.raises(UserError, match=r"image size 12x40 is too small"):
        AutoencoderConfig(image_size=(12, 40))
    with pytest.raises(UserError, match=r"sprite_size 21.*shorter side"):
        AutoencoderConfig(encoder_kind="moments", latent_dim=4, decoder_kind="sprite",
                          sprite_size=21, image_size=(20, 28))
    with pytest.raises(UserError, match=r"image_size is 32 but d\.h5 has image_size 20x28"):
        AutoencoderConfig(image_size=32).resolve(3, (20, 28), "d.h5")
    ae = Autoencoder(AutoencoderConfig(channels=3, image_size=32))
    with pytest.raises(UserError, match=r"images of shape \(C, H, W\) = \(3, 32, 32\), got "
                                         r"\(3, 20, 28\)"):
        ae.encode(torch.zeros(2, *SHAPE))


def test_image_sizes_serialize_as_before_for_squares_and_as_pairs_otherwise() -> None:
    square = AutoencoderConfig(image_size=(32, 32))
    assert square == AutoencoderConfig(image_size=32) and to_json(square)["image_size"] == 32
    wide = AutoencoderConfig(channels=3, image_size=(20, 28))
    record = json.loads(json.dumps(to_json(wide)))
    assert record["image_size"] == [20, 28]
    assert from_json(AutoencoderConfig, record, "model") == wide
    assert (wide.height, wide.width) == (20, 28)


def test_keypoints_run_across_each_side_of_a_non_square_image() -> None:
    enc = Autoencoder(AutoencoderConfig(channels=1, image_size=(17, 25), latent_dim=2,
                                        encoder_kind="keypoints")).encoder
    enc.net = torch.nn.Identity()
    enc.log_temperature.data.fill_(-3.0)
    x = torch.zeros(1, 1, 17, 25)
    x[0, 0, 4, 18] = 1.0  # row 4 of 17, column 18 of 25
    torch.testing.assert_close(enc(x)[0], torch.tensor([0.5, -0.5]), atol=1e-3, rtol=0)


# ----------------------------------------------------------------------------- records
def test_a_model_record_is_nested_and_reads_back() -> None:
    """config.json's model: the observation with one settings group per part, each with its
    ``kind``; it reads back as the same config, and a bad value is named by its path."""
    new = ModelConfig(observation=AutoencoderConfig(encoder=MomentEncoderConfig(), latent_dim=4,
                                                    decoder=SpriteDecoderConfig()),
                      dynamics=SindyConfig(order=1, library="face"))
    record = json.loads(json.dumps(to_json(new)))
    assert "observation" in record and "encoder" not in record
    assert record["observation"]["encoder"] == {"kind": "moments", "order": 4}
    assert from_json(ModelConfig, record, "model") == new
    assert new.observation.encoder_kind == "moments" and new.observation.decoder_kind == "sprite"
    bad = json.loads(json.dumps(record))
    bad["observation"]["encoder"]["order"] = "many"
    with pytest.raises(UserError, match=r"config\.json: model\.observation\.encoder\.order"):
        from_json(ModelConfig, bad, "config.json: model")
    # the flat form is the command line's and the constructor's, not a record's
    flat = {**record["observation"], "encoder_kind": "moments", "decoder_kind": "sprite"}
    del flat["encoder"], flat["decoder"]
    with pytest.raises(UserError, match=r"unknown settings \['decoder_kind', 'encoder_kind'\]"):
        from_json(AutoencoderConfig, flat, "model")
    with pytest.raises(dataclasses.FrozenInstanceError):
        new.observation.encoder_kind = "conv"  # type: ignore[misc]
