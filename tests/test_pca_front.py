"""The principal-component front of the fully connected autoencoder: fitted from the training
frames with the model's statistics, exact for derivatives, kept in the model's state."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig
from latent_sindy.models.derivatives import along
from latent_sindy.models.pca_front import principal_components


def _low_rank(m: int, p: int, rank: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(m, rank, generator=g) * torch.tensor([5.0, 3.0, 1.0][:rank])
            @ torch.randn(rank, p, generator=g) + torch.randn(p, generator=g))


@pytest.mark.parametrize("m, p", [(200, 30), (20, 300)])  # more frames than values, and fewer
def test_the_components_span_the_frames_and_are_orthonormal(m: int, p: int) -> None:
    frames = _low_rank(m, p, 3)
    mean, basis, spread = principal_components(frames, 3)
    assert torch.allclose(mean, frames.mean(0), atol=1e-4)
    coords = (frames - mean) @ basis
    assert spread == pytest.approx(float(coords.square().mean().sqrt()), rel=1e-4)
    assert torch.allclose(basis.T @ basis, torch.eye(3), atol=1e-4)
    centred = frames - mean
    rebuilt = centred @ basis @ basis.T  # rank 3 data: three components hold all of it
    assert torch.allclose(rebuilt, centred, atol=1e-3 * centred.abs().max())
    # the first direction is the largest one (SVD's)
    first = torch.linalg.svd(centred.double(), full_matrices=False)[2][0].float()
    assert abs(float(first @ basis[:, 0])) == pytest.approx(1.0, abs=1e-4)


def test_more_components_than_frames_or_values_is_refused() -> None:
    with pytest.raises(UserError, match="at most 5"):
        principal_components(torch.randn(5, 40), 6)


@pytest.mark.parametrize("kwargs, message", [
    ({"encoder_kind": "conv", "decoder_kind": "mlp"}, "mlp encoder and decoder"),
    ({"encoder_kind": "mlp", "decoder_kind": "fc"}, "mlp encoder and decoder"),
    ({"encoder_kind": "mlp", "decoder_kind": "mlp", "channels": 1, "image_size": 4},
     "more than the 16 values"),
])
def test_a_front_needs_the_mlp_autoencoder_and_enough_values(kwargs, message) -> None:
    with pytest.raises(UserError, match=message):
        AutoencoderConfig(pca_components=20, **kwargs)


def test_the_front_carries_derivatives_exactly() -> None:
    cfg = AutoencoderConfig(channels=1, image_size=6, latent_dim=2, encoder_kind="mlp",
                            decoder_kind="mlp", pca_components=5)
    torch.manual_seed(0)
    auto = cfg.build()
    frames = _low_rank(50, 36, 3).reshape(50, 1, 6, 6)
    auto.fit_statistics(frames)
    x, dx = frames[:4], torch.randn(4, 1, 6, 6)
    z, dz = auto.encoder.along(x, dx)
    ref_z, ref_dz = along(auto.encoder, x, dx)  # forward mode through the whole encoder
    assert torch.allclose(z, ref_z, atol=1e-5) and torch.allclose(dz, ref_dz, atol=1e-5)
    # the decoder's output lies in the span of the components, about the frames' mean
    mean, basis, _ = principal_components(frames.flatten(1), 5)
    out = auto.decode(z).flatten(1) - mean
    # and the networks see coordinates of unit spread
    first = auto.encoder.net[0](frames.flatten(1))
    assert float(first.square().mean().sqrt()) == pytest.approx(1.0, rel=1e-3)
    assert torch.allclose(out @ basis @ basis.T, out, atol=1e-4)


def _video(seed: int = 0) -> SequenceData:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 3, 12)
    phase = rng.uniform(0, 6, (8, 1))
    xs = np.arange(10)
    frames = np.exp(-(xs[None, None, None, :] - 4.5 - 3 * np.sin(t[None, :, None, None]
                                                                  + phase[..., None, None])) ** 2)
    images = np.broadcast_to(frames, (8, 12, 10, 10))[:, :, None].astype(np.float32)
    return SequenceData(np.ascontiguousarray(images), np.zeros((8, 11, 0), np.float32),
                        dt=t[1] - t[0])


def test_the_estimator_fits_and_reloads_a_model_with_a_front(tmp_path) -> None:
    data = _video()
    kwargs = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False,
              "time": "continuous", "pca_components": 6}
    model = LatentSINDy(1, seed=0, **kwargs).fit(data, epochs=2, starts=1, out=tmp_path / "r")
    w = model.model_.autoencoder.encoder.net[0].weight  # the directions over their spread
    gram = w @ w.T
    assert torch.allclose(gram, gram[0, 0] * torch.eye(6), atol=1e-4 * float(gram[0, 0]))
    assert float(gram[0, 0]) > 0  # fitted, not zeros
    again = LatentSINDy.load(tmp_path / "r")
    frames = data.images[0]
    assert np.array_equal(model.encode(frames), again.encode(frames))


def test_subspace_iteration_finds_the_same_directions_as_the_eigendecomposition(monkeypatch):
    import latent_sindy.models.pca_front as front

    gen = torch.Generator().manual_seed(0)
    # frames with a slowly decaying spectrum, as a moving blob's are
    scales = torch.logspace(0, -2, 60, dtype=torch.float64)
    frames = ((torch.randn(700, 60, generator=gen, dtype=torch.float64) * scales)
              @ torch.randn(60, 500, generator=gen, dtype=torch.float64)
              + 1e-3 * torch.randn(700, 500, generator=gen, dtype=torch.float64)).float()
    exact = principal_components(frames, 12)
    monkeypatch.setattr(front, "EXACT_BELOW", 100)
    fast = principal_components(frames, 12)
    cosines = torch.linalg.svdvals(exact[1].double().T @ fast[1].double())
    assert float(cosines.min()) > 0.999
    assert fast[2] == pytest.approx(exact[2], rel=1e-4)
    # the directions come in the same order (each matches its own, up to sign)
    assert torch.allclose((exact[1] * fast[1]).sum(0).abs(), torch.ones(12), atol=1e-2)
