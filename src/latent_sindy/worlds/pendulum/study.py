"""The controlled pendulum from images: fit latent SINDy, MLP and linear models on the same
camera data, swing up with latent MPPI from random starts, and tabulate with intervals.

One run: random torques from random starts give the images; three image models (the latent
dynamics "sindy", "mlp", "linear", same autoencoder and training) are fitted, and a state
SINDy on the true features (cos θ, sin θ, θ̇) shows what the data say about the physics.
Each image model then plans with MPPI in its own latent space, from the image alone, with
the distance to the goal image's code along the data (:mod:`.graph_cost`), on ``episodes``
seeded tasks of 100 steps. The same three kinds are also fitted, by regression, on a
fixed latent of the images, each frame's intensity centroid (:mod:`.centroid_sindy`), and
plan alike ("... (images, centroid latent)"). The table holds, per model, the swing-up
success (upright within 10° over the last 20 steps) with its 95 % Wilson interval, the mean
fraction of steps upright (E2C's measure) with a 95 % normal interval, the one-step R²,
sparsity and times; every model's equations are printed.

    python -m latent_sindy.worlds.pendulum.study --help
    python -m latent_sindy.worlds.pendulum.study --episodes 50        # the default run
    >>> result = compare_swing_ups(StudyConfig(episodes=5)); print(result.table())
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
import tyro

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.api import LatentSINDy
from latent_sindy.control.episodes import Observation
from latent_sindy.control.mppi import MPPI, MPPIConfig, latent_step
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models import LossWeights
from latent_sindy.stats import wilson_interval
from latent_sindy.training import TrainConfig
from latent_sindy.worlds.pendulum.centroid_sindy import (
    CentroidMlp,
    CentroidSindy,
    Encode,
    frame_centroids,
    geodesic_latent,
)
from latent_sindy.worlds.pendulum.config import PendulumConfig
from latent_sindy.worlds.pendulum.diagnostics import TrueDynamicsImageCost
from latent_sindy.worlds.pendulum.graph_cost import GraphDistanceCost
from latent_sindy.worlds.pendulum.render import observe
from latent_sindy.worlds.pendulum.state_sindy import StateSindy
from latent_sindy.worlds.pendulum.swing_up import StateMPPI, SwingUp, run_swing_up
from latent_sindy.worlds.pendulum.world import UPRIGHT, PendulumWorld

__all__ = ["LatentSwingUp", "ModelRow", "StudyConfig", "StudyResult", "compare_swing_ups"]

MODELS = ("sindy", "mlp", "linear")


@dataclass(frozen=True)
class StudyConfig:
    """Settings of one pendulum study (the defaults: the measured runs of RESULTS.md and,
    for the centroid rows and the planner, docs/pendulum_swing_up.md)."""

    image_size: int = 16
    """Camera side in pixels (16 trained 3.6 times faster than 32 here)."""
    sequences: int = 400
    """Random-torque sequences from random starts (θ uniform, θ̇ in [−1, 1])."""
    steps: int = 12
    """Steps per sequence."""
    latent_dim: int = 3
    """Latent size of every image model."""
    order: int = 2
    """SINDy's polynomial order (the library also holds sin z)."""
    epochs: int = 40
    """Training epochs of each image model."""
    window: int = 5
    """Steps of the multi-step prediction loss."""
    lambda_l1: float = 1e-2
    """SINDy's L1 weight."""
    models: tuple[str, ...] = MODELS
    """Image models to fit: any of sindy, mlp, linear (empty: none)."""
    centroid_models: tuple[str, ...] = MODELS
    """Models fitted on the fixed centroid latent of the images (:mod:`.centroid_sindy`):
    any of sindy, mlp, linear (empty: none)."""
    centroid_latent: Literal["centroid", "geodesic"] = "centroid"
    """The fixed latent of the centroid rows: each frame's intensity centroid (a reader
    chosen knowing that one bright object moves on a plain background), or ``geodesic``:
    each frame's angle about the centre of its geodesic coordinates, learned from the
    training frames alone (:func:`~.centroid_sindy.geodesic_latent`; no world knowledge)."""
    centroid_order: int = 4
    """The centroid SINDy's polynomial order (order 2 diverged within 8 steps)."""
    centroid_sparsifier: Literal["stepwise", "stlsq"] = "stepwise"
    """The centroid SINDy's sparse regression: backward elimination by the fit a term costs,
    most complex first (``StepwiseSR``), or STLSQ (keeps about half of the library there:
    the centroids stay on circles, so the library's terms are dependent)."""
    centroid_min_share: float | None = None
    """The sparsifier's setting: stepwise, the share of a step's mean square one dropped
    term may cost; STLSQ, the smallest relative contribution of a kept term. None: chosen
    on the validation sequences, the sparsest fit whose rollouts are within three times the
    best error (``CentroidSindy``)."""
    state_control: bool = True
    """Also swing up with the state SINDy on the true state (a reference, not from images)."""
    episodes: int = 50
    """Swing-up tasks per model (the same tasks for every model)."""
    start: Literal["hanging", "random"] = "random"
    """Where the swing-up tasks start: anywhere (θ uniform, θ̇ in [−1, 1]; E2C's measure) or
    hanging (π ± ``perturbation``, each task a full swing-up)."""
    perturbation: float = 0.1
    """Hanging starts: θ = π + U(−p, p) rad and θ̇ = U(−p, p) rad/s (the world's
    ``perturbation``)."""
    episode_steps: int = 100
    """Actions per episode."""
    last: int = 20
    """Success: upright within 10° over each of the last this many steps."""
    samples: int = 500
    """MPPI's K (500 with λ = 0.3: the centroid SINDy 50 of 50, against 43 at 300 with
    λ = 1; docs/pendulum_swing_up.md)."""
    horizon: int = 30
    """MPPI's H."""
    sigma: float = 1.0
    """MPPI's noise variance Σ."""
    lambda_: float = 0.3
    """MPPI's temperature λ."""
    nodes: int = 600
    """Nodes of the latent graph of the distance cost."""
    neighbours: int = 8
    """Edges per node of that graph."""
    grid: int = 32
    """Points per latent axis of the cost's table (0: exact, slower)."""
    cost_check: int = 10
    """Episodes of the diagnostic per image model: MPPI on the true dynamics with the
    model's latent cost of each state's image (does the cost suffice?); 0: none."""
    seed: int = 0
    """Seeds the data, the models, the tasks and the planners."""
    device: Literal["auto", "cpu", "cuda"] = "cpu"
    """Where the image models train (cpu, cuda, or auto: cuda when torch sees one); they
    plan on the CPU."""

    def __post_init__(self) -> None:
        self.world_config()  # the camera and the tasks' starts, checked by the world
        unknown = (set(self.models) | set(self.centroid_models)) - set(MODELS)
        if unknown or not (self.models or self.centroid_models):
            raise UserError(f"pendulum study models {self.models!r} and centroid_models "
                            f"{self.centroid_models!r}: choose from {', '.join(MODELS)}")
        for name in ("sequences", "steps", "epochs", "window", "episodes", "episode_steps"):
            if getattr(self, name) < 1:
                raise UserError(f"pendulum study {name} {getattr(self, name)!r} must be >= 1")
        if self.window > self.steps:
            raise UserError(f"pendulum study window {self.window} exceeds steps {self.steps}")
        if not 1 <= self.last <= self.episode_steps:
            raise UserError(f"pendulum study last {self.last} must lie in 1..episode_steps "
                            f"({self.episode_steps}): success is judged on the last steps")

    def world_config(self) -> PendulumConfig:
        """The world of the swing-up tasks: this camera and these starts."""
        return PendulumConfig(image_size=self.image_size, start=self.start,
                              perturbation=self.perturbation)

    def mppi(self) -> MPPIConfig:
        return MPPIConfig(samples=self.samples, horizon=self.horizon, sigma=self.sigma,
                          lambda_=self.lambda_)


class LatentSwingUp:
    """A swing-up policy from images only: encode the image, plan with MPPI through the
    model's latent dynamics, cost the distance to the goal's code along the data's codes.
    ``encode`` and ``step`` replace the model's (the centroid latent and its models)."""

    def __init__(self, model: LatentSINDy | None, codes: np.ndarray, config: StudyConfig,
                 encode: Callable[[np.ndarray], np.ndarray] | None = None,
                 step: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None
                 ) -> None:
        self.model = model
        self.codes = codes
        self.config = config
        self.encode = encode or model.encode
        self.step = step or latent_step(model.model_.dynamics)
        self.mppi: MPPI | None = None
        self._costs: dict[bytes, GraphDistanceCost] = {}  # per goal code

    def cost(self, goal_image: np.ndarray) -> GraphDistanceCost:
        """The cost toward ``goal_image`` (built once per goal)."""
        cfg = self.config
        goal = np.asarray(self.encode(goal_image))
        if goal.tobytes() not in self._costs:
            cost = GraphDistanceCost(self.codes, goal, cfg.neighbours, cfg.nodes,
                                     seed=cfg.seed, grid=cfg.grid)
            # scaled so that the farthest code costs π², as hanging does in Pendulum-v1's
            # θ² (so λ reads alike)
            far = float(cost.node_distance.max())
            cost.weight = (math.pi / max(far, 1e-9)) ** 2
            self._costs[goal.tobytes()] = cost
        return self._costs[goal.tobytes()]

    def reset(self, goal: Observation, seed: int | None = None) -> None:
        cfg = self.config
        self.mppi = MPPI(self.step, self.cost(goal.image), cfg.mppi(), (-physics.MAX_TORQUE,),
                         (physics.MAX_TORQUE,), seed=cfg.seed if seed is None else seed)

    def act(self, observation: Observation) -> np.ndarray:
        z = torch.as_tensor(np.asarray(self.encode(observation.image)))  # not the state
        return self.mppi.command(z)[0].numpy()


@dataclass
class ModelRow:
    """One model's line of the table."""

    name: str
    episodes: list[SwingUp]
    equations: list[str]
    r2: float | None = None
    sparsity: float | None = None
    fit_seconds: float = 0.0
    control_seconds: float = 0.0
    cost_check: list[SwingUp] = field(default_factory=list)
    """The diagnostic's episodes (true dynamics, this model's cost from images)."""
    step: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = field(
        default=None, repr=False)
    """The fitted latent step (centroid rows)."""

    @property
    def successes(self) -> int:
        return sum(e.success for e in self.episodes)

    @property
    def success_interval(self) -> tuple[float, float]:
        return wilson_interval(self.successes, len(self.episodes))

    @property
    def upright(self) -> tuple[float, float, float]:
        """Mean fraction of steps upright and its 95 % normal interval."""
        f = np.array([e.upright_fraction for e in self.episodes])
        half = 1.959964 * f.std(ddof=1) / math.sqrt(len(f)) if len(f) > 1 else math.inf
        return float(f.mean()), max(0.0, f.mean() - half), min(1.0, f.mean() + half)


@dataclass
class StudyResult:
    config: StudyConfig
    rows: list[ModelRow] = field(default_factory=list)
    data_seconds: float = 0.0

    def table(self) -> str:
        """The results as a markdown table."""
        n = self.config.episodes
        lines = [f"| model | swing-ups of {n} (95 % Wilson) | time upright (95 %) | one-step "
                 "R² | sparsity | fit s | control s | its cost, true dynamics |",
                 "|---|---|---|---|---|---|---|---|"]
        for r in self.rows:
            lo, hi = r.success_interval
            f, flo, fhi = r.upright
            r2 = "" if r.r2 is None else f"{r.r2:.3f}"
            sp = "" if r.sparsity is None else f"{100 * r.sparsity:.1f} %"
            check = (f"{sum(e.success for e in r.cost_check)} of {len(r.cost_check)}"
                     if r.cost_check else "")
            lines.append(f"| {r.name} | {r.successes} ({100 * lo:.0f}–{100 * hi:.0f} %) | "
                         f"{100 * f:.0f} % ({100 * flo:.0f}–{100 * fhi:.0f}) | {r2} | {sp} | "
                         f"{r.fit_seconds:.0f} | {r.control_seconds:.0f} | {check} |")
        return "\n".join(lines)

    def equations(self) -> str:
        return "\n".join(f"{r.name}:\n  " + "\n  ".join(r.equations) for r in self.rows)


def fit_image_model(data: SequenceData, kind: str, config: StudyConfig) -> LatentSINDy:
    """One image model of the study (``kind``: sindy, mlp or linear)."""
    model = LatentSINDy(latent_dim=config.latent_dim, dynamics=kind, order=config.order,
                        seed=config.seed, settings=TrainConfig(lr=3e-3, prune="absolute", starts=1),
                        device=config.device,
                        loss=LossWeights(lambda_l1=config.lambda_l1))
    return model.fit(data, epochs=config.epochs, batch_size=64, window=config.window)


def compare_swing_ups(config: StudyConfig | None = None,
                      report: Callable[[str], None] = print) -> StudyResult:
    """Collect, fit, swing up and tabulate (``report`` hears progress and equations)."""
    cfg = config or StudyConfig()
    t0 = time.perf_counter()
    world = PendulumWorld(PendulumConfig(start="random", image_size=cfg.image_size))
    data = world.collect(cfg.sequences, cfg.steps, seed=cfg.seed)
    result = StudyResult(cfg, data_seconds=time.perf_counter() - t0)
    report(f"data: {data.n} sequences of {data.steps} steps, frames {data.frame_shape} "
           f"({result.data_seconds:.0f} s)")
    tasks = PendulumWorld(cfg.world_config())
    train = data.split("train")
    frames = train.images.reshape(-1, *data.frame_shape)

    t0 = time.perf_counter()
    state = StateSindy().fit(data)
    row = ModelRow("state SINDy (true state)", [], state.equations(),
                   sparsity=state.sparsity(), fit_seconds=time.perf_counter() - t0)
    report("state SINDy on (cos θ, sin θ, θ̇):\n  " + "\n  ".join(row.equations))
    if cfg.state_control:
        t0 = time.perf_counter()
        policy = StateMPPI(cfg.mppi(), dynamics=state.step)
        row.episodes = run_swing_up(tasks, policy, cfg.episodes, cfg.episode_steps,
                                    cfg.seed, cfg.last)
        row.control_seconds = time.perf_counter() - t0
        result.rows.append(row)
        report(f"state SINDy: {row.successes} of {cfg.episodes} swing-ups "
               f"({row.control_seconds:.0f} s)")
    for kind in cfg.models:
        t0 = time.perf_counter()
        model = fit_image_model(data, kind, cfg)
        fit_s = time.perf_counter() - t0
        eq = model.equations() if kind != "mlp" else ["(an MLP: no equations)"]
        dyn = model.model_.dynamics
        row = ModelRow(f"{kind} (images)", [], eq, r2=model.score(data),
                       sparsity=dyn.sparsity() if kind == "sindy" else None, fit_seconds=fit_s)
        report(f"{kind}: fitted in {fit_s:.0f} s, one-step R² {row.r2:.3f}\n  "
               + "\n  ".join(eq))
        t0 = time.perf_counter()
        policy = LatentSwingUp(model, model.encode(frames), cfg)
        row.episodes = run_swing_up(tasks, policy, cfg.episodes, cfg.episode_steps,
                                    cfg.seed, cfg.last)
        row.control_seconds = time.perf_counter() - t0
        if cfg.cost_check:
            check = TrueDynamicsImageCost(model, policy.cost(observe(*UPRIGHT, cfg.image_size)),
                                          cfg.image_size, cfg.mppi())
            row.cost_check = run_swing_up(tasks, check, cfg.cost_check, cfg.episode_steps,
                                          cfg.seed, cfg.last)
        result.rows.append(row)
        report(f"{kind}: {row.successes} of {cfg.episodes} swing-ups "
               f"({row.control_seconds:.0f} s); with the true dynamics and this cost "
               f"{sum(e.success for e in row.cost_check)} of {len(row.cost_check)}")
    if not cfg.centroid_models:
        return result
    t0 = time.perf_counter()
    encode = (frame_centroids if cfg.centroid_latent == "centroid"
              else geodesic_latent(train.images, cfg.seed))
    if cfg.centroid_latent == "geodesic":
        report(f"geodesic latent learned from {len(frames)} training frames "
               f"({time.perf_counter() - t0:.0f} s)")
    codes = encode(frames).numpy()
    for kind in cfg.centroid_models:
        row = centroid_row(kind, data, cfg, report, encode)
        t0 = time.perf_counter()
        policy = LatentSwingUp(None, codes, cfg, encode=lambda x: encode(x).numpy(),
                               step=row.step)
        row.episodes = run_swing_up(tasks, policy, cfg.episodes, cfg.episode_steps,
                                    cfg.seed, cfg.last)
        row.control_seconds = time.perf_counter() - t0
        result.rows.append(row)
        report(f"{row.name}: {row.successes} of {cfg.episodes} swing-ups "
               f"({row.control_seconds:.0f} s)")
    return result


def centroid_row(kind: str, data: SequenceData, cfg: StudyConfig,
                 report: Callable[[str], None] = print, encode: Encode = frame_centroids
                 ) -> ModelRow:
    """Fit one model on the fixed latent ``encode`` (the config's ``centroid_latent``); its
    row, with ``step`` set, not yet run."""
    t0 = time.perf_counter()
    if kind == "mlp":
        model = CentroidMlp(seed=cfg.seed, encode=encode).fit(data)
        eq = ["(an MLP: no equations)"]
    else:
        model = (CentroidSindy(1, 0.0, "stlsq", encode) if kind == "linear" else CentroidSindy(
            cfg.centroid_order, cfg.centroid_min_share, cfg.centroid_sparsifier, encode)
        ).fit(data)
        eq = model.equations()
    row = ModelRow(f"{kind} (images, {cfg.centroid_latent} latent)", [], eq,
                   sparsity=model.sparsity() if kind == "sindy" else None,
                   fit_seconds=time.perf_counter() - t0)
    row.step = model.step
    chosen = getattr(model, "selection_", None)
    if chosen is not None:
        report(f"{row.name}: {kind} setting chosen on validation rollouts\n{chosen.table()}")
    report(f"{row.name}: fitted in {row.fit_seconds:.1f} s\n  " + "\n  ".join(eq))
    return row


def main(argv: list[str] | None = None) -> StudyResult:
    torch.set_num_threads(1)
    cfg = tyro.cli(StudyConfig, args=argv, description=__doc__.split("\n\n")[0])
    t0 = time.perf_counter()
    try:
        result = compare_swing_ups(cfg)
    except UserError as err:
        raise SystemExit(f"error: {err}") from None
    print("\n" + result.table())
    print(f"\n(the whole run: {time.perf_counter() - t0:.0f} s)")
    return result


if __name__ == "__main__":
    main()
