"""The PyBullet world behind :class:`~latent_sindy.worlds.push.panda_push.PandaPushEnv`: the
simulation, and the push planned and carried out in it.

Two physics clients, both headless (DIRECT):

* the *simulation*: Panda arm (``pybullet_data``), table, block and goal marker; every push is
  simulated here;
* the *camera world*: table and block only (and the textured world's distractor).
  Observations are rendered here with the block copied to its simulated pose, in the
  episode's look (:class:`~latent_sindy.worlds.push.scene.Look`: its light and where the
  distractor stands, drawn from the episode's seed by the environment). The arm has
  retreated out of view before every observation, so the picture is the same (a test checks
  it pixel for pixel) while TinyRenderer no longer rasterises the arm's meshes, which cost
  about 65x the rest of the frame.

Free-space arm moves (to the start of a push, and home out of the camera's view afterwards)
are kinematic resets: they never touch the block, so simulating them would only spend time.
Everything from just before contact until the pusher has backed off the block is simulated
at PyBullet's 240 Hz with IK and joint position control, and the block is then left to come
to rest. The scene without the arm (table, block, camera world) is :mod:`.scene`, the arm
:mod:`.arm`.

    python -c "from latent_sindy.worlds.push.world import PushWorld; w = PushWorld(); \
w.reset((0.5, 0, 0), (0.7, 0, 0)); w.push(0, 0, 1); print(w.block_pose())"
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from latent_sindy.worlds.push._bullet import BulletClient, pybullet_data, quiet_c_output
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.arm import APPROACH_GAPS, HOME, MAX_START_DISTANCE, Arm
from latent_sindy.worlds.push.config import BLOCK_SIZE, CONTACT_SPAN, MAX_PUSH, PushEnvConfig
from latent_sindy.worlds.push.criteria import wrap_angle
from latent_sindy.worlds.push.scene import (
    GOAL_RGBA,
    PARKED,
    CameraView,
    Look,
    add_distractor,
    add_table_and_block,
    place,
    place_distractor,
    yaw_quaternion,
)

__all__ = ["PushWorld", "contact_frame"]

PUSH_HEIGHT = 0.025  # pusher height above the table: the block's mid-height
PUSHER_RADIUS = 0.014  # closed fingertips' half-thickness along the push (m)
PUSH_SPEED = 0.25  # m/s cruise speed along the push line
PUSH_ACCEL = 2.0  # m/s^2 speeding up
PUSH_DECEL = 0.5  # m/s^2 slowing down: below the block's friction deceleration (0.1 g), so
#                   the block stops with the pusher instead of sliding on
RETREAT = (0.02, 0.06)  # back off (m along -push) and lift (m) before leaving
SETTLE_STEPS = 240  # at most one simulated second for the block to come to rest
DT = 1.0 / 240.0


def _profile(travel: float, speed: float = PUSH_SPEED, accel: float = PUSH_ACCEL,
             decel: float | None = PUSH_DECEL) -> np.ndarray:
    """Distance along a path at each simulation step: trapezoidal speed, ends at `travel`.

    `decel=None` stops as hard as it starts (used where no block rides along).
    """
    decel = decel or accel
    v = speed
    # lower the cruise speed if the path is too short to reach it
    v = min(v, math.sqrt(2 * travel / (1 / accel + 1 / decel)))
    t_up, t_down = v / accel, v / decel
    t_cruise = max(0.0, (travel - v * v / (2 * accel) - v * v / (2 * decel)) / v) if v > 0 else 0
    total = t_up + t_cruise + t_down
    t = np.arange(1, max(1, math.ceil(total / DT)) + 1) * DT
    t = np.minimum(t, total)
    s = np.where(
        t < t_up, 0.5 * accel * t**2,
        np.where(t < t_up + t_cruise, v * t_up / 2 + v * (t - t_up),
                 travel - 0.5 * decel * np.maximum(total - t, 0.0) ** 2))
    return np.minimum(s, travel)


def contact_frame(style: str, theta: float, angle: float
                  ) -> tuple[float, float, tuple[float, float]]:
    """Where a push starts: (frame, phi, half extents) for a block at orientation `theta`.

    The push is made from the -x face of a frame at world angle `frame`, at angle `phi` to
    that frame's x axis; the half extents are the block's along the frame's (x, y) axes.
    "paper": the block's own frame and `angle` = phi. "symmetric": `angle` = psi is the push
    direction in the world, and the frame is the block's turned by the quarter turn that
    brings it nearest psi, so the pushed face is the one whose outward normal is most
    opposite to psi and |phi| <= pi/4. Turning the block by a quarter turn picks the same
    face in the world: equal pictures, equal pushes.
    """
    hx, hy = BLOCK_SIZE[0] / 2, BLOCK_SIZE[1] / 2
    if style == "paper":
        return theta, angle, (hx, hy)
    k = round((angle - theta) / (math.pi / 2))
    frame = theta + k * math.pi / 2
    return frame, angle - frame, ((hy, hx) if k % 2 else (hx, hy))


class PushWorld:
    """Panda, table, block and goal marker, simulated and rendered headless."""

    def __init__(self, cfg: PushEnvConfig | None = None, arm_visuals: bool = False) -> None:
        """``arm_visuals``: load the arm's visual meshes (only :meth:`observe_full_scene`
        needs them, to check that no picture would show the arm)."""
        self.cfg = cfg or PushEnvConfig()
        self._arm_visuals = arm_visuals
        with quiet_c_output():
            self.sim = BulletClient(connection_mode=pb.DIRECT)
        self.sim.setAdditionalSearchPath(pybullet_data.getDataPath())
        self.view = CameraView(self.cfg)
        self.camera = self.view.camera
        self._build()
        self.goal_pose = np.array([0.0, 0.0, 0.0])
        self.last_push_executed = True
        self.sim_steps = 0  # simulated steps since construction, for benchmarks
        # Symmetric pushes of the uniform block simulate it turned into (-pi/4, pi/4] (see
        # push); `_turned` (a multiple of pi/2) is added back so its pose stays continuous.
        self._canonical = self.cfg.push == "symmetric" and self.cfg.block_look == "uniform"
        self._turned = 0.0

    def _build(self) -> None:
        """(Re)create the simulated scene from nothing.

        PyBullet's saveState/restoreState leave the joint motors' warm-start impulses behind,
        so a restored world does not repeat itself; a rebuilt one does (about 80 ms, mostly
        loading the Panda).
        """
        c = self.sim
        c.resetSimulation()
        c.setGravity(0, 0, -9.81)
        c.setTimeStep(DT)
        self.block = add_table_and_block(c, self.cfg)
        half = [s / 2 for s in BLOCK_SIZE]
        self.goal = c.createMultiBody(
            0, -1, c.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=GOAL_RGBA),
            basePosition=PARKED,
        )
        self.arm = Arm(c, self._arm_visuals)
        # last, so the bodies the physics knows keep their ids; it has no collision shape
        self.distractor = add_distractor(c) if self.cfg.distractor else None

    # ------------------------------------------------------------------ state
    def reset(self, start: tuple[float, float, float], goal: tuple[float, float, float],
              look: Look | None = None) -> None:
        """Rebuild the world with the block resting at `start` and the goal marker at `goal`,
        seen in `look` (an episode's light and distractor; None: as before)."""
        self._build()
        if look is not None:
            self.view.set_look(look)
        if self.distractor is not None:
            place_distractor(self.sim, self.distractor, self.view.look.distractor)
        self.last_push_executed = True
        self._turned = 0.0
        place(self.sim, self.block, start)
        self.goal_pose = np.asarray(goal, dtype=float)
        place(self.sim, self.goal, goal)

    def block_pose(self) -> np.ndarray:
        """The block's planar pose (x, y, theta), theta in (-pi, pi]."""
        pos, orn = self.sim.getBasePositionAndOrientation(self.block)
        th = self.sim.getEulerFromQuaternion(orn)[2]
        return np.array([pos[0], pos[1], wrap_angle(th + self._turned) if self._turned else th])

    def close(self) -> None:
        with quiet_c_output(), contextlib.suppress(pb.error):
            self.sim.disconnect()
        self.view.close()

    # ------------------------------------------------------------------ motion
    def push(self, p: float, angle: float, ell: float) -> None:
        """Execute one push u = [p, angle, ell] and let the block come to rest.

        The config's `push` style says what the angle means (see :func:`contact_frame`).
        """
        contact, psi = self._push_line(p, angle)
        self.arm.teleport_joints(HOME)  # the search starts where can_push's does, not from
        #                                 wherever the arm drooped while the block settled
        found = self._find_start(contact, psi)
        if found is None:
            # out of the arm's reach: the robot does not attempt it, the block stays put
            self.last_push_executed = False
            self.arm.teleport_joints(HOME)
            return
        start, gap, orn = found
        d = np.array([math.cos(psi), math.sin(psi)])
        self.last_push_executed = True
        touch = self.arm.distance_to_touch(d, gap, self.block)
        travel = touch + ell * MAX_PUSH  # ell counts from first touch
        along = _profile(travel)  # (n,) distance along the push line at each step
        path = np.column_stack([start + d * along[:, None], np.full(len(along), PUSH_HEIGHT)])
        self.sim_steps += self.arm.follow(path, orn)
        end = start + d * travel
        back, lift = RETREAT
        length = math.hypot(back, lift)
        f = _profile(length, decel=None)[:, None] / length
        self.sim_steps += self.arm.follow(
            np.column_stack([end - d * back * f, PUSH_HEIGHT + lift * f]), orn)
        self.arm.teleport_joints(HOME)
        self._settle()

    def can_push(self, p: float, angle: float, pose=None) -> bool:
        """Could the arm start push u = [p, angle, *] with the block at `pose` (default:
        where it is)? See :meth:`push_start`."""
        return self.push_start(p, angle, pose) is not None

    def push_start(self, p: float, angle: float, pose=None) -> np.ndarray | None:
        """Where the pusher would start push u = [p, angle, *] (x, y), or None when the arm
        reaches no start, with the block at `pose` (default: where it is).

        The same search for a start as :meth:`push` makes, from the same arm posture (HOME),
        without moving the block: it answers exactly what a push would do. Given a `pose`,
        the block is put there first.
        """
        if pose is not None:
            self._turned = 0.0
            place(self.sim, self.block, pose)
        contact, psi = self._push_line(p, angle)
        self.arm.teleport_joints(HOME)
        found = self._find_start(contact, psi)
        self.arm.teleport_joints(HOME)
        return None if found is None else found[0]

    def _push_line(self, p: float, angle: float) -> tuple[np.ndarray, float]:
        """The contact point (2,) in the world and the push direction psi of u = [p, angle]."""
        x, y, th = self.block_pose()
        if self._canonical:
            th = self._turn_to_canonical(th)
        frame, phi, (hx, hy) = contact_frame(self.cfg.push, th, angle)
        cl = np.array([-hx, p * hy * CONTACT_SPAN])  # contact point in the face's frame
        rot = np.array([[math.cos(frame), -math.sin(frame)],
                        [math.sin(frame), math.cos(frame)]])
        return np.array([x, y]) + rot @ cl, frame + phi

    def _find_start(self, contact: np.ndarray, psi: float):
        """(start (2,), approach gap, hand orientation) of the first posture the arm reaches
        behind `contact` for a push along `psi`, the arm left there; None if none."""
        d = np.array([math.cos(psi), math.sin(psi)])
        starts = [contact - d * (PUSHER_RADIUS + gap) for gap in APPROACH_GAPS]
        if min(np.hypot(*start) for start in starts) > MAX_START_DISTANCE:
            return None  # beyond every posture's reach: no IK needed to say so
        for orn, seed in self.arm.start_postures(contact, psi):
            if seed is not None:
                self.arm.teleport_joints(seed)
            for gap, start in zip(APPROACH_GAPS, starts, strict=True):
                self.arm.teleport([*start, PUSH_HEIGHT], orn)
                if self.arm.can_start_at(start, self.block):
                    return start, gap, orn
        return None

    def _turn_to_canonical(self, th: float) -> float:
        """Turn the simulated block by whole quarter turns into (-pi/4, pi/4]; returns its
        new orientation.

        A uniform square block turned by a quarter turn is the same object, but Bullet's box
        contacts depend on which box axis is which: pushed alike, two poses that look alike
        ended up to 5 mm apart. Simulating both from one representative (rounded to 1e-9
        rad so that both round to it) makes them end up alike to the last bit.
        """
        quarter = math.pi / 2
        canonical = round(wrap_angle(th, quarter), 9)
        self._turned = round((th - canonical) / quarter) * quarter
        pos, _ = self.sim.getBasePositionAndOrientation(self.block)
        self.sim.resetBasePositionAndOrientation(self.block, pos, yaw_quaternion(canonical))
        self.sim.resetBaseVelocity(self.block, [0, 0, 0], [0, 0, 0])
        return canonical

    def _settle(self) -> None:
        for _ in range(SETTLE_STEPS):
            self.sim.stepSimulation()
            self.sim_steps += 1
            v, w = self.sim.getBaseVelocity(self.block)
            if math.hypot(v[0], v[1]) < 1e-3 and abs(w[2]) < 1e-2:
                break

    def ee_position(self) -> np.ndarray:
        return self.arm.ee_position()

    # ------------------------------------------------------------------ pictures
    def observe(self, pose=None) -> np.ndarray:
        """The camera's image (C, S, S) uint8 with the block at `pose` (default: where it is).

        Rendered in the camera world, so it never disturbs the simulation: `observe(goal)`
        is the goal image used by control.
        """
        return self.view.observe(self.block_pose() if pose is None else pose)

    def observe_full_scene(self) -> np.ndarray:
        """The same image rendered in the simulation (arm included, goal marker hidden).

        Slow; exists to check that :meth:`observe` shows exactly what the camera would
        (build the world with ``arm_visuals=True`` for that, or the arm is invisible here).
        """
        self.sim.resetBasePositionAndOrientation(self.goal, PARKED, [0, 0, 0, 1])
        try:
            return self.view.to_obs(self.view.render(self.sim, self.cfg.image_size))
        finally:
            place(self.sim, self.goal, self.goal_pose)

    def render_rgb(self) -> np.ndarray:
        """A larger (S, S, 3) RGB frame of the whole scene with the goal marker, for people."""
        return self.view.render(self.sim, self.cfg.render_size)

    def world_to_pixel(self, xyz) -> np.ndarray:
        """(row, col) of a world point in the observation image (float, pixel units)."""
        return self.camera.world_to_pixel(xyz)
