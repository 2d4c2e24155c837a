"""How big a study is: its scales, and the closed-loop conditions a scale runs for a model.

A scale is the base :class:`Scale` (the demo) with the few settings that differ, as nanoGPT's
config files list only what they change; :data:`SCALES` names them for ``--scale``.

    >>> SCALES["paper"].epochs, SCALES["demo"].epochs
    (3000, 30)
    >>> [c.name for c in SCALES["demo"].all_conditions()]
    ['paper/latent', 'random/latent', 'paper/image', 'random/image']
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.episodes import ControlConfig
from latent_sindy.worlds.push.planner import world_planner

if TYPE_CHECKING:
    from latent_sindy.worlds.push.study.spec import ModelSpec

__all__ = ["DEMO_LONG", "SCALES", "SCALE_ABOUT", "Condition", "Scale"]

Task = Literal["paper", "random"]
Space = Literal["latent", "image"]


@dataclass(frozen=True)
class Condition:
    """One closed-loop condition of the study: a task, a planning space, its episodes."""

    task: Task
    space: Space
    episodes: int
    max_steps: int
    cost: Literal["latent", "image", "pose"] | None = None
    """The cost MPPI minimises (:attr:`ControlConfig.space`); None: the planning space's own.
    Latent MPPI of a model with a pose head may minimise its pose cost ("pose")."""

    @property
    def name(self) -> str:
        """The metric prefix, e.g. ``paper/latent`` (metrics ``control/paper/latent/...``)."""
        return f"{self.task}/{self.space}"

    @property
    def label(self) -> str:
        return f"{self.task}, {self.space}" + (f" ({self.cost} cost)" if self.cost else "")

    @property
    def cost_space(self) -> str:
        """The cost's name: what ``latent-sindy control --space`` calls it, and the run's
        control folder (control-TASK-COST)."""
        return self.cost or self.space


@dataclass(frozen=True)
class Scale:
    """How big a study is: data, training schedule and control episodes.

    The defaults are the demo scale; the other scales are named overrides of it
    (:data:`SCALES`).
    """

    trajectories: int = 200
    """Trajectories in all splits (1/2 train, 1/4 validation, 1/4 test)."""
    steps: int = 10
    """Pushes per trajectory."""
    # 30 epochs of batch 64 are 480 updates at twice the paper's learning rate, pruning every
    # 6 epochs (5 times; pruning every 3 left SINDy-1 no term in one run): sized for the demo's 10
    # minutes on 2 cores, at a cost in validation loss (BENCHMARKS.md, "Where the demo's time
    # goes"); the demo-long scale keeps 60 epochs at 1e-3. Fewer training trajectories than
    # the paper's 100 overfitted every model (RESULTS.md, "What changed since the first demo
    # run"), hence its data even in the demo.
    epochs: int = 30
    batch_size: int = 64
    lr: float = 2e-3
    """Adam's learning rate (the paper's: 1e-3)."""
    prune_below: float = 1e-3
    """SINDy: prune |Ψ| below this ..."""
    prune_every: int = 6
    """... every this many epochs."""
    eval_every: int = 1
    """Validation loss every this many epochs (and at the last); it does not change the model."""
    # At batch 64 a batch of whole trajectories holds only 6 of them and trained worse than
    # windows; at the paper's batch of 500 they train as well for less CPU (BENCHMARKS.md,
    # "Trajectory batches"). So the paper scale uses them where the trainer's "auto" does
    # (single-step windows; the H = 4 row keeps windows).
    batching: Literal["auto", "windows", "trajectories"] = "windows"
    """Training mini-batches of windows or of whole trajectories (`latent-sindy train
    --batching`)."""
    multistep_window: int = 4
    """Training window H of the multi-step SINDy model."""
    paper_episodes: int = 3
    """Latent MPPI episodes on the paper's task (each with its own controller seed)."""
    random_episodes: int = 25
    """Latent MPPI episodes on random tasks of the headline rows (SINDy-2, linear, the
    state-space references): one fixed task list, the same for every model."""
    other_random_episodes: int = 10
    """... and of the other rows."""
    image_paper_episodes: int = 2
    """Image-space MPPI episodes on the paper's task (models with ``image_space``)."""
    image_random_episodes: int = 8
    """Image-space MPPI episodes on random tasks (the first of the same task list)."""
    max_steps: int = 20
    """Pushes per latent MPPI episode (the course: 20)."""
    image_max_steps: int = 30
    """Pushes per image-space MPPI episode (the course: 30)."""
    until: Literal["course", "strict"] = "strict"
    """Run episodes until the strict criterion (so both criteria are measured) or the course's."""
    mppi: MPPIConfig | None = None
    """The planner of every condition; None: the world's
    (:func:`~latent_sindy.worlds.push.planner.world_planner`)."""

    def all_conditions(self) -> tuple[Condition, ...]:
        """Every kind of closed-loop condition, in report order (episodes of a headline row)."""
        return (Condition("paper", "latent", self.paper_episodes, self.max_steps),
                Condition("random", "latent", self.random_episodes, self.max_steps),
                Condition("paper", "image", self.image_paper_episodes, self.image_max_steps),
                Condition("random", "image", self.image_random_episodes, self.image_max_steps))

    def conditions(self, spec: ModelSpec) -> tuple[Condition, ...]:
        """The closed-loop conditions of one model, with at least one episode."""
        out = []
        for c in self.all_conditions():
            if c.space == "image" and not spec.image_space:
                continue
            if c.task == "random" and c.space == "latent" and not spec.headline:
                c = dataclasses.replace(c, episodes=self.other_random_episodes)
            if c.space == "latent" and spec.latent_cost != "latent":
                c = dataclasses.replace(c, cost=spec.latent_cost)
            if c.episodes > 0:
                out.append(c)
        return tuple(out)

    def planner(self, world: str) -> MPPIConfig:
        return self.mppi if self.mppi is not None else world_planner(PushEnvConfig.named(world))

    def control_config(self, condition: Condition, seed: int, world: str) -> ControlConfig:
        return ControlConfig(task=condition.task, space=condition.cost_space,
                             episodes=condition.episodes, max_steps=condition.max_steps,
                             seed=seed, until=self.until, gif_episodes=1,
                             mppi=self.planner(world))


#: The demo: the paper's data (100/50/50 trajectories) and a short schedule, sized for the
#: demo's budget on 2 cores (RESULTS.md); every other scale lists what differs from it.
DEMO = Scale()

#: The paper's settings: 3000 epochs, batch 500, pruning every 300 epochs; 10 paper-task
#: runs (as its image-space test) and more random tasks per model and planner.
PAPER = dataclasses.replace(
    DEMO, epochs=3000, lr=1e-3, batch_size=500, prune_every=300, eval_every=10, batching="auto",
    paper_episodes=10, random_episodes=100, other_random_episodes=50, image_paper_episodes=10,
    image_random_episodes=50)

#: The demo's first schedule (60 epochs; 5 paper-task episodes, 50 / 20 random tasks, 5 / 20
#: image-space episodes), the one the first round of figures used.
DEMO_LONG = dataclasses.replace(
    DEMO, epochs=60, lr=1e-3, paper_episodes=5, random_episodes=50,
    other_random_episodes=20, image_paper_episodes=5, image_random_episodes=20)

#: Ten times the paper's data (1000 / 500 / 500 trajectories of 10 pushes) on the demo-long
#: schedule: ten times the updates. What data buys (issue 11): RESULTS.md, "What five
#: times the data buys" and "Large scale".
LARGE = dataclasses.replace(DEMO_LONG, trajectories=2000)

#: Seconds: only checks that the pipeline runs end to end (tests).
TINY = dataclasses.replace(
    DEMO, trajectories=6, steps=3, epochs=2, batch_size=500, prune_every=1,
    multistep_window=2, paper_episodes=1, random_episodes=1, other_random_episodes=1,
    image_paper_episodes=1, image_random_episodes=1, max_steps=2, image_max_steps=2,
    mppi=MPPIConfig(samples=8, horizon=2))

#: The scales ``--scale`` names.
SCALES: dict[str, Scale] = {"demo": DEMO, "paper": PAPER, "large": LARGE, "tiny": TINY,
                            "demo-long": DEMO_LONG}

#: What each scale runs, in a phrase (``reproduce --help``).
SCALE_ABOUT: dict[str, str] = {
    "demo": "the whole study in under 10 minutes on 2 cores",
    "paper": "the paper's sizes, many hours on a CPU",
    "large": "ten times the paper's data on the demo-long schedule",
    "tiny": "seconds, for tests",
    "demo-long": "the demo's data on a twice longer schedule: 60 epochs at lr 1e-3, 50 random "
                 "tasks per headline row",
}
