"""Pushes the arm cannot make: the world's reach answer, the collected flags and the planner.

The reach answer (`PushWorld.feasible`, worlds/push/reach.py) must agree with what the
simulated arm does; collection records which pushes were made; `latent-sindy info` counts
the others; and the closed loop never executes a push the world says is out of reach when
one of its samples is within it.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch

from latent_sindy.control.mppi import MPPI, MPPIConfig
from latent_sindy.control.planner import feasible_action
from latent_sindy.control.world import feasible
from latent_sindy.data import SequenceData, read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.collect import CollectionPlan, collect, collect_one
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.plugin import PushWorld

FAR = ((0.78, -0.34, 1.77), (-0.05, -2.33, 0.4))  # pushed back towards the base from 0.85 m
EASY = ((0.5, 0.0, 0.3), (0.0, 0.2, 0.5))


@pytest.fixture(scope="module")
def world():
    w = PushWorld(PushEnvConfig())
    yield w
    if w._reach is not None:
        w._reach.close()


def test_the_reach_answer_agrees_with_the_simulated_arm(env, world):
    """40 pushes in 4 episodes of 10 from poses near the arm's far reach (where about a
    fifth are out of it); each is asked of the reach answer at the block's true pose, then
    made. The answer is the world's own search, so they agree exactly on the recording
    machine; 38 of 40 allow for another platform's rounding at the reach's edge."""
    rng = np.random.default_rng(7)
    cfg = env.config
    agree, out_of_reach = 0, 0
    for episode in range(4):
        bearing = rng.uniform(-0.45, 0.45)
        start = (0.76 * math.cos(bearing), 0.76 * math.sin(bearing), rng.uniform(-1.5, 1.5))
        _, info = env.reset(seed=episode, options={"start": start, "goal": (0.5, 0.0, 0.0)})
        for _ in range(10):
            action = rng.uniform(cfg.action_low, cfg.action_high).astype(np.float32)
            said = bool(world.feasible(info["pose"], action[None])[0])
            _, _, terminated, _, info = env.step(action)
            agree += said == info["push_executed"]
            out_of_reach += not info["push_executed"]
            if terminated:
                _, info = env.reset(seed=episode, options={"start": start,
                                                           "goal": (0.5, 0.0, 0.0)})
    assert out_of_reach >= 3  # the sample tests both answers
    assert agree >= 38


def test_the_world_interface_answers_in_batches(world):
    states = np.array([FAR[0], EASY[0]])
    actions = np.array([FAR[1], EASY[1]])
    assert world.feasible(states, actions).tolist() == [False, True]
    sideways = np.array([FAR[1], (0.0, 0.8, 0.5)])  # from the same pose: back, or sideways
    assert feasible(world, FAR[0], sideways).tolist() == [False, True]  # one state for all
    with pytest.raises(UserError, match=r"\(K, 3\) block poses"):
        world.feasible(states, actions[:, :2])

    class Plain:  # a world without the optional method can carry out every action
        pass
    assert feasible(Plain(), np.zeros((3, 2)), np.zeros((3, 1))).all()


# --------------------------------------------------------------------------- collection
class ScriptedEnv:
    """Stands in for PandaPushEnv: every third push is out of reach."""

    def __init__(self) -> None:
        self.k = 0
        self.said: list[bool] = []

    def reset(self, seed=None):
        return np.zeros((1, 8, 8), np.uint8), {"pose": np.zeros(3)}

    def step(self, action):
        self.k += 1
        ok = self.k % 3 != 0
        self.said.append(ok)
        return (np.zeros((1, 8, 8), np.uint8), 0.0, False, False,
                {"pose": np.zeros(3), "push_executed": ok})


def test_collection_records_which_pushes_were_made(tmp_path):
    env = ScriptedEnv()
    item = collect_one(env, 0, CollectionPlan(trajectories=2, steps=7, seed=1))
    assert item["executed"].dtype == bool
    assert item["executed"].tolist() == env.said
    assert not item["executed"].all()

    plan = CollectionPlan(trajectories=2, steps=2, seed=3, val_fraction=0.0, test_fraction=0.0,
                          env=PushEnvConfig(image_size=16))
    data = read_sequences(collect(tmp_path / "d.h5", plan, workers=1))
    assert data.executed is not None and data.executed.shape == (2, 2)
    # the flags are the world's: replayed from the recorded poses, the reach answer agrees
    reach = PushWorld(plan.env)
    try:
        answer = reach.feasible(data.states[:, :-1].reshape(-1, 3),
                                data.actions.reshape(-1, 3)).reshape(2, 2)
    finally:
        reach._reach.close()
    assert np.array_equal(answer, data.executed)


def test_info_counts_the_pushes_not_made(tmp_path):
    executed = np.ones((4, 5), bool)
    executed[1, 2] = executed[3, 0] = False
    path = tmp_path / "flags.h5"
    write_sequences(path, SequenceData(np.zeros((4, 6, 1, 8, 8), np.uint8),
                                       np.zeros((4, 5, 1), np.float32), action_low=(-1,),
                                       action_high=(1,), executed=executed))
    out = subprocess.run([sys.executable, "-m", "latent_sindy.cli", "info", str(path)],
                         capture_output=True, text=True, check=True).stdout
    assert "not executed: 2 of 20 actions (10.0%)" in out
    write_sequences(tmp_path / "none.h5", SequenceData(np.zeros((2, 3, 1, 8, 8), np.uint8)))
    out = subprocess.run([sys.executable, "-m", "latent_sindy.cli", "info",
                          str(tmp_path / "none.h5")], capture_output=True, text=True,
                         check=True).stdout
    assert "not executed" not in out


# --------------------------------------------------------------------------- planning
def planned(seed: int = 0) -> tuple[MPPI, np.ndarray]:
    """MPPI on z' = z + u toward z = 1: the plan pushes u up, into u > 0.3 (out of reach)."""
    mppi = MPPI(lambda z, u: z + u, torch.ones(1), MPPIConfig(samples=64, horizon=3, sigma=0.3),
                (-1.0,), (1.0,), seed=seed)
    action, _ = mppi.command(torch.zeros(1))
    return mppi, action.numpy()


def reachable(actions: np.ndarray) -> np.ndarray:
    return np.asarray(actions)[:, 0] <= 0.3


@pytest.mark.parametrize("seed", range(5))
def test_the_planner_replaces_a_push_out_of_reach_by_the_best_within_it(seed):
    mppi, action = planned(seed)
    assert not reachable(action[None])[0]
    chosen, replaced = feasible_action(action, mppi, reachable)
    assert replaced and reachable(chosen[None])[0]
    firsts, costs = mppi.actions[:, 0].numpy(), mppi.costs.numpy()
    best = np.argmin(np.where(reachable(firsts), costs, np.inf))
    assert np.array_equal(chosen, firsts[best])  # the lowest-cost sample within reach
    kept, replaced = feasible_action(action, mppi, lambda a: np.ones(len(a), bool))
    assert not replaced and kept is action
    kept, replaced = feasible_action(action, mppi, lambda a: np.zeros(len(a), bool))
    assert not replaced and kept is action  # nothing within reach: MPPI's push stands


def test_the_controller_asks_the_world_at_the_true_pose():
    from latent_sindy.control.episodes import Observation
    from latent_sindy.data.windows import Normalizer
    from latent_sindy.models.latent_model import LatentModel, ModelConfig
    from latent_sindy.worlds.push.episodes import ControlConfig, Controller

    model = LatentModel(ModelConfig().resolve(1, 32, 3))
    ctl = Controller(model, Normalizer(0.0, 1.0), ControlConfig(), PushEnvConfig())
    asked = []

    def reach(pose, actions):
        asked.append(np.asarray(pose))
        return np.asarray(actions)[:, 1] > 0  # only pushes with psi > 0 are within reach

    ctl.reach = reach
    ctl.reset(Observation(np.zeros((1, 32, 32), np.uint8), np.zeros(3)), seed=0)
    pose = np.array([0.5, 0.1, 0.2])
    for _ in range(5):
        action = ctl.act(Observation(np.zeros((1, 32, 32), np.uint8), pose))
        assert action[1] > 0 and ctl.last.plan.seconds >= 0
    assert all(np.array_equal(p, pose) for p in asked)
    assert ControlConfig(reach=False).reach is False
