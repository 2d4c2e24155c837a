"""The continuous-time recipe's start: the encoder begins at the frames' own coordinates.

A video of one moving thing is a curve in pixel space (a surface for two), and its motion a
path along it. An autoencoder trained from random weights often settles on a latent that
reads the curve twice (a pendulum's height, the same left and right of the bottom), and no
law of that latent exists. So the recipe starts each fit from the curve's own coordinates:

1. **Geodesic coordinates** (:func:`geodesic_coordinates`): landmarks spread over the
   training frames by farthest-point sampling (on the principal-component front), a graph of
   each landmark's nearest neighbours (and a spanning tree, so it is connected), shortest
   paths along it, and classical scaling of those distances (Isomap, Tenenbaum et al. 2000).
   Distances along the curve are distances of the moving thing's path, so the coordinate is
   an affine function of the path's parameter (a pendulum's angle, a spring's excursion).
2. **Regression**: the encoder (and the decoder, reconstructing) is trained to give that
   coordinate, standardised, on every training frame (:func:`regress_encoder`).
3. **Two latents turned apart** (:func:`choose_rotation`): two independent motions give
   two uncorrelated coordinates, which scaling returns turned by an unknown angle; the turn
   under which each latent's second derivative is best explained by that latent alone is
   folded into the encoder's last layer and the decoder's first.

The main fit then trains as before from there. The standardised coordinate is near a
pendulum's radians when it swings widely (its angle's spread is about 1), and the main fit's
sin(z) term pulls it the rest of the way. Every choice is the data's: nothing here knows
what is filmed.

    >>> begin_session(session)          # the recipe's hook, before a start's main fit
"""

from __future__ import annotations

import math

import torch
from torch import nn

from latent_sindy.models.manifold import geodesic_coordinates
from latent_sindy.training.reselect import latent_derivatives
from latent_sindy.training.samples import CoordinateSamples

__all__ = ["begin_session", "choose_rotation", "regress_encoder"]

#: Updates of the regression onto the coordinates (batches of :data:`REGRESSION_BATCH`).
REGRESSION_STEPS = 3000
REGRESSION_BATCH = 100
#: Samples the turn of two latents is chosen on at most (an even subsample beyond).
TURN_SAMPLES = 5000


def regress_encoder(encoder: nn.Module, decoder: nn.Module, inputs: torch.Tensor,
                    target: torch.Tensor, steps: int = REGRESSION_STEPS,
                    batch: int = REGRESSION_BATCH, lr: float = 3e-3, seed: int = 0) -> float:
    """Train ``encoder`` (inputs -> latent) onto ``target`` (N, nz) and ``decoder`` (latent
    -> inputs) back, by Adam on mean squared errors (the inputs' scaled by their variance);
    returns the last hundred updates' mean latent error."""
    params = [*encoder.parameters(), *decoder.parameters()]
    opt = torch.optim.Adam(params, lr=lr)
    spread = inputs.var().clamp_min(1e-12)
    gen = torch.Generator(device=inputs.device).manual_seed(seed)
    errors = []
    for _ in range(steps):
        b = torch.randint(len(inputs), (min(batch, len(inputs)),), generator=gen,
                          device=inputs.device)
        z = encoder(inputs[b])
        err = (z - target[b]).square().mean()
        loss = err + (decoder(z) - inputs[b]).square().mean() / spread
        opt.zero_grad()
        loss.backward()
        opt.step()
        errors.append(float(err.detach()))
    return sum(errors[-100:]) / len(errors[-100:])


def _own_basis(z: torch.Tensor, rate: torch.Tensor) -> torch.Tensor:
    """A flexible basis of one latent and its rate (polynomials of z to degree 7, the rate
    times powers of z to 2, the rate's square and cube)."""
    cols = [z ** p for p in range(8)] + [rate * z ** p for p in range(3)] + [rate ** 2, rate ** 3]
    return torch.stack(cols, 1)


def choose_rotation(phase: torch.Tensor, top: torch.Tensor, steps: int = 90) -> float:
    """The angle φ by which two whitened latents (phase (N, 2k), top (N, 2)) are turned so
    that each one's k-th derivative is best explained by itself alone (a smooth function of
    it and its rate): independent motions mixed by a turn come apart."""
    if len(phase) > TURN_SAMPLES:
        pick = torch.linspace(0, len(phase) - 1, TURN_SAMPLES).round().long()
        phase, top = phase[pick], top[pick]
    p = phase.double()
    y = top.double()

    def unexplained(phi: float) -> float:
        r = _turn(phi)
        z = p[:, :2] @ r.T
        rate = p[:, 2:4] @ r.T if p.shape[1] >= 4 else torch.zeros_like(z)
        acc = y @ r.T
        total = 0.0
        for i in range(2):
            basis = _own_basis(z[:, i], rate[:, i])
            fit = torch.linalg.lstsq(basis, acc[:, i:i + 1]).solution
            total += float((acc[:, i:i + 1] - basis @ fit).var() / acc[:, i].var())
        return total

    coarse = [math.pi / 2 * j / steps for j in range(steps)]
    phi = min(coarse, key=unexplained)
    fine = [phi + math.pi / 2 / steps * (j / 10 - 1) for j in range(21)]
    return min(fine, key=unexplained)


def _turn(phi: float) -> torch.Tensor:
    c, s = math.cos(phi), math.sin(phi)
    return torch.tensor([[c, -s], [s, c]], dtype=torch.float64)


@torch.no_grad()
def _fold(encoder_last: nn.Linear, decoder_first: nn.Linear, a: torch.Tensor,
          c: torch.Tensor) -> None:
    """The latent z of the layers becomes A z + c (A (nz, nz) invertible)."""
    w, bias = encoder_last.weight.double(), encoder_last.bias.double()
    encoder_last.weight.copy_(a @ w)
    encoder_last.bias.copy_(a @ bias + c)
    inverse = torch.linalg.inv(a)
    wd = decoder_first.weight.double()
    decoder_first.bias.copy_(decoder_first.bias.double() - wd @ inverse @ c)
    decoder_first.weight.copy_(wd @ inverse)


def begin_session(session) -> dict | None:
    """The start above, on a continuous-time training session whose model has a
    principal-component front (the recipe's); returns what it chose (None: not such a
    model, nothing done)."""
    model = session.model
    dyn = model.dynamics
    train = session.tensors.train
    if not isinstance(train, CoordinateSamples) or not getattr(dyn, "continuous", False):
        return None
    enc = model.autoencoder.encoder.net[1:]
    dec = model.autoencoder.decoder.net[:-1]
    if not (isinstance(enc[-1], nn.Linear) and isinstance(dec[0], nn.Linear)):
        return None
    middle = 2 if train.stencil else 0
    frames = train.coords[:, middle].detach()
    nz = dyn.nz
    seed = session.cfg.seed
    manifold = geodesic_coordinates(frames.cpu(), nz, seed=seed)
    target = manifold.transform(frames.cpu())
    # the coordinates are uncorrelated (the scaling's eigenvectors): standardised, white
    target = ((target - target.mean(0)) / target.std(0).clamp_min(1e-12)).float()
    with torch.enable_grad():
        error = regress_encoder(enc, dec, frames, target.to(frames.device), seed=seed)
    out: dict = {"eigenvalues": manifold.eigenvalues[:nz + 2].tolist(),
                 "regression_error": error}
    if nz == 2:  # two motions: turned apart, each a latent of its own
        phase, top, _ = latent_derivatives(model, train)
        phi = choose_rotation(phase, top)
        _fold(enc[-1], dec[0], _turn(phi), torch.zeros(2, dtype=torch.float64))
        out["turn"] = phi
    return out
