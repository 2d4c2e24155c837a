"""The law chosen again, on the trained encoder's held-out derivatives.

Pruning during training cuts every coefficient below one fixed size, so a term that matters
but is small in the model's time unit (a pendulum's friction c/ω of 0.05) is lost, and
whatever law is left when the cut falls is the one printed. After training, the encoder's
latent and its derivatives on the training and validation samples are a regression problem
of their own: :func:`reselect_law` compares the trained law with its neighbours, one term
added, removed or swapped, each refitted by least squares on the training samples
(:func:`~latent_sindy.sindy.selection.select_law`), and keeps the sparsest that explains
the validation samples as well as any, in place of the trained one. A law never grows by
more than one term a latent, so a latent that no sparse law fits keeps its trained law (and
the warning its unexplained share earns).

    choice = reselect_law(session.model, session.tensors.train, session.tensors.val)
    choice.fvu            # the share of the validation latent's z^(k) left unexplained
"""

from __future__ import annotations

import torch

from latent_sindy.models.derivatives import along, along_layers
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.sindy.selection import LawChoice, select_law
from latent_sindy.training.samples import CoordinateSamples, DerivativeSamples

__all__ = ["latent_derivatives", "reselect_law", "reselect_session"]

#: Samples of each split the regression uses at most (an even subsample beyond).
MAX_SAMPLES = 20000


@torch.no_grad()
def latent_derivatives(model: LatentModel, samples: CoordinateSamples | DerivativeSamples,
                       limit: int = MAX_SAMPLES, chunk: int = 4096
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The encoder's phase (z[, ż]) (N, k nz), its z^(k) (N, nz) and the actions (N, nu) on
    ``samples`` (frames with their derivatives, or their front coordinates), in the data's
    time, at most ``limit`` of them evenly spaced."""
    k = model.dynamics.derivative_order
    n = samples.n
    pick = torch.linspace(0, n - 1, min(n, limit)).round().long() if n > limit else slice(None)
    part = samples.pick(pick)
    phases, tops = [], []
    for lo in range(0, part.n, chunk):
        piece = part.pick(slice(lo, lo + chunk))
        coords = isinstance(piece, CoordinateSamples)
        if piece.stencil:  # five frames around each: their latents differentiated
            z = model.stencil_encode(piece.coords if coords else piece.frames, piece.stencil,
                                     coords)
        elif coords:
            z = along_layers(model.autoencoder.encoder.net[1:], *piece.coords.unbind(1))
        else:
            z = along(model.autoencoder.encoder, *piece.frames.unbind(1))
        phases.append(torch.cat(z[:k], -1))
        tops.append(z[k])
    return torch.cat(phases).cpu(), torch.cat(tops).cpu(), part.actions.cpu()


def reselect_law(model: LatentModel, train: CoordinateSamples | DerivativeSamples,
                 val: CoordinateSamples | DerivativeSamples | None) -> LawChoice | None:
    """Check the continuous-time ``model``'s law against its neighbours on its encoder's
    derivatives (fit on ``train``, judged on ``val``) and set its coefficients and mask to
    the one kept; None (nothing
    changed) without validation samples or where the derivatives are not finite."""
    dyn = model.dynamics
    if val is None or val.n == 0 or not getattr(dyn, "continuous", False):
        return None
    k = dyn.derivative_order
    unit = dyn.time_unit
    fitted = []
    for samples in (train, val):
        phase, top, u = latent_derivatives(model, samples)
        scale = dyn._phase_scale
        # the library in the model's time
        theta = dyn.library(phase.to(scale.device) * scale, u.to(scale.device)).cpu()
        fitted += [theta.double(), (top * unit ** k).double()]
    if not all(torch.isfinite(t).all() for t in fitted):
        return None
    choice = select_law(*fitted, start=dyn.mask.detach().cpu().numpy())
    coef = torch.as_tensor(choice.coef, dtype=dyn.psi.dtype)
    with torch.no_grad():
        dyn.mask.copy_(torch.as_tensor(choice.mask, device=dyn.mask.device))
        dyn.psi.copy_(coef.to(dyn.psi.device))
        dyn.psi.masked_fill_(~dyn.mask, 0.0)
    return choice


def reselect_session(session) -> float | None:
    """:func:`reselect_law` on a training session's model and samples (the model holding
    the weights it keeps); returns the chosen law's validation FVU, None where nothing was
    chosen. (The continuous-time recipe's last step: ``fit_in_memory(..., finish=``.)"""
    choice = reselect_law(session.model, session.tensors.train, session.tensors.val)
    return None if choice is None else choice.fvu
