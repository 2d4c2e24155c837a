"""Training a latent model on a trajectory file, and the run folder it writes.

``config`` holds the settings (:class:`TrainConfig`), ``runs`` the run folder
(:class:`RunDir`: every file name, reading and writing them), ``loop`` the training loop and
its schedule (:func:`train`).

    from latent_sindy.training import TrainConfig, train, load_run
    run = train(TrainConfig(data=Path("data/push.h5"), out=Path("runs/sindy2")))
    model, normalizer, cfg, env_config = load_run(run)
"""

from latent_sindy.training.config import RESUMABLE, TrainConfig, default_threads
from latent_sindy.training.loop import TrainingDiverged, evaluate, train
from latent_sindy.training.runs import METRIC_COLUMNS, Run, RunDir, load_run, read_metrics

__all__ = ["METRIC_COLUMNS", "RESUMABLE", "Run", "RunDir", "TrainConfig", "TrainingDiverged",
           "default_threads", "evaluate", "load_run", "read_metrics", "train"]
