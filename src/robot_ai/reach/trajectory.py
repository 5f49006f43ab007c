"""What a joint_trajectory_controller does with the trajectories it is sent, for a simulated arm. No rospy.

    follower = Follower(positions)
    follower.take(now, start, times, positions, velocities)   # a trajectory_msgs/JointTrajectory's numbers
    follower.state_at(t)                                      # (positions, velocities) at time t

As ros_controls' joint_trajectory_controller: a new trajectory replaces the one being followed from its start time
(header.stamp, or now when it is zero or past); the arm goes from its state at that time through the points, by cubic
Hermite interpolation where the points give velocities (a segment of constant acceleration is followed exactly) and
straight lines where they do not; after the last point it holds there. Points at or before the start are dropped
(the arm's own state starts the trajectory); points whose times do not increase are refused.
"""
from __future__ import annotations

import math

import numpy as np


class TrajectoryError(ValueError):
    """A trajectory a controller refuses; one line."""


class Follower:

    def __init__(self, positions):
        p = np.asarray(positions, dtype=float)
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
        v0, v1 = self.velocities[k], self.velocities[k + 1]
        u = s / span
        u2, u3 = u * u, u * u * u
        h00, h10, h01, h11 = 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2
        d00, d10, d01, d11 = 6 * u2 - 6 * u, 3 * u2 - 4 * u + 1, -6 * u2 + 6 * u, 3 * u2 - 2 * u
        p = h00 * p0 + h10 * span * v0 + h01 * p1 + h11 * span * v1
        v = (d00 * p0 + d01 * p1) / span + d10 * v0 + d11 * v1
        return p, v

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
        self.times = np.concatenate((self.times[:b], [first], absolute[keep]))
        self.positions = np.vstack((self.positions[:b], p, positions[keep]))
        self.velocities = np.vstack((self.velocities[:b], v,
                                     velocities[keep] if given else np.zeros_like(positions[keep])))
        self.hermite = np.concatenate((self.hermite[:max(b - 1, 0)], cut, np.full(int(keep.sum()), given)))
