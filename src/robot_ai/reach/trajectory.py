"""What a joint_trajectory_controller does with the trajectories it is sent, for a simulated arm. No rospy.

    follower = Follower(positions)
    follower.take(now, start, times, positions, velocities)   # a trajectory_msgs/JointTrajectory's numbers
    follower.state_at(t)                                      # (positions, velocities) at time t

As ros_controls' joint_trajectory_controller: a new trajectory replaces the one being followed from its start time
(header.stamp, or now when it is zero or past); the arm goes from its state at that time through the points, by cubic
Hermite interpolation where the points give velocities (a segment of constant acceleration is followed exactly) and
straight lines where they do not; after the last point it holds there. Points at or before the start are dropped
(the arm's own state starts the trajectory); points whose times do not increase are refused.

A follower given what its arm can do (ArmBounds: a real arm's drives) joins a trajectory within them. The controller
joins a trajectory that came after its start from where the arm is to its next point, however near: a jolt (a
trajectory 74 ms late took a simulated arm to 17 times its acceleration limit). This follower joins such a one
(and one in time whose join would pass the limits) further on instead: at the first time the joining curve stays
within the share of the arm's acceleration and velocity limits the trajectory itself uses, and within the positions;
failing that within the limits themselves (the soonest: the least way off the trajectory's path); failing that (a
trajectory too short to catch) as gently as its points allow. A trajectory in time whose join is within the limits is
joined as the controller joins it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

JOIN_STEP = 0.005          # s between the times a late trajectory may be joined at
JOIN_TIMES = 2000          # at most this many of them (a longer trajectory: a coarser step)
JOIN_SAMPLES = 9           # points inside the joining curve checked against the positions and velocities
MAX_JOIN_AFTER = 30.0      # s after a trajectory's end a late one may be joined at rest where it ends, at most


@dataclass(frozen=True)
class ArmBounds:
    """What the arm can do, per joint in the follower's order: positions, velocities (/s), accelerations (/s^2)."""
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class TrajectoryError(ValueError):
    """A trajectory a controller refuses; one line."""


class Follower:

    def __init__(self, positions, bounds: ArmBounds | None = None):
        p = np.asarray(positions, dtype=float)
        self.bounds = bounds
        self.joined = -math.inf               # when the last trajectory taken was joined (with bounds), and how
        self.joined_how = ''
        self.times = np.array([-1e9])         # at rest since long ago
        self.positions = p[None].copy()
        self.velocities = np.zeros((1, len(p)))
        self.hermite = np.zeros(0, dtype=bool)     # per segment: velocities given (else a straight line)

    @property
    def final(self) -> np.ndarray:
        return self.positions[-1].copy()

    @property
    def end(self) -> float:
        return float(self.times[-1])

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(np.searchsorted(self.times, t, side='right')) - 1
        if k >= len(self.times) - 1:
            return self.positions[-1].copy(), np.zeros(self.positions.shape[1])
        if k < 0:
            return self.positions[0].copy(), np.zeros(self.positions.shape[1])
        t0, t1 = self.times[k], self.times[k + 1]
        p0, p1 = self.positions[k], self.positions[k + 1]
        span, s = t1 - t0, t - t0
        if not self.hermite[k]:
            slope = (p1 - p0) / span
            return p0 + slope * s, slope
        return _hermite(s / span, span, p0, self.velocities[k], p1, self.velocities[k + 1])

    def take(self, now: float, start: float, times, positions, velocities=None) -> None:
        """A trajectory: points at start + times[k] (s), positions (K, n), velocities (K, n) or None (a message
        whose stamp is zero starts now: give now). From max(start, now) on it replaces the motion being followed.
        TrajectoryError (nothing changes) for one that cannot be followed."""
        times = np.asarray(times, dtype=float).reshape(-1)
        positions = np.asarray(positions, dtype=float)
        n = self.positions.shape[1]
        if positions.shape != (len(times), n):
            raise TrajectoryError(f'{len(times)} points of {positions.shape[-1] if positions.ndim == 2 else "?"} '
                                  f'positions: expected one position per joint ({n}) at every point')
        if velocities is not None:
            velocities = np.asarray(velocities, dtype=float)
            if velocities.shape != positions.shape:
                raise TrajectoryError('velocities must be given at every point or at none')
        if not len(times):
            raise TrajectoryError('a trajectory with no point')
        if not (np.isfinite(times).all() and np.isfinite(positions).all()
                and (velocities is None or np.isfinite(velocities).all())) or not math.isfinite(start):
            raise TrajectoryError('a trajectory with a NaN or infinite number')
        if (np.diff(times) <= 0).any():
            raise TrajectoryError('the points\' times_from_start must increase')
        absolute = start + times
        first = max(start, now)
        keep = absolute > first + 1e-9
        if not keep.any():
            raise TrajectoryError(f'every point is in the past ({first - absolute[-1]:.3f} s before now)')
        p, v = self.state_at(first)
        b = int((self.times < first).sum())         # the points before the new start stay (followed until then)
        # the segment that runs into the new start keeps its kind: cut at the start, the same curve
        cut = [bool(self.hermite[b - 1]) if b - 1 < len(self.hermite) else False] if b else []
        given = velocities is not None
        if velocities is None:
            velocities = np.zeros_like(positions)
        if self.bounds is not None:
            joined, p_join, v_join, after, self.joined_how = self._join(first, p, v, absolute, positions,
                                                                        velocities, given, now > start + 1e-9)
            self.joined = joined
            self.times = np.concatenate((self.times[:b], [first, joined], absolute[after:]))
            self.positions = np.vstack((self.positions[:b], p, p_join, positions[after:]))
            self.velocities = np.vstack((self.velocities[:b], v, v_join, velocities[after:]))
            self.hermite = np.concatenate((self.hermite[:max(b - 1, 0)], cut, [True],
                                           np.full(len(absolute) - after, given)))
            return
        self.times = np.concatenate((self.times[:b], [first], absolute[keep]))
        self.positions = np.vstack((self.positions[:b], p, positions[keep]))
        self.velocities = np.vstack((self.velocities[:b], v, velocities[keep]))
        self.hermite = np.concatenate((self.hermite[:max(b - 1, 0)], cut, np.full(int(keep.sum()), given)))

    def _join(self, first: float, p: np.ndarray, v: np.ndarray, absolute: np.ndarray, positions: np.ndarray,
              velocities: np.ndarray, given: bool, late: bool) -> tuple[float, np.ndarray, np.ndarray, int, str]:
        """Where a trajectory is joined from the state (p, v) at first (see the module): (the time, the position and
        velocity there, the index of its first point after that time, how: within which limits)."""
        bounds = self.bounds
        new = Follower(positions[0])
        new.times, new.positions, new.velocities = absolute, positions, velocities
        new.hermite = np.full(len(absolute) - 1, given)
        # the share of the limits the trajectory uses (its own curve, its points; the arm's state now)
        share_a = float(np.max(_accelerations(new) / bounds.acceleration, initial=0.0))
        speeds = velocities if given else np.diff(positions, axis=0) / np.diff(absolute)[:, None]
        share_v = max(float(np.max(np.abs(speeds) / bounds.velocity, initial=0.0)),
                      float(np.max(np.abs(v) / bounds.velocity)))
        kept = absolute[absolute > first + 1e-9]
        step = max(JOIN_STEP, (kept[-1] - first) / JOIN_TIMES)
        # and after its end, at rest where it ends: long enough to get there from here within the limits
        far = np.abs(positions[-1] - p)
        beyond = float(np.max(np.sqrt(6 * far / bounds.acceleration) + 4 * np.abs(v) / bounds.acceleration
                              + 1.5 * far / bounds.velocity))
        beyond = min(beyond, MAX_JOIN_AFTER)
        times = np.unique(np.concatenate((kept, np.arange(kept[0], kept[-1], step),
                                          kept[-1] + np.arange(1, JOIN_TIMES + 1) * max(step, beyond / JOIN_TIMES))))
        times = times[times <= kept[-1] + beyond + step]
        p1, v1 = new.states_at(times)                                # (m, n) each: the join's end at each time
        span = (times - first)[:, None]
        a0, a1 = _end_accelerations(p1 - p, v, v1, span)
        ratio_a = np.max(np.maximum(np.abs(a0), np.abs(a1)) / bounds.acceleration, axis=1)
        u = np.linspace(0, 1, JOIN_SAMPLES + 2)[1:-1][:, None, None]      # (k, 1, 1)
        inside, speed = _hermite(u, span, p, v, p1, v1)                    # (k, m, n) each
        ratio_v = np.max(np.abs(speed) / bounds.velocity, axis=(0, 2))
        within = ((inside >= bounds.lower - 1e-9) & (inside <= bounds.upper + 1e-9)).all(axis=(0, 2))
        fits_arm = within & (ratio_a <= 1.0) & (ratio_v <= 1.0)
        fits_share = within & (ratio_a <= share_a * (1 + 1e-9)) & (ratio_v <= share_v * (1 + 1e-9))
        if not late and fits_arm[0]:
            k, how = 0, 'in time, within the arm\'s limits'     # joined as the controller joins it
        elif fits_share.any():
            k, how = int(np.argmax(fits_share)), 'within the share of the limits it uses'
        elif fits_arm.any():
            k, how = int(np.argmax(fits_arm)), 'within the arm\'s limits'
        else:
            worst = np.maximum(ratio_a, ratio_v)
            k, how = int(np.argmin(np.where(within, worst, worst + 1e9))), 'as gently as its points allow'
        joined = float(times[k])
        return joined, p1[k], v1[k], int(np.searchsorted(absolute, joined, side='right')), how

    def states_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """state_at at each of times, at once: positions and velocities, (len(times), joints) each."""
        times = np.asarray(times, dtype=float)
        last = len(self.times) - 1
        k = np.clip(np.searchsorted(self.times, times, side='right') - 1, 0, max(last - 1, 0))
        if last == 0:
            return np.tile(self.positions[0], (len(times), 1)), np.zeros((len(times), self.positions.shape[1]))
        t0, t1 = self.times[k][:, None], self.times[k + 1][:, None]
        p0, p1 = self.positions[k], self.positions[k + 1]
        v0, v1 = self.velocities[k], self.velocities[k + 1]
        span = t1 - t0
        u = np.clip((times[:, None] - t0) / span, 0.0, 1.0)
        hermite = self.hermite[k][:, None]
        slope = (p1 - p0) / span
        curve_p, curve_v = _hermite(u, span, p0, v0, p1, v1)
        p = np.where(hermite, curve_p, p0 + slope * u * span)
        v = np.where(hermite, curve_v, slope)
        after = times >= self.times[-1]
        p[after], v[after] = self.positions[-1], 0.0
        before = times < self.times[0]
        p[before], v[before] = self.positions[0], 0.0
        return p, v


def _accelerations(follower: Follower) -> np.ndarray:
    """The largest acceleration of each joint over a follower's Hermite segments (both ends of each: a cubic's
    acceleration is linear), (joints,); 0 for straight lines."""
    if not follower.hermite.any():
        return np.zeros(follower.positions.shape[1])
    a0, a1 = _end_accelerations(np.diff(follower.positions, axis=0), follower.velocities[:-1],
                                follower.velocities[1:], np.diff(follower.times)[:, None])
    worst = np.maximum(np.abs(a0), np.abs(a1))[follower.hermite]
    return worst.max(axis=0)


def _hermite(u, span, p0, v0, p1, v1):
    """(position, velocity) of the cubic Hermite segment from (p0, v0) to (p1, v1) over span, a share u into it
    (numbers or arrays that broadcast)."""
    u2, u3 = u * u, u * u * u
    h00, h10, h01, h11 = 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2
    d00, d10, d01, d11 = 6 * u2 - 6 * u, 3 * u2 - 4 * u + 1, -6 * u2 + 6 * u, 3 * u2 - 2 * u
    return (h00 * p0 + h10 * span * v0 + h01 * p1 + h11 * span * v1,
            (d00 * p0 + d01 * p1) / span + d10 * v0 + d11 * v1)


def _end_accelerations(d, v0, v1, span):
    """The accelerations at both ends of cubic Hermite segments that move d from velocity v0 to v1 over span (a
    cubic's acceleration is linear between them)."""
    return (6 * d - (4 * v0 + 2 * v1) * span) / span ** 2, (-6 * d + (2 * v0 + 4 * v1) * span) / span ** 2
