"""The reach task: a goal for the tip, and how near the tip is to it. No rospy.

gymnasium-robotics' goal-env convention (FetchReach, panda-gym's PandaReach): ``compute_reward(achieved_goal,
desired_goal, info)`` works on one pair or on any batch of them (stable-baselines3's HER relabels goals in batches),
success is a distance below ``distance_threshold`` (0.05 m, Panda's and Fetch's), and the sparse reward is 0 on
success and -1 otherwise, the dense one minus the distance.

Pose goals (goal='pose'): a goal is the tip's position and orientation, 7 numbers ``[x, y, z, qx, qy, qz, qw]`` (the
quaternion in ROS's order, unit, qw >= 0), as gymnasium-robotics' HandManipulate goals are; success is a position
within ``distance_threshold`` and an orientation within ``angle_threshold`` (0.1 rad) of the goal's; the dense
reward is minus (the distance + the angle x distance_threshold / angle_threshold), so that both thresholds weigh the
same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robot_ai.reach.arm import Arm, ReachError

REWARD_TYPES = ('sparse', 'dense')
GOALS = ('position', 'pose')
DISTANCE_THRESHOLD = 0.05
ANGLE_THRESHOLD = 0.1        # rad, pose goals


def goal_distance(achieved, desired) -> np.ndarray:
    """Euclidean distance over the last axis (3), for one pair or a batch; element-wise operations only, so that a
    batch gives each pair's distance bit for bit."""
    d = np.asarray(achieved, dtype=np.float64) - np.asarray(desired, dtype=np.float64)
    return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])


def goal_distance_one(achieved: list, desired: list) -> float:
    """goal_distance of one pair of 3 floats, the same operations in the same order (so the same number)."""
    d0, d1, d2 = achieved[0] - desired[0], achieved[1] - desired[1], achieved[2] - desired[2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


def quaternions_t(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (4, N) [x, y, z, w] with w >= 0 of rotation matrices (3, 3, N) (rows, columns, batch):
    Shepperd's method, from the largest of the four squared components; element-wise over the batch."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    squares = np.array([1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1.0 - m[0, 0] + m[1, 1] - m[2, 2],
                        1.0 - m[0, 0] - m[1, 1] + m[2, 2], 1.0 + trace])
    largest = np.argmax(squares, axis=0)
    root = np.sqrt(np.maximum(np.take_along_axis(squares, largest[None], 0)[0], 1e-300))   # 4 x that component
    k = 0.5 / root
    sums = (m[0, 1] + m[1, 0], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1])
    diffs = (m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1])
    half = 0.5 * root
    candidates = np.array([
        [half, sums[0] * k, sums[1] * k, diffs[0] * k],          # x largest
        [sums[0] * k, half, sums[2] * k, diffs[1] * k],          # y
        [sums[1] * k, sums[2] * k, half, diffs[2] * k],          # z
        [diffs[0] * k, diffs[1] * k, diffs[2] * k, half]])       # w
    q = np.take_along_axis(candidates, largest[None, None], 0)[0]
    q = q * np.where(q[3] < 0, -1.0, 1.0)
    return q / np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def goal_angle(achieved, desired) -> np.ndarray:
    """The angle (rad, in [0, pi]) between the orientations of pose goals (..., 7): 2 acos |<q_a, q_d>|."""
    a = np.asarray(achieved, dtype=np.float64)
    d = np.asarray(desired, dtype=np.float64)
    dot = a[..., 3] * d[..., 3] + a[..., 4] * d[..., 4] + a[..., 5] * d[..., 5] + a[..., 6] * d[..., 6]
    return 2.0 * np.arccos(np.minimum(np.abs(dot), 1.0))


def rotation_error(achieved, desired) -> np.ndarray:
    """(..., 3): the rotation vector (axis x angle, base frame, angle in [0, pi]) that turns the orientation of pose
    goal achieved (..., 7) into desired's: the angular velocity a P-controller on the orientation commands."""
    a = np.asarray(achieved, dtype=np.float64)
    d = np.asarray(desired, dtype=np.float64)
    ax, ay, az, aw = a[..., 3], a[..., 4], a[..., 5], a[..., 6]
    dx, dy, dz, dw = d[..., 3], d[..., 4], d[..., 5], d[..., 6]
    w = dw * aw + dx * ax + dy * ay + dz * az                     # q_d * conj(q_a)
    x = aw * dx - dw * ax - (dy * az - dz * ay)
    y = aw * dy - dw * ay - (dz * ax - dx * az)
    z = aw * dz - dw * az - (dx * ay - dy * ax)
    sign = np.where(w < 0, -1.0, 1.0)
    w, v = w * sign, np.stack((x, y, z), axis=-1) * sign[..., None]
    norm = np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])
    angle = 2.0 * np.arctan2(norm, w)
    scale = np.where(norm > 1e-12, angle / np.maximum(norm, 1e-300), 2.0)
    return v * scale[..., None]


@dataclass(frozen=True)
class ReachTask:
    """Goals drawn as the tip (its position, or its pose) of a configuration uniform within the limits (every goal
    reachable), a reward, and success."""
    reward_type: str = 'sparse'
    distance_threshold: float = DISTANCE_THRESHOLD
    goal: str = 'position'
    angle_threshold: float = ANGLE_THRESHOLD

    def __post_init__(self):
        if self.reward_type not in REWARD_TYPES:
            raise ReachError(f'reward_type must be one of {", ".join(REWARD_TYPES)}, got {self.reward_type!r}')
        if not (isinstance(self.distance_threshold, (int, float)) and 0 < self.distance_threshold < float('inf')):
            raise ReachError(f'distance_threshold must be a positive number of metres, got {self.distance_threshold!r}')
        if self.goal not in GOALS:
            raise ReachError(f'goal must be one of {", ".join(GOALS)}, got {self.goal!r}')
        if isinstance(self.angle_threshold, bool) or not isinstance(self.angle_threshold, (int, float)) \
                or not 0 < self.angle_threshold <= math.pi:
            raise ReachError(f'angle_threshold must be a number of radians in (0, pi], got {self.angle_threshold!r}')

    @property
    def size(self) -> int:
        """The numbers of a goal: 3 (a position) or 7 (position and quaternion)."""
        return 7 if self.goal == 'pose' else 3

    def outcome(self, achieved, desired) -> tuple[np.ndarray, np.ndarray]:
        """(reward, success) of achieved goals against desired ones (..., size)."""
        distance = goal_distance(achieved, desired)
        if self.goal != 'pose':
            return self.reward_of(distance), distance < self.distance_threshold
        angle = goal_angle(achieved, desired)
        success = (distance < self.distance_threshold) & (angle < self.angle_threshold)
        if self.reward_type == 'sparse':
            return -(~success).astype(np.float64), success
        return -self._pose_error(distance, angle), success

    def error(self, achieved, desired) -> np.ndarray:
        """The dense reward's error of achieved goals against desired ones (..., size): the distance, plus for pose
        goals the angle weighted distance_threshold / angle_threshold metres a radian."""
        distance = goal_distance(achieved, desired)
        return distance if self.goal != 'pose' else self._pose_error(distance, goal_angle(achieved, desired))

    def _pose_error(self, distance, angle):
        return distance + angle * (self.distance_threshold / self.angle_threshold)

    @staticmethod
    def goal_configuration(arm: Arm, rng: np.random.Generator) -> np.ndarray:
        """Joint positions (n,) uniform within the limits, whose tip is the goal."""
        return rng.uniform(arm.lower, arm.upper)

    def reward_one(self, distance: float) -> float:
        """reward_of for one distance."""
        if self.reward_type == 'sparse':
            return -1.0 if distance >= self.distance_threshold else 0.0
        return -distance

    def reward_of(self, distance) -> np.ndarray:
        distance = np.asarray(distance, dtype=np.float64)
        if self.reward_type == 'sparse':
            return -(distance >= self.distance_threshold).astype(np.float64)
        return -distance

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        """The reward of reaching achieved_goal when desired_goal was asked, for one pair (size,) or a batch
        (..., size)."""
        if self.goal == 'pose':
            return self.outcome(achieved_goal, desired_goal)[0]
        return self.reward_of(goal_distance(achieved_goal, desired_goal))

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        if self.goal == 'pose':
            return self.outcome(achieved_goal, desired_goal)[1]
        return goal_distance(achieved_goal, desired_goal) < self.distance_threshold


def why_unreached(arm: Arm, goal, q, distance: float) -> tuple[str, str]:
    """(kind, a line) of why the tip stopped distance metres from goal (3,) with the arm at q (n,), truthfully:
    'beyond' (the goal lies farther than the tip can ever be), 'limits' (joints at their limits, named) or 'other'
    (neither: a singular configuration, or a point the arm cannot take)."""
    away = math.sqrt(sum(float(v) * float(v) for v in goal))
    if away > arm.radius:
        return 'beyond', (f'beyond the arm\'s reach: {away:.3f} m from {arm.base}, and its tip is never farther than '
                          f'{arm.radius:.3f} m')
    stuck = arm.at_limits(q)
    if stuck:
        return 'limits', (f'stalled {distance:.3f} m away with {", ".join(stuck)} at '
                          f'{"its limit" if len(stuck) == 1 else "their limits"}')
    return 'other', (f'stalled {distance:.3f} m away with no joint at a limit (a singular configuration, or a point '
                     f'the arm cannot take)')
