"""ReachEnv and ReachVectorEnv: any arm's reach task as gymnasium environments. No rospy.

    env = gymnasium.make('robot_ai/Reach-v0', model='/path/arm.urdf.xacro', tip='tool0')     # 50 steps
    envs = gymnasium.make_vec('robot_ai/Reach-v0', num_envs=4096)                            # ReachVectorEnv

The observation follows gymnasium-robotics' goal-env convention (FetchReach): ``Dict(achieved_goal=Box(3),
desired_goal=Box(3), observation=Box(n + 3))`` in float64, positions in metres in the arm's base frame; observation
holds the n joint positions (the arm's joints, in chain order), then the tip. ``compute_reward(achieved_goal,
desired_goal, info)`` is vectorised, so stable-baselines3's HER relabels goals on it as on FetchReach;
``info['is_success']`` is a tip within ``distance_threshold`` (0.05 m) of the goal.

Action: control='ee' (default): ``Box(-1, 1, (3,))``, a tip displacement of ``ee_step`` x action, turned into joint
motion by damped least squares on the analytic Jacobian, the joints then clipped to their limits; ``ee_step``
defaults to a twentieth of the chain's length, so that 50 steps cross any arm's workspace; limit_recovery (default
on): a step that a joint limit blocks, or an arm stalled away from the goal for a tenth of an episode, sends the arm,
in joint space, to a configuration that reaches the goal, once an episode (ReachSetup.recover), so that a goal beyond
a limit the way the arm stands, or past a local minimum of the pose error, is reached from wherever it starts.
control='joints':
``Box(-1, 1, (n,))``, joint displacements of 0.05 rad (or m) x action. Actions are clipped to [-1, 1]; NaN or
infinite ones are refused (ValueError).

Episode: reset draws the goal as the tip of a configuration uniform within the limits (every goal reachable), then
puts the arm at its start: start='home' (the middle of every joint's range, or ``home``), 'random' (uniform within
the limits, from the env's np_random) or 'chained' (where the last episode left the arm, home at the first: how
goals clicked one after another in rviz arrive). limit_avoidance (ee control; 0 = none, default 4): joint motion away
from the limits in the Jacobian's null space (Arm.move_t), which the tip does not feel; at 1 a joint at its limit
steps back as far as a joint turns for a full ee_step. 50 steps (TimeLimit); no termination on success (Fetch's
convention: the policy has to stay there). reward_type 'sparse': -1 outside the threshold, 0 inside; 'dense':
-distance.

Pose goals (goal='pose'): the goals, achieved and desired, are the tip's position and orientation, 7 numbers
``[x, y, z, qx, qy, qz, qw]`` (unit quaternion, qw >= 0), and observation holds the n joint positions, then the tip's
7; success is also an orientation within ``angle_threshold`` (0.1 rad; robot_ai.reach.task). ee control's action is
``Box(-1, 1, (6,))``: the tip's displacement (ee_step x the first three) and its turn about the base frame's axes
(``angle_step`` x the last three, 0.2 rad, in the base frame), solved together by damped least squares on the
6-row Jacobian, the turn's rows weighted by ee_step / angle_step metres per radian.

ReachVectorEnv computes its N arms in one numpy pass per step and equals gymnasium's SyncVectorEnv over N ReachEnvs
bit for bit (autoreset next-step, reset(seed=s) seeds env i with s + i).
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from robot_ai.motion.body import BodyError, CollisionModel, parse_obstacles
from robot_ai.reach.arm import LIMIT_TOLERANCE, Arm, ReachError
from robot_ai.reach.model import Model, load_model
from robot_ai.reach.safety import LEAD_PERIODS, Limits, read_joint_limits, step_end
from robot_ai.reach.task import (ANGLE_THRESHOLD, DISTANCE_THRESHOLD, ReachTask, goal_angle, goal_distance,
                                 goal_distance_one, quaternions_t, rotation_error)

CONTROLS = ('ee', 'joints')
STARTS = ('home', 'random', 'chained')
EPISODE_STEPS = 50
JOINT_STEP = 0.05            # rad (or m) per unit of a joints action
EE_STEP_FRACTION = 1 / 20    # of the chain's length: 50 steps cross the workspace
DAMPING_FRACTION = 0.5       # damped least squares' damping, in ee_steps
ANGLE_STEP = 0.2             # rad per unit of a pose goal's rotation action: pi in 16 steps
LIMIT_AVOIDANCE = 4.0        # ee control: the null-space step away from a joint limit, at the limit, in ee_step's turn
RENDER_FPS = 10
MAX_DRAWS = 1000             # draws of a goal or a start clear of collisions before the world is called too full
CONTROL_PERIOD = 0.05        # s: reach_controller's step (its ~rate, 20 Hz), an env step with velocity_scale
LAYER_EPISODE = 4            # with velocity_scale: episodes this many times as long, over the scale (10 s at 1.0)
# ee control's limit recovery (ReachSetup.recover): a step is blocked when the action asks for at least RECOVERY_ASK
# of a full step (or RECOVERY_ASK_OF_ERROR of the way to the goal, if that is less: a learned policy asks little near
# its goal), the arm is not at its goal, a joint of its answer is at a limit, and the tip moves less than
# RECOVERY_PROGRESS of the way asked;
# an arm is stalled when, asked as much, it is not at the goal and its dense error has not fallen STALL_GAIN of a full
# step below the least it reached for STALL_FRACTION of an episode's steps in which the action asked toward the goal
# (its cosine with the P-controller's at least STALL_COSINE): a local minimum, no limit in the way;
# the arm then goes in joint space to a configuration that reaches the goal (the P-controller's steps for
# RECOVERY_ITERATIONS from home and RECOVERY_SEEDS - 1 fixed postures), each joint at most RECOVERY_STEP of its half
# range a step, and the policy has the arm again once every joint is within RECOVERY_ARRIVED of its half range of it;
# with a body, to one clear of contacts on a way checked step by step, straight or through one via point
RECOVERY_ASK = 0.15
RECOVERY_ASK_OF_ERROR = 0.1
RECOVERY_PROGRESS = 0.3
RECOVERY_STEP = 0.15
RECOVERY_ARRIVED = 0.05
STALL_GAIN = RECOVERY_PROGRESS * RECOVERY_ASK
STALL_FRACTION = 0.1
STALL_BAND = 2.0
STALL_COSINE = 0.5
RECOVERY_SEEDS = 8
RECOVERY_ITERATIONS = 30
RECOVERY_STRIDE = 2.0        # ... in steps of up to this many full steps (a search, not a motion: the arm goes there
                             # in joint space, at RECOVERY_STEP)
RECOVERY_VIAS = 56           # with a body: fixed draws beside the seeds, clear of contacts, where a way round the
                             # obstacles and the arm's own links may pass (and the search starts from)
GUARD_SPACING = 0.04         # m: a step's motion is checked at configurations about this far apart along the body
GUARD_ARC = 1.25             # the longest path of a sphere over its chord that the checks allow for
GOAL_DRAWS = 4032            # postures (fixed draws) beyond recovery_seeds that a goal's clear configurations are
GOAL_ROUND = 48              # sought from, that many at a time, until one reaches clear of contacts (4,032: a UR5
                             # goal 15 cm above the table beside its base had 2 clear in 4,000 draws, none in 960)
GOAL_REACHING_ROUNDS = 5     # rounds after which a goal that no answer reaches at all is given up (beyond reach)
RECOVERY_PLAN_BUDGET = 300   # motion checks a planned way round may take (where the via points find none): a
RECOVERY_PLAN_TIME = 5.0     # budget, not a time, so that a loaded machine plays the same episodes; s at most
RECOVERY_PLAN_GOALS = 8      # reaching configurations the planner is given, the nearest first
SPREAD_SEARCH = 64           # and where it finds no way to them: reaching configurations sought from more postures,
SPREAD_GOALS = 16            # of which this many, spread from the nearest to the farthest, are given to it again
PLAN_BUDGET = 1500           # motion checks a goal's plan at an episode's start may take (plan_first; reach_controller
                             # plans so too: RRT-Connect's, twice where the first finds none: plan_path): 300 found 9 of
                             # 13 UR5 goals from random starts among a table and two objects, 3,000 at once 10, 1,500
                             # twice 14
MAX_REPLANS = 3              # an episode's (a goal's) tries to plan a way again after a collision held the arm (on
                             # a way, or the policy's arm short of the goal: ReachSetup.replanning)
FIRST_PLAN_TIME = 60.0       # s such a plan may take in the env: its budget bounds it (the same episodes on a loaded
                             # machine), the time only a stuck one
RECOVERY_PLAN_PADDING = 0.01  # m kept beyond way_margin by a planned way through a safety layer (velocity_scale)
RECOVERY_PLAN_SPACING = 0.01  # m: a planned way's checks at most this far apart along the body (its margin, if more)
LEAVING = 0.1                # m of body motion from a start within the padding where the way may keep less of it
READY, RECOVERING, RECOVERED = 0, 1, 2      # an arm's limit recovery in its episode


@dataclasses.dataclass(frozen=True)
class Recovery:
    """One arm's limit recovery in its episode (ReachSetup.recover_one): its state (READY, RECOVERING or
    RECOVERED), the configuration it goes to, the least dense error of the episode (lowered by STALL_GAIN of a
    full step or more at a time), the steps since then that asked toward the goal, the configuration it goes to
    after q (the end of its way; q itself when the way has no via point), and the way's points between q and then
    (a planned way: motion.JointPlanner's path, a step apart)."""
    state: int = READY
    q: tuple[float, ...] | None = None
    best: float = math.inf
    since: int = 0
    then: tuple[float, ...] | None = None
    way: tuple[tuple[float, ...], ...] = ()

    @classmethod
    def along(cls, points: np.ndarray) -> Recovery:
        """The arm on a planned way (its points after where it stands, (k, n)): to the first, then on to the last."""
        points = [tuple(p) for p in np.asarray(points, dtype=float).tolist()]
        return cls(RECOVERING, points[0], then=points[-1], way=tuple(points[1:-1]))

    def give_up(self) -> Recovery:
        """Recoveries.give_up for this arm, whose motion a collision refused: a way round it was on ends there (the
        policy has the arm again); the count of steps without progress goes on."""
        return dataclasses.replace(self, state=RECOVERED, way=()) if self.state == RECOVERING else self


@dataclasses.dataclass(frozen=True)
class PlannedWay:
    """ReachSetup.planned_way's answer: the way's points after the start (k, n; None without a way), how the planner
    found it ('straight': the straight motion was clear; 'RRTConnect': round the contacts) and the reason there is
    none (one line; '' with a way)."""
    points: np.ndarray | None
    how: str
    reason: str

    @property
    def found(self) -> bool:
        return self.points is not None


def _no_ways(count: int) -> np.ndarray:
    out = np.empty(count, dtype=object)
    out[:] = [() for _ in range(count)]
    return out


@dataclasses.dataclass
class Recoveries:
    """The limit recovery's state of a batch of arms (ReachSetup.recover), Recovery's fields as arrays on the
    batch's last axis: state (N,) int8, q (n, N), best (N,), since (N,) int32, then (n, N), way (N,) of tuples."""
    state: np.ndarray
    q: np.ndarray
    best: np.ndarray
    since: np.ndarray
    then: np.ndarray
    way: np.ndarray | None = None

    def __post_init__(self):
        if self.way is None:
            self.way = _no_ways(len(self.state))

    @classmethod
    def fresh(cls, n: int, count: int) -> Recoveries:
        return cls(np.full(count, READY, dtype=np.int8), np.zeros((n, count)), np.full(count, np.inf),
                   np.zeros(count, dtype=np.int32), np.zeros((n, count)))

    def __getitem__(self, rows) -> Recoveries:
        return Recoveries(self.state[rows], self.q[:, rows], self.best[rows], self.since[rows], self.then[:, rows],
                          self.way[rows])

    def __setitem__(self, rows, other: Recoveries) -> None:
        self.state[rows], self.q[:, rows], self.best[rows], self.since[rows] = (other.state, other.q, other.best,
                                                                                other.since)
        self.then[:, rows] = other.then
        self.way[rows] = other.way

    def planned(self) -> np.ndarray:
        """(N,) bool: the arms on a planned way (points of it still ahead)."""
        return np.fromiter((len(w) > 0 for w in self.way), dtype=np.bool_, count=len(self.way))

    def take(self, i: int, one: Recovery) -> None:
        """Arm i's state set to one's (a Recovery)."""
        self.state[i], self.best[i], self.since[i] = one.state, one.best, one.since
        if one.q is not None:
            self.q[:, i] = one.q
        if one.then is not None:
            self.then[:, i] = one.then
        self.way[i] = one.way

    def restart(self, rows) -> None:
        """A new episode for these arms."""
        self.state[rows], self.best[rows], self.since[rows] = READY, np.inf, 0
        self.way[rows] = _no_ways(len(self.state[rows]))

    def give_up(self, hit: np.ndarray | None) -> None:
        """Arms going to their configuration whose motion a collision refused: the policy has them again."""
        if hit is not None:
            gone = hit & (self.state == RECOVERING)
            self.state[gone] = RECOVERED
            self.way[gone] = _no_ways(int(gone.sum()))


def episode_steps(limits: Limits | None) -> int:
    """Steps an episode: 50, or through a safety layer of these limits as long in time. There a step covers about a
    quarter of an instant one at full speed (each step's target is followed two periods on, and each plan can stop
    at it), and velocity_scale of that when scaled."""
    if limits is None:
        return EPISODE_STEPS
    return math.ceil(EPISODE_STEPS * LAYER_EPISODE / limits.velocity_scale - 1e-9)


def stall_steps(steps: int) -> int:
    """The steps an arm stalls before the recovery takes it (ReachSetup.recover): a tenth of an episode of steps."""
    return max(2, round(STALL_FRACTION * steps))


class ReachSetup:
    """What ReachEnv and ReachVectorEnv share: the arm, the task, the control, the spaces, and the batched steps
    (every array with the batch on its last axis)."""

    def __init__(self, model: str | None = None, xacro_args=None, tip: str | None = None, control: str = 'ee',
                 start: str = 'home', reward_type: str = 'sparse', distance_threshold: float = DISTANCE_THRESHOLD,
                 ee_step: float | None = None, damping: float | None = None, home=None, urdf: str | None = None,
                 limit_avoidance: float = LIMIT_AVOIDANCE, obstacles=None, collision: bool | None = None,
                 goal: str = 'position', angle_threshold: float = ANGLE_THRESHOLD, angle_step: float | None = None,
                 velocity_scale: float | None = None, acceleration_scale: float | None = None, joint_limits=None,
                 control_period: float = CONTROL_PERIOD, limit_recovery: bool = True,
                 plan_first: bool | None = None):
        if control not in CONTROLS:
            raise ReachError(f'control must be one of {", ".join(CONTROLS)}, got {control!r}')
        if start not in STARTS:
            raise ReachError(f'start must be one of {", ".join(STARTS)}, got {start!r}')
        self.model: Model = load_model(model, xacro_args, urdf)
        self.arm = Arm(self.model.tree, tip)
        self.task = ReachTask(reward_type, distance_threshold, goal, angle_threshold)
        self.pose = goal == 'pose'
        self.control, self.start = control, start
        self.ee_step = self._positive('ee_step', ee_step, self.arm.length * EE_STEP_FRACTION)
        self.angle_step = self._positive('angle_step', angle_step, ANGLE_STEP)
        if self.angle_step > math.pi:
            raise ReachError(f'angle_step must be at most pi rad, got {angle_step!r}')
        # pose goals: the Jacobian's angular rows in metres, so that a full turn action weighs as a full move
        self.angular_weight = self.ee_step / self.angle_step
        self.damping = self._positive('damping', damping, self.ee_step * DAMPING_FRACTION)
        if isinstance(limit_avoidance, bool) or not isinstance(limit_avoidance, (int, float)) \
                or not 0 <= limit_avoidance <= 10:
            raise ReachError(f'limit_avoidance must be a number from 0 (none) to 10, got {limit_avoidance!r}')
        self.limit_avoidance = float(limit_avoidance)
        # at 1, a joint at its limit steps back as far as a joint turns in a full ee_step (ee_step / the chain)
        self.limit_gain = self.limit_avoidance * self.ee_step / self.arm.length
        if not isinstance(limit_recovery, (bool, np.bool_)):
            raise ReachError(f'limit_recovery must be true or false, got {limit_recovery!r}')
        self.limit_recovery = bool(limit_recovery) and control == 'ee'
        self.home = self._home(home)
        # the postures the recovery seeks a goal's configuration from: home, then fixed draws within the limits
        draws = np.random.default_rng(0).uniform(self.arm.lower, self.arm.upper, (RECOVERY_SEEDS - 1, self.arm.n))
        self.recovery_seeds = np.ascontiguousarray(np.vstack((self.home[None], draws)).T)
        self.limits: Limits | None = None        # the safety layer's, when the env models it (velocity_scale)
        self.joint_limits = read_joint_limits(joint_limits)
        self.control_period = self._positive('control_period', control_period, CONTROL_PERIOD)
        if velocity_scale is not None:
            self.limits = Limits.of(self.arm, {'joint_limits': self.joint_limits} if self.joint_limits else None,
                                    velocity_scale, acceleration_scale)
        elif self.joint_limits or acceleration_scale is not None:
            raise ReachError('joint_limits and acceleration_scale are the safety layer\'s: give velocity_scale too '
                             '(1.0: the limits unscaled)')
        self.episode_steps = episode_steps(self.limits)
        self.stall_steps = stall_steps(self.episode_steps)
        try:
            self.obstacles = parse_obstacles(obstacles)
        except BodyError as e:
            raise ReachError(str(e)) from None
        self.way_margin = 0.0       # metres the recovery's ways keep clear of contacts (through a layer: its margin)
        self._planner = None        # (way_margin, motion.JointPlanner): the recovery's planned ways, made when needed
        self._goal_draws = None     # (n, GOAL_DRAWS): postures a goal's clear configurations are sought from
        if collision is None:
            collision = bool(self.obstacles)
        if not isinstance(collision, (bool, np.bool_)):
            raise ReachError(f'collision must be true or false, got {collision!r}')
        self.body: CollisionModel | None = None
        if collision:
            try:
                self.body = CollisionModel(self.model.tree, self.model.urdf, self.arm, self.obstacles,
                                           urdf_dir=os.path.dirname(self.model.path) if self.model.path else '')
            except BodyError as e:
                raise ReachError(str(e)) from None
            touching = self.body.contacts(self.home)
            if touching:
                raise ReachError(f'home is in collision: {", ".join(touching[:4])} (move the obstacles, or give a '
                                 f'home that is clear of them)')
            # the recovery's via points round the obstacles and the arm's own links: fixed draws clear of them
            draws = np.random.default_rng(1).uniform(self.arm.lower, self.arm.upper, (RECOVERY_VIAS, self.arm.n))
            vias = np.vstack((self.recovery_seeds.T, draws))
            self.recovery_vias = np.ascontiguousarray(vias[~self.body.in_collision(vias)].T)
        if plan_first is not None and not isinstance(plan_first, (bool, np.bool_)):
            raise ReachError(f'plan_first must be true or false, got {plan_first!r}')
        if plan_first and self.body is None:
            raise ReachError('plan_first plans round the arm\'s body: give collision=True (or obstacles)')
        self.plan_first = None if plan_first is None else bool(plan_first)
        bound = self.arm.radius + 1e-6
        goal_low = np.full(3, -bound) if not self.pose else np.concatenate((np.full(3, -bound), -np.ones(4)))
        goal_high = -goal_low
        goal_space = spaces.Box(goal_low, goal_high, dtype=np.float64)
        low = np.concatenate((self.arm.lower, goal_low))
        high = np.concatenate((self.arm.upper, goal_high))
        self.observation_space = spaces.Dict(achieved_goal=goal_space, desired_goal=goal_space,
                                             observation=spaces.Box(low, high, dtype=np.float64))
        size = (6 if self.pose else 3) if control == 'ee' else self.arm.n
        self.action_space = spaces.Box(-1.0, 1.0, (size,), np.float32)

    @staticmethod
    def _positive(name: str, value, default: float) -> float:
        if value is None:
            return float(default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float('inf'):
            raise ReachError(f'{name} must be a positive number, got {value!r}')
        return float(value)

    def _home(self, home) -> np.ndarray:
        return self.arm.home.copy() if home is None else self.configuration(home, 'home', self.arm.home)

    def configuration(self, values, what: str, default: np.ndarray | None = None) -> np.ndarray:
        """Joint positions (n,) within the limits from a list in the arm's order or a dict by joint name (the others
        from default); ReachError of one line naming `what` otherwise."""
        arm = self.arm
        if isinstance(values, dict):
            unknown = sorted(set(values) - set(arm.joints))
            if unknown:
                raise ReachError(f'{what} names joints the arm does not have: {", ".join(unknown)} (its joints: '
                                 f'{", ".join(arm.joints)})')
            missing = [n for n in arm.joints if n not in values]
            if missing and default is None:
                raise ReachError(f'{what} must name every joint: {", ".join(missing)} missing')
            try:
                fallback = arm.home if default is None else default
                out = np.array([float(values.get(n, d)) for n, d in zip(arm.joints, fallback)])
            except (TypeError, ValueError):
                raise ReachError(f'{what} must map joint names to numbers') from None
        else:
            try:
                out = np.asarray(values, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise ReachError(f'{what} must be {arm.n} joint positions ({", ".join(arm.joints)})') from None
            if out.shape != (arm.n,):
                raise ReachError(f'{what} must be {arm.n} joint positions ({", ".join(arm.joints)}), got {out.size}')
        outside = [f'{n} {v:g} not in [{lo:g}, {hi:g}]'
                   for n, v, lo, hi in zip(arm.joints, out, arm.lower, arm.upper) if not lo <= v <= hi]
        if outside:
            raise ReachError(f'{what} outside the joint limits: {"; ".join(outside)}')
        return out

    def goal_text(self) -> str:
        return (f'[x, y, z, qx, qy, qz, qw] in {self.arm.base}' if self.pose else f'[x, y, z] in {self.arm.base}')

    def check_goal(self, value, what: str) -> list[float]:
        """A goal given by a user: x, y, z (metres, in the base frame; any finite numbers: a goal out of reach is
        the user's to try), and for pose goals a quaternion qx, qy, qz, qw of any non-zero length, returned as a
        unit one with qw >= 0; ReachError of one line naming `what` otherwise."""
        try:
            g = np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            g = np.zeros(0)
        size = self.task.size
        if g.shape != (size,) or not np.isfinite(g).all():
            raise ReachError(f'{what} must be {size} finite numbers ({self.goal_text()}, metres), got '
                             f'{str(value)[:80]}')
        if self.pose:
            norm = float(np.linalg.norm(g[3:]))
            if norm < 1e-6:
                raise ReachError(f'{what}: the quaternion {g[3:].tolist()} has no length (a unit quaternion '
                                 f'qx, qy, qz, qw is an orientation; 0, 0, 0, 1 is the base frame\'s)')
            g[3:] = g[3:] / norm * (-1.0 if g[6] < 0 else 1.0)
        return g.tolist()

    def obstacle_holding(self, goal, within_reach: bool = False) -> str | None:
        """The name of the obstacle a goal's point is inside, or None (goals inside one are refused, by the env's
        options and by reach_controller, and never drawn). within_reach: only the obstacles the arm's body can
        reach (a drawn goal is a tip's position: thousands of far ones need no look)."""
        obstacles = self.body.obstacles if within_reach and self.body is not None else self.obstacles
        return next((o.name for o in obstacles if o.contains(goal[:3])), None)

    def reset_options(self, options: dict, goal: list, q: list) -> tuple[list, list]:
        """(goal, start configuration) of an episode with reset options: 'goal' (check_goal's) and 'q' (joint
        positions, as `configuration` takes them) replace the drawn ones."""
        unknown = sorted(set(options) - {'goal', 'q'})
        if unknown:
            raise ReachError(f'reset options are goal ({self.goal_text()}) and q (joint positions), got '
                             f'{", ".join(map(str, unknown))}')
        if options.get('goal') is not None:
            goal = self.check_goal(options['goal'], 'options goal')
            inside = self.obstacle_holding(goal)
            if inside is not None:        # as reach_controller, which ignores such a goal: the two agree
                raise ReachError(f'options goal ({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) is inside {inside}: '
                                 f'no tip reaches it')
        if options.get('q') is not None:
            q = self.configuration(options['q'], 'options q').tolist()
        return goal, q

    def settings(self) -> dict:
        """The env's kwargs as plain values (a policy file keeps them)."""
        out = dict(tip=self.arm.tip, control=self.control, start=self.start, reward_type=self.task.reward_type,
                   distance_threshold=self.task.distance_threshold, ee_step=self.ee_step, damping=self.damping,
                   home=[float(v) for v in self.home], limit_avoidance=self.limit_avoidance,
                   limit_recovery=self.limit_recovery)
        if self.body is not None:         # the world a policy learned in (files without these: none)
            out.update(collision=True, obstacles=[json.dumps(o.spec) for o in self.obstacles])
        if self.pose:                     # files without these: position goals
            out.update(goal='pose', angle_threshold=self.task.angle_threshold, angle_step=self.angle_step)
        if self.limits is not None:       # files without these: joints moved at once
            out.update(velocity_scale=self.limits.velocity_scale, acceleration_scale=self.limits.acceleration_scale,
                       control_period=self.control_period)
            if self.joint_limits:
                out['joint_limits'] = {'joint_limits': self.joint_limits}
        return out

    # ---------------------------------------------------------------------------- the safety layer's motion
    def through(self, limits: Limits, control_period: float = CONTROL_PERIOD, margin: float = 0.0) -> ReachSetup:
        """This setup with the arm moved through a safety layer of these limits (what velocity_scale and
        joint_limits make), without loading the model again: a node's prediction of its own arm. margin: the
        metres the layer keeps clear of contacts, which the recovery's ways keep too (recovery_way)."""
        out = copy.copy(self)
        out.limits, out.way_margin = limits, float(margin)
        out.control_period = self._positive('control_period', control_period, CONTROL_PERIOD)
        out.episode_steps = episode_steps(limits)
        out.stall_steps = stall_steps(out.episode_steps)
        return out

    @property
    def joint_weights(self) -> np.ndarray | None:
        """(n,) through a safety layer: each joint's velocity limit over the fastest one's, move's weights (the layer
        moves each joint within its own limit, so a joint asked for more than its share lags, and the tip goes
        elsewhere than the step asked: the PR2's torso, 0.013 m/s beside 2 rad/s, took the tip 30 cm off a goal it
        had reached); None without a layer (every joint alike)."""
        if self.limits is None:
            return None
        return self.limits.velocity / self.limits.velocity.max()

    @property
    def plans_first(self) -> bool:
        """Each episode's goal is planned at its start and the arm follows the way first, the policy then (as
        reach_controller drives a goal): plan_first, by default where the arm has a body and moves through a
        safety layer."""
        return self.body is not None and (self.limits is not None if self.plan_first is None else self.plan_first)

    def first_way(self, goal, q) -> Recovery:
        """An episode's start where the setup plans first: the arm on its planned way from q (n,) to goal
        (planned_way within PLAN_BUDGET motion checks, as reach_controller plans); a fresh Recovery (the policy
        drives) where it does not plan first or finds no way."""
        if not self.plans_first:
            return Recovery()
        way = self.planned_way(np.asarray(goal, dtype=float), np.asarray(q, dtype=float), PLAN_BUDGET,
                               FIRST_PLAN_TIME)
        return Recovery.along(way.points) if way.found else Recovery()

    def replanning(self, on_way, tip_t: np.ndarray, goal_t: np.ndarray) -> np.ndarray:
        """(N,): whether arms a collision holds get a way planned again from where they stand (MAX_REPLANS tries a
        goal at most; the envs' rule where they plan first, and reach_controller's): held on a way (on_way (N,)), or
        with the policy driving and the tip (size, N) not at the goal: a policy that had the arm after its way, or
        whose start had none, pressed on into a box for the rest of the episode (2 of the UR5's 3 misses from 200
        random starts through the layer, 3 of the PR2's 4)."""
        return np.asarray(on_way) | ~self.task.is_success(tip_t.T, goal_t.T)

    def motion_start(self, q_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(velocities (n, N), the targets already sent (LEAD_PERIODS, n, N)) of arms at rest at q_t."""
        return np.zeros_like(q_t), np.repeat(q_t[None], LEAD_PERIODS, axis=0)

    def advance(self, q_t: np.ndarray, v_t: np.ndarray, sent_t: np.ndarray,
                target_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One control period of arms (n, N) driven through reach_controller's safety layer: each step's target
        (the joints the action asks for) is planned LEAD_PERIODS periods on, as the layer plans it (a command
        reaches the arm before it starts), so that this period the arm moves toward the target of LEAD_PERIODS
        steps ago, within the velocity, acceleration and position limits (safety.step_end). (positions,
        velocities, the targets sent)."""
        target_t = np.minimum(np.maximum(target_t, self.limits.lower[:, None]), self.limits.upper[:, None])
        q_t, v_t = step_end(q_t, v_t, sent_t[0], self.limits, self.control_period)
        return q_t, v_t, np.concatenate((sent_t[1:], target_t[None]))

    # -------------------------------------------------------------------------------- batched steps
    def check_actions(self, actions: np.ndarray) -> np.ndarray:
        """Actions (N, a) as float64 clipped to [-1, 1]; ValueError for NaN or infinite ones."""
        if not np.isfinite(actions).all():
            raise ValueError(f'an action must be finite numbers in [-1, 1], got {actions.tolist()[:4]}')
        return np.clip(actions, -1.0, 1.0)

    def check_action_one(self, action) -> list[float]:
        """One action as floats clipped to [-1, 1] (check_actions' numbers); ValueError as there."""
        shape = getattr(action, 'shape', None)
        if shape == self.action_space.shape and getattr(action, 'dtype', None) in (np.float32, np.float64):
            values = [float(v) for v in action.tolist()]      # an agent's array: no copy to float64 first
        else:
            a = np.asarray(action, dtype=np.float64)
            if a.shape != self.action_space.shape:
                raise ValueError(f'an action is {self.action_space.shape[0]} numbers in [-1, 1], got shape '
                                 f'{a.shape}')
            values = a.tolist()
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'an action must be finite numbers in [-1, 1], got {values[:4]}')
        return [min(max(v, -1.0), 1.0) for v in values]

    def first_states(self, rngs: list, where: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(goal configurations, start configurations), each (n, k), drawn from each env's np_random in turn.
        start 'chained': each env's start is where its arm stands (where[i], (n,)), home where that is None."""
        goals = self._clear([lambda rng=rng: self.task.goal_configuration(self.arm, rng) for rng in rngs],
                            goal=True)
        starts = []
        for i, rng in enumerate(rngs):
            if self.start == 'random':
                starts.append(lambda rng=rng: rng.uniform(self.arm.lower, self.arm.upper))
            elif self.start == 'chained' and where is not None and where[i] is not None:
                starts.append(lambda q=where[i]: q)
            else:
                starts.append(lambda: self.home)
        starts = self._clear(starts) if self.start == 'random' else [draw() for draw in starts]
        return np.ascontiguousarray(np.array(goals).T), np.ascontiguousarray(np.array(starts).T)

    def _clear(self, draws: list, goal: bool = False) -> list:
        """One configuration from each draw (a function of its env's generator), drawn again while the arm would be
        in collision there (with a body), or with goal, while its tip is inside an obstacle (a tip that is no body's
        link, a TCP frame, can be clear of collisions there): every env's draws come in the order a single env makes
        them."""
        out = [draw() for draw in draws]
        if self.body is None:
            return out
        waiting = list(range(len(out)))
        for _ in range(MAX_DRAWS):
            hits = self.body.in_collision(np.array([out[i] for i in waiting]))
            if goal and self.obstacles:
                tips = self.goals_of(np.array([out[i] for i in waiting]).T)
                hits = [bool(hit) or self.obstacle_holding(tips[:, k], within_reach=True) is not None
                        for k, hit in enumerate(hits)]
            waiting = [i for i, hit in zip(waiting, hits) if hit]
            if not waiting:
                return out
            for i in waiting:
                out[i] = draws[i]()
        raise ReachError(f'no configuration clear of collisions in {MAX_DRAWS} draws: the obstacles fill the arm\'s '
                         f'workspace')

    def guard_one(self, before: list, after: list) -> tuple[list, bool | None]:
        """guard's rule for one arm in plain floats: (the joint positions it takes, collision or None without a
        body)."""
        if self.body is None:
            return after, None
        hit = bool(self._motion_hits(np.array(before, dtype=np.float64)[:, None],
                                     np.array(after, dtype=np.float64)[:, None])[0])
        return (before if hit else after), hit

    def guard(self, before_t: np.ndarray, after_t: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(joint positions (n, N), collision (N,) or None without a body): a motion that would put the arm in
        contact with itself or an obstacle, at its end or on its way there (_motion_hits), is not made, and that arm
        holds where it was."""
        if self.body is None:
            return after_t, None
        hit = self._motion_hits(before_t, after_t)
        if hit.any():
            after_t = after_t.copy()
            after_t[:, hit] = before_t[:, hit]
        return after_t, hit

    def _motion_hits(self, before_t: np.ndarray, after_t: np.ndarray, padding: float = 0.0) -> np.ndarray:
        """(N,): the straight motions before_t -> after_t (n, N) touch (or come within padding), checked at the end
        and at as many configurations on the way as keep the body's spheres within about GUARD_SPACING of a checked
        place: their farthest move from one end to the other (a chord) times GUARD_ARC (the arc a turning joint
        takes is longer than its chord: by 3 % at 0.9 rad), split evenly. A step between two clear configurations
        went 15.6 cm into a box when only its end was checked. Each arm's checks are its own (its count from its
        own motion): the same in any batch."""
        body = self.body
        n = after_t.shape[1]
        centres = body.sphere_centres(np.concatenate((after_t, before_t), axis=1).T)[:, body.moving_spheres]
        moved = centres[:n] - centres[n:]
        chord = np.sqrt((moved * moved).sum(axis=2)).max(axis=1) if moved.shape[1] else np.zeros(n)
        counts = np.maximum(1, np.ceil(GUARD_ARC * chord / GUARD_SPACING)).astype(int)
        if (counts == 1).all():
            return body.in_collision(after_t.T, padding)
        delta = after_t - before_t
        arm = np.repeat(np.arange(len(counts)), counts)
        share = (np.arange(len(arm)) - np.repeat(np.cumsum(counts) - counts, counts) + 1) / counts[arm]
        q = before_t[:, arm] + delta[:, arm] * share
        q[:, share == 1.0] = after_t[:, arm[share == 1.0]]       # the end exactly where the motion ends
        hits = body.in_collision(q.T, padding)
        return np.logical_or.reduceat(hits, np.cumsum(counts) - counts)

    def goals_of(self, q_t: np.ndarray) -> np.ndarray:
        """The goals (size, N) the tip achieves at joint positions q_t (n, N): its position, or its pose."""
        if self.pose:
            tip, rotation, _, _ = self.arm.pose_t(q_t)
            return np.concatenate((tip, quaternions_t(rotation)))
        return self.arm.forward(q_t, with_axes=False)[0]

    def place(self, q_t: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(tip (size, N): the achieved goal, Jacobian (3 or 6, n, N) for ee control, else None) of joint positions
        q_t (n, N)."""
        if self.pose:
            tip, rotation, axes, origins = self.arm.pose_t(q_t)
            pose = np.concatenate((tip, quaternions_t(rotation)))
            if self.control == 'ee':
                return pose, self.arm.jacobian6_t(tip, axes, origins, self.angular_weight)
            return pose, None
        if self.control == 'ee':
            tip, axes, origins = self.arm.forward(q_t)
            return tip, self.arm.jacobian_t(tip, axes, origins)
        return self.arm.forward(q_t, with_axes=False)[0], None

    def move(self, q_t: np.ndarray, jac_t: np.ndarray | None, actions_t: np.ndarray) -> np.ndarray:
        """Joint positions (n, N) after actions_t (a, N), within the limits. Pose goals: the turn's rows are in
        metres already (angular_weight), so that the six rows move by ee_step x action. Through a safety layer each
        joint's share of the motion is weighted by its velocity limit (joint_weights)."""
        if self.control == 'ee':
            return self.arm.move_t(q_t, jac_t, actions_t * self.ee_step, self.damping, limit_gain=self.limit_gain,
                                   weights=self.joint_weights)
        return self.arm.clip(q_t + actions_t * JOINT_STEP)

    def recover(self, q_t: np.ndarray, tip_t: np.ndarray, target_t: np.ndarray, actions_t: np.ndarray,
                goal_t: np.ndarray, rec: Recoveries) -> tuple[np.ndarray, Recoveries]:
        """ee control's limit recovery: (targets (n, N), the recovery's state after the step) of arms at q_t (n, N)
        with their tips (achieved goals) tip_t (size, N), whose actions_t (a, N) moved gave target_t (move's), their
        goals goal_t (size, N); rec is each arm's state in its episode (READY, RECOVERING, or RECOVERED: once an
        episode; Recoveries).

        Damped least squares is local: from a start whose joints lie on the wrong side of the goal (a base turned
        toward its limit the short way round, a shoulder against its stop under a goal overhead) it pushes a joint
        onto its limit and the tip stalls there, however the policy acts; away from the limits, a pose goal's
        position and turn can hold each other in a local minimum (the UR5 from home, 10 % of goals). A step whose
        action asks for at least RECOVERY_ASK of a full step, or RECOVERY_ASK_OF_ERROR of the dense error if that is
        less (ARS's gain is a fraction of the P-controller's: a KUKA KR210's policy asked for a few centimetres at a
        limit 5-13 cm short, and was never taken), is blocked when the arm is not at its goal, a joint of its answer
        is at a limit and the tip moves less than RECOVERY_PROGRESS of the way asked, along it; an arm so asked is
        stalled when
        stall_steps steps in a row (a tenth of an episode) tried, asking toward the goal (_stall_count), and its
        dense error did not fall STALL_GAIN of a full step below the least it reached nor rise STALL_BAND full steps
        above it (an arm going the long way round is going somewhere), short of the goal (an arm that a collision
        holds stalls so). The arm then goes in joint space (a straight line within the limits' box, which no limit
        blocks) to reaching_configuration's answer, each joint at most RECOVERY_STEP of its half range a step, and
        the policy has it again there (or once a collision refuses the way: Recoveries.give_up). With a body, it goes
        to recovery_way's answer: a reaching configuration clear of contacts, on a way whose every step is clear,
        through a via point where the straight way touches (the next leg starts once the arm itself is there). A
        stalled arm for whose goal no configuration is found (a goal beyond its reach) stays where it is: the
        recovery is spent for the episode. An arm's result does not depend on its batch."""
        if not self.limit_recovery and not (rec.state == RECOVERING).any():
            return target_t, rec         # a way given from outside (reach_controller's plan) is followed all the same
        arm = self.arm
        asked = actions_t * self.ee_step
        asked2 = (asked * asked).sum(axis=0)
        error = self.task.error(tip_t.T, goal_t.T)
        best, since = self._stall_count(error, tip_t, goal_t, actions_t, rec.best, rec.since)
        rec = Recoveries(rec.state.copy(), rec.q, best, since, rec.then, rec.way.copy())
        least = np.minimum(RECOVERY_ASK * self.ee_step, RECOVERY_ASK_OF_ERROR * error)
        ready = (rec.state == READY) & (asked2 >= least * least) & self.limit_recovery
        at_limit = ((target_t <= arm.lower[:, None] + LIMIT_TOLERANCE)
                    | (target_t >= arm.upper[:, None] - LIMIT_TOLERANCE)).any(axis=0)
        check = np.flatnonzero(ready & at_limit)
        if len(check):                  # an arm at its goal needs no way round (its small steps near it count)
            check = check[~self.task.is_success(tip_t[:, check].T, goal_t[:, check].T)]
        blocked = check[:0]
        if len(check):
            moved = self._tip_motion(q_t[:, check], target_t[:, check])
            blocked = check[(moved * asked[:, check]).sum(axis=0) < RECOVERY_PROGRESS * asked2[check]]
        stalled = np.flatnonzero(ready & (rec.since >= self.stall_steps))
        if len(stalled):
            stalled = stalled[~self.task.is_success(tip_t[:, stalled].T, goal_t[:, stalled].T)]
        going = np.union1d(blocked, stalled)
        if len(going):
            rec.q, rec.then = rec.q.copy(), rec.then.copy()
            via, to, ways = self.recovery_way(goal_t[:, going], q_t[:, going], with_ways=True)
            rec.q[:, going], rec.then[:, going] = via, to
            rec.way[going] = ways
            # a stall where no configuration reaches (a goal beyond the arm's reach): nowhere to go, this episode
            hopeless = ~np.isin(going, blocked) & ~self.task.is_success(self.goals_of(to).T, goal_t[:, going].T)
            rec.state[going] = np.where(hopeless, RECOVERED, RECOVERING)
        recovering = rec.state == RECOVERING
        if not recovering.any():
            return target_t, rec
        half = arm._half[:, None]
        # at its via point (the arm itself, which a safety layer may bring there later than its targets): onward
        # (a planned way's next point, then its end)
        more = rec.planned()
        onward = recovering & ((rec.then != rec.q).any(axis=0) | more) & (
            np.abs(rec.q - q_t) <= RECOVERY_ARRIVED * half).all(axis=0)
        if onward.any():
            rec.q = rec.q.copy()
            for i in np.flatnonzero(onward):
                if more[i]:
                    rec.q[:, i], rec.way[i] = rec.way[i][0], rec.way[i][1:]
                else:
                    rec.q[:, i] = rec.then[:, i]
            more = rec.planned()
        step = np.minimum(np.maximum(rec.q - q_t, -RECOVERY_STEP * half), RECOVERY_STEP * half)
        back = q_t + step
        done = recovering & (rec.then == rec.q).all(axis=0) & ~more & (
            np.abs(rec.q - back) <= RECOVERY_ARRIVED * half).all(axis=0)
        rec.state = np.where(done, RECOVERED, rec.state).astype(np.int8)
        return np.where(recovering, back, target_t), rec

    def reaching_configuration(self, goal_t: np.ndarray, q_t: np.ndarray) -> np.ndarray:
        """(n, M): for each goal (size, M), a configuration within the limits that reaches it: the P-controller's
        steps in this action space from each of recovery_seeds (home, then fixed postures), up to
        RECOVERY_ITERATIONS, until one of them is well within the thresholds; of those that are, the nearest to q_t
        (n, M). From one of several starts the local steps find a way round the limits (or out of a local minimum)
        that they cannot find from where the arm stands. Where none reaches, the answer that comes nearest. A
        search costs as many steps as it takes, whatever the batch: stopping at the first answer (not the last
        iteration) halved an evaluation's time on pose goals."""
        q, reached, error, far = self._reaching_search(goal_t, q_t, self.recovery_seeds, clear=False)
        best = np.where(reached.any(axis=0), np.where(reached, far, np.inf).argmin(axis=0), error.argmin(axis=0))
        return np.ascontiguousarray(q[:, best, np.arange(goal_t.shape[1])])

    def _reaching_search(self, goal_t: np.ndarray, q_t: np.ndarray, seeds: np.ndarray,
                         clear: bool, each: bool = False) -> tuple[np.ndarray, ...]:
        """reaching_configuration's search from seeds (n, k), a goal's stopping once one answer is well within the
        thresholds (and, clear, clear of collisions; each: every answer going on until it is itself well within):
        (configurations (n, k, M), reached (k, M), error (k, M), squared distance from q_t in half ranges (k, M))."""
        n, k, m = self.arm.n, seeds.shape[1], goal_t.shape[1]
        steps = self._tip_steps()
        q = np.repeat(seeds, m, axis=1)                 # column i * m + j: seed i, goal j
        goal = np.tile(goal_t, (1, k))
        going = np.arange(k * m)      # a goal's columns stop once one is well within the thresholds (batch-free)
        found = np.zeros(m, dtype=np.bool_)
        for _ in range(RECOVERY_ITERATIONS):
            tip, jac = steps.place(q[:, going])
            there = self._well_within(tip, goal[:, going])
            if there.any():
                on = np.ones(len(going), dtype=np.bool_)
                if clear:           # an answer that touches stops there too, and its goal's search goes on
                    on[there] = False
                    there[there] = ~self.body.in_collision(q[:, going[there]].T, self.way_margin)
                if each:
                    on &= ~there
                else:
                    found[going[there] % m] = True
                    on &= ~found[going % m]
                going, tip, jac = going[on], tip[:, on], jac[..., on]
                if not len(going):
                    break
            q[:, going] = steps.move(q[:, going], jac, steps._p_action(tip, goal[:, going], RECOVERY_STRIDE))
        achieved = self.goals_of(q)
        reached, error = self.task.is_success(achieved.T, goal.T), self.task.error(achieved.T, goal.T)
        q = q.reshape(n, k, m)
        far = (((q - q_t[:, None, :]) / self.arm._half[:, None, None]) ** 2).sum(axis=0)
        return q, reached.reshape(k, m), error.reshape(k, m), far

    def _tip_steps(self) -> ReachSetup:
        """The setup whose steps the reaching search takes (the P-controller's on the tip): this one, or with joints
        control its twin with ee control (a joints policy's arm planned for: its goal configurations are found so)."""
        if self.control == 'ee':
            return self
        twin = copy.copy(self)
        twin.control = 'ee'
        return twin

    def recovery_way(self, goal_t: np.ndarray, q_t: np.ndarray, with_ways: bool = False) -> tuple[np.ndarray, ...]:
        """(via, to), each (n, M) (with_ways: and the ways' points between, (M,) of tuples): where the recovery
        takes arms at q_t (n, M) for goals goal_t (size, M): to is reaching_configuration's answer and via is to,
        without a body. With one, a goal's search stops once an
        answer reaches it clear of contacts, and where no way to its answers from recovery_seeds is clear, it
        starts again from every one of recovery_vias (from the seeds alone, every answer touched a box for 25 of 29
        goals missed among test/world.yaml, when the search stopped at any answer). Then to is the
        nearest such answer whose way (the recovery's own steps, every one checked, way_margin kept) is clear, and
        via is to; else, the nearest whose way through one of recovery_vias (there, then on) is, and via is that
        point (the shorter way first). Where no way is clear, a planned one (motion.JointPlanner: OMPL's RRT-Connect
        over the body, way_margin kept, at most RECOVERY_PLAN_BUDGET motion checks) to the nearest answers, its
        points a recovery step apart so that each step goes straight along the planned path (through a safety layer,
        a period's travel apart and RECOVERY_PLAN_PADDING more kept): via is its first point and the way's points
        follow (with_ways). Where none is found either, the nearest answer, straight (a collision will refuse
        it and the policy has the arm again: Recoveries.give_up). Arm by arm: an arm's way does not depend on its
        batch."""
        ways = _no_ways(q_t.shape[1])
        if self.body is None:
            to = self.reaching_configuration(goal_t, q_t)
            return (to, to, ways) if with_ways else (to, to)
        via, to = np.empty_like(q_t), np.empty_like(q_t)
        left = np.arange(q_t.shape[1])
        if self.limits is not None:     # through a safety layer: a planned way first, whose points a period apart
            # the layer's steps follow (two straight legs, each joint on its own trapezoid, left them by centimetres)
            left = left[~self._take_planned_ways(goal_t, q_t, left, via, to, ways)]
        for seeds in (self.recovery_seeds, self.recovery_vias):     # the few seeds first: most goals need no more
            if not len(left):
                break
            q, reached, error, far = self._reaching_search(goal_t[:, left], q_t[:, left], seeds, clear=True)
            orders = []
            for i in range(len(left)):                 # each arm's answers, the nearest reaching one first
                order = np.flatnonzero(reached[:, i])
                orders.append(order[np.argsort(far[order, i], kind='stable')] if len(order)
                              else np.array([error[:, i].argmin()]))
            owner = np.repeat(np.arange(len(left)), [len(order) for order in orders])
            ends = np.concatenate([q[:, order, i] for i, order in enumerate(orders)], axis=1)
            clear = ~self.body.in_collision(ends.T, self.way_margin)
            nearest = {}                       # each arm's nearest answer clear of contacts: its straight way first,
            for k in np.flatnonzero(clear):    # all arms at once
                nearest.setdefault(owner[k], k)
            tried = np.array(list(nearest.values()), dtype=np.intp)
            straight = np.zeros(len(owner), dtype=np.bool_)
            straight[tried] = self._way_clear(q_t[:, left[owner[tried]]], ends[:, tried])[0]
            found = np.zeros(len(left), dtype=np.bool_)
            for i, j in enumerate(left):
                mine = np.flatnonzero((owner == i) & clear)
                if len(mine) and straight[mine[0]]:
                    way = ends[:, mine[0]], ends[:, mine[0]]
                else:
                    way = self._clear_way(q_t[:, j], ends[:, mine])
                found[i] = way is not None
                first = q[:, orders[i][0], i]
                via[:, j], to[:, j] = way if found[i] else (first, first)
            left = left[~found]
            if not len(left):
                break
        self._take_planned_ways(goal_t, q_t, left, via, to, ways)
        return (via, to, ways) if with_ways else (via, to)

    def _take_planned_ways(self, goal_t: np.ndarray, q_t: np.ndarray, arms: np.ndarray, via: np.ndarray,
                           to: np.ndarray, ways: np.ndarray) -> np.ndarray:
        """(len(arms),) bool: the arms (columns of goal_t and q_t) a planned way was found for, whose via (its first
        point), to (its last) and ways (the points between) are set."""
        found = np.zeros(len(arms), dtype=np.bool_)
        for i, j in enumerate(arms):
            way = self._planned_way(goal_t[:, j], q_t[:, j])
            if way is not None:
                via[:, j], ways[j], to[:, j] = way[0], tuple(map(tuple, way[1:-1])), way[-1]
                found[i] = True
        return found

    def clear_reaching_configurations(self, goal: np.ndarray, q: np.ndarray, margin: float,
                                      box=None, least: int = 1) -> tuple[np.ndarray, float]:
        """(configurations (m, n) within box's lower and upper (the arm's limits by default) that reach goal clear
        of contacts by margin, the nearest to q (n,) first; the least error found): the search's steps from where the
        arm stands, home and recovery_seeds, then from GOAL_ROUND of GOAL_DRAWS fixed postures at a time until one
        answer is clear, or `least` are (after GOAL_REACHING_ROUNDS rounds, only while some answer reaches the goal at
        all, and well within the thresholds). Each answer is taken on until it is well within them (_polished); only
        where none of those is clear, the answers as they came (a goal beside a ball). A joint whose range is more
        than a turn (a UR's +-2 pi) is taken at the turn nearest to q: the same pose, but a shoulder at 6.03 rad from
        -1.57 must pass through the table to get there, where -0.25 need not."""
        box = box if box is not None else self.arm
        if self._goal_draws is None:
            self._goal_draws = np.random.default_rng(2).uniform(self.arm.lower, self.arm.upper,
                                                                (GOAL_DRAWS, self.arm.n)).T
        q = np.asarray(q, dtype=float)
        seeds = np.hstack((q[:, None], self.recovery_seeds))
        parts = [seeds] + [self._goal_draws[:, k:k + GOAL_ROUND] for k in range(0, GOAL_DRAWS, GOAL_ROUND)]
        found, best = np.zeros((0, self.arm.n)), np.inf
        # clear answers well within the thresholds (the search's steps taken on from its answers, _polished), and
        # those it came to within them (a way's end where none well within is clear: a goal beside a ball)
        kept = {True: [], False: []}
        some_well = False                 # whether any answer came well within (clear or not)
        for k, part in enumerate(parts):
            if k > GOAL_REACHING_ROUNDS and (best > self.task.distance_threshold or not some_well):
                break            # none reaches at all (beyond reach), or none well (its edge): more draws find none
            answers, reached, error, _ = self._reaching_search(goal[:, None], q[:, None], part, clear=False)
            best = min(best, float(error.min()))
            near = answers[:, reached[:, 0], 0].T
            polished, well = self._polished(near, goal)
            some_well |= bool(well.any())
            for within, candidates in ((True, polished[well]), (False, near)):
                candidates = candidates[np.all((candidates >= box.lower) & (candidates <= box.upper), axis=1)]
                if len(candidates):
                    candidates = self._nearest_turns(candidates, q, box)
                    candidates = candidates[~self.body.in_collision(candidates, margin)]
                kept[within].append(candidates)
            counts = {within: sum(map(len, got)) for within, got in kept.items()}
            if counts[True] >= least or (k >= GOAL_REACHING_ROUNDS and not counts[True] and counts[False] >= least):
                break        # enough well within; or, after as many rounds as the goal's reach is given, none is
        found = np.concatenate(kept[True]) if sum(map(len, kept[True])) else np.concatenate(kept[False] or [found])
        order = np.argsort(np.linalg.norm((found - q) / self._speed(box), axis=1), kind='stable')
        return found[order], best

    def _speed(self, box) -> np.ndarray:
        """(n,) what a joint's motion costs per unit is 1 / this: through a safety layer (box a Limits) its velocity
        limit (the nearest configuration is the soonest reached: the PR2's torso lifts at 0.013 m/s, its arm turns at
        2 rad/s), else its half range (the recovery's steps)."""
        return box.velocity if isinstance(box, Limits) else self.arm._half

    def none_clear(self, best: float, margin: float) -> str:
        """Why clear_reaching_configurations found none, one line, from the least error its search met (best)."""
        if best > self.task.distance_threshold:
            return f'the goal is beyond the arm\'s reach (no configuration found within {best:.3f} m of it)'
        return f'no configuration reaches the goal clear of contacts by {margin:g} m'

    def _nearest_turns(self, found: np.ndarray, q: np.ndarray, box) -> np.ndarray:
        """The configurations, and before them the same ones with each joint whose range is more than a turn taken at
        the turn nearest to q (where that is within box)."""
        turning = [k for k, name in enumerate(self.arm.joints)
                   if self.arm.tree.joints[name].type in ('revolute', 'continuous')
                   and box.upper[k] - box.lower[k] > 2 * np.pi]
        if not turning:
            return found
        near = found.copy()
        for k in turning:
            shifted = near[:, k] + 2 * np.pi * np.round((q[k] - near[:, k]) / (2 * np.pi))
            inside = (shifted >= box.lower[k]) & (shifted <= box.upper[k])
            near[inside, k] = shifted[inside]
        return np.vstack((near, found[np.any(near != found, axis=1)]))

    def _polished(self, found: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(configurations (m, n), well (m,)): found (m, n), each reaching goal (size,), taken on by the search's steps
        until it is well within the thresholds (RECOVERY_ITERATIONS at most), and whether it is. A search stops every
        answer of a goal once one of them is well within, so the others may reach it by 4 cm of 5: the end of a way
        so far off left the PR2's P-controller a step whose weighted joints took its tip into a collision."""
        seeds = np.ascontiguousarray(found.T)
        q = self._reaching_search(goal[:, None], seeds[:, :1], seeds, clear=False, each=True)[0][:, :, 0]
        tip, _ = self._tip_steps().place(q)
        return q.T, self._well_within(tip, np.repeat(goal[:, None], q.shape[1], axis=1))

    def joint_planner(self, margin: float, box, spacing: float, clear=None):
        """A motion.JointPlanner within box's lower and upper (Limits, or the Arm) whose configurations are clear of
        every contact of the body by margin (or those `clear` accepts), its motions checked spacing metres apart
        along the body; through a layer (box a Limits) its paths measured in time."""
        from robot_ai.motion import JointPlanner
        if clear is None:
            clear = lambda q: ~self.body.in_collision(q, margin)      # noqa: E731
        return JointPlanner(box.lower, box.upper, clear, self.body.sweep(), spacing=spacing,
                            speed=box.velocity if isinstance(box, Limits) else 1.0)

    def _planned_way(self, goal: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """planned_way's points, or None without a way."""
        return self.planned_way(goal, q).points

    def planned_way(self, goal: np.ndarray, q: np.ndarray, budget: int = RECOVERY_PLAN_BUDGET,
                    time_limit: float = RECOVERY_PLAN_TIME) -> PlannedWay:
        """A planned way from q (n,) to a configuration that reaches goal clear of contacts by way_margin (less
        where q itself is nearer than that to a contact), its points after q a recovery step apart (no joint more
        than RECOVERY_STEP of its half range from one to the next, through a safety layer a period's travel: each
        step lands on the next point, straight along the path), found within `budget` motion checks (and
        time_limit s; twice where plan_path tries a spread); or why there is none (one line)."""
        from robot_ai.motion.timing import densify
        box = self.limits if self.limits is not None else self.arm       # within the layer's positions
        # through a layer the arm follows the points a little off the straight legs: a centimetre more kept. An arm
        # that stands within that already (a policy drove it there) is planned for with the layer's own margin (an
        # arm clear by it is checked with it: a way planned with less was refused at its first step), else with
        # what it has, else none, as the layer lets it move out (it refuses only motions that would touch then).
        # A goal reached clear by the layer's margin only: planned with that
        wanted = self.way_margin + (RECOVERY_PLAN_PADDING if self.limits is not None else 0.0)
        tried = (wanted, self.way_margin, 0.5 * self.way_margin, 0.25 * self.way_margin)
        margin = next((m for m in tried if not self.body.in_collision(q[None], m)[0]), 0.0)
        least = RECOVERY_PLAN_GOALS if self.limits is not None else 1
        ends, best = self.clear_reaching_configurations(goal, q, margin, box, least)
        if not len(ends) and margin > self.way_margin:
            margin = self.way_margin
            ends, best = self.clear_reaching_configurations(goal, q, margin, box, least)
        if not len(ends):
            return PlannedWay(None, '', self.none_clear(best, margin))
        path = None
        if margin < wanted and margin >= self.way_margin > 0:     # within the centimetre more: it is kept beyond
            leaving = self._leaving_planner(q, margin, wanted, box)  # the start's neighbourhood (a way planned
            path = self.plan_path(leaving, goal, q, ends, margin, box, time_limit, budget)   # with the margin alone
        if path is None or not path.found:                        # hugged a ball, and the layer refused it there)
            if self._planner is None or self._planner[0] != margin:
                self._planner = (margin, self.joint_planner(margin, box, max(margin, RECOVERY_PLAN_SPACING)))
            path = self.plan_path(self._planner[1], goal, q, ends, margin, box, time_limit, budget)
        if not path.found:
            return PlannedWay(None, path.how, path.reason)
        step = RECOVERY_STEP * self.arm._half
        if self.limits is not None:     # a period's travel at most: each joint reaches its point within the period
            step = np.minimum(step, self.limits.velocity * self.control_period)
        return PlannedWay((densify(path.waypoints / step, 1.0) * step)[1:], path.how, '')

    def _leaving_planner(self, q: np.ndarray, margin: float, wanted: float, box):
        """A motion.JointPlanner for a start clear by margin but not by wanted: configurations clear by wanted, or
        by margin within LEAVING metres of body motion from q (sweep), so that the way leaves the start's
        neighbourhood and keeps wanted beyond it."""
        sweep, body = self.body.sweep(), self.body

        def clear(qs: np.ndarray) -> np.ndarray:
            ok = ~body.in_collision(qs, wanted)
            rest = np.flatnonzero(~ok)
            near = rest[(np.abs(qs[rest] - q) @ sweep) <= LEAVING]
            if len(near):
                ok[near] = ~body.in_collision(qs[near], margin)
            return ok
        # checked states 2 (wanted - margin) apart: between two of them the body keeps margin (a check with a padding
        # covers half the spacing), where the layer refuses less
        return self.joint_planner(margin, box, min(2 * (wanted - margin), wanted), clear)

    def plan_path(self, planner, goal: np.ndarray, q: np.ndarray, ends: np.ndarray, margin: float, box,
                  time_limit: float, budget: int | None = None):
        """planner's (a motion.JointPlanner's) path from q to the nearest RECOVERY_PLAN_GOALS of ends (reaching
        configurations clear by margin, nearest first); where its tree search finds none, once more (with the same
        time and budget) to SPREAD_GOALS configurations spread over SPREAD_SEARCH found from more postures: the
        nearest ones are often of one wrist's turn, and a UR5 from a random start, its wrist folded on the forearm,
        can reach only another (10 of 15 goals found a way, 14 of 15 with the spread)."""
        path = planner.plan(q, ends[:RECOVERY_PLAN_GOALS], time_limit, budget=budget)
        if path.found or path.how in ('', 'straight'):       # found, or no search was made (a start in contact)
            return path
        more = self.clear_reaching_configurations(goal, q, margin, box, least=SPREAD_SEARCH)[0]
        spread = more[np.unique(np.linspace(0, len(more) - 1, min(SPREAD_GOALS, len(more))).astype(int))]
        again = planner.plan(q, spread, time_limit, budget=budget)
        return again if again.found else path

    def _clear_way(self, q: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(via, to) from q (n,) to the first of ends (n, c) (clear of contacts; the first one's straight way
        touches) whose way is clear: straight (via is to), else through one of recovery_vias, the shortest way
        through one for the first end that has one; None without one."""
        c = ends.shape[1]
        if not c:
            return None
        straight = self._way_clear(np.repeat(q[:, None], c - 1, axis=1), ends[:, 1:])[0]
        if straight.any():
            end = ends[:, 1 + straight.argmax()]
            return end, end
        vias = self.recovery_vias
        v = vias.shape[1]
        first, there = self._way_clear(np.repeat(q[:, None], v, axis=1), vias)
        if not first.any():
            return None
        vias, there = vias[:, first], there[:, first]
        v = vias.shape[1]
        second = self._way_clear(np.repeat(there, c, axis=1), np.tile(ends, (1, v)))[0]
        second = second.reshape(v, c)          # via i, end j: column i * c + j
        half = self.arm._half[:, None]
        for j in range(c):                     # the nearest end first, then the shortest way through a via point
            ok = np.flatnonzero(second[:, j])
            if len(ok):
                length = (np.abs((vias[:, ok] - q[:, None]) / half).max(axis=0)
                          + np.abs((ends[:, j:j + 1] - there[:, ok]) / half).max(axis=0))
                return vias[:, ok[length.argmin()]], ends[:, j]
        return None

    def _way_clear(self, start_t: np.ndarray, end_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(clear (P,), where each way stops (n, P)): the recovery's steps from start_t to end_t (n, P), each joint
        at most RECOVERY_STEP of its half range a step until every joint is within RECOVERY_ARRIVED of it (recover's
        rule), every step's motion checked against the body as guard checks it (way_margin kept)."""
        if not start_t.shape[1]:
            return np.zeros(0, dtype=np.bool_), start_t.copy()
        half = self.arm._half[:, None]
        x, stops = start_t.copy(), [start_t]
        going = np.ones(x.shape[1], dtype=np.bool_)
        while going.any():
            step = np.minimum(np.maximum(end_t[:, going] - x[:, going], -RECOVERY_STEP * half),
                              RECOVERY_STEP * half)
            x[:, going] += step
            stops.append(x.copy())
            going[going] = ~(np.abs(end_t[:, going] - x[:, going]) <= RECOVERY_ARRIVED * half).all(axis=0)
        # each step's whole motion, as guard checks it (an arm that has arrived stays: a motion of nothing)
        hits = self._motion_hits(np.concatenate(stops[:-1], axis=1), np.concatenate(stops[1:], axis=1),
                                 self.way_margin).reshape(len(stops) - 1, -1)
        return ~hits.any(axis=0), x

    def _well_within(self, achieved_t: np.ndarray, goal_t: np.ndarray) -> np.ndarray:
        """(N,): achieved goals (size, N) within half the task's thresholds of goal_t."""
        task = self.task
        close = goal_distance(achieved_t[:3].T, goal_t[:3].T) < 0.5 * task.distance_threshold
        if self.pose:
            close &= goal_angle(achieved_t.T, goal_t.T) < 0.5 * task.angle_threshold
        return close

    def _p_action(self, tip_t: np.ndarray, goal_t: np.ndarray, most: float = 1.0) -> np.ndarray:
        """(a, N): learn.p_controller's action, the tip error over ee_step (and the turn over angle_step), clipped to
        +-most."""
        move = np.minimum(np.maximum((goal_t[:3] - tip_t[:3]) / self.ee_step, -most), most)
        if not self.pose:
            return move
        turn = rotation_error(tip_t.T, goal_t.T).T / self.angle_step
        return np.concatenate((move, np.minimum(np.maximum(turn, -most), most)))

    def _stall_count(self, error: np.ndarray, tip_t: np.ndarray, goal_t: np.ndarray, actions_t: np.ndarray,
                     best: np.ndarray, since: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """recover's (best, since) after a step from tips tip_t toward goal_t (size, N), their dense error (N,), with
        actions_t (a, N): the count goes on while the action tries, asking toward the goal (its cosine with the
        P-controller's, unclipped, at least STALL_COSINE: random actions seldom do, and seldom stall_steps in a row),
        and the dense error stays between best less STALL_GAIN of a full step and best plus STALL_BAND full steps."""
        lower = error < best - STALL_GAIN * self.ee_step
        toward = self._p_action(tip_t, goal_t, np.inf)
        dot, tt, aa = toward[0] * actions_t[0], toward[0] * toward[0], actions_t[0] * actions_t[0]
        for row in range(1, len(toward)):         # row by row: _stall_count_one's sums, in its order
            dot = dot + toward[row] * actions_t[row]
            tt = tt + toward[row] * toward[row]
            aa = aa + actions_t[row] * actions_t[row]
        trying = (dot > 0) & (dot >= STALL_COSINE * np.sqrt(tt * aa))
        away = error > best + STALL_BAND * self.ee_step
        return np.where(lower, error, best), np.where(lower | ~trying | away, 0, since + 1).astype(np.int32)

    def _stall_count_one(self, error: float, tip: list, goal: list, a: list, best: float,
                         since: int) -> tuple[float, int]:
        """_stall_count's numbers for one arm (error: its dense error, _error_one's), in floats for position goals
        (the same operations in the same order), through a batch of one for pose goals."""
        if self.pose:
            column = lambda v: np.array(v, dtype=np.float64)[:, None]     # noqa: E731
            b, n = self._stall_count(np.array([error]), column(tip), column(goal), column(a), np.array([best]),
                                     np.array([since], dtype=np.int32))
            return float(b[0]), int(n[0])
        lower = error < best - STALL_GAIN * self.ee_step
        toward = [(g - t) / self.ee_step for g, t in zip(goal, tip)]
        dot, tt, aa = toward[0] * a[0], toward[0] * toward[0], a[0] * a[0]
        for row in (1, 2):
            dot = dot + toward[row] * a[row]
            tt = tt + toward[row] * toward[row]
            aa = aa + a[row] * a[row]
        trying = dot > 0 and dot >= STALL_COSINE * math.sqrt(tt * aa)
        away = error > best + STALL_BAND * self.ee_step
        return (error if lower else best), (0 if lower or not trying or away else since + 1)

    def _error_one(self, tip: list, goal: list) -> float:
        """task.error's number for one arm: in floats for position goals, through a batch of one for pose goals."""
        if self.pose:
            column = lambda v: np.array(v, dtype=np.float64)[:, None]     # noqa: E731
            return float(self.task.error(column(tip).T, column(goal).T)[0])
        return goal_distance_one(tip, goal)

    def _tip_motion(self, q_t: np.ndarray, target_t: np.ndarray) -> np.ndarray:
        """(3 or 6, N): how the tip moves from q_t to target_t, in the action's units times ee_step (pose goals:
        the turn as a rotation vector, weighted by angular_weight)."""
        if not self.pose:
            return self.arm.forward(target_t, with_axes=False)[0] - self.arm.forward(q_t, with_axes=False)[0]
        before, after = self.goals_of(q_t), self.goals_of(target_t)
        turn = rotation_error(before.T, after.T).T * self.angular_weight
        return np.concatenate((after[:3] - before[:3], turn))

    def recover_one(self, q: list, tip: list, target: list, a: list, goal: list,
                    recovery: Recovery) -> tuple[list, Recovery]:
        """recover's numbers for one arm at q with its tip (achieved goal) tip (a: the action's floats, clipped)."""
        if recovery.state == RECOVERED or (recovery.state == READY and not self.limit_recovery):
            return target, recovery
        if recovery.state == READY:         # recover's bookkeeping alone, while nothing can block or stall
            error = self._error_one(tip, goal)
            best, counted = self._stall_count_one(error, tip, goal, a, recovery.best, recovery.since)
            least = min(RECOVERY_ASK * self.ee_step, RECOVERY_ASK_OF_ERROR * error)
            asks = sum((v * self.ee_step) * (v * self.ee_step) for v in a) >= least * least
            at_limit = any(t <= lo + LIMIT_TOLERANCE or t >= hi - LIMIT_TOLERANCE
                           for t, lo, hi in zip(target, self.arm._lower, self.arm._upper))
            if not (asks and (at_limit or counted >= self.stall_steps)):
                return target, Recovery(READY, recovery.q, best, counted)
        column = lambda v: np.array(v, dtype=np.float64)[:, None]     # noqa: E731
        to = column(recovery.q) if recovery.q is not None else np.zeros((self.arm.n, 1))
        then = column(recovery.then) if recovery.then is not None else to.copy()
        way = np.empty(1, dtype=object)
        way[0] = recovery.way
        rec = Recoveries(np.array([recovery.state], dtype=np.int8), to, np.array([recovery.best]),
                         np.array([recovery.since], dtype=np.int32), then, way)
        out, rec = self.recover(column(q), column(tip), column(target), column(a), column(goal), rec)
        return out[:, 0].tolist(), Recovery(int(rec.state[0]), tuple(rec.q[:, 0].tolist()), float(rec.best[0]),
                                            int(rec.since[0]), tuple(rec.then[:, 0].tolist()), tuple(rec.way[0]))

    # ------------------------------------------------------------------------------- one arm (plain floats)
    def place_one(self, q: list) -> tuple[list, list | None]:
        """(tip, Jacobian rows for ee control, else None) of one arm: place's numbers for a batch of one (pose
        goals: place's own, on a batch of one)."""
        if self.pose:
            tip, jac = self.place(np.array(q, dtype=np.float64)[:, None])
            return tip[:, 0].tolist(), jac
        tip, axes, origins = self.arm.forward_one(q)
        return tip, (self.arm.jacobian_one(tip, axes, origins) if self.control == 'ee' else None)

    def move_one(self, q: list, jac: list | None, a: list) -> list:
        """move's numbers for a batch of one: a, the action's floats already clipped (check_action_one)."""
        if self.pose:
            return self.move(np.array(q, dtype=np.float64)[:, None], jac,
                             np.array(a, dtype=np.float64)[:, None])[:, 0].tolist()
        if self.control == 'ee':
            weights = self.joint_weights
            return self.arm.move_one(q, jac, [v * self.ee_step for v in a], self.damping,
                                     limit_gain=self.limit_gain, weights=None if weights is None else weights.tolist())
        lower, upper = self.arm._lower, self.arm._upper
        return [min(max(q[k] + a[k] * JOINT_STEP, lower[k]), upper[k]) for k in range(self.arm.n)]

    def observation_one(self, q: list, tip: list, goal: list) -> dict:
        return {'achieved_goal': np.array(tip), 'desired_goal': np.array(goal), 'observation': np.array(q + tip)}

    @staticmethod
    def observations(q_t: np.ndarray, tip_t: np.ndarray, goal_t: np.ndarray) -> dict:
        """The observation dict of a batch: (N, size), (N, size), (N, n + size), float64."""
        return {'achieved_goal': tip_t.T.copy(), 'desired_goal': goal_t.T.copy(),
                'observation': np.concatenate((q_t, tip_t)).T.copy()}


class ReachEnv(gymnasium.Env):
    """Any arm's reach task (see the module's docstring). Registered as robot_ai/Reach-v0 (50 steps).

    Args: model (a URDF or xacro path; default the package's UR5), xacro_args ('a:=1 b:=2' or a dict), tip (a link;
    default the arm's end: a tool frame, not a finger), control ('ee' or 'joints'), start ('home', 'random' or
    'chained'), reward_type ('sparse' or 'dense'), distance_threshold (0.05 m), ee_step (default: a twentieth of the
    chain), damping (of the least squares; default ee_step), home (joint positions, a list in the arm's order or a
    dict; default mid-range), urdf (a URDF text instead of a model file), render_mode ('rgb_array'), limit_avoidance
    (0 to 10, default 4), obstacles (boxes and spheres in the arm's base frame: a list of {box: [sx, sy, sz],
    position: [x, y, z], rpy: [r, p, y]} or {sphere: r, position: [x, y, z]}, or a YAML file or text of one;
    robot_ai.motion.body), collision (the arm's body from its URDF <collision> geometry checked against itself
    and the obstacles; default: on when obstacles are given). With a body, goals and random starts are drawn clear
    of collisions, and a step whose motion would touch is not made: the arm holds, info['collision'] is True, the
    episode goes on. goal ('position' or 'pose'), angle_threshold (0.1 rad) and angle_step (0.2 rad): pose goals,
    see the module's docstring. velocity_scale, acceleration_scale, joint_limits, control_period: the arm moved as
    reach_controller's safety layer moves it. limit_recovery (ee control, default True): ReachSetup.recover.
    plan_first (default: on with a body through the safety layer, as reach_controller plans each goal): each
    episode's goal planned at its start round the body (ReachSetup.first_way), the arm following that way before
    the policy's actions move it."""

    metadata = {'render_modes': ['rgb_array'], 'render_fps': RENDER_FPS}

    def __init__(self, model: str | None = None, xacro_args=None, tip: str | None = None, control: str = 'ee',
                 start: str = 'home', reward_type: str = 'sparse', distance_threshold: float = DISTANCE_THRESHOLD,
                 ee_step: float | None = None, damping: float | None = None, home=None, urdf: str | None = None,
                 render_mode: str | None = None, limit_avoidance: float = LIMIT_AVOIDANCE, obstacles=None,
                 collision: bool | None = None, goal: str = 'position', angle_threshold: float = ANGLE_THRESHOLD,
                 angle_step: float | None = None, velocity_scale: float | None = None,
                 acceleration_scale: float | None = None, joint_limits=None, control_period: float = CONTROL_PERIOD,
                 limit_recovery: bool = True, plan_first: bool | None = None):
        if render_mode not in (None, *self.metadata['render_modes']):
            raise ReachError(f'render_mode must be one of {self.metadata["render_modes"]} or None, got {render_mode!r}')
        self.setup = ReachSetup(model, xacro_args, tip, control, start, reward_type, distance_threshold, ee_step,
                                damping, home, urdf, limit_avoidance, obstacles, collision, goal, angle_threshold,
                                angle_step, velocity_scale, acceleration_scale, joint_limits, control_period,
                                limit_recovery, plan_first)
        self.arm = self.setup.arm
        self.task = self.setup.task
        self.observation_space = self.setup.observation_space
        self.action_space = self.setup.action_space
        self.render_mode = render_mode
        self._q = self._tip = self._goal = self._jac = None
        self._v = self._sent = None             # with velocity_scale: the joints' velocities, the targets sent
        self._recovery = Recovery()             # limit recovery's state in the episode (ReachSetup.recover)
        self._replans = 0                       # the episode's ways planned again (plan_first, MAX_REPLANS)
        self._renderer = None

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """A new episode: the goal and the start drawn from np_random (seeded by seed), or given by options:
        {'goal': [x, y, z]} (in the root frame: the point a click in rviz gives, to try it in-process) and
        {'q': [...]} (the start configuration, in the arm's joint order or by name). The draws are made either way,
        so the env's random numbers stay those of the same seed without options."""
        super().reset(seed=seed)
        goal_q, start_q = self.setup.first_states([self.np_random], [self._q])
        if self.setup.pose:
            goal = self.setup.goals_of(goal_q)[:, 0].tolist()
        else:
            goal = self.arm.forward_one(goal_q[:, 0].tolist())[0]
        q = start_q[:, 0].tolist()
        if options:
            goal, q = self.setup.reset_options(options, goal, q)
        if self.setup.limits is not None and (self.setup.start != 'chained' or self._v is None
                                              or q != self._q):   # chained: the arm goes on as it was going
            self._v, self._sent = self.setup.motion_start(np.array(q)[:, None])
        self._goal, self._q = goal, q
        self._recovery, self._replans = self.setup.first_way(goal, q), 0
        if self._recovery.state == RECOVERING and self.setup.limits is not None:
            self._drop_sent()                       # the way starts from where the arm is (_reset_envs' rule)
        self._tip, self._jac = self.setup.place_one(self._q)
        if self._renderer is not None:
            self._renderer.new_episode()
        return self.setup.observation_one(self._q, self._tip, self._goal), self._info()

    def step(self, action):
        if self._q is None:
            raise ResetNeeded('Cannot call env.step() before calling env.reset()')
        a = self.setup.check_action_one(action)
        target = self.setup.move_one(self._q, self._jac, a)
        was = self._recovery.state
        target, self._recovery = self.setup.recover_one(self._q, self._tip, target, a, self._goal, self._recovery)
        if self.setup.limits is not None:           # through the safety layer: one control period toward it
            if self._recovery.state == RECOVERING and was != RECOVERING and self._recovery.way:   # (_moved's rule)
                self._drop_sent()
            q, v, self._sent = self.setup.advance(np.array(self._q)[:, None], self._v, self._sent,
                                                   np.array(target)[:, None])
            self._q, hit = self.setup.guard_one(self._q, q[:, 0].tolist())
            self._v = np.zeros_like(v) if hit else v
            if hit:                                 # held: the targets sent are dropped (ReachVectorEnv._moved)
                self._drop_sent()
        else:
            self._q, hit = self.setup.guard_one(self._q, target)
        if hit:
            held = self.setup.plans_first and self.setup.replanning(
                [self._recovery.state == RECOVERING], np.array(self._tip)[:, None], np.array(self._goal)[:, None])[0]
            self._recovery = self._recovery.give_up()
            if held and self._replans < MAX_REPLANS:   # as reach_controller: the way planned again from here (each
                self._replans += 1                      # try counts: one that finds none is not made every step)
                again = self.setup.first_way(self._goal, self._q)
                if again.state == RECOVERING:
                    self._recovery = again
        info = {} if hit is None else {'collision': hit}
        self._tip, self._jac = self.setup.place_one(self._q)
        if self.setup.pose:
            reward, success = self.task.outcome(np.array(self._tip), np.array(self._goal))
            reward, info['is_success'] = float(reward), bool(success)
        else:
            distance = goal_distance_one(self._tip, self._goal)
            reward, info['is_success'] = self.task.reward_one(distance), distance < self.task.distance_threshold
        return self.setup.observation_one(self._q, self._tip, self._goal), reward, False, False, info

    def _drop_sent(self) -> None:
        """The targets sent to the layer replaced by where the arm is: it holds there."""
        self._sent = np.repeat(np.array(self._q)[None, :, None], self._sent.shape[0], axis=0)

    def _info(self) -> dict:
        if self.setup.pose:
            return {'is_success': bool(self.task.is_success(np.array(self._tip), np.array(self._goal)))}
        return {'is_success': goal_distance_one(self._tip, self._goal) < self.task.distance_threshold}

    @property
    def joint_positions(self) -> np.ndarray:
        """The arm's joint positions (n,) now."""
        return np.array(self._q)

    def render(self):
        if self.render_mode != 'rgb_array':
            return None
        if self._renderer is None:
            from robot_ai.reach.render import ArmRenderer
            self._renderer = ArmRenderer(self.arm, self.task.distance_threshold)
        if self._q is None:
            return self._renderer.draw(self.setup.home, None)
        return self._renderer.draw(np.array(self._q), np.array(self._goal[:3]))

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()


def vector_reset_args(num_envs: int, seed, options) -> tuple[list, np.ndarray]:
    """(a seed per env, the envs to reset) of a vector env's reset(seed=, options=) as gymnasium's SyncVectorEnv
    reads them: seed s seeds env i with s + i, a list gives one per env; options['reset_mask'] (a bool array, one per
    env, at least one true) resets those envs only. ValueError or TypeError as SyncVectorEnv words them."""
    if seed is None:
        seeds = [None] * num_envs
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        seeds = [int(seed) + i for i in range(num_envs)]
    else:
        seeds = list(seed)
        if len(seeds) != num_envs:
            raise ValueError(f'If seeds are passed as a list the length must match num_envs={num_envs} '
                             f'but got length={len(seeds)}.')
    mask = np.ones(num_envs, dtype=np.bool_)
    if options is not None and 'reset_mask' in options:     # as SyncVectorEnv: reset only these envs
        mask = options['reset_mask']
        if not isinstance(mask, np.ndarray):
            raise TypeError(f"`options['reset_mask']` must be a numpy array, got {type(mask)}")
        if mask.shape != (num_envs,):
            raise ValueError(f"`options['reset_mask']` must have shape `({num_envs},)`, got {mask.shape}")
        if mask.dtype != np.bool_:
            raise TypeError(f"`options['reset_mask']` must have `dtype=np.bool_`, got {mask.dtype}")
        if not mask.any():
            raise ValueError(f"`options['reset_mask']` must contain a boolean array with at least one True "
                             f"value, got reset_mask={mask}")
    return seeds, mask


class ReachVectorEnv(VectorEnv):
    """num_envs ReachEnvs computed together, equal bit for bit to gymnasium's SyncVectorEnv over them (autoreset
    next-step, reset(seed=s) seeds env i with s + i, infos with their masks). The kwargs are ReachEnv's (or a
    ReachSetup already made, setup=)."""

    metadata = {'render_modes': ['rgb_array'], 'render_fps': RENDER_FPS, 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = None, render_mode: str | None = None,
                 setup: ReachSetup | None = None, **kwargs: Any):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ReachError(f'num_envs must be a whole number of at least 1, got {num_envs!r}')
        if max_episode_steps is not None and (isinstance(max_episode_steps, bool) or not isinstance(
                max_episode_steps, (int, np.integer)) or max_episode_steps < 1):
            raise ReachError(f'max_episode_steps must be a whole number of at least 1, got {max_episode_steps!r}')
        if setup is not None and kwargs:
            raise ReachError(f'give a setup or its settings, not both: {sorted(kwargs)}')
        self.setup = setup or ReachSetup(**kwargs)
        if max_episode_steps is None:        # 50, or as long in time with velocity_scale
            max_episode_steps = self.setup.episode_steps
        self.arm = self.setup.arm
        self.task = self.setup.task
        self.num_envs = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        self.single_observation_space = self.setup.observation_space
        self.single_action_space = self.setup.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        n = self.num_envs
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._q = np.zeros((self.arm.n, n))
        size = self.task.size
        self._tip = np.zeros((size, n))
        self._goal = np.zeros((size, n))
        self._jac = np.zeros((6 if self.setup.pose else 3, self.arm.n, n)) if self.setup.control == 'ee' else None
        self._v, self._sent = self.setup.motion_start(self._q)
        self._recovery = Recoveries.fresh(self.arm.n, n)        # limit recovery's states (ReachSetup.recover)
        self._replans = np.zeros(n, dtype=np.int64)              # each episode's ways planned again (MAX_REPLANS)
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=np.bool_)
        self._started = np.zeros(n, dtype=np.bool_)
        self._renderers = None

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    def _rng(self, i: int, seed: int | None) -> np.random.Generator:
        if seed is not None or self._rngs[i] is None:    # gymnasium.Env.reset(seed) and np_random's first use
            self._rngs[i] = seeding.np_random(seed)[0]
        return self._rngs[i]

    def _reset_envs(self, chosen: np.ndarray, seeds: list) -> None:
        rngs = [self._rng(int(i), seeds[i]) for i in chosen]
        goal_q, q = self.setup.first_states(rngs, [self._q[:, i].copy() if self._started[i] else None
                                                   for i in chosen])
        goal = self.setup.goals_of(goal_q)
        tip, jac = self.setup.place(q)
        if self.setup.limits is not None:        # at rest, but chained: the arm goes on as it was going
            fresh = chosen if self.setup.start != 'chained' else chosen[~self._started[chosen]]
            self._v[:, fresh], self._sent[:, :, fresh] = self.setup.motion_start(q[:, np.isin(chosen, fresh)])
        self._q[:, chosen], self._goal[:, chosen], self._tip[:, chosen] = q, goal, tip
        if jac is not None:
            self._jac[:, :, chosen] = jac
        self._elapsed[chosen] = 0
        self._recovery.restart(chosen)
        self._replans[chosen] = 0
        if self.setup.plans_first:          # each goal planned first (as reach_controller plans it): the way
            for k, i in enumerate(chosen):  # starts from where the arm is, the targets queued dropped
                first = self.setup.first_way(goal[:, k], q[:, k])
                if first.state == RECOVERING:
                    self._recovery.take(i, first)
                    if self.setup.limits is not None:
                        self._sent[:, :, i] = q[None, :, k]
        self._started[chosen] = True
        if self._renderers is not None:
            for i in chosen:
                if i < len(self._renderers):
                    self._renderers[i].new_episode()

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        seeds, mask = vector_reset_args(self.num_envs, seed, options)
        chosen = np.flatnonzero(mask)
        self._reset_envs(chosen, seeds)
        self._autoreset[chosen] = False
        success = self.task.is_success(self._tip.T, self._goal.T)
        infos = {'is_success': np.where(mask, success, False), '_is_success': mask.copy()}
        return ReachSetup.observations(self._q, self._tip, self._goal), infos

    def step(self, actions):
        if not self._started.all():
            raise ResetNeeded('Cannot call env.step() before calling env.reset()')
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != self.action_space.shape:
            raise ValueError(f'actions must have shape {self.action_space.shape}, got {actions.shape}')
        stepping = ~self._autoreset
        a = self.setup.check_actions(actions[stepping])
        rows = np.flatnonzero(stepping)
        collision = np.zeros(self.num_envs, dtype=np.bool_)
        if len(rows) == self.num_envs:
            q, hit = self._moved(slice(None), self._jac, a)
            self._q = q
            self._tip, self._jac = self.setup.place(self._q)
            if hit is not None:
                collision[:] = hit
        elif len(rows):
            jac = self._jac[:, :, rows] if self._jac is not None else None
            q, hit = self._moved(rows, jac, a)
            tip, jac = self.setup.place(q)
            self._q[:, rows], self._tip[:, rows] = q, tip
            if jac is not None:
                self._jac[:, :, rows] = jac
            if hit is not None:
                collision[rows] = hit
        resetting = np.flatnonzero(self._autoreset)
        if len(resetting):
            self._reset_envs(resetting, [None] * self.num_envs)
        self._elapsed[rows] += 1
        reward, success = self.task.outcome(self._tip.T, self._goal.T)
        rewards = np.where(stepping, reward, 0.0)
        terminations = np.zeros(self.num_envs, dtype=np.bool_)
        truncations = stepping & (self._elapsed >= self.max_episode_steps)
        self._autoreset = truncations.copy()
        infos = {'is_success': success, '_is_success': np.ones(self.num_envs, dtype=np.bool_)}
        if self.setup.body is not None and stepping.any():   # as SyncVectorEnv gathers the envs' info['collision']
            infos = {'collision': collision, '_collision': stepping.copy(), **infos}
        return ReachSetup.observations(self._q, self._tip, self._goal), rewards, terminations, truncations, infos

    def _moved(self, rows, jac: np.ndarray | None, a: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """guard's (joints (n, len(rows)), collision or None) of the arms of rows after the actions a (len(rows),
        size): moved at once, or one control period through the safety layer (velocity_scale), whose state
        (velocities, targets sent) moves on here; an arm whose motion would touch stops where it was, at rest."""
        before = self._q[:, rows]
        a_t = np.ascontiguousarray(a.T)
        target = self.setup.move(before, jac, a_t)
        target, rec = self.setup.recover(before, self._tip[:, rows], target, a_t, self._goal[:, rows],
                                         self._recovery[rows])
        if self.setup.limits is None:
            q, hit = self.setup.guard(before, target)
        else:
            # a planned way round starts from where the arm is: the targets queued are dropped (through the
            # layer they ran the arm into the contact the way goes round, and the way was given up at its start)
            arms = np.arange(self.num_envs)[rows]
            starting = (rec.state == RECOVERING) & (self._recovery.state[rows] != RECOVERING) & rec.planned()
            self._sent[:, :, arms[starting]] = before[None, :, starting]
            q, v, self._sent[:, :, rows] = self.setup.advance(before, self._v[:, rows], self._sent[:, :, rows],
                                                              target)
            q, hit = self.setup.guard(before, q)
            if hit is not None and hit.any():    # the layer holds the arm: the targets it had sent are dropped (a
                v[:, hit] = 0.0                  # way round starts from where it holds, not after them)
                self._sent[:, :, arms[hit]] = q[None, :, hit]
            self._v[:, rows] = v
        held = None
        if hit is not None and self.setup.plans_first:
            held = hit & self.setup.replanning(rec.state == RECOVERING, self._tip[:, rows], self._goal[:, rows])
        rec.give_up(hit)
        self._recovery[rows] = rec
        if held is not None and held.any():     # as reach_controller (ReachEnv.step)
            arms = np.arange(self.num_envs)[rows]
            for i in np.flatnonzero(held):
                j = arms[i]
                if self._replans[j] < MAX_REPLANS:
                    self._replans[j] += 1
                    again = self.setup.first_way(self._goal[:, j], q[:, i])
                    if again.state == RECOVERING:
                        self._recovery.take(j, again)
        return q, hit

    def render(self):
        if self.render_mode != 'rgb_array':
            return None
        from robot_ai.reach.render import ArmRenderer
        if self._renderers is None:
            self._renderers = [ArmRenderer(self.arm, self.task.distance_threshold) for _ in range(self.num_envs)]
        return tuple(r.draw(self._q[:, i], self._goal[:3, i] if self._started[i] else None)
                     for i, r in enumerate(self._renderers))

    def close_extras(self, **kwargs):
        for r in self._renderers or []:
            r.close()
        self._renderers = None
