"""A path's timing within the joints' velocity and acceleration limits: TOPP-RA (toppra) over a spline through the
path's points, from rest to rest. No rospy.

A spline through a path's corners leaves the straight segments the planner checked, a little, near each corner. The
path is therefore given points every `step` along its segments (so that the spline hugs them), and where a check is
given the timed motion is checked at DENSE_SAMPLES points; one that is not clear is timed again with points twice
as close, and after REFINEMENTS such tries, segment by segment from rest to rest (exactly the checked segments,
each a synchronised trapezoid: slower, never off the path).

toppra's discretised answer may pass a limit by a percent between its grid points: it is given LIMIT_SHARE of the
limits, and the timing is stretched until the motion, sampled finely, is within them.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

DENSIFY_STEP = 0.1          # rad (or m): the most any joint moves between two of the spline's points
REFINEMENTS = 3
DENSE_SAMPLES = 400         # samples of a timed motion that its check and the limits' check look at
GRID_POINTS = 200           # toppra's discretisation of the path
LIMIT_SHARE = 0.95          # of each limit toppra is given: its constant-acceleration answer peaks between its grid
                            # points (1.2 % over, seen), and _stretch slows what still passes
STRETCH_SPARE = 1.02        # more stretch than the samples ask for, where they ask for any
STRETCH_SAMPLES = 2000      # samples of a timed motion the limits are checked at (toppra evaluates 20,000 in 25 ms)


@dataclass
class TimedPath:
    """A motion from rest to rest: positions(t), velocities(t) and accelerations(t) for t in [0, duration] (before
    and after: at rest at either end); how it was timed ('toppra' or 'rest to rest'); end: the path's last point,
    which positions(duration) is exactly."""
    duration: float
    how: str
    _at: Callable[[np.ndarray, int], np.ndarray]
    end: np.ndarray

    def positions(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        value = self._at(t, 0)
        return np.where((t >= self.duration)[..., None], self.end, value)

    def velocities(self, t) -> np.ndarray:
        return self._at(np.asarray(t, dtype=float), 1)

    def accelerations(self, t) -> np.ndarray:
        return self._at(np.asarray(t, dtype=float), 2)

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(times (k,), positions (k, n), velocities (k, n)) every dt seconds, the last at duration."""
        count = max(2, math.ceil(self.duration / dt) + 1)
        t = np.linspace(0.0, self.duration, count)
        return t, self.positions(t), self.velocities(t)


def densify(waypoints: np.ndarray, step: float) -> np.ndarray:
    """The path with points added along each segment so that no joint moves more than step between two."""
    out = [waypoints[:1]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        k = max(1, math.ceil(float(np.abs(b - a).max()) / step))
        out.append(a + np.linspace(0.0, 1.0, k + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def _stretch(at: Callable, duration: float, velocity: np.ndarray, acceleration: np.ndarray) -> tuple[Callable, float]:
    """at(t, order) slowed so that its samples keep within the limits: velocities scale by 1/k, accelerations by
    1/k^2 when time is stretched by k."""
    t = np.linspace(0.0, duration, STRETCH_SAMPLES)
    over_v = float((np.abs(at(t, 1)) / velocity).max())
    over_a = float((np.abs(at(t, 2)) / acceleration).max())
    k = max(over_v, math.sqrt(max(over_a, 0.0)))
    if k <= 1.0:
        return at, duration
    k *= STRETCH_SPARE          # a peak between the samples: seen 0.2 % above the sampled one

    def slower(t, order, k=k):
        return at(np.asarray(t) / k, order) / k ** order
    return slower, duration * k


def _toppra(waypoints: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray) -> tuple[Callable, float] | None:
    import toppra
    import toppra.algorithm
    import toppra.constraint
    # its warnings only (toppra.setup_logging would add a handler at every call: a line said n times after n plans)
    logging.getLogger('toppra').setLevel(logging.WARNING)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(waypoints, axis=0), axis=1))])
    s /= s[-1]
    path = toppra.SplineInterpolator(s, waypoints, bc_type='clamped')
    constraints = [toppra.constraint.JointVelocityConstraint(np.stack([-velocity, velocity], axis=1)),
                   toppra.constraint.JointAccelerationConstraint(np.stack([-acceleration, acceleration], axis=1))]
    instance = toppra.algorithm.TOPPRA(constraints, path, gridpoints=np.linspace(0.0, 1.0, GRID_POINTS + 1),
                                       parametrizer='ParametrizeConstAccel')
    trajectory = instance.compute_trajectory(0.0, 0.0)
    if trajectory is None:
        return None
    duration = float(trajectory.duration)

    def at(t, order):
        return np.asarray(trajectory(np.clip(t, 0.0, duration), order), dtype=float)
    return at, duration


def _rest_to_rest(waypoints: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray) -> tuple[Callable, float]:
    """Each segment a straight motion from rest to rest, every joint on the same trapezoid of the segment's share."""
    segments = []           # (start time, duration, a, b, peak share speed, share acceleration, ramp time)
    t0 = 0.0
    for a, b in zip(waypoints[:-1], waypoints[1:]):     # time_path keeps no segment that does not move
        d = np.abs(b - a)
        moving = d > 0
        v = float((velocity[moving] / d[moving]).min())         # of the share s in [0, 1]
        acc = float((acceleration[moving] / d[moving]).min())
        if v * v / acc >= 1.0:             # never reaches v: a triangle
            ramp = math.sqrt(1.0 / acc)
            v = acc * ramp
            span = 2.0 * ramp
        else:
            ramp = v / acc
            span = 1.0 / v + ramp
        segments.append((t0, span, a, b, v, acc, ramp))
        t0 += span
    duration = t0

    def share(u, span, v, acc, ramp, order):
        if order == 0:
            return np.where(u < ramp, 0.5 * acc * u * u,
                            np.where(u > span - ramp, 1.0 - 0.5 * acc * (span - u) ** 2, 0.5 * acc * ramp * ramp
                                     + v * (u - ramp)))
        if order == 1:
            return np.where(u < ramp, acc * u, np.where(u > span - ramp, acc * (span - u), v))
        return np.where(u < ramp, acc, np.where(u > span - ramp, -acc, 0.0))

    starts = np.array([seg[0] for seg in segments])

    def at(t, order):
        t = np.clip(np.asarray(t, dtype=float), 0.0, duration)
        flat = np.atleast_1d(t)
        out = np.empty((len(flat), len(waypoints[0])))
        which = np.clip(np.searchsorted(starts, flat, side='right') - 1, 0, len(segments) - 1)
        for k, (s0, span, a, b, v, acc, ramp) in enumerate(segments):
            rows = which == k
            if rows.any():
                u = np.clip(flat[rows] - s0, 0.0, span)
                s = share(u, span, v, acc, ramp, order)
                out[rows] = (a if order == 0 else 0.0) + s[:, None] * (b - a)
        return out if np.ndim(t) else out[0]
    return at, duration


def time_path(waypoints, velocity, acceleration, is_clear: Callable[[np.ndarray], bool] | None = None,
              step: float = DENSIFY_STEP) -> TimedPath:
    """The path (k, n) timed from rest to rest within velocity and acceleration (n,) limits; is_clear(samples (m, n))
    says whether a motion through those samples is clear (the planner's path check): the timing keeps to it."""
    waypoints = np.atleast_2d(np.asarray(waypoints, dtype=float))
    velocity, acceleration = np.asarray(velocity, dtype=float), np.asarray(acceleration, dtype=float)
    if not (np.all(velocity > 0) and np.all(acceleration > 0)):
        raise ValueError('velocity and acceleration limits must be positive')
    keep = np.concatenate([[True], np.abs(np.diff(waypoints, axis=0)).max(axis=1) > 1e-12])
    waypoints = waypoints[keep]
    if len(waypoints) < 2:
        still = waypoints[0]
        return TimedPath(0.0, 'still', lambda t, order: (np.broadcast_to(still if order == 0 else 0.0 * still,
                                                                         np.shape(t) + still.shape).copy()), still)
    for _ in range(REFINEMENTS):
        timed = _toppra(densify(waypoints, step), LIMIT_SHARE * velocity, LIMIT_SHARE * acceleration)
        if timed is not None:
            at, duration = _stretch(*timed, velocity, acceleration)
            if is_clear is None or is_clear(at(np.linspace(0.0, duration, DENSE_SAMPLES), 0)):
                return TimedPath(duration, 'toppra', at, waypoints[-1].copy())
        step /= 2.0
    at, duration = _rest_to_rest(waypoints, velocity, acceleration)
    return TimedPath(duration, 'rest to rest', at, waypoints[-1].copy())
