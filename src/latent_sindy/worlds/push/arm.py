"""The Panda arm of the pushing world: IK, kinematic moves, where a push may start, and
tracking a pusher path in the simulation.

Free-space moves are kinematic resets (:meth:`Arm.teleport`): they never touch the block.
A push's path is tracked at PyBullet's 240 Hz with IK and joint position control
(:meth:`Arm.follow`). :class:`~latent_sindy.worlds.push.world.PushWorld` plans the push and
drives the arm through it.

    python -c "from latent_sindy.worlds.push.world import PushWorld; \
print(PushWorld().arm.ee_position())"
"""

from __future__ import annotations

import math

import numpy as np

from latent_sindy.worlds.push._bullet import BulletClient
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.criteria import wrap_angle

__all__ = ["HOME", "Arm"]

EE_LINK = 11  # panda_grasptarget: between the fingertips
ARM_JOINTS = list(range(7))
FINGER_JOINTS = [9, 10]
HOME = [0.0, -1.3, 0.0, -2.8, 0.0, 1.6, 0.785]  # folded above the base, out of the camera's view
JOINT_FORCE = [87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0]  # Panda torque limits (N m)

APPROACH_GAPS = (0.005, 0.015, 0.03, 0.05)  # free space before contact at the push's start (m)
IK_EVERY = 4  # simulation steps between IK solutions (joint targets interpolated between)
HAND_TILTS = (0.0, 0.15, -0.15, 0.3, -0.3)  # rad the hand may lean away from the base (far
#   starts) or towards it (starts close to the base, where IK otherwise folds the elbow past
#   its limit), tried in this order; at 0.45 some pushes threw the block sideways
JOINT_MARGIN = 0.1  # rad a push's start must keep from every joint limit
START_TOLERANCE = 0.005  # m: IK error beyond which a push start counts as out of reach
MAX_START_DISTANCE = 0.88  # m from the base's axis: no posture reached a push start beyond
#   0.86 m (benchmarks/reach.py), so a posture whose starts are all further is not tried


class Arm:
    """The Panda in simulation client `sim`: loaded at HOME with the fingers closed.

    Without ``visuals`` its visual meshes are not loaded: loading them was about four fifths
    of a world's rebuild (BENCHMARKS.md), and no picture shows the arm, which is parked out
    of the camera's view before every frame. The physics is the same bit for bit.
    """

    def __init__(self, sim: BulletClient, visuals: bool = False) -> None:
        self.sim = sim
        flags = 0 if visuals else pb.URDF_IGNORE_VISUAL_SHAPES
        self.body = sim.loadURDF("franka_panda/panda.urdf", useFixedBase=True, flags=flags)
        info = [sim.getJointInfo(self.body, j) for j in ARM_JOINTS]
        self.lower = [i[8] for i in info]
        self.upper = [i[9] for i in info]
        self.ranges = [u - lo for lo, u in zip(self.lower, self.upper, strict=True)]
        self._lower_margin = np.array(self.lower) + JOINT_MARGIN
        self._upper_margin = np.array(self.upper) - JOINT_MARGIN
        for j, q in zip(ARM_JOINTS, HOME, strict=True):
            sim.resetJointState(self.body, j, q)
        for j in FINGER_JOINTS:
            sim.resetJointState(self.body, j, 0.0)
            sim.setJointMotorControl2(self.body, j, pb.POSITION_CONTROL, 0.0, force=40.0)
        self.hold(HOME)

    # ------------------------------------------------------------------ where a push starts
    def start_postures(self, contact: np.ndarray, psi: float):
        """(hand orientation, IK seed or None) to try in turn for a push along `psi`; each
        is tried at every approach gap (APPROACH_GAPS), the first gap from the seed, the next
        from the last one's solution.

        First the hand pointing straight down with the fingers across the push, backing off
        along the push line (at steep angles a finger's side would be inside the block just
        behind the contact point); then the hand turned round (the closed fingers are
        symmetric, and the wrist's joint range may only allow one of the two); then the hand
        leaning away from the base, which reaches further than the straight-down reach
        (about 0.8 m from the base), or towards it, which reaches closer to the base
        (HAND_TILTS, the smaller lean first). The first candidate is the only one the
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
                yield orn, None if first else self.posture_towards(radial, yaw)
                first = False

    def posture_towards(self, radial: np.ndarray, yaw: float) -> list[float]:
        """HOME turned to face `radial` with the wrist giving the hand about `yaw`.

        With the hand pointing down its yaw is about q1 - q7 + HOME's q7; of the wrist
        angles that give it (2 pi apart) take the one furthest inside the joint's range.
        """
        q1 = math.atan2(radial[1], radial[0])
        q7 = q1 - yaw + HOME[6]
        lo, hi = self.lower[6], self.upper[6]
        mid = (lo + hi) / 2
        q7 = mid + wrap_angle(q7 - mid)
        return [q1, *HOME[1:6], float(np.clip(q7, lo, hi))]

    def can_start_at(self, start: np.ndarray, block: int) -> bool:
        """Did the teleport reach the push's start, with the arm clear of `block` and its
        joints inside their limits (with a margin for the push itself)?

        IK does not keep to the limits and a teleport does not enforce them, but the
        simulation does: a start beyond them twists the hand as soon as the push begins.
        """
        if np.linalg.norm(self.ee_position()[:2] - start) > START_TOLERANCE:
            return False
        q = self.joint_positions()
        if np.any(q < self._lower_margin) or np.any(q > self._upper_margin):
            return False
        self.sim.performCollisionDetection()
        return all(c[8] > -1e-3 for c in self.sim.getContactPoints(self.body, block))

    def distance_to_touch(self, d: np.ndarray, gap: float, block: int) -> float:
        """How far the hand can move along `d` before it first touches `block`.

        From the closest points between each arm link and the block: a gap `dist` closes
        at rate -n.d per metre moved, n the block's surface normal there.
        """
        best = gap
        for c in self.sim.getClosestPoints(self.body, block, distance=0.1):
            n = np.array(c[7][:2])  # contact normal on the block, pointing to the arm
            rate = -float(n @ d)
            if rate > 0.1:
                best = min(best, max(0.0, c[8]) / rate)
        return best

    # ------------------------------------------------------------------ moving
    def ik(self, pos, orn) -> list[float]:
        q = self.sim.calculateInverseKinematics(
            self.body, EE_LINK, pos, orn, lowerLimits=self.lower, upperLimits=self.upper,
            jointRanges=self.ranges, restPoses=HOME, maxNumIterations=50,
            residualThreshold=1e-5)
        return list(q[:7])

    def hold(self, q) -> None:
        self.sim.setJointMotorControlArray(
            self.body, ARM_JOINTS, pb.POSITION_CONTROL, targetPositions=q, forces=JOINT_FORCE)

    def teleport_joints(self, q) -> None:
        for j, qj in zip(ARM_JOINTS, q, strict=True):
            self.sim.resetJointState(self.body, j, qj)
        self.hold(q)

    def teleport(self, pos, orn) -> None:
        # IK from the current configuration converges better in a few rounds
        for _ in range(3):
            self.teleport_joints(self.ik(pos, orn))

    def follow(self, path: np.ndarray, orn) -> int:
        """Track a Cartesian path (n, 3), one point per simulation step; returns the
        simulation steps taken (n).

        IK runs every IK_EVERY steps; joint targets in between are interpolated, which on
        these straight millimetre-scale segments differs from per-step IK by far less than
        the controller's own tracking error and costs a quarter of the time.
        """
        q_prev = self.joint_positions()
        for k0 in range(0, len(path), IK_EVERY):
            k1 = min(k0 + IK_EVERY, len(path))
            q_next = np.array(self.ik(path[k1 - 1].tolist(), orn))
            for k in range(k0, k1):
                w = (k - k0 + 1) / (k1 - k0)
                self.hold((q_prev + w * (q_next - q_prev)).tolist())
                self.sim.stepSimulation()
            q_prev = q_next
        return len(path)

    # ------------------------------------------------------------------ state
    def joint_positions(self) -> np.ndarray:
        """The arm joints' angles (7,)."""
        return np.array([s[0] for s in self.sim.getJointStates(self.body, ARM_JOINTS)])

    def ee_position(self) -> np.ndarray:
        return np.array(self.sim.getLinkState(self.body, EE_LINK)[4])
