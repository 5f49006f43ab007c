"""A reach goal planned with the arm's body: configurations that reach the goal clear of contacts, a collision-free
path to one of them (motion.JointPlanner: OMPL's RRT-Connect over the sphere body), timed within the joint limits
(motion.time_path: TOPP-RA). No rospy.

    planner = ReachPlanner(setup)                     # setup: a ReachSetup with a body (collision=True)
    plan = planner.plan(q_now, goal)                  # plan.timed.sample(0.05), or plan.reason
    python -m robot_ai.reach plan --model M --obstacles W --goal 0.4 0.2 0.3
    followed = follow_through_layer(setup, goal, q_now)   # as reach_controller drives a planned goal

A goal with no way says why, in one line: inside an obstacle, beyond the arm's reach, no configuration that reaches
it clear of contacts, or no path found in the time.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from robot_ai.motion import PlannedPath, TimedPath, time_path
from robot_ai.motion.planner import DEFAULT_TIME_LIMIT
from robot_ai.reach.arm import ReachError
from robot_ai.reach.env import PLAN_BUDGET, RECOVERED, PlannedWay, ReachSetup, Recovery
from robot_ai.reach.safety import DEFAULT_MARGIN, DEFAULT_VELOCITY_SCALE, Limits, Plan, SafetyLayer

GOAL_CONFIGURATIONS = 8  # reaching configurations given to the planner at most (the nearest to the start first)


@dataclass
class ReachPlan:
    """A goal's plan: the start (n,), the goal, the path (PlannedPath: waypoints or a reason), the timed motion
    (None without a path), the reason there is none ('' with one), the reaching configurations found clear, and the
    seconds the whole plan took (configurations, path and timing)."""
    start: np.ndarray
    goal: np.ndarray
    path: PlannedPath | None
    timed: TimedPath | None
    reason: str
    configurations: int
    seconds: float

    @property
    def found(self) -> bool:
        return self.timed is not None


class ReachPlanner:
    """Plans for one arm in one world (the setup's body and obstacles), keeping `margin` metres from every contact
    (the safety layer's), within Limits.of(arm, joint_limits, velocity_scale)."""

    def __init__(self, setup: ReachSetup, margin: float = DEFAULT_MARGIN,
                 velocity_scale: float = DEFAULT_VELOCITY_SCALE, joint_limits=None,
                 time_limit: float = DEFAULT_TIME_LIMIT):
        if setup.body is None:
            raise ReachError('a plan needs the arm\'s body: give collision=True (or obstacles)')
        if not margin >= 0:
            raise ReachError(f'margin must be a number of metres >= 0, got {margin!r}')
        if not time_limit > 0:
            raise ReachError(f'time_limit must be a positive number of seconds, got {time_limit!r}')
        self.setup, self.body, self.arm = setup, setup.body, setup.arm
        self.margin, self.time_limit = float(margin), float(time_limit)
        self.limits = setup.limits if setup.limits is not None and joint_limits is None else Limits.of(
            self.arm, joint_limits, velocity_scale)
        # checked states at most `spacing` apart, each with the margin as padding: the body between two of them keeps
        # at least half the margin (and touches nothing with no margin: 1 mm steps then)
        self.spacing = max(self.margin, 0.001)
        self.joints = setup.joint_planner(self.margin, self.limits, self.spacing)

    def clear(self, q: np.ndarray) -> np.ndarray:
        """(N,) bool: configurations (N, n) clear of every contact by the margin."""
        return ~self.body.in_collision(q, self.margin)

    def goal_configurations(self, goal, q) -> tuple[np.ndarray, str]:
        """(configurations (m, n) that reach the goal clear by the margin, the nearest to q (n,) first; the reason
        there is none, '' otherwise)."""
        setup = self.setup
        goal = np.asarray(setup.check_goal(goal, 'goal'), dtype=float)
        inside = setup.obstacle_holding(goal)
        if inside is not None:
            return np.zeros((0, self.arm.n)), f'the goal is inside {inside}'
        found, best = setup.clear_reaching_configurations(goal, q, self.margin, self.limits)
        if not len(found):
            return found, setup.none_clear(best, self.margin)
        return found[:GOAL_CONFIGURATIONS], ''

    def plan(self, q, goal, time_limit: float | None = None) -> ReachPlan:
        """The plan from joint positions q (n,) to the goal (a position, or a pose for pose goals)."""
        began = time.monotonic()
        q = np.asarray(q, dtype=float).reshape(self.arm.n)
        goal_array = np.asarray(goal, dtype=float)
        configurations, reason = self.goal_configurations(goal, q)
        if reason:
            return ReachPlan(q, goal_array, None, None, reason, 0, time.monotonic() - began)
        path = self.setup.plan_path(self.joints, np.asarray(goal, dtype=float), q, configurations, self.margin,
                                    self.limits, self.time_limit if time_limit is None else time_limit)
        if not path.found:
            return ReachPlan(q, goal_array, path, None, path.reason, len(configurations), time.monotonic() - began)
        timed = time_path(path.waypoints, self.limits.velocity, self.limits.acceleration, self.joints.path_clear)
        return ReachPlan(q, goal_array, path, timed, '', len(configurations), time.monotonic() - began)


@dataclass
class Followed:
    """follow_through_layer's answer: the way planned, the plans the layer sent (each followed from its start until
    the next one's), how many steps it refused, and where the arm comes to rest."""
    way: PlannedWay
    plans: list[Plan]
    refused: int
    end: np.ndarray


def follow_through_layer(setup: ReachSetup, goal, start, velocity_scale: float = DEFAULT_VELOCITY_SCALE,
                         period: float = 0.05, margin: float = DEFAULT_MARGIN, most: int = 3000) -> Followed:
    """What reach_controller does with a goal where the arm has a body, in-process: the way planned through its
    safety layer (ReachSetup.planned_way, PLAN_BUDGET motion checks), followed by the recovery's steps (recover_one,
    the policy asking nothing), every step made and checked by a SafetyLayer (a trajectory controller following
    its plans in time), and at the way's end the arm asked to hold there. No way: nothing sent."""
    limits = Limits.of(setup.arm, velocity_scale=velocity_scale)
    moving = setup.through(limits, period, margin)
    layer = SafetyLayer(limits, period, setup.body, margin)
    start = np.asarray(start, dtype=float)
    way = moving.planned_way(np.asarray(goal, dtype=float), start, PLAN_BUDGET)
    if not way.found:
        return Followed(way, [], 0, start)
    recovery, end = Recovery.along(way.points), way.points[-1]
    layer.plan(0.0, start, start)
    refused, t, nothing = 0, 0.0, [0.0] * len(setup.action_space.low)
    for _ in range(most):
        q = layer.commanded_at(t).tolist()
        target, recovery = moving.recover_one(q, moving.place_one(q)[0], q, nothing, list(goal), recovery)
        if recovery.state == RECOVERED:     # the policy has the arm again: here, asked to hold the way's end
            target = end
            if np.abs(layer.last.rest() - target).max() < 1e-9:
                break
        refused += bool(layer.plan(t, target, None).held)
        t += period
    return Followed(way, list(layer.history), refused, layer.last.rest())
