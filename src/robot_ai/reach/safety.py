"""The safety layer between any reach policy and an arm's controller: limits no policy can pass. No rospy.

    limits = Limits.of(arm, joint_limits='joint_limits.yaml', velocity_scale=0.25)
    layer = SafetyLayer(limits, period=0.05, body=collision_model, margin=0.02)
    plan = layer.plan(now, target, measured)      # every control step; target None: stop
    plan.state_at(t)                              # (positions, velocities) the arm is commanded to be at, at t

Each step plans from the state the previous plan commands at the plan's start (``now`` + ``lead``, two control
periods by default): one step of
``period`` seconds toward the target at a constant acceleration per joint, then a stop at the acceleration limits.
The plan is sent whole (a trajectory's points: the step's end, then where each joint comes to rest), so an arm whose
next command is late, or never comes, stops on a path already checked. A plan is sent only if its whole path, step
and stop, stays within the joint limits and clear of the arm's body and the world (with a margin); otherwise the
previous plan's stop goes on, and the plan says why. Every velocity is within the limit, every acceleration within
its limit, by construction: within a segment between two points each joint's acceleration is constant, so a cubic
Hermite interpolation of the points (what joint_trajectory_controller does with positions and velocities) is the
plan itself.

The measured state is compared with where the plans sent put the arm at the time it was measured (its stamp), not
at now: joint_states come tens of milliseconds late on a loaded machine, and a moving arm is then "behind" its
commands by its speed times the delay. Only an arm that stays RESYNC from its commands for RESYNC_AFTER (someone
else moved it, a controller that does not follow) is planned from where it was measured, its stop from that moment.

Limits come from the URDF (position, velocity) and MoveIt's ``joint_limits.yaml`` (``joint_limits: {name:
{has_velocity_limits, max_velocity, has_acceleration_limits, max_acceleration, has_position_limits, min_position,
max_position}}``), which can only narrow the URDF's; velocities and accelerations are scaled by velocity_scale (and
acceleration_scale, the same by default), as a real bring-up starts well below full speed. A joint without an
acceleration limit anywhere gets ``DEFAULT_ACCELERATION_TIME``'s: full (scaled) speed in a quarter second.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from robot_ai.motion.body import BodyError, read_yaml
from robot_ai.reach.arm import Arm, ReachError

DEFAULT_VELOCITY_SCALE = 0.25
DEFAULT_ACCELERATION_TIME = 0.25   # s to full speed where no acceleration limit is given: max_acceleration = v / this
DEFAULT_MARGIN = 0.02              # m kept between the arm's body and itself or an obstacle
SAMPLE_STEP = 0.005                # rad (or m) of any joint between two configurations checked along a plan
MAX_SAMPLES = 200                  # configurations checked per plan at most
RESYNC = 0.1                       # rad (or m): an arm this far from where its plan puts it holds, and
RESYNC_AFTER = 0.3                 # s: if it stays that far this long, is planned from where it stands
HISTORY = 2.0                      # s of plans kept: a state measured up to this long ago is compared with what
                                   # was commanded at its time
POSITION_TOLERANCE = 1e-9
LEAD_PERIODS = 2                   # a plan starts this many control periods after it is made: a command that reaches
                                   # the arm later than that is spliced in from where the arm is, with a jolt
SHORTER = (0.5, 0.25, 0.1)         # a step that would touch is tried again toward these shares of its target
READY_WITHIN = 0.6                 # of the lead: a plan made later than this after its `now` (its collision checks
                                   # slowed by a loaded machine) is not sent: the rest of the lead is for the delivery
MAX_LEAD_PERIODS = 10              # the longest lead measure_lead gives: a goal's first motion starts this late


@dataclass(frozen=True)
class Limits:
    """Per joint of the arm, in its order: the positions, velocities and accelerations no command passes."""
    joints: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray         # scaled
    acceleration: np.ndarray     # scaled
    velocity_scale: float
    acceleration_scale: float
    notes: tuple[str, ...] = ()  # what was assumed (no acceleration limit given)

    @classmethod
    def of(cls, arm: Arm, joint_limits=None, velocity_scale: float = DEFAULT_VELOCITY_SCALE,
           acceleration_scale: float | None = None) -> Limits:
        """The arm's URDF limits, narrowed by joint_limits (a MoveIt joint_limits.yaml: a path, its text, or its
        parsed dict; None: none) and scaled."""
        velocity_scale = _scale('velocity_scale', velocity_scale)
        acceleration_scale = velocity_scale if acceleration_scale is None else _scale('acceleration_scale',
                                                                                        acceleration_scale)
        given, named = joint_names(read_joint_limits(joint_limits), list(arm.tree.joints))
        lower, upper = arm.lower.copy(), arm.upper.copy()
        velocity = arm.velocity.copy()
        for k, name in enumerate(arm.joints):
            entry = given.get(name, {})
            if entry.get('has_position_limits'):
                lower[k] = max(lower[k], entry.get('min_position', lower[k]))
                upper[k] = min(upper[k], entry.get('max_position', upper[k]))
                if lower[k] >= upper[k]:
                    raise ReachError(f'joint_limits: {name} has no positions left between the URDF\'s range and '
                                     f'min_position/max_position')
            if entry.get('has_velocity_limits') and 'max_velocity' in entry:
                velocity[k] = min(velocity[k], entry['max_velocity'])
        acceleration, missing = acceleration_limits(given, arm.joints, velocity)
        notes = named + ((f'no acceleration limit for {", ".join(missing)}: full speed in '
                          f'{DEFAULT_ACCELERATION_TIME:g} s assumed (give them in a joint_limits.yaml)',)
                         if missing else ())
        return cls(tuple(arm.joints), lower, upper, velocity * velocity_scale, acceleration * acceleration_scale,
                   velocity_scale, acceleration_scale, notes)

    @property
    def unscaled_acceleration(self) -> np.ndarray:
        """The acceleration limits before acceleration_scale: the hardest the arm can brake."""
        return self.acceleration / self.acceleration_scale

    def describe(self) -> str:
        return (f'velocities x{self.velocity_scale:g} (up to {self.velocity.max():.3g}), accelerations '
                f'x{self.acceleration_scale:g} (up to {self.acceleration.max():.3g})')


def acceleration_limits(given: dict[str, dict], joints, velocity: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(each joint's acceleration limit, the joints that had none): a joint_limits entry's max_acceleration (keyed
    by joint_names), else full speed (velocity) in DEFAULT_ACCELERATION_TIME."""
    acceleration = np.asarray(velocity, dtype=float) / DEFAULT_ACCELERATION_TIME
    missing = []
    for k, name in enumerate(joints):
        entry = given.get(name, {})
        if entry.get('has_acceleration_limits') and 'max_acceleration' in entry:
            acceleration[k] = entry['max_acceleration']
        else:
            missing.append(name)
    return acceleration, missing


def _scale(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1:
        raise ReachError(f'{name} must be a number in (0, 1], got {value!r}')
    return float(value)


def joint_names(given: dict[str, dict], joints: list[str]) -> tuple[dict[str, dict], tuple[str, ...]]:
    """(the joint limits keyed by the robot's joint names, notes of one line each): a name that is no joint but whose
    `<name>_joint` is exactly one (ur_description's file says shoulder_pan for shoulder_pan_joint, or for
    left_shoulder_pan_joint under a prefix) is taken for it, and said; names that are no joint are said and left out
    (a gripper's joints beside an arm's are usual); a file none of whose names is a joint is ReachError."""
    if not given:
        return given, ()
    known, out, mapped, unknown = set(joints), {}, [], []
    for name, entry in given.items():
        if name in known:
            out[name] = entry
            continue
        found = [j for j in joints if j == f'{name}_joint' or j.endswith(f'_{name}_joint')]
        if len(found) == 1 and found[0] not in given:
            out[found[0]] = entry
            mapped.append(f'{name} -> {found[0]}')
        else:
            unknown.append(name)
    if not out:
        raise ReachError(f'joint_limits: none of its names ({", ".join(sorted(given)[:8])}) is a joint of this robot '
                         f'({", ".join(joints[:8])}{", ..." if len(joints) > 8 else ""})')
    notes = ((f'joint_limits: names taken for the robot\'s joints: {", ".join(mapped)}',) if mapped else ()) + \
        ((f'joint_limits: {", ".join(sorted(unknown))} {"is no joint" if len(unknown) == 1 else "are no joints"} of '
          f'this robot: left out',) if unknown else ())
    return out, notes


MIN_LIMIT, MAX_LIMIT = 1e-6, 1e6    # a velocity or acceleration limit no plan can use outside these (rad/s, rad/s^2)


def read_joint_limits(source) -> dict[str, dict]:
    """{joint: {has_velocity_limits: bool, max_velocity: float, ...}} of MoveIt's joint_limits.yaml format, from a
    path, YAML text or a dict (a ROS parameter); None or '' is {}. ReachError of one line for anything else."""
    if source is None or source == '' or source == {}:
        return {}
    if isinstance(source, str):
        try:
            source = read_yaml(source, 'joint_limits')
        except BodyError as e:
            raise ReachError(str(e)) from None
    if not isinstance(source, dict) or not isinstance(source.get('joint_limits'), dict):
        raise ReachError('joint_limits: expected MoveIt\'s format, a mapping with joint_limits: {joint: {...}}')
    out = {}
    for name, entry in source['joint_limits'].items():
        if not isinstance(entry, dict):
            raise ReachError(f'joint_limits: {name} must be a mapping, got {entry!r}')
        clean = {}
        for key, value in entry.items():
            if key.startswith('has_'):
                if not isinstance(value, bool):
                    raise ReachError(f'joint_limits: {name}.{key} must be true or false, got {value!r}')
            elif key in ('max_velocity', 'max_acceleration', 'max_jerk', 'max_deceleration'):
                if entry.get(f'has_{key[len("max_"):]}_limits') is not True:
                    continue      # MoveIt's meaning: a value without its has_..._limits: true is no limit
                                  # (panda_moveit_config's max_acceleration: 0 beside has_acceleration_limits: false)
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
                    raise ReachError(f'joint_limits: {name}.{key} must be a positive number, got {value!r}')
                if not MIN_LIMIT <= value <= MAX_LIMIT:      # 5e-324 made every plan NaN, 1e-9 a stop of 1.8e8 rad
                    raise ReachError(f'joint_limits: {name}.{key} {value!r} is outside what a plan can use '
                                     f'({MIN_LIMIT:g} to {MAX_LIMIT:g})')
            elif key in ('min_position', 'max_position'):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ReachError(f'joint_limits: {name}.{key} must be a finite number, got {value!r}')
            clean[key] = value
        out[str(name)] = clean
    return out


# ----------------------------------------------------------------------------------------------- the state
STAMP_WINDOW = (5.0, 0.05)   # s before and after a node's time within which the first stamped state says the stamps
                             # are on its clock (a driver's and a simulator's are; another machine's may not be)


@dataclass
class StampClock:
    """The time a joint state describes. Its stamp, when the stamps are on the node's clock, as the first stamped
    state says (within STAMP_WINDOW of the node's time), so that a state delivered late is old however fresh its
    arrival (issue 55: states 0.3-0.6 s late were taken as fresh, and the arm moved at 4 times its scaled velocity
    limit); otherwise, and for a state without a stamp, the time it came, said once.

        clock = StampClock()
        at, note = clock.time_of(stamp, now)        # stamp None: none; note: '' or the one line to say, once
    """
    ours: bool | None = None       # the stamps are on the node's clock (None: no stamped state yet)
    said: bool = False

    def time_of(self, stamp: float | None, now: float) -> tuple[float, str]:
        if stamp is not None and math.isfinite(stamp) and self.ours is None:
            self.ours = now - STAMP_WINDOW[0] <= stamp <= now + STAMP_WINDOW[1]
        if stamp is not None and math.isfinite(stamp) and self.ours:
            return min(stamp, now), ''
        note = ''
        if not self.said:
            self.said = True
            note = ('joint_states ' + ('has no stamps' if stamp is None else
                                       f'is stamped on another clock (its first stamp was over '
                                       f'{STAMP_WINDOW[0]:g} s from this node\'s time)')
                    + ': its age is taken from when it comes, not from when it was measured')
        return now, note


# ----------------------------------------------------------------------------------------------------- plans
@dataclass
class Plan:
    """Commanded motion from ``start`` (s): at ``times[k]`` after it each joint is at ``positions[k]`` with
    ``velocities[k]``, each joint's acceleration constant between two points; the last point is at rest.
    ``held``: '' when the step moves toward the target asked for, else why it does not (the previous plan's stop
    goes on); ``contacts``: the pairs that refused it."""
    start: float
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    held: str = ''
    contacts: list[str] = field(default_factory=list)

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) commanded at time t (before the start: the first point; after the end: rest)."""
        tau = t - self.start
        if tau <= 0.0:
            return self.positions[0].copy(), self.velocities[0].copy()
        if tau >= self.times[-1]:
            return self.positions[-1].copy(), np.zeros_like(self.velocities[-1])
        k = int(np.searchsorted(self.times, tau, side='right')) - 1
        return _along(self.times[k + 1] - self.times[k], self.positions[k], self.velocities[k],
                      self.velocities[k + 1], tau - self.times[k])

    @property
    def end(self) -> float:
        return self.start + float(self.times[-1])

    def rest(self) -> np.ndarray:
        return self.positions[-1].copy()

    def after(self, t: float) -> Plan:
        """This plan from time t on (its state at t first), to be sent again."""
        t = max(t, self.start)
        p, v = self.state_at(t)
        keep = self.start + self.times > t + 1e-9
        times = np.concatenate(([0.0], self.start + self.times[keep] - t))
        return Plan(t, times, np.vstack((p, self.positions[keep])), np.vstack((v, self.velocities[keep])),
                    self.held, self.contacts)

    def points(self, hold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(times from the start, positions, velocities) of a trajectory message: the points after the first (the
        state at the start, which the arm is in); a plan at rest is one point at rest, hold seconds on."""
        if len(self.times) > 1:
            return self.times[1:], self.positions[1:], self.velocities[1:]
        return np.array([hold]), self.positions[:1], np.zeros_like(self.positions[:1])

    def samples(self, step: float = SAMPLE_STEP, most: int = MAX_SAMPLES) -> np.ndarray:
        """(M, n) configurations along the plan, no joint moving more than about step between two."""
        out = [self.positions[:1]]
        for k in range(len(self.times) - 1):
            span = self.times[k + 1] - self.times[k]
            p0, v0, v1 = self.positions[k], self.velocities[k], self.velocities[k + 1]
            # the most a joint travels within the segment (a reversal included)
            a = (v1 - v0) / span
            reach = np.abs(self.positions[k + 1] - p0)
            with np.errstate(divide='ignore', invalid='ignore'):
                turn = np.where((v0 * v1 < 0) & (a != 0), v0 * v0 / np.abs(a), 0.0)
            m = int(min(most, max(1, math.ceil(float(np.max(reach + turn, initial=0.0)) / step))))
            taus = np.linspace(span / m, span, m)[:, None]
            out.append(p0 + v0 * taus + 0.5 * a * taus * taus)
        q = np.vstack(out)
        if len(q) > most:
            q = q[np.linspace(0, len(q) - 1, most).round().astype(int)]
        return q


def _along(span: float, p0: np.ndarray, v0: np.ndarray, v1: np.ndarray, tau: float):
    """(position, velocity) tau into a segment of constant acceleration from (p0, v0) to velocity v1 over span."""
    a = (v1 - v0) / span
    return p0 + v0 * tau + 0.5 * a * tau * tau, v0 + a * tau


def stop_from(start: float, p: np.ndarray, v: np.ndarray, acceleration: np.ndarray) -> Plan:
    """Each joint from (p, v) to rest at its acceleration limit: points at every joint's stop time."""
    with np.errstate(divide='ignore', invalid='ignore'):
        stops = np.where(v != 0.0, np.abs(v) / acceleration, 0.0)
    times = [0.0]
    for s in sorted(float(s) for s in stops if s > 0.0):      # stops closer than 1 us: one point, at the later
        if s - times[-1] < 1e-6 and len(times) > 1:
            times[-1] = s
        elif s >= 1e-6:
            times.append(s)
    positions, velocities = [], []
    for t in times:
        tt = np.minimum(t, stops)
        sign = np.sign(v)
        positions.append(p + v * tt - 0.5 * sign * acceleration * tt * tt)
        velocities.append(np.where(t >= stops, 0.0, v - sign * acceleration * tt))
    if len(times) == 1:                         # at rest already: one point
        return Plan(start, np.array([0.0]), p[None].copy(), np.zeros((1, len(p))))
    return Plan(start, np.array(times), np.array(positions), np.array(velocities))


def reach_bounds(p0, v0, lower, upper, acceleration) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, the positions a plan from (p0, v0) may pass through: the position limits, widened only to where the
    arm is and to where braking at the acceleration limit stops it. A state outside a narrowed range, or moving too
    fast to stop before a limit, can only come back in: every plan from it is checked against these, so that none
    takes it farther out, and none is refused for where it already is (issue 55: after one such state every goal
    and ~home were refused). Within the limits and able to stop there: the limits themselves."""
    with np.errstate(divide='ignore', invalid='ignore'):
        stop = p0 + v0 * np.abs(v0) / (2.0 * acceleration)
    stop = np.where(np.isfinite(stop), stop, p0)
    return np.minimum(lower, np.minimum(p0, stop)), np.maximum(upper, np.maximum(p0, stop))


def stop_within(start: float, p: np.ndarray, v: np.ndarray, limits: Limits) -> Plan:
    """The stop of a measured state (p, v): at the layer's acceleration, or harder, up to the unscaled limit
    (acceleration / acceleration_scale: what the arm can), where that keeps a joint within its position limits; a
    joint that cannot stop before its limit even so brakes at that, the least it can pass it by."""
    a, full = limits.acceleration, limits.unscaled_acceleration
    room = np.where(v > 0, limits.upper - p, np.where(v < 0, p - limits.lower, np.inf))
    with np.errstate(divide='ignore', invalid='ignore'):
        needed = np.where(room > 0, v * v / (2.0 * room), np.inf)
    return stop_from(start, p, v, np.clip(np.nan_to_num(needed, nan=0.0, posinf=np.inf), a, full))


def step_velocity(p0: np.ndarray, v0: np.ndarray, target: np.ndarray, limits: Limits, dt: float) -> np.ndarray:
    """Each joint's velocity at the end of a step of dt at constant acceleration from (p0, v0): as fast toward the
    target as the velocity and acceleration limits let it and still able to stop at the target (and so within the
    position limits, where the target is)."""
    return _step_velocity(p0, v0, target, limits.velocity, limits.acceleration, dt)


def _step_velocity(p0, v0, target, vmax, a, dt: float) -> np.ndarray:
    """step_velocity's numbers, element-wise (the limits broadcast against p0: (n,) or (n, 1) for a batch)."""
    e = target - p0
    sign = np.where(e >= 0.0, 1.0, -1.0)
    e, w0 = np.abs(e), v0 * sign                 # toward the target is positive
    # the largest w1 with w1^2 / (2a) <= e - (w0 + w1) dt / 2 (stop at the target after the step)
    disc = (a * dt) ** 2 + 4.0 * (2.0 * a * e - a * dt * w0)
    w1 = np.where(disc >= 0.0, (-a * dt + np.sqrt(np.maximum(disc, 0.0))) / 2.0, -np.inf)
    w1 = np.minimum(w1, 2.0 * e / dt - w0)                             # reach the target, no farther, in one step
    with np.errstate(divide='ignore', invalid='ignore'):                # a turn within the step: not beyond it either
        w1 = np.where((w0 > 0.0) & (w1 < 0.0), np.minimum(w1, w0 - dt * w0 * w0 / (2.0 * e)), w1)
    w1 = np.clip(w1, -vmax, vmax)
    w1 = np.clip(w1, w0 - a * dt, w0 + a * dt)                         # the acceleration limit wins
    return w1 * sign


@dataclass
class StepKinds:
    """How each joint moves within one step toward its target (SafetyLayer._step), element-wise: joints (n,) or a
    batch (n, N), the limits (n,) or (n, 1). brake: it would pass a position limit, so it brakes (at the
    acceleration limit a, to rest at its stop time); arrive: it comes to rest at the target at the step's end (from
    v0 to vm over the first half at a1, to rest at a2); else steady: a constant acceleration to v1."""
    dt: float
    a: np.ndarray
    v1: np.ndarray
    steady: np.ndarray
    brake: np.ndarray
    arrive: np.ndarray
    vm: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    stops: np.ndarray           # a braking joint's stop time (inf for the others)

    @classmethod
    def of(cls, p0, v0, target, lower, upper, velocity, a, dt: float) -> StepKinds:
        half = dt / 2.0
        lower, upper = reach_bounds(p0, v0, lower, upper, a)   # from outside a range: back in, never farther out
        out = lambda x: (x < lower - POSITION_TOLERANCE) | (x > upper + POSITION_TOLERANCE)   # noqa: E731
        v1 = _step_velocity(p0, v0, target, velocity, a, dt)
        p1 = p0 + 0.5 * (v0 + v1) * dt
        steady = (v1 - v0) / dt
        with np.errstate(divide='ignore', invalid='ignore'):
            turn = np.where(v0 * v1 < 0.0, p0 - 0.5 * v0 * v0 / steady, p1)        # the turning point, if any
        rest = p1 + v1 * np.abs(v1) / (2.0 * a)
        brake = out(turn) | out(p1) | out(rest)
        # to rest at the target: from v0 to vm over the first half, from vm to 0 over the second
        vm = (4.0 * (target - p0) / dt - v0) / 2.0
        a1, a2 = (vm - v0) / half, -vm / half
        with np.errstate(divide='ignore', invalid='ignore'):
            turn1 = np.where(v0 * vm < 0.0, p0 - 0.5 * v0 * v0 / a1, p0)
        tol = 1 + 1e-9
        arrive = ((np.abs(a1) <= a * tol) & (np.abs(a2) <= a * tol) & (np.abs(vm) <= velocity) & ~out(turn1)
                  & ~brake)
        return cls(dt, a, v1, steady, brake, arrive, vm, a1, a2, np.where(brake, np.abs(v0) / a, np.inf))

    def at(self, t: float, p0: np.ndarray, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) t seconds into the step (0 to dt), each joint the way its kind moves."""
        a, half = self.a, self.dt / 2.0
        tb = np.minimum(t, self.stops)
        sign = np.sign(v0)
        pb, vb = p0 + v0 * tb - 0.5 * sign * a * tb * tb, np.where(t >= self.stops, 0.0, v0 - sign * a * tb)
        if t <= half:
            pa, va = p0 + v0 * t + 0.5 * self.a1 * t * t, v0 + self.a1 * t
        else:
            pm = p0 + v0 * half + 0.5 * self.a1 * half * half
            pa, va = pm + self.vm * (t - half) + 0.5 * self.a2 * (t - half) ** 2, self.vm + self.a2 * (t - half)
        ps, vs = p0 + v0 * t + 0.5 * self.steady * t * t, v0 + self.steady * t
        return (np.where(self.brake, pb, np.where(self.arrive, pa, ps)),
                np.where(self.brake, vb, np.where(self.arrive, va, vs)))


def step_end(p0: np.ndarray, v0: np.ndarray, target: np.ndarray, limits: Limits,
             dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) one step of dt on, each joint moving as the safety layer plans it (SafetyLayer._step,
    whose plan is this at its step's end), element-wise: p0, v0, target (n,) or a batch (n, N). What an arm driven
    through reach_controller does in one control period, for an env to model (ReachSetup velocity_scale)."""
    shape = (-1,) + (1,) * (np.ndim(p0) - 1)
    lower, upper = limits.lower.reshape(shape), limits.upper.reshape(shape)
    velocity, a = limits.velocity.reshape(shape), limits.acceleration.reshape(shape)
    k = StepKinds.of(p0, v0, target, lower, upper, velocity, a, dt)
    positions, velocities = k.at(dt, p0, v0)
    return np.where(k.arrive, target, positions), np.where(k.arrive, 0.0, velocities)   # at rest there exactly


class SafetyLayer:
    """Plans every command (see the module); body: a CollisionModel (motion.body) or None (limits only)."""

    def __init__(self, limits: Limits, period: float, body=None, margin: float = DEFAULT_MARGIN,
                 lead: float | None = None, follows_plans: bool = True):
        if not 0 < period < math.inf:
            raise ReachError(f'period must be a positive number of seconds, got {period!r}')
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not 0 <= margin <= 1:
            raise ReachError(f'margin must be a number of metres from 0 to 1, got {margin!r}')
        self.limits, self.period, self.body, self.margin = limits, float(period), body, float(margin)
        self.lead = LEAD_PERIODS * self.period if lead is None else float(lead)
        # True: the arm follows each plan in time (a trajectory controller); False: it goes to each plan's first
        # point as it comes (a position controller, sent that point), so it is where the last plan sent starts
        self.follows_plans = bool(follows_plans)
        self.last: Plan | None = None
        self.history: list[Plan] = []           # the plans sent, each followed from its start until the next's
        self.resynced = ''       # why the last plan started from the measured state rather than the previous plan
        self.off_since: float | None = None    # since when the arm is RESYNC from where its plan puts it

    def _commit(self, plan: Plan) -> None:
        """plan is sent: the arm follows it from its start on (until the next one's)."""
        self.last = plan
        self.history.append(plan)
        while len(self.history) > 1 and self.history[1].start <= plan.start - HISTORY:
            del self.history[0]

    def commanded_at(self, t: float) -> np.ndarray:
        """Where the plans sent put the arm at time t: following them in time, the state at t of the last that
        started by t; else (follows_plans False) the first point of the last sent by t (made lead before its
        start)."""
        for plan in reversed(self.history):
            if self.follows_plans and plan.start <= t:
                return plan.state_at(t)[0]
            if not self.follows_plans and plan.start - self.lead <= t + 1e-9:
                return plan.positions[0].copy()
        return self.history[0].positions[0].copy()

    def start_state(self, now: float, measured: np.ndarray | None,
                    measured_velocity: np.ndarray | None = None,
                    measured_at: float | None = None) -> tuple[float, np.ndarray, np.ndarray, str]:
        """(the next plan's start, positions and velocities there, '' or why the arm is planned from anew, or
        'off: ...' while it is far from where its commands put it but not yet for RESYNC_AFTER: a state that came
        late, say, whose next message puts it right; a trajectory that started from it would jump). measured is
        the arm's state at time measured_at (now when None), compared with where the plans sent put it then;
        None: not measured (a hold), from the plans."""
        start = now + self.lead
        at = now if measured_at is None else min(float(measured_at), now)
        if self.last is not None and measured is None:
            p, v = self.last.state_at(start)
            return start, p, v, ''
        measured = np.asarray(measured, dtype=float)
        if self.last is not None:
            here = self.commanded_at(at)
            off = np.abs(here - measured)
            if off.max() <= RESYNC:
                self.off_since = None
                p, v = self.last.state_at(start)
                return start, p, v, ''
            k = int(np.argmax(off))
            self.off_since = now if self.off_since is None else self.off_since
            if now - self.off_since < RESYNC_AFTER:
                p, v = self.last.state_at(start)
                return start, p, v, (f'off: the arm is {off[k]:.3f} away from where its commands put it '
                                     f'({self.limits.joints[k]})')
            why = (f'the arm is {off[k]:.3f} away from where its commands put it ({self.limits.joints[k]}) for '
                   f'{now - self.off_since:.1f} s: planned from where it stands')
            self.off_since = None
        else:
            why = ''
        v = np.zeros(len(measured)) if measured_velocity is None else np.clip(
            np.nan_to_num(np.asarray(measured_velocity, dtype=float)), -self.limits.velocity, self.limits.velocity)
        # where the arm is, never clipped into the range (a narrowed range the arm stands outside of: it was a jump
        # of 1 rad at once); its stop from when it was measured, within the position limits wherever the arm can
        # stop within them, checked as every plan is (issue 55)
        stop = stop_within(at, measured, v, self.limits)
        refused = self.check_limits(stop)
        if refused:
            raise ReachError(f'the stop from the measured state {refused}')      # not expected: reach_bounds
        self._commit(stop)
        p, v = self.last.state_at(start)
        return start, p, v, why

    def plan(self, now: float, target, measured, measured_velocity=None, why_not: str = '',
             measured_at: float | None = None, clock: Callable[[], float] | None = None) -> Plan:
        """The plan to send at time now toward target (joint positions; None, or why_not given: stop and hold),
        the arm measured at `measured` at time measured_at (now when None; measured None: not measured, from the
        plans sent). Never raises on numbers: a NaN anywhere stops the arm. clock: the time now, read once the plan
        is made: a plan not made within READY_WITHIN of the lead would reach the arm after its start, spliced in
        with a jolt, so the previous plan's stop goes on instead (a hold: the same path, harmless however late)."""
        if measured is None and self.last is None:
            raise ReachError('the arm has not been measured and there is no plan to hold: nothing to send')
        if measured is not None:
            measured = np.asarray(measured, dtype=float)
            if not np.isfinite(measured).all():
                if self.last is None:
                    raise ReachError('the arm\'s state is not finite and there is no plan to hold: nothing to send')
                return self._hold(now + self.lead, 'the arm\'s state has a NaN or infinite position')
        start, p0, v0, self.resynced = self.start_state(now, measured, measured_velocity, measured_at)
        if self.resynced.startswith('off: '):
            why, self.resynced = self.resynced[5:], ''
            return self._hold(start, why)
        if why_not or target is None:
            return self._hold(start, why_not or 'stopped')
        target = np.asarray(target, dtype=float)
        if target.shape != p0.shape or not np.isfinite(target).all():
            return self._hold(start, 'the target has a NaN or infinite position' if target.shape == p0.shape else
                              f'the target has {target.size} positions, the arm {p0.size} joints')
        target = np.clip(target, self.limits.lower, self.limits.upper)
        plan = self._step(start, p0, v0, target)
        padding = self.padding(p0)
        refused, contacts = self.check(plan, padding)
        for share in SHORTER:            # refused: a step toward a nearer target (a slower approach, a shorter stop)
            if not contacts:
                break
            shorter = self._step(start, p0, v0, p0 + (target - p0) * share)
            if not self.check(shorter, padding)[0]:
                plan, refused = shorter, ''
                break
        if refused:
            held = self._hold(start, refused)
            held.contacts = contacts
            return held
        if clock is not None:
            took = clock() - now
            if took > READY_WITHIN * self.lead:
                return self._hold(start, f'the plan took {1000 * took:.0f} ms to make (a loaded machine), too late to '
                                         f'reach the arm before its start')
        self._commit(plan)
        return plan

    def _step(self, start: float, p0: np.ndarray, v0: np.ndarray, target: np.ndarray) -> Plan:
        """One step of period toward target, then the stop. Each joint moves in one of three ways within the step
        (StepKinds): at a constant acceleration (step_velocity's); to rest at the target at the step's end, in two
        halves, where the limits allow it (so that a target held still is reached, not circled); or, where the
        first would pass a position limit (a target that moved, a float's last bit), braking as the previous plan's
        stop has it do, to rest within the step if it can (a point at its stop time)."""
        lim, dt = self.limits, self.period
        k = StepKinds.of(p0, v0, target, lim.lower, lim.upper, lim.velocity, lim.acceleration, dt)
        times = sorted({0.0, dt, *([dt / 2.0] if k.arrive.any() else []),
                        *(float(t) for t in k.stops if 1e-6 < t < dt - 1e-6)})
        states = [k.at(t, p0, v0) for t in times]
        positions, velocities = np.array([p for p, _ in states]), np.array([v for _, v in states])
        velocities[-1, k.arrive] = 0.0
        positions[-1, k.arrive] = target[k.arrive]
        tail = stop_from(start + dt, positions[-1], velocities[-1], lim.acceleration)
        return Plan(start, np.concatenate((times, dt + tail.times[1:])), np.vstack((positions, tail.positions[1:])),
                    np.vstack((velocities, tail.velocities[1:])))

    def padding(self, here: np.ndarray) -> float:
        """The margin a plan from here keeps: ~margin, or none where the arm is within it already (it may move
        out, touching nothing)."""
        if self.body is None or not self.margin or self.body.in_collision(here[None], self.margin)[0]:
            return 0.0
        return self.margin

    def clear_of(self, q: np.ndarray) -> str:
        """'' where a plan may take the arm to q and stay (within the position limits, clear of its body and the world
        by the margin), else why not, one line: a home within the margin was refused step by step for a minute while
        ~home answered success (issue 55)."""
        q = np.asarray(q, dtype=float)
        lim = self.limits
        outside = [n for n, v, lo, hi in zip(lim.joints, q, lim.lower, lim.upper)
                   if not lo - POSITION_TOLERANCE <= v <= hi + POSITION_TOLERANCE]
        if outside:
            return f'outside the limits of {", ".join(outside)}'
        if self.body is None or not self.body.in_collision(q[None], self.margin)[0]:
            return ''
        touching = self.body.contacts(q)
        if touching:
            return f'in contact ({", ".join(touching)})'
        return f'within the {self.margin:g} m margin ({", ".join(self.body.contacts(q, self.margin))})'

    def resting(self, now: float) -> bool:
        """Whether the arm is at rest by its commands at now (no plan, or the last one's stop has run out or holds
        it still): nothing more needs sending."""
        last = self.last
        return last is None or last.end < now or not last.velocities.any()

    def check_limits(self, plan: Plan, q: np.ndarray | None = None) -> str:
        """'' or why the plan (its samples q) passes a position limit: the bounds of its start (reach_bounds)."""
        q = plan.samples() if q is None else q
        lim = self.limits
        # widened only to where braking as hard as the arm can (the unscaled limit) stops it: a plan that brakes
        # gentler past a limit is refused, and the harder stop already sent goes on
        lower, upper = reach_bounds(plan.positions[0], plan.velocities[0], lim.lower, lim.upper,
                                    lim.unscaled_acceleration)
        low, high = q < lower - POSITION_TOLERANCE, q > upper + POSITION_TOLERANCE
        if low.any() or high.any():
            k = int(np.argmax((low | high).any(axis=0)))
            return f'it would pass {lim.joints[k]}\'s limit'
        return ''

    def check(self, plan: Plan, padding: float) -> tuple[str, list[str]]:
        """('' or why the plan may not be sent, the contacts): within the position limits and, with a body, clear
        of it and the world by padding (padding())."""
        q = plan.samples()
        refused = self.check_limits(plan, q)
        if refused:
            return refused, []
        if self.body is None:
            return '', []
        hit = self.body.in_collision(q, padding)
        if not hit.any():
            return '', []
        first = q[int(np.argmax(hit))]
        contacts = self.body.contacts(first, padding)
        within = f' within {padding:g} m' if padding else ''
        return f'the motion would touch{within} ({", ".join(contacts) or "a contact"})', contacts

    def _hold(self, start: float, why: str) -> Plan:
        """The previous plan's stop from start on (already checked when it was sent)."""
        if self.last is None:
            raise ReachError(f'{why}, and there is no plan to hold')
        plan = self.last.after(start)
        plan.held, plan.contacts = why, []
        self._commit(plan)
        return plan


# ------------------------------------------------------------------------------------------------- measuring
@dataclass
class Violations:
    """Limits passed by a motion sampled in time (what a test reads from joint_states)."""
    position: int = 0
    velocity: int = 0
    acceleration: int = 0
    worst: dict = field(default_factory=dict)     # kind -> (ratio of the limit, joint)

    @property
    def total(self) -> int:
        return self.position + self.velocity + self.acceleration


@dataclass(frozen=True)
class LeadMeasure:
    """What measure_lead found: the lead (s), the plans' making times' 95th percentile (s), and a line on them."""
    lead: float
    p95: float
    note: str


def measure_lead(limits: Limits, period: float, body=None, margin: float = DEFAULT_MARGIN, home=None,
                 plans: int = 30, seed: int = 0, clock: Callable[[], float] | None = None) -> LeadMeasure:
    """The lead this machine needs: plans made as the control loop makes them (from home toward random targets
    within the limits, one a period, each from the one before, the arm's body and obstacles checked), timed; the
    lead is the LEAD_PERIODS periods unless the slowest twentieth of them take more than READY_WITHIN of it (many
    obstacles, a large body, a slow machine), then as many whole periods as leave that share, up to
    MAX_LEAD_PERIODS. clock: seconds (time.perf_counter)."""
    clock = time.perf_counter if clock is None else clock
    rng = np.random.default_rng(seed)
    q = (limits.lower + limits.upper) / 2.0 if home is None else np.asarray(home, dtype=float)
    layer = SafetyLayer(limits, period, body, margin, follows_plans=True)
    took = []
    now = 0.0
    for k in range(plans):
        target = np.clip(q + rng.uniform(-0.5, 0.5, q.shape), limits.lower, limits.upper)
        t0 = clock()
        layer.plan(now, target, q if k == 0 else None)
        took.append(clock() - t0)
        now += period
    p95 = float(np.percentile(took, 95))
    base = LEAD_PERIODS * period
    if p95 <= READY_WITHIN * base:
        return LeadMeasure(base, p95, f'plans take {1000 * p95:.1f} ms to make here (95th percentile of {plans}): '
                                      f'each is sent {1000 * base:.0f} ms ({LEAD_PERIODS} periods) ahead of its start')
    periods = min(MAX_LEAD_PERIODS, math.ceil(p95 / READY_WITHIN / period - 1e-9))
    lead = periods * period
    note = (f'plans take {1000 * p95:.1f} ms to make here (95th percentile of {plans}), more than '
            f'{READY_WITHIN:g} of the {1000 * base:.0f} ms lead: each is sent {1000 * lead:.0f} ms ({periods} periods) '
            f'ahead of its start')
    if p95 > READY_WITHIN * lead:
        note += (', the longest lead; slower plans are not sent (the arm holds): fewer obstacles, '
                 '~collision_margin 0 or a faster machine would let it move')
    return LeadMeasure(lead, p95, note)


def violations(times, positions, limits: Limits, tolerance: float = 1e-3, min_dt: float = 1e-4) -> Violations:
    """Counts of samples whose position is outside the limits, whose velocity (between two samples) or
    acceleration (between three) is beyond the limits, by more than tolerance (relative: 0.1 % covers a plan's stop
    times kept to a microsecond and a message's times to a nanosecond). Samples closer than min_dt in time are
    merged (a message published twice)."""
    t = np.asarray(times, dtype=float)
    q = np.asarray(positions, dtype=float)
    keep = np.concatenate(([True], np.diff(t) > min_dt))
    t, q = t[keep], q[keep]
    out = Violations()
    slack = lambda bound: bound * (1 + tolerance) + 1e-12      # noqa: E731
    out.position = int(((q < limits.lower - POSITION_TOLERANCE) | (q > limits.upper + POSITION_TOLERANCE)).any(
        axis=1).sum())
    if len(t) < 2:
        return out
    dt = np.diff(t)[:, None]
    v = np.diff(q, axis=0) / dt
    ratio = np.abs(v) / limits.velocity
    out.velocity = int((np.abs(v) > slack(limits.velocity)).any(axis=1).sum())
    out.worst['velocity'] = (float(ratio.max()), limits.joints[int(np.argmax(ratio.max(axis=0)))])
    if len(t) >= 3:
        mid = (t[2:] - t[:-2])[:, None] / 2.0
        acc = np.diff(v, axis=0) / mid
        ratio = np.abs(acc) / limits.acceleration
        out.acceleration = int((np.abs(acc) > slack(limits.acceleration)).any(axis=1).sum())
        out.worst['acceleration'] = (float(ratio.max()), limits.joints[int(np.argmax(ratio.max(axis=0)))])
    return out
