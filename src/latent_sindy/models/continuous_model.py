"""The continuous-time latent model: the SINDy autoencoder's loss (Champion et al., PNAS 2019)
on a frame and its time derivatives.

:class:`ContinuousLatentModel` is the :class:`~latent_sindy.models.latent_model.LatentModel`
of continuous-time dynamics (:mod:`latent_sindy.models.dynamics.continuous`: z^(k) =
Θ(z[, ż], u) Ξ, k = 1 or 2); ``LatentModel(config)`` builds it for such a config, with the
same parameters (and state dict keys). It trains not on sequences but on samples of one frame
and its k time derivatives, x (B, 1+k, C, h, w) = (x, ẋ[, ẍ]), with the action acting at it,
u (B, nu) (the trainer's ``DerivativeSamples``). :func:`~latent_sindy.models.derivatives.along`
takes the encoder's ż, z̈ and the decoder's derivatives by the chain rule (forward mode), and
the loss terms are, every one a mean squared error per element as the discrete loss's:

    z, ż[, z̈] = enc along (x, ẋ[, ẍ])         the encoder's latent and its derivatives
    ẑ^(k)     = Θ(z[, ż], u) Ξ                the dynamics' k-th derivative of z
    x̂, x̂^(k)  = dec along (z[, ż], ẑ^(k))     x̂^(k): x^(k) predicted through the decoder
    recon  = mean_b ‖x − x̂‖² / (C·h·w)
    pred_x = T^(2k) mean_b ‖x^(k) − x̂^(k)‖² / (C·h·w)
    pred_z = T^(2k) mean_b ‖z^(k) − ẑ^(k)‖² / nz    (``relative_pred_z``: the relative error,
                                                  without T^(2k))
    l1     = ‖M ⊙ Ψ‖₁                         (Ψ: the trained coefficients, Ξ at T = 1)
    objective = recon + λ1 pred_x + λ2 pred_z
    total  = objective + λ3 l1                    (pose and reward: 0)

T is the dynamics' ``time_unit`` (1 unless set): it weighs the derivative terms as in the
model's own time, so that a fit in real time is the fit in model time. A window, poses and
rewards belong to sequences: the loss refuses them.

Behind a principal-component front (``pca_components``: the encoder's first layer and the
decoder's last are one fixed linear map E and its inverse D = W c + mean, W's columns
orthogonal), the same terms need no pixel: a frame is its coordinates c = E(x) and what the
front leaves out r = x − D(c), so ‖x − D(ĉ)‖² = ‖r‖² + Σ_j ‖W_j‖² (c_j − ĉ_j)² (r is
orthogonal to W's columns), and likewise for the derivatives. :meth:`~ContinuousLatentModel.
coordinates` turns samples into (c, ‖r‖²) once; :meth:`~ContinuousLatentModel.
coordinate_loss` gives the terms from them, equal to :meth:`~ContinuousLatentModel.loss` on
the frames up to rounding, at the networks' cost without the pixels'.

    >>> from latent_sindy.models import AutoencoderConfig, ModelConfig
    >>> from latent_sindy.models.dynamics import ContinuousSindyConfig
    >>> cfg = ModelConfig(dynamics=ContinuousSindyConfig(derivative_order=2),
    ...                   observation=AutoencoderConfig(latent_dim=1, encoder_kind="mlp",
    ...                                                 decoder_kind="mlp")).resolve(1, 8, 0)
    >>> model = LatentModel(cfg)  # a ContinuousLatentModel
    >>> terms = model.loss(torch.zeros(4, 3, 1, 8, 8), torch.zeros(4, 0))
    >>> type(model).__name__, sorted(terms)[:3]
    ('ContinuousLatentModel', ['l1', 'objective', 'pose'])
"""

from __future__ import annotations

import torch

from latent_sindy.errors import UserError
from latent_sindy.models.derivatives import along, along_layers
from latent_sindy.models.latent_model import LatentModel, ModelConfig
from latent_sindy.models.loss import DEFAULT_WEIGHTS, LossWeights, latent_error
from latent_sindy.models.pca_front import LinearMap
from latent_sindy.models.reward_head import Targets

__all__ = ["ContinuousLatentModel"]


class ContinuousLatentModel(LatentModel, dynamics_kind="continuous"):
    """Autoencoder + continuous-time dynamics, trained on frames and their time derivatives
    (the module's docstring); ``step(z, u)`` integrates the dynamics over one ``dt``."""

    def __init__(self, config: ModelConfig) -> None:
        if config.dynamics.kind != "continuous":
            raise ValueError(f"ContinuousLatentModel takes continuous-time dynamics, got "
                             f"{config.dynamics.kind!r}: build LatentModel(config) instead")
        super().__init__(config)

    def loss(
        self, x: torch.Tensor, u: torch.Tensor, weights: LossWeights | None = None,
        poses: torch.Tensor | Targets | None = None, window: int | None = None,
        stencil: float = 0.0,
    ) -> dict[str, torch.Tensor]:
        """The loss terms of :data:`~latent_sindy.models.latent_model.LOSS_TERMS` on frames
        and their k time derivatives x (B, 1+k, C, h, w) and their actions u (B, nu).
        ``weights`` None uses the defaults of :class:`LossWeights`; ``poses`` and ``window``
        (a discrete model's) must be None. ``stencil`` h > 0: x (B, 5, C, h, w) holds five
        frames h apart around each sample instead (:meth:`stencil_loss`)."""
        k = self.dynamics.derivative_order
        if stencil:
            return self.stencil_loss(x, u, stencil, weights)
        if poses is not None:
            raise ValueError("a continuous-time model's loss has no pose or reward term: call "
                             "loss(x, u, weights) without poses or targets")
        if window is not None:
            raise ValueError(f"a continuous-time model's loss takes single frames with their "
                             f"derivatives, not sequences to cut into windows: call "
                             f"loss(x, u, weights) without window (got window={window})")
        if x.ndim != 5 or x.shape[1] != k + 1 or u.shape != (x.shape[0], self.dynamics.nu):
            raise ValueError(f"a continuous-time loss of order {k} expects x (B, {k + 1}, C, h, "
                             f"w) and u (B, nu), got {tuple(x.shape)} and {tuple(u.shape)}")
        frames = x.unbind(1)  # x, ẋ[, ẍ]: (B, C, h, w) each
        ae = self.autoencoder
        z = along(ae.encoder, *frames)  # z, ż[, z̈]: (B, nz) each
        top = self.dynamics.derivative(torch.cat(z[:k], -1), u)  # the library's z^(k)
        x_hat = along(ae.decoder, *z[:k], top)  # x̂, and x̂^(k) from z[, ż] and top
        recon = (x_hat[0] - frames[0]).square().mean()
        pred_x = (x_hat[k] - frames[k]).square().mean()
        return self._terms(recon, pred_x, top, z[k], weights or DEFAULT_WEIGHTS)

    def phase(self, x: torch.Tensor, before: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """The phase state (z, ż) (N, 2 nz) of a second-order model at normalised frames x
        (N, C, h, w), from ``before``, the frames dt earlier: ż is the two latents'
        difference over dt, corrected by the model's own acceleration at x (z(t − dt) = z −
        dt ż + dt² z̈ / 2, so second order in dt; ``u`` (N, nu), the actions taken there)."""
        dyn = self.dynamics
        if before.shape != x.shape:
            raise UserError(f"previous of shape {tuple(before.shape)} does not match the "
                            f"images' {tuple(x.shape)}: give one frame before each image")
        z = self.encode(x)
        rate = (z - self.encode(before)) / dyn.dt
        velocity = rate
        for _ in range(3):  # a fixed point: the acceleration depends on the velocity
            velocity = rate + 0.5 * dyn.dt * dyn.derivative(torch.cat([z, velocity], -1), u)
        return torch.cat([z, velocity], -1)

    def stencil_latents(self, z: torch.Tensor, h: float) -> tuple[torch.Tensor, ...]:
        """The latent and its k time derivatives at the middle of five latents h apart,
        z (B, 5, nz), by fourth-order central differences (their error for a motion of
        frequency ω is about (ωh)^4/30 of ż and (ωh)^4/90 of z̈): (z, ż[, z̈]) (B, nz) each."""
        d1 = (z[:, 0] - 8 * z[:, 1] + 8 * z[:, 3] - z[:, 4]) / (12 * h)
        d2 = (-z[:, 0] + 16 * z[:, 1] - 30 * z[:, 2] + 16 * z[:, 3] - z[:, 4]) / (12 * h * h)
        return (z[:, 2], d1, d2)[: self.dynamics.derivative_order + 1]

    def stencil_encode(self, x: torch.Tensor, h: float, coords: bool = False
                       ) -> tuple[torch.Tensor, ...]:
        """The latent and its k derivatives (:meth:`stencil_latents`) of five frames ``h``
        apart around each sample, x (B, 5, C, h, w), or with ``coords`` their coordinates on
        the front (B, 5, K), through the encoder without it."""
        net = self.autoencoder.encoder.net[1:] if coords else self.autoencoder.encoder
        return self.stencil_latents(net(x.flatten(0, 1)).view(len(x), 5, -1), h)

    def stencil_loss(self, x: torch.Tensor, u: torch.Tensor, h: float,
                     weights: LossWeights | None = None) -> dict[str, torch.Tensor]:
        """The loss on frames without derivatives: x (B, 5, C, h, w), five frames ``h`` apart
        around each sample. The encoder's latents of the five are differentiated
        (:meth:`stencil_latents`), so no pixel is: a pixel's intensity changes far faster
        than the motion it shows (a blob passing it), and its differences are wrong long
        before the latent's are. The reconstruction is the middle frame's; there is no
        x^(k) term (no pixel derivative to compare with)."""
        if x.ndim != 5 or x.shape[1] != 5 or u.shape != (x.shape[0], self.dynamics.nu):
            raise ValueError(f"a stencil loss expects x (B, 5, C, h, w) and u (B, nu), got "
                             f"{tuple(x.shape)} and {tuple(u.shape)}")
        zs = self.stencil_encode(x, h)
        k = self.dynamics.derivative_order
        top = self.dynamics.derivative(torch.cat(zs[:k], -1), u)
        recon = (self.autoencoder.decoder(zs[0]) - x[:, 2]).square().mean()
        return self._terms(recon, recon.new_zeros(()), top, zs[k], weights or DEFAULT_WEIGHTS)

    def front(self) -> tuple[LinearMap, LinearMap] | None:
        """The fixed linear front (the encoder's first map, the decoder's last), or None."""
        enc = getattr(self.autoencoder.encoder, "net", None)
        dec = getattr(self.autoencoder.decoder, "net", None)
        if enc is not None and dec is not None and isinstance(enc[0], LinearMap) and (
                isinstance(dec[-1], LinearMap)):
            return enc[0], dec[-1]
        return None

    @torch.no_grad()
    def coordinates(self, x: torch.Tensor, chunk: int = 1024, frames: bool = False
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames and their derivatives x (B, 1+k, C, h, w) on the front: their coordinates
        (B, 1+k, K) (the derivatives' without the mean) and the squared norm of what the
        front leaves out of each (B, 1+k), summed over pixels in float64; ``frames``: every
        entry of x is a frame (a stencil's), each with the mean. ValueError without a
        front."""
        front = self.front()
        if front is None:
            raise ValueError("coordinates: this model has no principal-component front "
                             "(pca_components 0, or not the mlp encoder and decoder)")
        enc, dec = front
        coords = []
        left = []
        for part in x.split(chunk):
            flat = part.flatten(2)  # (b, 1+k, P)
            c = flat @ enc.weight.T
            which = slice(None) if frames else 0
            c[:, which] += enc.bias
            back = c.double() @ dec.weight.T.double()
            back[:, which] += dec.bias.double()
            coords.append(c)
            left.append((flat.double() - back).square().sum(-1).float())
        return torch.cat(coords), torch.cat(left)

    def coordinate_loss(self, c: torch.Tensor, u: torch.Tensor, left: torch.Tensor,
                        weights: LossWeights | None = None, stencil: float = 0.0
                        ) -> dict[str, torch.Tensor]:
        """:meth:`loss` from the samples' coordinates c (B, 1+k, K) and what the front leaves
        out of them, ``left`` (B, 1+k) (:meth:`coordinates`), through the networks without
        the front: the same terms up to rounding. ``stencil`` h > 0: c (B, 5, K), left
        (B, 5) of five frames h apart (:meth:`stencil_loss`)."""
        k = self.dynamics.derivative_order
        _, dec = self.front() or (None, None)
        if stencil:
            if dec is None or c.ndim != 3 or c.shape[1:] != (5, dec.weight.shape[1]):
                raise ValueError(f"a stencil's coordinate_loss expects coordinates (B, 5, K) "
                                 f"on the model's front, got {tuple(c.shape)}")
            zs = self.stencil_encode(c, stencil, coords=True)
            top = self.dynamics.derivative(torch.cat(zs[:k], -1), u)
            c_hat = self.autoencoder.decoder.net[:-1](zs[0])
            column = dec.weight.square().sum(0)
            recon = ((c_hat - c[:, 2]).square() @ column + left[:, 2]).mean() / dec.weight.shape[0]
            return self._terms(recon, recon.new_zeros(()), top, zs[k],
                               weights or DEFAULT_WEIGHTS)
        if dec is None or c.ndim != 3 or c.shape[1:] != (k + 1, dec.weight.shape[1]) or (
                left.shape != c.shape[:2]):
            raise ValueError(f"coordinate_loss expects coordinates (B, {k + 1}, K) on the "
                             f"model's front and left (B, {k + 1}), got {tuple(c.shape)} and "
                             f"{tuple(left.shape)}")
        parts = c.unbind(1)
        z = along_layers(self.autoencoder.encoder.net[1:], *parts)
        top = self.dynamics.derivative(torch.cat(z[:k], -1), u)
        c_hat = along_layers(self.autoencoder.decoder.net[:-1], *z[:k], top)
        column = dec.weight.square().sum(0)  # (K,): ‖W_j‖²
        pixels = dec.weight.shape[0]
        recon = ((c_hat[0] - parts[0]).square() @ column + left[:, 0]).mean() / pixels
        pred_x = ((c_hat[k] - parts[k]).square() @ column + left[:, k]).mean() / pixels
        return self._terms(recon, pred_x, top, z[k], weights or DEFAULT_WEIGHTS)

    def _terms(self, recon: torch.Tensor, pred_x: torch.Tensor, top: torch.Tensor,
               zk: torch.Tensor, weights: LossWeights) -> dict[str, torch.Tensor]:
        """The terms from the reconstruction and x^(k) errors, the library's z^(k) and the
        encoder's."""
        k = self.dynamics.derivative_order
        pred_z = latent_error(top, zk, weights.relative_pred_z)
        unit = self.dynamics.time_unit ** (2 * k)  # the derivative terms in the model's time
        if unit != 1.0:
            pred_x = pred_x * unit
            pred_z = pred_z if weights.relative_pred_z else pred_z * unit
        l1 = self.l1_penalty()
        objective = recon + weights.lambda_pred_x * pred_x + weights.lambda_pred_z * pred_z
        return {"total": objective + weights.lambda_l1 * l1, "recon": recon, "pred_x": pred_x,
                "pred_z": pred_z, "l1": l1, "pose": recon.new_zeros(()), "objective": objective,
                "reward": recon.new_zeros(())}
