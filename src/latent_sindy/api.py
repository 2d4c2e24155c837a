"""The estimator: a latent SINDy model of your own images and actions, in a few lines.

:class:`LatentSINDy` follows pysindy's conventions: the constructor stores settings, ``fit``
trains and returns the estimator, learned state ends in ``_``. The linear ("E2C") and MLP
baselines are the same class with ``dynamics="linear"`` or ``"mlp"``; the SINDy autoencoder's
continuous-time model (z'' = Θ(z, z') Ξ, trained on the images' time derivatives) is
``time="continuous", derivative_order=2``.

    >>> from latent_sindy import LatentSINDy, SequenceData
    >>> model = LatentSINDy(latent_dim=2, order=2, seed=0).fit(data, epochs=300)
    >>> model.print()                                  # z0' = ... sparse equations
    >>> next_images = model.predict(images[:, 0], actions[:, 0])
    >>> model.save("runs/mine"); model = LatentSINDy.load("runs/mine")
    >>> u = model.planner().act(image, goal_image)     # (nu,) action toward the goal
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.control.planner import ImagePlanner, Objective
from latent_sindy.data import SequenceData, inputs
from latent_sindy.equations import coefficient_table, doubt_notes, name_actions, pruned_note
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.models import DYNAMICS_KINDS, AutoencoderConfig, LossWeights, ModelConfig
from latent_sindy.models.dynamics.continuous import ContinuousSindyConfig
from latent_sindy.progress import Progress
from latent_sindy.sindy import LibrarySpec
from latent_sindy.training import recipe as recipes
from latent_sindy.training.config import TrainConfig, check_fit_settings
from latent_sindy.training.runs import RunDir
from latent_sindy.training.session import Phase, Restarts, fit_in_memory
from latent_sindy.training.train_run import train

__all__ = ["AllTermsPruned", "LatentSINDy", "UncertainLaw"]


class AllTermsPruned(UserWarning):
    """A fit whose SINDy model lost every term: it predicts that nothing moves."""


class UncertainLaw(UserWarning):
    """A fit whose law may be wrong: its starts disagreed, its terms were a close call, or
    it leaves much of the latent's derivative unexplained
    (:func:`latent_sindy.equations.doubt_notes`)."""


class LatentSINDy:
    """An autoencoder whose latent state evolves by sparse (SINDy), linear or MLP dynamics.

    Args:
        latent_dim: size of the latent state z.
        dynamics: "sindy" (sparse, interpretable), "linear" (z' = A z + B u + c) or "mlp".
        order: SINDy's polynomial order of the library in (z, u) (None: 2; continuous time 3).
        library: SINDy's library: a name ("poly"; worlds register their own) or a spec
            composed from the grammar (``Polynomial(("z", "u"), 2) + Sine("z")``), which
            holds its own terms (``order`` and ``include_sine`` are then not read).
        include_sine: SINDy's library also holds sin(z).
        encoder: "conv" (learned), "mlp" (fully connected, 128-64-32 sigmoid), or a kind a
            world registers; decoder: "conv", "fc" or "mlp" (None: mlp in continuous time).
        pca_components: with the mlp encoder and decoder, the first this many principal
            components of the training frames in front of the encoder and behind the
            decoder (a fixed linear map; derivatives pass it exactly): much cheaper steps on
            large frames. 0: none; None: the recipe's in continuous time, else none.
        time: "discrete" (z[t+1] = z + Θ(z, u) Ξ) or "continuous" (SINDy only: the
            latent's time derivative is Θ(...) Ξ, trained on the images' derivatives, which
            the data gives or its frames, dt apart, estimate).
        derivative_order: continuous time: 1 (z' = Θ(z, u) Ξ) or 2 (z'' = Θ(z, z', u) Ξ).
        time_unit: continuous time: the unit of time the coefficients are fitted in (the
            equations are shown in the data's): 1, the data's; "data", chosen from the data
            (so a faster or slower system trains alike); None: "data" with the recipe, else 1.
        loss: weights of the loss terms (reconstruction, prediction, L1 of the coefficients).
        settings: the training settings (epochs, learning rate, pruning threshold, ...),
            a :class:`~latent_sindy.training.TrainConfig`; ``seed`` and ``device`` override it.
            Continuous time without ``settings`` or ``model`` follows the recipe
            (:mod:`latent_sindy.training.recipe`) wherever an argument is not given.
        model: a whole :class:`~latent_sindy.models.ModelConfig` instead of the above.

    Attributes after ``fit`` (or ``load``): ``model_`` (the torch module), ``normalizer_``,
    ``description_`` (what the model knows of its data: frame shape, action box and names),
    ``metrics_`` (one row per epoch), ``kept_`` (which epoch's weights were kept).
    """

    def __init__(self, latent_dim: int = 4, *, dynamics: Literal["sindy", "linear", "mlp"]
                 = "sindy", order: int | None = None, library: str | LibrarySpec = "poly",
                 include_sine: bool = True, encoder: str | None = None,
                 decoder: str | None = None,
                 loss: LossWeights | None = None, settings: TrainConfig | None = None,
                 model: ModelConfig | None = None, seed: int = 0,
                 device: Literal["cpu", "cuda", "auto"] = "cpu",
                 time: Literal["discrete", "continuous"] = "discrete",
                 derivative_order: int = 1, pca_components: int | None = None,
                 time_unit: float | Literal["data"] | None = None) -> None:
        inputs.check_estimator_arguments(latent_dim, order, include_sine, seed,
                                         derivative_order, pca_components, time_unit)
        if time not in ("discrete", "continuous"):
            raise UserError(f"time {time!r}: use discrete or continuous")
        if model is not None and model.dynamics.kind == "continuous":  # (a whole model given)
            time = "continuous"
            derivative_order = model.dynamics.derivative_order
            order = model.dynamics.order
        self.time = time
        self.derivative_order = derivative_order
        if order is None:
            order = 3 if time == "continuous" else 2
        self.latent_dim = latent_dim
        self.dynamics = dynamics
        self.order = order
        self.library = library
        self.include_sine = include_sine
        net = "mlp" if time == "continuous" else "conv"
        self.seed = seed
        self.device = device
        self.encoder = encoder or net
        self.decoder = decoder or net
        self.pca_components = pca_components
        self.time_unit = time_unit
        self.recipe = time == "continuous" and model is None and settings is None
        self._loss_given = loss
        self.loss = loss or LossWeights()
        self.settings = settings or recipes.default_settings(self.recipe)
        self.model = model
        self.model_config  # noqa: B018  (validates the settings now)

    # ------------------------------------------------------------------ configuration
    @property
    def model_config(self) -> ModelConfig:
        """The model these settings describe (its shapes not yet taken from data)."""
        if self.model is not None:
            return self.model
        if self.dynamics not in DYNAMICS_KINDS:
            raise UserError(f"dynamics {self.dynamics!r} is unknown: use one of "
                            f"{', '.join(DYNAMICS_KINDS)}")
        extra: dict[str, Any] = {}
        if self.time == "continuous" and (self.dynamics != "sindy" or self.library != "poly"):
            raise UserError(f"time='continuous' is for SINDy on the poly library, got dynamics "
                            f"{self.dynamics!r}, library {self.library!r}: use "
                            "dynamics='sindy', library='poly'")
        if self.time == "discrete" and (self.derivative_order != 1
                                        or self.time_unit not in (None, 1)):
            raise UserError(f"derivative_order {self.derivative_order}, time_unit "
                            f"{self.time_unit} are for time='continuous': add it, or drop them")
        if self.time == "continuous":
            dyn: Any = ContinuousSindyConfig(derivative_order=self.derivative_order,
                                             order=self.order, include_sine=self.include_sine,
                                             time_unit=recipes.unit_of(self.time_unit, self.recipe),
                                             **(recipes.INIT if self.recipe else {}))
        elif self.dynamics == "sindy" and isinstance(self.library, LibrarySpec):
            extra = {"composed": self.library}
        elif self.dynamics == "sindy":
            extra = {"order": self.order, "library": self.library,
                     "include_sine": self.include_sine}
        if self.time == "discrete":
            dyn = DYNAMICS_KINDS[self.dynamics](**extra)
        return ModelConfig(dynamics=dyn,
                           observation=AutoencoderConfig(latent_dim=self.latent_dim,
                                                         encoder_kind=self.encoder,
                                                         decoder_kind=self.decoder,
                                                         pca_components=self.pca_components
                                                         or 0))

    def train_config(self, **overrides: Any) -> TrainConfig:
        """The training settings of a fit (``overrides``: any TrainConfig field)."""
        return dataclasses.replace(self.settings, model=self.model_config, loss=self.loss,
                                   seed=self.seed, device=self.device, **overrides)

    # ------------------------------------------------------------------ fitting
    def fit(self, data: SequenceData, epochs: int | None = None, *,
            out: str | os.PathLike | None = None, progress: Progress | None = None,
            phases: Sequence[Phase] | None = None, warmup: Sequence[Phase] = (),
            restarts: Restarts | None = None, **settings: Any) -> LatentSINDy:
        """Train on ``data`` (its training split; its validation split selects the kept
        weights). In memory, or into the run folder ``out`` (with checkpoints; resumable).
        ``settings``: TrainConfig fields for this fit (``window``, ``lr``, ...). In memory
        only: ``phases``, :class:`~latent_sindy.Phase` stretches trained after it from its
        kept weights, each with settings of its own (a calibration: ``Phase(300,
        "calibration", {"lr": 1e-3, "loss": ...})``); ``warmup``, phases before it; and
        ``restarts``, a :class:`~latent_sindy.Restarts` rule for fresh starts (None: the
        recipe's, in continuous time without settings; else none)."""
        if not isinstance(data, SequenceData):
            raise UserError(f"fit takes a SequenceData, got {type(data).__name__}")
        if epochs is not None:
            settings["epochs"] = epochs
        check_fit_settings(settings, out)  # (names and types: epochs=1.5 or True refused)
        folder = {} if out is None else {"out": Path(out), "data": Path(data.source)}
        cfg = self.train_config(**folder, **(recipes.recipe_epochs(settings) if self.recipe
                                             else settings))
        hooks: dict[str, Any] = {}
        if self.recipe:  # (into a folder: its main fit, the phases and restarts in memory)
            cfg, phases, restarts, hooks = recipes.apply_recipe(
                cfg, data, self._loss_given, self.pca_components, phases, restarts, bool(folder),
                scale="epochs" not in settings)
        if out is not None:
            if phases or warmup or restarts:
                raise UserError("phases, warmup and restarts train in memory: drop out= (save "
                                "the model afterwards)")
            train(cfg, progress, data=data)
            self._adopt(RunDir(out))
        else:
            session, result, metrics = fit_in_memory(cfg, data, progress, phases or (),
                                                     warmup=warmup, restarts=restarts,
                                                     **hooks)
            self.model_ = session.model
            self.normalizer_ = session.norm
            record = session.record
            self.description_ = record["description"]
            self.world_record_ = record["world"]["record"]
            self.record_ = {**record, "kept": result.kept}
            self.metrics_ = metrics
            self.kept_ = result.kept
        if note := pruned_note(self.model_.dynamics):
            warnings.warn(note, AllTermsPruned, stacklevel=2)
        else:
            for note in doubt_notes(self.kept_):
                warnings.warn(note, UncertainLaw, stacklevel=2)
        return self

    def _adopt(self, folder: RunDir) -> LatentSINDy:
        """Take the model, record, metrics and kept epoch of the finished run ``folder``."""
        run = folder.load()
        self.model_ = run.model
        self.normalizer_ = run.normalizer
        self.description_ = run.description
        self.world_record_ = run.world_record
        record = folder.read_record()
        kept = record.get("kept")
        if not isinstance(kept, dict):
            raise UserError(f"{folder / folder.CONFIG} names no kept epoch (the file was "
                            "edited): retrain the run")
        self.record_ = {**record, "kept": kept}
        self.kept_ = kept
        try:
            self.metrics_: list[dict[str, Any]] | None = folder.read_metrics()
        except UserError:  # the model is usable without its history (missing or damaged)
            self.metrics_ = None
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "model_"):
            raise UserError("this LatentSINDy is not fitted yet: call fit(data) or "
                            "LatentSINDy.load(run_folder) first")

    # ------------------------------------------------------------------ using the model
    def _observe(self, images: Any, name: str, dims: tuple[int, ...]) -> torch.Tensor:
        """``images`` (argument ``name``) of ``dims`` dimensions, each a frame (C, H, W) of
        this model in its data's pixel type, normalised; UserError naming what differs."""
        kind = self.model_.config.observation.kind
        if kind != "image":
            raise UserError(f"this model observes {kind}s, not images")
        d = self.description_
        return self.normalizer_.normalize(inputs.check_frames(
            images, name, dims, d["frame_shape"], d.get("pixel_dtype", "uint8")))

    def _pixels(self, x: torch.Tensor) -> np.ndarray:
        top = 255.0 if self.description_.get("pixel_dtype", "uint8") == "uint8" else 1.0
        return self.normalizer_.denormalize(x).clamp(0, top).numpy().astype(np.float32)

    def _actions(self, actions: Any, lead: tuple[int, ...]) -> torch.Tensor:
        nu = len(self.description_["action_low"])
        return torch.as_tensor(inputs.check_actions(actions, "actions", lead, nu))

    @torch.no_grad()
    def encode(self, images: np.ndarray) -> np.ndarray:
        """Images (..., C, H, W) in the data's pixel scale -> latents (..., nz)."""
        self._check_fitted()
        x = self._observe(images, "images", tuple(range(3, 9)))
        lead = x.shape[:-3]
        return self.model_.encode(x.reshape(-1, *x.shape[-3:])).reshape(*lead, -1).numpy()

    def _start(self, x: torch.Tensor, previous: Any, u: torch.Tensor, second: bool
               ) -> torch.Tensor:
        """The latent at frames ``x``, or (``second``) the phase (z, ż) from them, ``previous``."""
        return self.model_.phase(x, self._observe(np.asarray(previous)[None] if np.ndim(
            previous) == 3 else previous, "previous", (4,)), u) if second else self.model_.encode(x)

    @torch.no_grad()
    def predict(self, images: np.ndarray, actions: np.ndarray, previous: Any = None) -> np.ndarray:
        """The next images (N, C, H, W) after ``actions`` (N, nu) from ``images`` (N, C, H, W),
        in the data's pixel scale, float32 (a uint8 model's 0..255: np.round(out).astype(np.uint8)
        feeds them back); a single image (C, H, W) and action (nu,) work too. A second-order
        continuous-time model also needs ``previous``, the frames one dt before ``images``."""
        self._check_fitted()
        second = inputs.check_previous(self.model_.dynamics, previous, "predict")
        single = np.ndim(images) == 3
        x = self._observe(np.asarray(images)[None] if single else images, "images", (4,))
        nu = len(self.description_["action_low"])
        u = self._actions(actions, () if single else (len(x),)).reshape(len(x), nu)
        z_next = self.model_.step(self._start(x, previous, u, second), u)
        z_next = z_next[:, :self.model_.dynamics.nz]
        out = self._pixels(self.model_.decode(z_next))
        return out[0] if single else out

    @torch.no_grad()
    def simulate(self, image: np.ndarray, actions: np.ndarray | int,
                 previous: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Roll the model out from ``image`` (C, H, W) under ``actions`` (T, nu): the latents
        (T+1, nz) and the decoded images (T+1, C, H, W), in the data's pixel scale; from a
        batch of images (N, C, H, W) under actions (N, T, nu), (N, T+1, nz) and
        (N, T+1, C, H, W). A model without actions (an autonomous system) takes the number of
        steps T instead; a continuous-time model steps dt apart. A second-order one also
        needs ``previous``, the frame(s) one time step before ``image`` (see :meth:`predict`)."""
        self._check_fitted()
        if np.ndim(image) not in (3, 4):
            raise UserError(f"simulate rolls out an image (C, H, W) or a batch (N, C, H, W), "
                            f"got shape {np.shape(image)}")
        single = np.ndim(image) == 3
        second = inputs.check_previous(self.model_.dynamics, previous, "simulate")
        nu = len(self.description_["action_low"])
        n = 1 if single else len(image)
        actions = inputs.check_rollout_actions(actions, single, n, nu)
        lead = np.shape(actions)[:-1]
        u = self._actions(actions, lead).reshape(n, lead[-1], nu)  # (N, T, nu)
        x = self._observe(np.asarray(image)[None] if single else image, "image", (4,))
        first = u[:, 0] if u.shape[1] else u.new_zeros(n, nu)
        z = self.model_.rollout_latent(self._start(x, previous, first, second), u)
        z = z[..., :self.model_.dynamics.nz]  # (N, T+1, nz)
        frames = self._pixels(self.model_.decode(z.flatten(0, 1))).reshape(
            *z.shape[:2], *x.shape[1:])
        return (z[0].numpy(), frames[0]) if single else (z.numpy(), frames)

    def score(self, data: SequenceData, split: str = "test") -> float:
        """R² of the one-step image prediction on ``data``'s ``split`` (1: perfect; 0: no
        better than the mean next image)."""
        part = data.split(split) if split else data
        if part.n == 0:
            raise UserError(f"{data.source} has no {split} sequences to score on")
        x = part.images[:, :-1].reshape(-1, *part.frame_shape)
        u = part.actions.reshape(len(x), part.actions.shape[-1])
        truth = part.images[:, 1:].reshape(-1, *part.frame_shape).astype(np.float64)
        pred = self.predict(x, u).astype(np.float64)
        sst = float(((truth - truth.mean(0)) ** 2).sum())
        return 1.0 - float(((truth - pred) ** 2).sum()) / max(sst, 1e-12)

    # ------------------------------------------------------------------ the equations
    def equations(self, precision: int = 3, action_names: list[str] | None = None
                  ) -> list[str]:
        """The latent update rules as text, one per latent state (SINDy: active terms only)."""
        self._check_fitted()
        return name_actions(self.model_.dynamics.equations(precision),
                            inputs.action_names(self.description_, action_names))

    def print(self, action_names: list[str] | None = None, precision: int = 3) -> None:
        """Print :meth:`equations` (with the data's action names unless others are given), or
        one line where every SINDy term was pruned."""
        self._check_fitted()
        note = pruned_note(self.model_.dynamics)
        print(note or "\n".join(self.equations(precision, action_names)))

    def coefficients(self) -> np.ndarray:
        """The coefficients as pysindy gives them, (latent states × candidate terms), pruned
        entries 0 (SINDy); [A | B | c] for the linear model; UserError for an MLP. Column k
        is the term ``get_feature_names()[k]``."""
        return self._table()[1].T

    def get_feature_names(self) -> list[str]:
        """The candidate terms, in the order of :meth:`coefficients`' columns (pysindy's
        name): "1", "z0", "u1", "z0 u1", "sin(z0)", ..., the actions by the names
        :meth:`equations` gives them (the data's: "vx", "z0 vx", ...)."""
        return name_actions(self._table()[0], inputs.action_names(self.description_))

    def _table(self) -> tuple[list[str], np.ndarray]:
        self._check_fitted()
        return coefficient_table(self.model_.dynamics)

    # ------------------------------------------------------------------ files and control
    def save(self, path: str | os.PathLike) -> Path:
        """Write the fitted model as a run folder (config.json, model.pt) that every command
        (``equations``, ``control`` where its world allows) and :meth:`load` read; the folder
        is locked while written (a `latent-sindy train` into it is refused meanwhile, and one
        that holds it refuses this save) and must hold no run."""
        self._check_fitted()
        from latent_sindy.training.fit_loop import to_cpu
        from latent_sindy.training.record import action_box
        from latent_sindy.version import __version__

        run = RunDir(inputs.check_folder(path, "save"))
        if run.path.exists() and not run.path.is_dir():
            raise UserError(f"{run.path} is a file: save to a folder")
        with exclusive(run.path, "run folder", "folder"):
            held = [name for name in run.FILES if (run / name).exists()]
            if held:
                raise UserError(f"save {run.path}: the folder already holds a run "
                                f"({', '.join(held)}): choose another folder, or delete it "
                                "first")
            run.path.mkdir(parents=True, exist_ok=True)
            run.write_record(self.record_)
            run.write_metrics(self.metrics_ or [])
            run.save_torch(run.MODEL, {
                "epoch": self.kept_["epoch"], "epochs": self.record_["train"]["epochs"],
                "selection": self.kept_["selection"], "model": to_cpu(self.model_.state_dict()),
                "model_config": self.record_["model"], "normalizer": self.record_["normalizer"],
                "action_box": action_box(self.description_), "package_version": __version__})
        return run.path

    @classmethod
    def load(cls, path: str | os.PathLike) -> LatentSINDy:
        """The model of a run folder (``save``'s, ``latent-sindy train``'s or the study's);
        weights are read with ``torch.load(weights_only=True)``."""
        folder = RunDir(path)
        run = folder.load()
        cfg = run.config
        est = cls(run.model.config.observation.latent_dim, model=run.model.config,
                  settings=cfg, loss=cfg.loss, seed=cfg.seed, device="cpu")
        return est._adopt(folder)

    def planner(self, mppi: MPPIConfig | None = None, space: Literal["latent", "image"]
                = "latent", seed: int = 0, objective: Objective = "goal") -> ImagePlanner:
        """MPPI in this model's latent space: ``planner.act(image, goal_image)`` -> (nu,);
        ``objective="reward"``: the most predicted reward (a reward head), ``act(image)``."""
        self._check_fitted()
        d = self.description_
        return ImagePlanner(self.model_, self.normalizer_, mppi or MPPIConfig(),
                            d["action_low"], d["action_high"], space=space, seed=seed,
                            pixel_dtype=d.get("pixel_dtype", "uint8"), objective=objective)

    def __repr__(self) -> str:
        state = "fitted" if hasattr(self, "model_") else "not fitted"
        time = f", time='continuous', derivative_order={self.derivative_order}" * (
            self.time == "continuous")
        return (f"LatentSINDy(latent_dim={self.latent_dim}, dynamics={self.dynamics!r}, "
                f"order={self.order}, library={self.library!r}{time}; {state})")
