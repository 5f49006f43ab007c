"""The reach task: a goal for the tip, and how near the tip is to it. No rospy.

gymnasium-robotics' goal-env convention (FetchReach, panda-gym's PandaReach): ``compute_reward(achieved_goal,
desired_goal, info)`` works on one pair or on any batch of them (stable-baselines3's HER relabels goals in batches),
success is a distance below ``distance_threshold`` (0.05 m, Panda's and Fetch's), and the sparse reward is 0 on
success and -1 otherwise, the dense one minus the distance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robot_ai.reach.arm import Arm, ReachError

REWARD_TYPES = ('sparse', 'dense')
DISTANCE_THRESHOLD = 0.05


def goal_distance(achieved, desired) -> np.ndarray:
    """Euclidean distance over the last axis (3), for one pair or a batch; element-wise operations only, so that a
    batch gives each pair's distance bit for bit."""
    d = np.asarray(achieved, dtype=np.float64) - np.asarray(desired, dtype=np.float64)
    return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])


def goal_distance_one(achieved: list, desired: list) -> float:
    """goal_distance of one pair of 3 floats, the same operations in the same order (so the same number)."""
    d0, d1, d2 = achieved[0] - desired[0], achieved[1] - desired[1], achieved[2] - desired[2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@dataclass(frozen=True)
class ReachTask:
    """Goals drawn as the tip of a configuration uniform within the limits (every goal reachable), a reward, and
    success."""
    reward_type: str = 'sparse'
    distance_threshold: float = DISTANCE_THRESHOLD

    def __post_init__(self):
        if self.reward_type not in REWARD_TYPES:
            raise ReachError(f'reward_type must be one of {", ".join(REWARD_TYPES)}, got {self.reward_type!r}')
        if not (isinstance(self.distance_threshold, (int, float)) and 0 < self.distance_threshold < float('inf')):
            raise ReachError(f'distance_threshold must be a positive number of metres, got {self.distance_threshold!r}')

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
        """The reward of reaching achieved_goal when desired_goal was asked, for one pair (3,) or a batch (..., 3)."""
        return self.reward_of(goal_distance(achieved_goal, desired_goal))

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
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
