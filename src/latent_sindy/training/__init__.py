"""Training a latent model: the one gradient loop and the run folder around it.

``fit_loop`` holds the loop (:func:`~latent_sindy.training.fit_loop.fit`, in memory) and ``samples``
what it trains on (:class:`Sequences`, a continuous-time model's :class:`DerivativeSamples`),
``session`` the
one set-up every training goes through (:func:`~latent_sindy.training.session.prepare`, a
:class:`~latent_sindy.training.session.Session` trained whole or by phases), ``prepare`` the
tensors it trains on and the model's start, ``record`` what config.json records, ``runs`` the
run folder (:class:`RunDir`: every file name, reading and writing them), ``train_run`` training into
a run folder with resume and checkpoints (:func:`train`), ``config`` the settings.

    from latent_sindy.training import TrainConfig, train, load_run
    run = train(TrainConfig(data=Path("data/push.h5"), out=Path("runs/sindy2")))
    model, normalizer, cfg, description, world_record = load_run(run)
"""

from latent_sindy.training.config import RESUMABLE, TrainConfig, default_threads
from latent_sindy.training.fit_loop import FitResult, TrainingDiverged, evaluate, fit
from latent_sindy.training.metrics import METRIC_COLUMNS
from latent_sindy.training.record import run_record
from latent_sindy.training.runs import Run, RunDir, load_run, read_metrics
from latent_sindy.training.samples import DerivativeSamples, Sequences
from latent_sindy.training.train_run import train

__all__ = ["METRIC_COLUMNS", "RESUMABLE", "DerivativeSamples", "FitResult", "Run", "RunDir",
           "Sequences", "TrainConfig", "TrainingDiverged", "default_threads", "evaluate", "fit",
           "load_run", "read_metrics", "run_record", "train"]
