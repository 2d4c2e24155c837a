"""The PyBullet scene behind :class:`~latent_sindy.worlds.push.panda_push.PandaPushEnv`.

Two physics clients, both headless (DIRECT):

* the *simulation*: Panda arm (``pybullet_data``), table, block and goal marker; every push is
  simulated here;
* the *camera world*: table and block only. Observations are rendered here with the block
  copied to its simulated pose. The arm has retreated out of view before every observation,
  so the picture is the same (a test checks it pixel for pixel) while TinyRenderer no longer
  rasterises the arm's meshes, which cost about 65x the rest of the frame.

Free-space arm moves (to the start of a push, and home out of the camera's view afterwards)
are kinematic resets: they never touch the block, so simulating them would only spend time.
Everything from just before contact until the pusher has backed off the block is simulated
at PyBullet's 240 Hz with IK and joint position control, and the block is then left to come
to rest.

    python -c "from latent_sindy.worlds.push.world import PushWorld; w = PushWorld(); \
w.reset((0.5, 0, 0), (0.7, 0, 0)); w.push(0, 0, 1); print(w.block_pose())"
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from latent_sindy.worlds.push._bullet import BulletClient, pybullet_data, quiet_c_output
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.camera import Camera
from latent_sindy.worlds.push.config import BLOCK_SIZE, CONTACT_SPAN, MAX_PUSH, PushEnvConfig

EE_LINK = 11  # panda_grasptarget: between the fingertips
ARM_JOINTS = list(range(7))
FINGER_JOINTS = [9, 10]
HOME = [0.0, -1.3, 0.0, -2.8, 0.0, 1.6, 0.785]  # folded above the base, out of the camera's view
JOINT_FORCE = [87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0]  # Panda torque limits (N m)

PUSH_HEIGHT = 0.025  # pusher height above the table: the block's mid-height
PUSHER_RADIUS = 0.014  # closed fingertips' half-thickness along the push (m)
APPROACH_GAPS = (0.005, 0.015, 0.03, 0.05)  # free space before contact at the push's start (m)
PUSH_SPEED = 0.25  # m/s cruise speed along the push line
PUSH_ACCEL = 2.0  # m/s^2 speeding up
PUSH_DECEL = 0.5  # m/s^2 slowing down: below the block's friction deceleration (0.1 g), so
#                   the block stops with the pusher instead of sliding on
IK_EVERY = 4  # simulation steps between IK solutions (joint targets interpolated between)
RETREAT = (0.02, 0.06)  # back off (m along -push) and lift (m) before leaving
HAND_TILTS = (0.0, 0.15)  # rad the hand may lean outwards to reach far push starts (more
#                           lean lets the fingers pass over the block or throw it)
JOINT_MARGIN = 0.1  # rad a push's start must keep from every joint limit
START_TOLERANCE = 0.005  # m: IK error beyond which a push start counts as out of reach
SETTLE_STEPS = 240  # at most one simulated second for the block to come to rest
DT = 1.0 / 240.0

TABLE_HALF = (0.6, 0.6, 0.02)
TABLE_CENTRE = (0.55, 0.0, -0.02)
TABLE_RGBA = (0.82, 0.80, 0.74, 1.0)
BLOCK_RGBA = (0.30, 0.45, 0.85, 1.0)
MARK_RGBA = (0.55, 0.10, 0.10, 1.0)  # the marked block's +x half: darker in grayscale too
GOAL_RGBA = (0.10, 0.90, 0.10, 0.4)
PARKED = (0.0, 0.0, -5.0)  # far below the table: out of every view


def wrap_angle(a: float, period: float = 2 * math.pi) -> float:
    """Map an angle to (-period/2, period/2] (default: (-pi, pi])."""
    return -((-a + period / 2) % period - period / 2)


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


def _quat(theta: float) -> list[float]:
    return [0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)]


def _add_table_and_block(c: BulletClient, cfg: PushEnvConfig) -> int:
    """Table (top at z = 0) and block; returns the block's body id."""
    c.createMultiBody(
        0,
        c.createCollisionShape(pb.GEOM_BOX, halfExtents=TABLE_HALF),
        c.createVisualShape(pb.GEOM_BOX, halfExtents=TABLE_HALF, rgbaColor=TABLE_RGBA),
        basePosition=TABLE_CENTRE,
    )
    half = [s / 2 for s in BLOCK_SIZE]
    if cfg.block_look == "marked":
        # two half-blocks side by side: the +x half light, so a quarter turn shows
        quarter = [half[0] / 2, half[1], half[2]]
        visual = c.createVisualShapeArray(
            [pb.GEOM_BOX, pb.GEOM_BOX], halfExtents=[quarter, quarter],
            visualFramePositions=[[-quarter[0], 0, 0], [quarter[0], 0, 0]],
            rgbaColors=[BLOCK_RGBA, MARK_RGBA])
    else:
        visual = c.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=BLOCK_RGBA)
    block = c.createMultiBody(
        cfg.block_mass,
        c.createCollisionShape(pb.GEOM_BOX, halfExtents=half),
        visual,
        basePosition=[0.5, 0.0, half[2]],
    )
    c.changeDynamics(block, -1, lateralFriction=cfg.block_friction)
    return block


def _place(c: BulletClient, body: int, pose) -> None:
    """Put `body` at rest on the table at planar pose (x, y, theta)."""
    x, y, th = (float(v) for v in pose)
    c.resetBasePositionAndOrientation(body, [x, y, BLOCK_SIZE[2] / 2], _quat(th))
    c.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


class CameraView:
    """The camera world: table and block only, and the observation camera.

    What :meth:`PushWorld.observe` renders, and cheap to build alone (no arm to load): e.g.
    for images of the block at given poses.
    """

    def __init__(self, cfg: PushEnvConfig | None = None) -> None:
        self.cfg = cfg or PushEnvConfig()
        with quiet_c_output():
            self.client = BulletClient(connection_mode=pb.DIRECT)
        self.block = _add_table_and_block(self.client, self.cfg)
        self.camera = Camera(self.cfg)

    def observe(self, pose) -> np.ndarray:
        """The camera's image (C, S, S) uint8 with the block at `pose` (x, y, theta)."""
        _place(self.client, self.block, pose)
        return self.to_obs(self.render(self.client, self.cfg.image_size))

    def render(self, c: BulletClient, size: int) -> np.ndarray:
        """An (S, S, 3) RGB frame of client `c`'s scene through the camera."""
        _, _, rgba, _, _ = c.getCameraImage(
            size, size, self.camera.view, self.camera.projection,
            renderer=pb.ER_TINY_RENDERER, shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK)
        return np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[..., :3]

    def to_obs(self, rgb: np.ndarray) -> np.ndarray:
        """RGB frame -> observation (C, S, S) uint8 (grayscale unless the config says 3)."""
        if self.cfg.channels == 3:
            return np.ascontiguousarray(rgb.transpose(2, 0, 1))
        gray = rgb.astype(np.float32) @ np.array([0.2989, 0.587, 0.114], dtype=np.float32)
        return np.clip(np.rint(gray), 0, 255).astype(np.uint8)[None]

    def close(self) -> None:
        with quiet_c_output(), contextlib.suppress(pb.error):
            self.client.disconnect()


class PushWorld:
    """Panda, table, block and goal marker, simulated and rendered headless."""

    def __init__(self, cfg: PushEnvConfig | None = None) -> None:
        self.cfg = cfg or PushEnvConfig()
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
        self.block = _add_table_and_block(c, self.cfg)
        half = [s / 2 for s in BLOCK_SIZE]
        self.goal = c.createMultiBody(
            0, -1, c.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=GOAL_RGBA),
            basePosition=PARKED,
        )
        self.arm = c.loadURDF("franka_panda/panda.urdf", useFixedBase=True)
        info = [c.getJointInfo(self.arm, j) for j in ARM_JOINTS]
        self._lower = [i[8] for i in info]
        self._upper = [i[9] for i in info]
        self._ranges = [u - lo for lo, u in zip(self._lower, self._upper, strict=True)]
        self._lower_margin = np.array(self._lower) + JOINT_MARGIN
        self._upper_margin = np.array(self._upper) - JOINT_MARGIN
        for j, q in zip(ARM_JOINTS, HOME, strict=True):
            c.resetJointState(self.arm, j, q)
        for j in FINGER_JOINTS:
            c.resetJointState(self.arm, j, 0.0)
            c.setJointMotorControl2(self.arm, j, pb.POSITION_CONTROL, 0.0, force=40.0)
        self._hold(HOME)

    # ------------------------------------------------------------------ state
    def reset(self, start: tuple[float, float, float], goal: tuple[float, float, float]) -> None:
        """Rebuild the world with the block resting at `start` and the goal marker at `goal`."""
        self._build()
        self.last_push_executed = True
        self._turned = 0.0
        self._set_pose(self.sim, self.block, start)
        self.goal_pose = np.asarray(goal, dtype=float)
        self._set_pose(self.sim, self.goal, goal)

    def block_pose(self) -> np.ndarray:
        """The block's planar pose (x, y, theta), theta in (-pi, pi]."""
        pos, orn = self.sim.getBasePositionAndOrientation(self.block)
        th = self.sim.getEulerFromQuaternion(orn)[2]
        return np.array([pos[0], pos[1], wrap_angle(th + self._turned) if self._turned else th])

    def close(self) -> None:
        with quiet_c_output(), contextlib.suppress(pb.error):
            self.sim.disconnect()
        self.view.close()

    _set_pose = staticmethod(_place)

    # ------------------------------------------------------------------ motion
    def push(self, p: float, angle: float, ell: float) -> None:
        """Execute one push u = [p, angle, ell] and let the block come to rest.

        The config's `push` style says what the angle means (see :func:`contact_frame`).
        """
        x, y, th = self.block_pose()
        if self._canonical:
            th = self._turn_to_canonical(th)
        frame, phi, (hx, hy) = contact_frame(self.cfg.push, th, angle)
        cl = np.array([-hx, p * hy * CONTACT_SPAN])  # contact point in the face's frame
        rot = np.array([[math.cos(frame), -math.sin(frame)],
                        [math.sin(frame), math.cos(frame)]])
        contact = np.array([x, y]) + rot @ cl
        psi = frame + phi
        d = np.array([math.cos(psi), math.sin(psi)])
        for gap, orn, seed in self._start_candidates(contact, psi):
            start = contact - d * (PUSHER_RADIUS + gap)
            if seed is not None:
                self._teleport_joints(seed)
            self._teleport([*start, PUSH_HEIGHT], orn)
            if self._can_start_at(start):
                break
        else:
            # out of the arm's reach: the robot does not attempt it, the block stays put
            self.last_push_executed = False
            self._teleport_joints(HOME)
            return
        self.last_push_executed = True
        travel = self._distance_to_touch(d, gap) + ell * MAX_PUSH  # ell counts from first touch
        along = _profile(travel)  # (n,) distance along the push line at each step
        path = np.column_stack([start + d * along[:, None], np.full(len(along), PUSH_HEIGHT)])
        self._follow(path, orn)
        end = start + d * travel
        back, lift = RETREAT
        length = math.hypot(back, lift)
        f = _profile(length, decel=None)[:, None] / length
        self._follow(np.column_stack([end - d * back * f, PUSH_HEIGHT + lift * f]), orn)
        self._teleport_joints(HOME)
        self._settle()

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
        self.sim.resetBasePositionAndOrientation(self.block, pos, _quat(canonical))
        self.sim.resetBaseVelocity(self.block, [0, 0, 0], [0, 0, 0])
        return canonical

    def _start_candidates(self, contact: np.ndarray, psi: float):
        """(approach gap, hand orientation, IK seed or None) to try in turn for a push along
        `psi`.

        First the hand pointing straight down with the fingers across the push, backing off
        along the push line (at steep angles a finger's side would be inside the block just
        behind the contact point); then the hand turned round (the closed fingers are
        symmetric, and the wrist's joint range may only allow one of the two); then, for
        starts beyond the straight-down reach (about 0.8 m from the base), the hand leaning
        away from the base, which reaches further. The first candidate is the only one the
        world had before, so a push it could start is made exactly as before; IK for the
        others starts from a posture that already points the hand their way, because IK
        from the last attempt keeps winding the wrist past its limit.
        """
        r = float(np.hypot(*contact))
        radial = contact / r if r > 0 else np.array([1.0, 0.0])
        axis = [-radial[1], radial[0], 0.0]  # horizontal, across the radial direction
        first = True
        for tilt in HAND_TILTS:
            lean = self.sim.getQuaternionFromAxisAngle(axis, -tilt)
            for yaw in (psi, psi + math.pi):
                down = self.sim.getQuaternionFromEuler([math.pi, 0.0, yaw])  # fingers across
                orn = (down if tilt == 0.0  # as before to the last bit
                       else self.sim.multiplyTransforms([0, 0, 0], lean, [0, 0, 0], down)[1])
                seed = None if first else self._posture_towards(radial, yaw)
                first = False
                for gap in APPROACH_GAPS:
                    yield gap, orn, seed
                    seed = None  # the next gap starts from this one's solution

    def _posture_towards(self, radial: np.ndarray, yaw: float) -> list[float]:
        """HOME turned to face `radial` with the wrist giving the hand about `yaw`.

        With the hand pointing down its yaw is about q1 - q7 + HOME's q7; of the wrist
        angles that give it (2 pi apart) take the one furthest inside the joint's range.
        """
        q1 = math.atan2(radial[1], radial[0])
        q7 = q1 - yaw + HOME[6]
        lo, hi = self._lower[6], self._upper[6]
        mid = (lo + hi) / 2
        q7 = mid + wrap_angle(q7 - mid)
        return [q1, *HOME[1:6], float(np.clip(q7, lo, hi))]

    def _can_start_at(self, start: np.ndarray) -> bool:
        """Did the teleport reach the push's start, with the arm clear of the block and its
        joints inside their limits (with a margin for the push itself)?

        IK does not keep to the limits and a teleport does not enforce them, but the
        simulation does: a start beyond them twists the hand as soon as the push begins.
        """
        if np.linalg.norm(self.ee_position()[:2] - start) > START_TOLERANCE:
            return False
        q = np.array([s[0] for s in self.sim.getJointStates(self.arm, ARM_JOINTS)])
        if np.any(q < self._lower_margin) or np.any(q > self._upper_margin):
            return False
        self.sim.performCollisionDetection()
        return all(c[8] > -1e-3 for c in self.sim.getContactPoints(self.arm, self.block))

    def _distance_to_touch(self, d: np.ndarray, gap: float) -> float:
        """How far the hand can move along `d` before it first touches the block.

        From the closest points between each arm link and the block: a gap `dist` closes
        at rate -n.d per metre moved, n the block's surface normal there.
        """
        best = gap
        for c in self.sim.getClosestPoints(self.arm, self.block, distance=0.1):
            n = np.array(c[7][:2])  # contact normal on the block, pointing to the arm
            rate = -float(n @ d)
            if rate > 0.1:
                best = min(best, max(0.0, c[8]) / rate)
        return best

    def _ik(self, pos, orn) -> list[float]:
        q = self.sim.calculateInverseKinematics(
            self.arm, EE_LINK, pos, orn, lowerLimits=self._lower, upperLimits=self._upper,
            jointRanges=self._ranges, restPoses=HOME, maxNumIterations=50,
            residualThreshold=1e-5)
        return list(q[:7])

    def _hold(self, q) -> None:
        self.sim.setJointMotorControlArray(
            self.arm, ARM_JOINTS, pb.POSITION_CONTROL, targetPositions=q, forces=JOINT_FORCE)

    def _teleport_joints(self, q) -> None:
        for j, qj in zip(ARM_JOINTS, q, strict=True):
            self.sim.resetJointState(self.arm, j, qj)
        self._hold(q)

    def _teleport(self, pos, orn) -> None:
        # IK from the current configuration converges better in a few rounds
        for _ in range(3):
            self._teleport_joints(self._ik(pos, orn))

    def _follow(self, path: np.ndarray, orn) -> None:
        """Track a Cartesian path (n, 3), one point per simulation step.

        IK runs every IK_EVERY steps; joint targets in between are interpolated, which on
        these straight millimetre-scale segments differs from per-step IK by far less than
        the controller's own tracking error and costs a quarter of the time.
        """
        q_prev = np.array([s[0] for s in self.sim.getJointStates(self.arm, ARM_JOINTS)])
        for k0 in range(0, len(path), IK_EVERY):
            k1 = min(k0 + IK_EVERY, len(path))
            q_next = np.array(self._ik(path[k1 - 1].tolist(), orn))
            for k in range(k0, k1):
                w = (k - k0 + 1) / (k1 - k0)
                self._hold((q_prev + w * (q_next - q_prev)).tolist())
                self.sim.stepSimulation()
            self.sim_steps += k1 - k0
            q_prev = q_next

    def _settle(self) -> None:
        for _ in range(SETTLE_STEPS):
            self.sim.stepSimulation()
            self.sim_steps += 1
            v, w = self.sim.getBaseVelocity(self.block)
            if math.hypot(v[0], v[1]) < 1e-3 and abs(w[2]) < 1e-2:
                break

    def ee_position(self) -> np.ndarray:
        return np.array(self.sim.getLinkState(self.arm, EE_LINK)[4])

    # ------------------------------------------------------------------ pictures
    def observe(self, pose=None) -> np.ndarray:
        """The camera's image (C, S, S) uint8 with the block at `pose` (default: where it is).

        Rendered in the camera world, so it never disturbs the simulation: `observe(goal)`
        is the goal image used by control.
        """
        return self.view.observe(self.block_pose() if pose is None else pose)

    def observe_full_scene(self) -> np.ndarray:
        """The same image rendered in the simulation (arm included, goal marker hidden).

        Slow; exists to check that :meth:`observe` shows exactly what the camera would.
        """
        self.sim.resetBasePositionAndOrientation(self.goal, PARKED, [0, 0, 0, 1])
        try:
            return self.view.to_obs(self.view.render(self.sim, self.cfg.image_size))
        finally:
            self._set_pose(self.sim, self.goal, self.goal_pose)

    def render_rgb(self) -> np.ndarray:
        """A larger (S, S, 3) RGB frame of the whole scene with the goal marker, for people."""
        return self.view.render(self.sim, self.cfg.render_size)

    def world_to_pixel(self, xyz) -> np.ndarray:
        """(row, col) of a world point in the observation image (float, pixel units)."""
        return self.camera.world_to_pixel(xyz)
