"""A pick and place of one object, as rviz asks for it (an object clicked, then a place): the arm taken to the task's
ready configuration by a planned way (motion's planner over its body and the world), then the scripted expert or a
learned PickAndPlace-v0 policy carries the object to the place; the gripper opens, the arm rises clear, and where
the object comes to rest says `placed` or why not. Every arm command is made and checked by a safety layer
(reach.safety: the joint limits, the arm's body against itself and the world). No rospy: pick_place is its node.

    picking = PickPlace(setup, obstacles=world)           # setup: ManipulationSetup('pick_and_place', ...)
    name = picking.choose(clicked, objects)                # the object nearest a click (objects: {name: position})
    picking.start(name, place, now)                        # PickError of one line: why it cannot
    step = picking.step(now, q, finger, object_pose)       # step.plan (to send), step.opening, step.said, step.outcome

The layer keeps `margin` from every contact on the way to the ready configuration and back; while the policy has the
arm it refuses only motions that would touch (the hand must come within millimetres of the table to grasp), and the
object picked is the one thing the hand may touch (it is not in the layer's world). Other loose objects are not in
the layer's world either: the arm may push them.

The policy learned the task's 4 cm cube; other objects are handed to it as that: a tall one as the point it is
gripped at (below the palm), and a box too wide across the fingers gripped across its narrow side (the gripper
turned about the vertical, the policy's actions still the grip point's moves).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from robot_ai.physics.env import EE_STEP, ManipulationSetup, rpy_of
from robot_ai.physics.learn import flatten
from robot_ai.physics.model import parse_objects
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.safety import DEFAULT_MARGIN, Limits, Plan, SafetyLayer

SELECT_RADIUS = 0.08        # m: a click this near an object's middle chooses it
PLACE_HEIGHT = 0.02         # m: a place is a click on the table: this near its top
AT_READY = 0.02             # rad (or m): the arm at the ready configuration, the policy takes over
READY_TRIES = 64            # other ready configurations tried where the task's touches the layer's body
READY_CHOICES = 8           # of which the clear ones found first: the nearest the task's is taken
TASK_TIME = 60.0            # s: the policy's longest time to bring the object to the place
STALL_TIME = 6.0            # s: ... and without progress (the hand nearer the object, or the object nearer the place)
PROGRESS = 0.005            # m: what counts as progress
PLACED_WITHIN = 0.02        # m: the object this near the place (and resting on what is under it), the gripper opens
CARRY = 0.08                # m: the object is carried this high over the place, then set down
OVER_PLACE = 0.01           # m: ... once this near it in the plane
LOWERING = 0.04             # m: and set down while it stays this near (an arm that sways as it lowers the object was
                            # sent back up by a centimetre's sway, over and over: the Gen3 with a brick)
FITS = 0.8                  # a box wider across the fingers than this share of their opening is gripped across its
                            # narrow side, the gripper turned about the vertical (a 3x8 cm bar along the Panda's
                            # fingers, as wide as they open, could not be gripped; turned when it need not be, a
                            # 3x5 cm brick held the Gen3 lite's six joints short of the pose)
PALM_CLEARANCE = 0.01       # m: a tall object is gripped this far below the palm (above its middle: the palm would
                            # stand on its top; the Gen3's Robotiq 2F-85 stalled on a 10 cm can's)
RELEASE_TIME = 1.5          # s: the gripper's time to open
RISE = 0.1                  # m: the grip point rises this far above the place once the gripper is open
RISE_TIME = 3.0             # s
SETTLE_SPEED = 0.01         # m/s: the object at rest
SETTLE_TIME = 2.0           # s: the longest wait for it
HELD_TIME = 2.0             # s: a layer that refuses every step this long ends the pick
PLAN_TIME = 5.0             # s: the planner's time for the way to the ready configuration


def world(setup: ManipulationSetup, count: int = 2, seed: int = 0, ready=None) -> dict:
    """The task's world for arm_sim and pick_place (both take the same YAML): the table (obstacles), count cubes
    on it at least 0.1 m apart (objects: cube, cube_2, ...), drawn from the task's object range with seed, and the
    ready configuration (home: {joint: position}, arm_sim's start: ready, PickPlace.ready, or the task's)."""
    if not (isinstance(count, int) and 0 <= count <= 20):
        raise PickError(f'count must be a whole number from 0 to 20, got {count!r}')
    rng = np.random.default_rng(seed)
    cubes: list[np.ndarray] = []
    for _ in range(1000):
        if len(cubes) == count:
            break
        p = setup.sample(rng)[0]
        if all(np.linalg.norm(p[:2] - c[:2]) >= 0.1 for c in cubes):
            cubes.append(p)
    if len(cubes) < count:
        raise PickError(f'{count} cubes 0.1 m apart do not fit in the task\'s {setup.obj_range:g} m square')
    names = ['cube'] + [f'cube_{k}' for k in range(2, count + 1)]
    table = setup.table()
    table['position'] = [round(float(x), 4) for x in table['position']]
    return {'obstacles': [table],
            'objects': [setup.cube([round(float(x), 4) for x in p], n) for n, p in zip(names, cubes)],
            'home': {n: round(float(v), 6) for n, v in zip(setup.arm.joints, setup.space.ready if ready is None
                                                           else ready)}}


class PickError(ValueError):
    """Why a pick cannot start, one line."""


@dataclasses.dataclass
class PickStep:
    """What to do now: plan (the safety layer's, to send; None: nothing new), opening (the gripper's target, 0
    closed to 1 open; None: unchanged), said (a line to log, '' for none), outcome ('' while it goes on; `placed ...`
    or `not placed: ...` when it ends)."""
    plan: Plan | None = None
    opening: float | None = None
    said: str = ''
    outcome: str = ''


def _point(p) -> str:
    return '(' + ', '.join(f'{x:+.3f}' for x in p) + ')'


class PickPlace:
    """Picks of objects in setup's task layout (its table, ready configuration and workspace) among obstacles (the
    world's, the table among them), driven by policy (flattened observations (N, 29) -> actions (N, 4); None: the
    scripted expert), through a safety layer of the arm's limits at velocity_scale, the arm's body and the
    obstacles, keeping margin; period: the control step (the env's step_time)."""

    def __init__(self, setup: ManipulationSetup, obstacles=(), policy: Callable | None = None,
                 velocity_scale: float = 0.5, margin: float = DEFAULT_MARGIN, joint_limits=None, objects=()):
        if setup.task != 'pick_and_place':
            raise PickError(f'a pick needs the pick_and_place task\'s setup, not {setup.task}\'s')
        self.setup, self.period = setup, setup.step_time
        # the scripted expert opens the fingers wide enough for the object being picked, not the task's cube
        self.policy = policy if policy is not None else \
            (lambda x: setup.expert(x[:, 6:], x[:, 3:6], ajar=self.ajar))
        self.reach = ReachSetup(urdf=setup.robot.urdf, tip=setup.arm.tip, obstacles=obstacles or None,
                                collision=True)
        self.limits = Limits.of(self.reach.arm, joint_limits, velocity_scale)
        self.margin = float(margin)
        self.layer = SafetyLayer(self.limits, self.period, self.reach.body, self.margin)
        self.planner = self.reach.joint_planner(self.margin, self.limits, max(self.margin, 0.001))
        self.span = float(setup.grip_open[0] - setup.grip_closed[0])
        self.objects = {o.name: o for o in parse_objects(objects)}      # their sizes: how high each is set down
        self.ready, self.ready_note = self._clear_ready()
        self.name = ''
        self.ajar = setup.ajar
        self.phase = ''

    def _clear_ready(self) -> tuple[np.ndarray, str]:
        """The task's ready configuration, or where the layer's body finds it touching (its spheres are a little
        larger than the meshes: the Fetch's upper arm by its head), another with the gripper at the same pose, clear
        by the margin (the policy acts on the grip point, not the joints); (configuration, a note for the log)."""
        from robot_ai.physics.workspace import READY_TOLERANCE, ready_pose
        s, body = self.setup, self.reach.body
        ready = s.space.ready
        if body is None or not body.in_collision(ready[None], self.margin)[0]:
            return ready, ''
        touching = ', '.join(body.contacts(ready, self.margin)[:2])
        grip, rng = s.space.grip, np.random.default_rng(0)
        clear = []
        for _ in range(READY_TRIES):
            q, miss, angle = ready_pose(s.arm, grip.offset, grip.approach, grip.closing, s.ready_grip,
                                        rng.uniform(s.arm.lower, s.arm.upper))
            if miss <= READY_TOLERANCE[0] and angle <= READY_TOLERANCE[1] and \
                    not body.in_collision(q[None], self.margin)[0]:
                clear.append(q)
                if len(clear) == READY_CHOICES:
                    break
        if clear:       # the nearest the task's own, which the policy learned from (the first found had the Fetch's
            nearest = min(clear, key=lambda q: float(np.abs(q - ready).max()))     # wrist roll by its limit)
            return nearest, (f'the task\'s ready configuration touches ({touching}) within {self.margin:g} m: '
                             f'another with the gripper there is used, the nearest it of {len(clear)} found')
        raise PickError(f'{s.robot.tree.name}: the task\'s ready configuration touches ({touching}) within '
                        f'{self.margin:g} m, and no other with the gripper there is clear')

    # ------------------------------------------------------------------------------------------- what to pick
    def choose(self, clicked, objects: dict[str, np.ndarray]) -> str:
        """The object (of objects: {name: position}) nearest the clicked point, within SELECT_RADIUS of the line up
        its middle, as high as it stands (rviz gives a point on what it draws: a tall can's top is farther than that
        from its middle); PickError."""
        clicked = np.asarray(clicked, dtype=float)
        if not objects:
            raise PickError('there are no objects to pick (give arm_sim and pick_place ~objects)')

        def gap(name: str) -> float:
            middle = np.asarray(objects[name], dtype=float)
            half = self.half_height(name)
            nearest = np.array([middle[0], middle[1], np.clip(clicked[2], middle[2] - half, middle[2] + half)])
            return float(np.linalg.norm(nearest - clicked))
        name = min(objects, key=gap)
        d = gap(name)
        if d > SELECT_RADIUS:
            raise PickError(f'no object within {SELECT_RADIUS:g} m of {_point(clicked)}: the nearest, {name}, is '
                            f'{d:.3f} m away (click on an object first)')
        return name

    def half_height(self, name: str) -> float:
        """How far the object's middle stands above what it rests on, upright (the task's cube where it is not one
        of the objects given)."""
        o = self.objects.get(name)
        if o is None:
            return self.setup.object_size / 2
        return {'box': o.size[-1] / 2, 'sphere': o.size[0], 'cylinder': o.size[-1] / 2}.get(o.kind, o.size[0])

    def width(self, name: str) -> float:
        """The object's widest across the table, upright (a box's longer side, a cylinder's or a sphere's diameter;
        the task's cube where it is not one of the objects given)."""
        o = self.objects.get(name)
        if o is None:
            return self.setup.object_size
        return max(o.size[0], o.size[1]) if o.kind == 'box' else 2 * o.size[0]

    def across(self, name: str) -> float:
        """The most the object can measure across the fingers, upright, however it is turned (a box's footprint's
        diagonal, a cylinder's or a sphere's diameter; the task's cube where it is not one of the objects given)."""
        o = self.objects.get(name)
        if o is not None and o.kind == 'box':
            return float(math.hypot(o.size[0], o.size[1]))
        return self.width(name)

    def grip_rotation(self, name: str, pose: np.ndarray) -> np.ndarray:
        """The tip's rotation to hold while the policy has the arm (3x3, the root frame): the ready configuration's,
        or, for an upright box (pose: its 4x4) wider across the fingers than FITS of their opening, that turned
        about the vertical by the least angle that puts the fingers' closing axis across its narrow side."""
        s = self.setup
        ready = s.space.rotation
        o = self.objects.get(name)
        if o is None or o.kind != 'box':
            return ready
        rotation = np.asarray(pose, dtype=float)[:3, :3]
        closing = ready @ s.space.grip.closing
        across = abs(rotation[:, 0] @ closing) * o.size[0] + abs(rotation[:, 1] @ closing) * o.size[1]
        x = rotation @ ([1.0, 0.0, 0.0] if o.size[0] <= o.size[1] else [0.0, 1.0, 0.0])
        if across <= FITS * s.space.grip.opening or abs(x[2]) > 0.5:    # it fits; or lying on a side: its footprint
            return ready                                                # is not the one described
        turn = math.atan2(x[1], x[0]) - math.atan2(closing[1], closing[0])
        turn = (turn + math.pi / 2) % math.pi - math.pi / 2             # the least turn: the axis has no sign
        c, t = math.cos(turn), math.sin(turn)
        return np.array([[c, -t, 0.0], [t, c, 0.0], [0.0, 0.0, 1.0]]) @ ready

    def grasp_above(self, name: str) -> float:
        """How far above its middle the object name is gripped: 0, or where it stands taller than the fingers are
        deep, so far that its top stays PALM_CLEARANCE below the palm."""
        return max(0.0, self.half_height(name) + PALM_CLEARANCE - self.setup.space.grip.depth)

    def place_of(self, clicked, others: dict[str, np.ndarray] | None = None, name: str = '') -> np.ndarray:
        """Where the middle of the object name goes for a click on the table (the object set down on it there),
        within the workspace and clear of the others (objects: {name: position}, the one picked left out);
        PickError."""
        s = self.setup
        clicked = np.asarray(clicked, dtype=float)
        goal = clicked + [0.0, 0.0, self.half_height(name)]
        low, high = s.low.copy(), s.high.copy()
        low[2] = s.space.table_top - 0.01
        if abs(clicked[2] - s.space.table_top) > PLACE_HEIGHT:
            raise PickError(f'the place {_point(clicked)} is {clicked[2] - s.space.table_top:+.3f} m from the table\'s '
                            f'top (z {s.space.table_top:+.3f}): click on the table where the object goes')
        if not ((goal >= low) & (goal <= high)).all():
            raise PickError(f'the place {_point(clicked)} is outside the workspace the arm picks and places in (x '
                            f'{low[0]:+.2f}..{high[0]:+.2f}, y {low[1]:+.2f}..{high[1]:+.2f}, from the table\'s top '
                            f'at z {s.space.table_top:+.3f} up to {high[2]:+.3f}, in the robot\'s root frame)')
        for other, where in (others or {}).items():
            gap = float(np.linalg.norm(np.asarray(where, dtype=float)[:2] - goal[:2]))
            if gap < 1.5 * max(s.object_size, self.width(name), self.width(other)):
                raise PickError(f'the place {_point(clicked)} is taken: {other} stands {gap:.3f} m from it (click '
                                f'where the table is clear)')
        return goal

    def check_object(self, name: str, position) -> None:
        """PickError where the object lies outside the workspace (off the table, beyond the policy's reach)."""
        s = self.setup
        p = np.asarray(position, dtype=float)
        low, high = s.low, s.high
        if not ((p[:2] >= low[:2]) & (p[:2] <= high[:2])).all() or not s.space.table_top - 0.01 <= p[2] <= high[2]:
            raise PickError(f'{name} at {_point(p)} lies outside the workspace the arm picks in (x {low[0]:+.2f}..'
                            f'{high[0]:+.2f}, y {low[1]:+.2f}..{high[1]:+.2f}, over the table\'s top at z '
                            f'{s.space.table_top:+.3f})')

    # ------------------------------------------------------------------------------------------------ a pick
    def start(self, name: str, position, place, now: float) -> str:
        """A pick of the object name (at position) to place (place_of's); the line to say. PickError."""
        self.check_object(name, position)
        self.name, self.place = name, np.asarray(place, dtype=float)
        self.began = now
        self._enter('ready', now)
        self.way = None
        self.last: tuple | None = None          # (now, grip, object position, object rotation, finger)
        self.held_since: float | None = None
        self.rise_to = None
        self.lowering = False
        self.above = np.array([0.0, 0.0, self.grasp_above(name)])
        self.ajar = self.setup.ajar_for(self.across(name), self.half_height(name) - self.above[2])
        self.held = None                        # the tip's rotation while the policy has the arm: set as it begins
        self.layer.margin = self.margin         # on the way to the task: clear of every contact by the margin
        return (f'picking {name} at {_point(position)} to place it at {_point(self.place)}: to the ready '
                f'configuration first')

    def stop(self) -> None:
        self.phase = ''

    def _enter(self, phase: str, now: float) -> None:
        self.phase, self.phase_began = phase, now
        self.best, self.best_at = np.inf, now
        if phase == 'task':         # the hand comes within millimetres of the table: only touching is refused
            self.layer.margin = 0.0

    def _end(self, outcome: str) -> PickStep:
        self.phase = ''
        return PickStep(plan=None, opening=None, said=outcome, outcome=outcome)

    def observe(self, now: float, q, finger: float, pose: np.ndarray) -> dict[str, np.ndarray]:
        """The env's observation (a dict) from the arm's joints q, the gripper's first joint and the object's pose
        (4x4 in the root frame), velocities from the last call's."""
        s = self.setup
        grip = s.grip_points(np.asarray(q, dtype=float)[:, None])[0][:, 0]
        cube, rotation = pose[:3, 3].copy(), pose[:3, :3]
        opening = (finger - s.grip_closed[0]) / self.span
        velocity, spin, grip_velocity, finger_speed = np.zeros(3), np.zeros(3), np.zeros(3), 0.0
        if self.last is not None and now > self.last[0]:
            dt = now - self.last[0]
            grip_velocity = (grip - self.last[1]) / dt
            velocity = (cube - self.last[2]) / dt
            turn = rotation @ self.last[3].T
            spin = np.array([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1]]) / 2.0 / dt
            finger_speed = (opening - self.last[4]) / dt
        self.last = (now, grip, cube, rotation.copy(), opening)
        observation = np.concatenate([grip, cube, cube - grip, [opening], rpy_of(rotation), velocity, spin,
                                      grip_velocity, [finger_speed]])
        return {'achieved_goal': cube, 'desired_goal': self.place.copy(), 'observation': observation}

    def _send(self, now: float, target, q, why_not: str = '') -> Plan:
        return self.layer.plan(now, target, q, why_not=why_not)

    def _toward(self, q: np.ndarray, grip: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Joint targets that move the grip point toward target, EE_STEP at most, the gripper held pointing down."""
        s = self.setup
        step = target - grip
        d = float(np.linalg.norm(step))
        if d > EE_STEP:
            step *= EE_STEP / d
        return s.joint_targets(q[:, None], (grip + step)[:, None], self.held)[:, 0]

    def step(self, now: float, q, finger: float, pose: np.ndarray) -> PickStep:
        """One control step at time now: the arm's joints q (Arm.joints order), the gripper's first joint (m or rad)
        and the object's pose (4x4, the root frame); what to send and say."""
        q = np.asarray(q, dtype=float)
        if not self.phase:
            return PickStep()
        if not (np.isfinite(q).all() and np.isfinite(finger) and np.isfinite(pose).all()):
            if self.layer.last is None:
                return PickStep()
            return PickStep(plan=self._send(now, None, None, 'a NaN in the arm\'s or the object\'s state'))
        obs = self.observe(now, q, finger, pose)
        cube = obs['achieved_goal']
        s = self.setup
        if self.phase == 'ready':
            return self._ready(now, q)
        if self.phase == 'task':
            if self.held is None:               # the gripper turned across a wide box's narrow side
                self.held = self.grip_rotation(self.name, pose)
            distance = float(np.linalg.norm(cube - self.place))
            if distance <= PLACED_WITHIN:
                self._enter('release', now)
                return PickStep(plan=self._send(now, q, q), opening=1.0,
                                said=f'{self.name} at the place ({distance:.3f} m): opening the gripper')
            progress = distance + float(np.linalg.norm(obs['observation'][6:9]))    # object to place, hand to it
            if progress < self.best - PROGRESS:
                self.best, self.best_at = progress, now
            if now - self.best_at > STALL_TIME or now - self.phase_began > TASK_TIME:
                took = f'no progress for {STALL_TIME:g} s' if now - self.best_at > STALL_TIME else \
                    f'after {TASK_TIME:g} s'
                return self._end(f'not placed: {self.name} is {distance:.3f} m from the place, {took} of the policy '
                                 f'({self._where(obs)})')
            # the goal the policy is given: the place, for the object (as the env's reward), above it until the
            # object is over it; a tall object as the point it is gripped at (the policy learned to grip a cube's
            # middle)
            o = obs['observation'].copy()
            o[3:6] += self.above
            o[6:9] += self.above
            goal = self.place + self.above
            off = float(np.linalg.norm(cube[:2] - self.place[:2]))
            self.lowering = off <= (LOWERING if self.lowering else OVER_PLACE)
            if not self.lowering:               # carried over it first, then down
                goal[2] += CARRY
            flat = flatten({'achieved_goal': o[None, 3:6], 'desired_goal': goal[None], 'observation': o[None]})
            action = np.asarray(self.policy(flat), dtype=float).reshape(-1)
            if action.shape != (4,) or not np.isfinite(action).all():
                return self._end(f'not placed: the policy answered {action.tolist()}, not 4 finite numbers')
            action = np.clip(action, -1.0, 1.0)
            target = np.clip(obs['observation'][:3] + EE_STEP * action[:3], s.low, s.high)
            plan = self._send(now, s.joint_targets(q[:, None], target[:, None], self.held)[:, 0], q)
            return self._checked(now, plan, PickStep(plan=plan, opening=(action[3] + 1.0) / 2.0))
        grip = obs['observation'][:3]
        if self.phase == 'release':
            if obs['observation'][9] > 0.9 or now - self.phase_began > RELEASE_TIME:
                self._enter('rise', now)
                self.rise_to = grip + [0.0, 0.0, RISE]
            return PickStep(plan=self._send(now, None, q, 'the gripper opens'), opening=1.0)
        if self.phase == 'rise':
            if np.linalg.norm(grip - self.rise_to) < 0.01 or now - self.phase_began > RISE_TIME:
                self._enter('settle', now)
            else:
                plan = self._send(now, self._toward(q, grip, self.rise_to), q)
                return self._checked(now, plan, PickStep(plan=plan))
        # settle: the arm holds; the object comes to rest, then the verdict
        speed = float(np.linalg.norm(obs['observation'][14:17]))
        plan = self._send(now, None, q, 'the pick is over')
        if speed > SETTLE_SPEED and now - self.phase_began < SETTLE_TIME:
            return PickStep(plan=plan)
        distance = float(np.linalg.norm(cube - self.place))
        took = now - self.began
        if distance <= s.distance_threshold:
            return self._end(f'placed {self.name} at {_point(cube)}, {distance:.3f} m from the place, in {took:.1f} s')
        return self._end(f'not placed: {self.name} came to rest at {_point(cube)}, {distance:.3f} m from the place '
                         f'({self._where(obs)})')

    def _where(self, obs) -> str:
        """Where the object is, for a line that says why not."""
        o = obs['observation']
        cube, grip = o[3:6], o[:3]
        top = self.setup.space.table_top
        if cube[2] < top - 0.01:
            return 'it fell off the table'
        if np.linalg.norm(cube - grip) < 0.05 and self.half_height(self.name) + 0.01 < cube[2] - top:
            return 'the gripper holds it'
        return 'on the table, not held'

    def _checked(self, now: float, plan: Plan, step: PickStep) -> PickStep:
        """step, or the pick's end where the layer has refused every step for HELD_TIME."""
        if not plan.held:
            self.held_since = None
            return step
        self.held_since = now if self.held_since is None else self.held_since
        if now - self.held_since > HELD_TIME:
            return self._end(f'not placed: the safety layer held the arm for {HELD_TIME:g} s ({plan.held})')
        return step

    def _ready(self, now: float, q: np.ndarray) -> PickStep:
        """The way to the ready configuration: planned once, followed in time through the layer."""
        ready = self.ready
        if self.way is None:
            if np.abs(q - ready).max() < AT_READY:
                self._enter('task', now)
                return PickStep(plan=self._send(now, q, q), opening=1.0, said='at the ready configuration')
            from robot_ai.motion import time_path
            planner = self.planner
            if self.reach.body.in_collision(q[None], self.margin)[0]:      # within the margin: out with none kept
                planner = self.reach.joint_planner(0.0, self.limits, 0.001)
            path = planner.plan(q, ready[None], PLAN_TIME)
            if not path.found:
                return self._end(f'not placed: no way to the ready configuration ({path.reason})')
            self.way = time_path(path.waypoints, self.limits.velocity, self.limits.acceleration, planner.path_clear)
            self.way_began = now
            return PickStep(plan=self._send(now, q, q), opening=1.0,
                            said=f'a way to the ready configuration planned ({path.how}, '
                                 f'{self.way.duration:.1f} s)')
        t = now - self.way_began + self.layer.lead + self.period
        if t > self.way.duration and np.abs(q - ready).max() < AT_READY:
            self._enter('task', now)
            self.way = None
            return PickStep(plan=self._send(now, ready, q), said='at the ready configuration: the policy has the arm')
        if now - self.way_began > self.way.duration + 5.0:
            return self._end(f'not placed: the arm did not come to the ready configuration (it stands '
                             f'{np.abs(q - ready).max():.3f} rad from it)')
        target = self.way.positions(min(t, self.way.duration))
        plan = self._send(now, target, q)
        return self._checked(now, plan, PickStep(plan=plan))


# ------------------------------------------------------------------------------------- in-process, measured
@dataclasses.dataclass
class PickRun:
    """run_in_physics' answer: the outcome line and what the physics measured while the layer drove the arm: the
    largest joint speed as a share of its URDF velocity limit, the largest gap between where the layer's plans put
    each joint and where the servos held it (rad or m), and every contact of the robot with anything else
    ('link - geom', the object picked among them), and whether every joint stayed within its position limits."""
    outcome: str
    seconds: float
    fastest: float
    tracking: float
    contacts: list[str]
    within_limits: bool


def run_in_physics(picking: PickPlace, arm, name: str, place, tick: float = 0.01, most: float = 60.0) -> PickRun:
    """A pick of the object name to place (a click on the table) in arm (a physics.sim.ArmPhysics of the same robot
    and world, its joints the setup's arm's), as arm_sim runs it: the layer's plans followed in time (each tick's
    servo target the plan's position then), the gripper's goals as gripper_action_controller takes them, a control
    step every picking.period; what the physics measured on the way."""
    from robot_ai.physics.model import robot_contacts
    s = picking.setup
    position = arm.object_poses()[name][:3, 3]
    picking.start(name, position, picking.place_of(place, name=name), 0.0)
    velocity_limit = s.arm.velocity           # the URDF's (unscaled)
    t, opening, outcome = 0.0, None, ''
    fastest, tracking, contacts, within = 0.0, 0.0, set(), True
    lower, upper = s.arm.lower - 1e-3, s.arm.upper + 1e-3
    ticks = max(1, int(round(picking.period / tick)))
    while t < most:
        step = picking.step(t, arm.positions, arm.gripper_state()[0], arm.object_poses()[name])
        if step.opening is not None and step.opening != opening:
            opening = step.opening
            arm.grip(s.grip_position(opening))
        if step.outcome:
            outcome = step.outcome
            break
        for k in range(ticks):
            now = t + tick * (k + 1)
            target = picking.layer.commanded_at(now) if picking.layer.last is not None else arm.positions
            arm.step(target, tick)
            fastest = max(fastest, float(np.max(np.abs(arm.velocities) / velocity_limit)))
            tracking = max(tracking, float(np.max(np.abs(target - arm.positions))))
            within = within and bool(((arm.positions >= lower) & (arm.positions <= upper)).all())
            contacts.update(robot_contacts(arm.model, arm.data))
        t += picking.period
    return PickRun(outcome or f'not placed: still going after {most:g} s', t, fastest, tracking, sorted(contacts),
                   within)
