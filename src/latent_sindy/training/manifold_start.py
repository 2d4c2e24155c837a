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
   Where consecutive frames barely overlap (a small object that moves far between frames),
   the distances are those of the frames blurred until they do (:func:`choose_blur`).
2. **Regression**: the encoder (and the decoder, reconstructing) is trained to give that
   coordinate, standardised, on every training frame (:func:`regress_encoder`).
3. **Two latents turned apart** (:func:`choose_rotation`): two independent motions give
   two uncorrelated coordinates, which scaling returns turned by an unknown angle; the turn
   under which each latent's second derivative is best explained by that latent alone is
   folded into the encoder's last layer and the decoder's first.

4. **The law on the coordinates** (:func:`coordinate_law`): the coordinates along every
   training and validation sequence (frames the landmarks do not cover left out), differentiated in
   time by fourth-order stencils, and each latent's unit, zero and sparse law searched
   together (:func:`~latent_sindy.sindy.unit_search.search_law`: a sine fixes the unit,
   nothing else does). Where the law found leaves at most :data:`SETTLED` of the held-out
   z̈ unexplained, its unit and zero are folded into the encoder and decoder, its
   coefficients become the model's, and the start is *settled*: the main fit does not
   train it (trained further, the autoencoder warps a latent that was right, RESULTS.md,
   "Videos drawn from a family"). Otherwise the main fit trains from the regression.

Every choice is the data's: nothing here knows what is filmed.

    >>> begin_session(session)          # the recipe's hook, before a start's main fit
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from latent_sindy.models.manifold import Manifold, geodesic_coordinates, principal_front
from latent_sindy.models.parts import moving_parts
from latent_sindy.models.pca_front import LinearMap, blurred_metric
from latent_sindy.sindy.unit_search import GAIN, UnitLaw, search_law
from latent_sindy.training.prepare import stencil_stride
from latent_sindy.training.reselect import latent_derivatives
from latent_sindy.training.samples import CoordinateSamples

__all__ = ["CLOSE", "OVERLAP", "SETTLED", "begin_session", "choose_blur", "choose_rotation",
           "coordinate_law", "graph_blur", "regress_encoder"]

#: Updates of the regression onto the coordinates (batches of :data:`REGRESSION_BATCH`).
REGRESSION_STEPS = 3000
REGRESSION_BATCH = 100
#: Samples the turn of two latents is chosen on at most (an even subsample beyond).
TURN_SAMPLES = 5000
#: The most of the held-out z̈ (a share of its variance) a law found on the coordinates may
#: leave unexplained for the start to be settled (no main fit).
SETTLED = 0.2
#: A law of one term more that took away this share of the error of the law before it
#: (a range about the search's :data:`~latent_sindy.sindy.unit_search.GAIN`) was a close
#: call: a settled law with one is doubted aloud.
CLOSE = (GAIN / 2, 2 * GAIN)
#: A law with no term in a latent's rate, where each sequence spans less than this many
#: radians of the law's own oscillation (a quarter period), is doubted aloud: on the video
#: family's draws a weak damping (c/ω 0.014 and 0.039) went unseen on such stretches.
SHORT_SPAN = math.pi / 2
#: Samples of each split the law is searched on at most (evenly spaced beyond).
LAW_SAMPLES = 6000
#: Fewest covered samples a split needs for the law to be searched on it; where the
#: validation sequences have fewer (they swing where no training frame went, so their
#: coordinates cannot be trusted), every :data:`HOLD_OUT_EVERY`-th training sequence is
#: held out in their place.
MIN_SAMPLES = 50
HOLD_OUT_EVERY = 5
#: The geodesic graph is built on the frames as they are where consecutive frames of the
#: training sequences lie apart (squared distance, the median) at most this share of what
#: lies between any two training frames (the median of :data:`PAIRS` random pairs); beyond
#: it (a small object that moves far between frames), on the frames blurred by the first of
#: :data:`BLUR_WIDTHS` (pixels) that brings them within it, or by the last
#: (:func:`graph_blur`).
OVERLAP = 0.15
BLUR_WIDTHS = (1.0, 2.0, 3.0, 4.0)
PAIRS = 4000
#: Training frames the parts and their coordinates are found on at most (several latents).
PART_FRAMES = 12000
#: Principal components of each part's pixels its coordinate is found on.
PART_COMPONENTS = 48


def regress_encoder(encoder: nn.Module, decoder: nn.Module, inputs: torch.Tensor,
                    target: torch.Tensor, steps: int | None = None,
                    batch: int = REGRESSION_BATCH, lr: float = 3e-3, seed: int = 0) -> float:
    """Train ``encoder`` (inputs -> latent) onto ``target`` (N, nz) and ``decoder`` (latent
    -> inputs) back, by Adam on mean squared errors (the inputs' scaled by their variance);
    returns the last hundred updates' mean latent error. ``steps``: Adam updates (None:
    :data:`REGRESSION_STEPS`)."""
    if steps is None:
        steps = REGRESSION_STEPS
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
    nz = dyn.nz
    seed = session.cfg.seed
    sequences = _training_sequences(session) if nz > 1 else None
    parts = _part_readers(session, sequences, nz) if sequences is not None else None
    if parts is not None:  # each latent the coordinate of one part's pixels
        pixels = sequences.flatten(0, 1)
        frames = model.autoencoder.encoder.net[0](pixels.to(session.device))
        target = torch.cat([r.read(pixels)[0] for r in parts], 1)
        out: dict = {"parts": [len(r.pixels) for r in parts]}
    else:
        # every frame of the windows (frames alone: all five of each stencil, so that the
        # coordinates reach each sequence's ends, where the stencils read them too)
        frames = (train.coords.flatten(0, 1) if train.stencil else train.coords[:, 0]).detach()
        width, metric = graph_blur(session)
        manifold = geodesic_coordinates(frames.cpu(), nz, seed=seed, metric=metric)
        target = manifold.project(frames.cpu())
        out = {"eigenvalues": manifold.eigenvalues[:nz + 2].tolist(), "blur": width}
    # the coordinates are uncorrelated (the scaling's eigenvectors): standardised, white
    centre, spread = target.mean(0), target.std(0).clamp_min(1e-12)
    target = ((target - centre) / spread).float()
    if parts is not None:
        reader = _parts_reader(parts, centre, spread)
    else:  # (two latents turned below: the encoder's latent is read, the turn in it)
        reader = _manifold_reader(manifold, centre, spread, coordinates=nz == 1)
    with torch.enable_grad():
        out["regression_error"] = regress_encoder(enc, dec, frames, target.to(frames.device),
                                                  seed=seed)
    if nz == 2 and parts is None:  # two motions: turned apart, each a latent of its own
        phase, top, _ = latent_derivatives(model, train)
        phi = choose_rotation(phase, top)
        _fold(enc[-1], dec[0], _turn(phi), torch.zeros(2, dtype=torch.float64))
        out["turn"] = phi
    law = coordinate_law(session, reader)
    if law is not None:
        out["law_fvu"] = law.fvu.tolist()
        out["unit"] = law.unit.tolist()
        out["zero"] = law.zero.tolist()
        names = session.model.dynamics.names
        out["laws"] = [[([names[j] for j in terms], fvu) for terms, fvu in path]
                       for path in law.paths]
        # a term more weighed near the margin: the law kept may have one term too many or few
        out["close"] = [([names[j] for j in terms], gain)
                        for weighed in law.gains for terms, gain in weighed
                        if CLOSE[0] <= gain <= CLOSE[1]]
        out["short"] = _short_of_a_swing(session, law)
        if float(law.fvu.max()) <= SETTLED:
            _settle(session, law)
            out["settled"] = True
    return out


@torch.no_grad()
def graph_blur(session) -> tuple[float, torch.Tensor | None]:
    """:func:`choose_blur` on a session's training sequences, on its model's
    principal-component front ((0, None) where the model has none)."""
    model = session.model
    back = model.autoencoder.decoder.net[-1]
    if not isinstance(back, LinearMap):
        return 0.0, None
    front = model.autoencoder.encoder.net[0]
    part = session.data.split("train")
    sequences = [front(session.norm.normalize(part.images[i]).to(session.device).flatten(1))
                 .cpu() for i in range(part.n)]
    return choose_blur(sequences, back.weight.detach().cpu(), session.data.frame_shape,
                       seed=session.cfg.seed)[:2]


def choose_blur(sequences: list[torch.Tensor], columns: torch.Tensor, shape: tuple[int, ...],
                seed: int = 0) -> tuple[float, torch.Tensor | None, float]:
    """The blur (pixels, 0: none) the geodesic graph measures distances between frames
    under, its metric on a linear front (:func:`~latent_sindy.models.pca_front.blurred_metric`;
    None: none) and the share it was chosen on, from ``sequences`` of frames on the front
    (each (F, k)), the front's map back to frames ``columns`` (pixels, k) and the frames'
    ``shape`` (C, H, W): the share of the squared distance between any two frames (the
    median over :data:`PAIRS` random pairs) that lies between consecutive frames (the
    median), none where it is at most :data:`OVERLAP`, else the first of
    :data:`BLUR_WIDTHS` under which it is (or the last).

    Frames of an object a few pixels wide that moves farther than its width between frames
    barely overlap, and where the sequences are few, the stretches where it moves fastest
    hold frames that overlap no other: each lies the same distance from every frame, and
    the graph's neighbours there stop following the motion's order (a second generator's
    pendulum σ 1.2 px wide, 20 sequences stepping about its width a frame at the bottom:
    the geodesic coordinate held 0.67 of the angle's variance; blurred by 1 px, 0.999).
    Blurred, the object is wider and neighbouring frames overlap again. Where frames already
    overlap, nothing changes."""
    steps = torch.cat([q[1:].double() - q[:-1].double() for q in sequences])
    frames = torch.cat(sequences).double()
    gen = torch.Generator().manual_seed(seed)
    a, b = torch.randint(len(frames), (2, PAIRS), generator=gen)
    pairs = frames[a] - frames[b]

    def share(metric: torch.Tensor | None) -> float:
        near, far = (steps, pairs) if metric is None else (steps @ metric.T, pairs @ metric.T)
        apart = float(far.square().sum(1).median())
        return float(near.square().sum(1).median()) / apart if apart > 0 else 0.0

    first = share(None) if len(steps) else 0.0
    if first <= OVERLAP:
        return 0.0, None, first
    for width in BLUR_WIDTHS:
        metric = blurred_metric(columns, shape, width)
        if share(metric) <= OVERLAP:
            break
    return width, metric, first


@torch.no_grad()
def _short_of_a_swing(session, law: UnitLaw) -> list[tuple[str, float]]:
    """The latents whose law holds no term in their own rate while each sequence spans less
    than :data:`SHORT_SPAN` radians of the law's own oscillation (√ of −∂z̈/∂z at its zero,
    in the data's time): a rate term weaker than the latent's warp cannot show over so
    short stretches. (name, span) each."""
    dyn = session.model.dynamics
    nz = dyn.nz
    data = session.data
    out = []
    for i in range(nz):
        coef = torch.as_tensor(law.coef[:, i], dtype=torch.float64)
        if any(c != 0 and f"z{i}'" in name for c, name in zip(coef, dyn.names, strict=True)):
            continue  # a term in the rate is there
        step = 1e-3
        probe = torch.zeros(2, 2 * nz)
        probe[0, i], probe[1, i] = step, -step
        cols = dyn.library(probe, torch.zeros(2, 0)).double()
        omega2 = -float((cols[0] - cols[1]) @ coef) / (2 * step)
        if omega2 <= 0:
            continue
        span = data.steps * data.dt * math.sqrt(omega2) / dyn.time_unit
        if span < SHORT_SPAN:
            out.append((f"z{i}", span))
    return out


Reader = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor | None]]
"""(pixels (F, P), front coordinates (F, K)) -> the frames the coordinates reach (F,) bool,
and the coordinates standardised as the encoder was regressed onto them (F, nz) (None: the
encoder's own latent is read)."""


def _manifold_reader(manifold: Manifold, centre: torch.Tensor, spread: torch.Tensor,
                     coordinates: bool) -> Reader:
    def read(pixels: torch.Tensor, coords: torch.Tensor):
        c = coords.cpu()
        z = ((manifold.project(c) - centre) / spread).float() if coordinates else None
        return manifold.covers(c), z
    return read


@dataclass
class _PartReader:
    """One part's coordinate: its pixels, their principal components and its manifold."""

    pixels: torch.Tensor
    mean: torch.Tensor
    basis: torch.Tensor
    manifold: Manifold

    def read(self, pixels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(F, 1) coordinate and (F,) covered of frames' pixels (F, P)."""
        c = (pixels[:, self.pixels].double().cpu() - self.mean) @ self.basis
        return self.manifold.project(c).float(), self.manifold.covers(c)


def _parts_reader(parts: list[_PartReader], centre: torch.Tensor, spread: torch.Tensor
                  ) -> Reader:
    def read(pixels: torch.Tensor, coords: torch.Tensor):
        each = [r.read(pixels) for r in parts]
        z = (torch.cat([q for q, _ in each], 1) - centre) / spread
        return torch.stack([c for _, c in each]).all(0), z.float()
    return read


@torch.no_grad()
def _training_sequences(session, limit: int = PART_FRAMES) -> torch.Tensor:
    """Normalised pixels (n, F', P) of the training sequences, every k-th frame of each,
    at most ``limit`` frames in all."""
    part = session.data.split("train")
    step = max(1, math.ceil(part.n * (part.steps + 1) / limit))
    return torch.stack([session.norm.normalize(part.images[i][::step]).flatten(1)
                        for i in range(part.n)])


def _part_readers(session, sequences: torch.Tensor, nz: int) -> list[_PartReader] | None:
    """One coordinate reader per independently moving part of the training ``sequences``
    (:func:`~latent_sindy.models.parts.moving_parts`), None where the frames do not fall
    into ``nz`` parts."""
    groups = moving_parts(sequences, nz)
    if groups is None:
        return None
    frames = sequences.flatten(0, 1)
    readers = []
    for g in groups:
        x = frames[:, g].double()
        mean, basis = principal_front(x, PART_COMPONENTS, seed=session.cfg.seed)
        manifold = geodesic_coordinates((x - mean) @ basis, 1, seed=session.cfg.seed)
        readers.append(_PartReader(g, mean, basis, manifold))
    return readers


@torch.no_grad()
def _sequences(session, split: str, reader: Reader) -> tuple[torch.Tensor, torch.Tensor]:
    """Which frames the coordinates reach (n, F) and the coordinates the encoder was
    regressed onto (or its latent) (n, F, nz), for every frame of ``split``'s sequences."""
    model = session.model
    front = model.autoencoder.encoder.net[0]
    enc = model.autoencoder.encoder.net[1:]
    part = session.data.split(split)
    reach, latents = [], []
    for i in range(part.n):
        x = session.norm.normalize(part.images[i]).to(session.device).flatten(1)
        c = front(x)
        covered, z = reader(x, c)
        reach.append(covered.cpu())
        latents.append((enc(c) if z is None else z).cpu())
    return torch.stack(reach), torch.stack(latents)


def _stencil_samples(model, z: torch.Tensor, covered: torch.Tensor, stride: int, dt: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(z, ż) (M, 2 nz), z̈ (M, nz) and the sequence (M,) of each sample, by fourth-order
    stencils of five latents ``stride`` frames apart along each sequence of z (n, F, nz)
    (the model's :meth:`stencil_latents`), where all five frames are covered (n, F), in
    sequence order."""
    n, f, _ = z.shape
    h = stride * dt
    centres = np.arange(2 * stride, f - 2 * stride)
    if len(centres) == 0:
        return np.zeros((0, 2 * z.shape[2])), np.zeros((0, z.shape[2])), np.zeros(0, int)
    window = torch.as_tensor(centres[:, None] + stride * np.arange(-2, 3))  # (C, 5)
    z5 = z.double()[:, window].flatten(0, 1)  # (n C, 5, nz)
    m, first, second = (t.numpy() for t in model.stencil_latents(z5, h))
    ok = covered[:, window].all(-1).flatten().numpy()
    sequence = np.repeat(np.arange(n), len(centres))
    return np.concatenate([m, first], -1)[ok], second[ok], sequence[ok]


def _held_out_every(train: tuple[np.ndarray, ...], every: int) -> dict[str, tuple]:
    """The training samples (phase, z̈, sequence) split by sequence: every ``every``-th
    sequence held out (as "val"), the others kept (as "train")."""
    held = train[2] % every == every - 1
    return {"train": tuple(a[~held] for a in train), "val": tuple(a[held] for a in train)}


def coordinate_law(session, reader: Reader) -> UnitLaw | None:
    """The law of a continuous second-order session's latent (the coordinates the encoder
    was regressed onto, as ``reader`` reads them: read on the manifold, pixel noise moves
    them less than through the encoder) searched with each latent's unit and zero (step 4
    of the module's docstring), in the model's time; None where the data hold actions or
    too few covered samples. The laws are scored on the validation sequences, or where
    those have too few covered samples, on every :data:`HOLD_OUT_EVERY`-th training
    sequence."""
    model = session.model
    dyn = model.dynamics
    data = session.data
    if dyn.derivative_order != 2 or dyn.nu:
        return None
    stride = stencil_stride(dyn.time_unit, data.dt, data.steps + 1)
    splits = {}
    for split in ("train", "val") if data.split_counts().get("val") else ("train",):
        reach, z = _sequences(session, split, reader)
        splits[split] = _stencil_samples(model, z, reach, stride, data.dt)
    if len(splits.get("val", ((),))[0]) < MIN_SAMPLES:
        # no validation sequences, or they swing where no training frame went (their
        # coordinates are not to be trusted): training sequences held out instead
        splits = _held_out_every(splits["train"], HOLD_OUT_EVERY)
    samples = []
    for phase, top, sequence in splits.values():
        if len(phase) > LAW_SAMPLES:
            pick = np.linspace(0, len(phase) - 1, LAW_SAMPLES).round().astype(int)
            phase, top, sequence = phase[pick], top[pick], sequence[pick]
        samples += [phase, top, sequence]
    if min(len(samples[0]), len(samples[3])) < MIN_SAMPLES:
        return None
    unit = dyn.time_unit
    scale = np.array([unit ** (j // dyn.nz) for j in range(2 * dyn.nz)])  # model time
    p = dyn.library.n_terms
    sines = [(p - len(dyn.library.trig) + j, var, float(freq))
             for j, (var, kind, freq) in enumerate(dyn.library.trig) if kind == "sin"]

    def library(phase: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            th = dyn.library(torch.as_tensor(phase, dtype=torch.float32),
                             torch.zeros(len(phase), 0))
        return th.double().numpy()

    # the zeros searched stand for the library's constant (z̈ = −k (z − z*) is a spring's
    # law at any z*): a constant beside them only soaks up a zero found a little off
    constant = [j for j, name in enumerate(dyn.library.names) if name == "1"]
    return search_law(library, sines, samples[0] * scale, samples[1] * unit ** 2,
                      samples[3] * scale, samples[4] * unit ** 2, samples[2], samples[5],
                      exclude=constant)


@torch.no_grad()
def _settle(session, law: UnitLaw) -> None:
    """The law's units and zeros folded into the encoder and decoder (q = unit (z − zero)),
    its coefficients and mask the model's."""
    model = session.model
    enc = model.autoencoder.encoder.net[1:]
    dec = model.autoencoder.decoder.net[:-1]
    a = torch.diag(torch.as_tensor(law.unit, dtype=torch.float64))
    c = -torch.as_tensor(law.unit * law.zero, dtype=torch.float64)
    _fold(enc[-1], dec[0], a, c)
    dyn = model.dynamics
    coef = torch.as_tensor(law.coef, dtype=dyn.psi.dtype, device=dyn.psi.device)
    dyn.mask.copy_(coef != 0)
    dyn.psi.copy_(coef)
