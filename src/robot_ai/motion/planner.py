"""Collision-free paths in joint space: OMPL's RRT-Connect (MoveIt's default planner) over a check of many
configurations at once. No rospy.

The check is what a sampling planner spends its time on: an arm's sphere body answers a batch at a few microseconds a
configuration but a single call in 0.4-1 ms, so OMPL is given a motion validator of its own kind (every state of a
motion checked in one call) instead of its discrete one (one call per state). A motion from a to b is checked at
`states(a, b)` evenly spaced configurations, as many as keep every point of the body within `spacing` metres of a
checked position: `sweep[i]` bounds how far any point of the body moves per unit of joint i (the longest reach below
it), so a point moves at most sum(|b - a| * sweep) along the whole motion. A check with a padding of at least half
the spacing then covers the configurations between the checked ones.

Before any tree is grown, the straight motion to each goal is checked (all of them in one call): in open space that
is the answer, at the cost of one check. Found paths are shortened by OMPL's PathSimplifier.

Each search's random numbers come from a seed of its own problem (start, goals and budget): with a budget of motion
checks (not a time), the same problem gets the same path in any process, whatever was planned before it.
"""
from __future__ import annotations

import math
import threading
import time
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np

DEFAULT_TIME_LIMIT = 1.0      # s a plan may take
SIMPLIFY_SHARE = 0.25         # of the time the search took (at least SIMPLIFY_LEAST s): for shortening the path
SIMPLIFY_LEAST = 0.02
MAX_GOALS = 16                # goal configurations given to the tree search (the nearest ones)


@dataclass
class PlannedPath:
    """A plan's answer: waypoints (k, n) from the start to a goal configuration (None without a path), the goal's
    index among those given, the reason there is none (one line; '' with a path), how it was found ('straight',
    'RRTConnect'), the wall time it took and how many motions and configurations were checked."""
    waypoints: np.ndarray | None
    goal: int
    reason: str
    how: str
    seconds: float
    motions: int
    states: int

    @property
    def found(self) -> bool:
        return self.waypoints is not None

    def length(self) -> float:
        """The path's length in joint space (the sum of its segments' Euclidean lengths)."""
        if self.waypoints is None:
            return math.inf
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


OMPL_SEED = 0                 # mixed into every search's seed: another number, other paths (the same ones each time)
_search_lock = threading.Lock()   # one search at a time: its random numbers are drawn from its own seed
_quiet = []


def _ompl():
    from ompl import base as ob, geometric as og, util as ou
    if not _quiet:
        _quiet.append(True)
        ou.setLogLevel(ou.LOG_WARN)       # not its progress of every search (info and debug lines)
    return ob, og, ou


def _seed_from(*arrays: np.ndarray) -> int:
    """A seed for OMPL (1 to 2**31 - 1) from the problem itself: the same problem is searched with the same random
    numbers whatever was planned before it in the process (or on another thread, or in another process)."""
    digest = zlib.crc32(np.asarray(OMPL_SEED, dtype=np.int64).tobytes())
    for a in arrays:
        digest = zlib.crc32(np.ascontiguousarray(a, dtype=np.float64).tobytes(), digest)
    return 1 + digest % (2 ** 31 - 1)


def _reseed(ou, seed: int) -> None:
    """OMPL's random numbers from here on from seed. OMPL draws each new generator's seed (a planner's, its
    sampler's, its nearest-neighbour structure's, a PathSimplifier's) from one stream per process, seeded once: that
    stream is seeded again before a search, every object of which is made after it. OMPL says, as an error, that
    a seed given after the first draw is not deterministic (for the objects made before): not so here, so not said."""
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed))
    finally:
        ou.setLogLevel(level)


class JointPlanner:
    """Paths between configurations within [lower, upper] (n,) whose every checked configuration `clear` accepts
    (clear: (N, n) -> (N,) bool, called with many configurations at once); sweep (n,) or a number: metres any point
    of the body moves at most per radian (or metre) of each joint; spacing: metres between checked states; speed
    (n,) or a number: what one unit of each joint's motion costs is 1 / speed, the planner's measure of a path (the
    joints' velocity limits: paths short in time; the PR2's torso lifts at 0.013 m/s, its arm turns at 2 rad/s)."""

    def __init__(self, lower, upper, clear: Callable[[np.ndarray], np.ndarray], sweep, spacing: float = 0.01,
                 planner: str = 'RRTConnect', speed=1.0):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.n = len(self.lower)
        if self.upper.shape != (self.n,) or not np.all(self.lower < self.upper):
            raise ValueError('lower and upper must be n limits with lower < upper')
        self.clear = clear
        self.sweep = np.broadcast_to(np.asarray(sweep, dtype=float), (self.n,)).copy()
        if not np.all(self.sweep > 0) or not spacing > 0:
            raise ValueError('sweep and spacing must be positive')
        self.spacing = float(spacing)
        self.speed = np.broadcast_to(np.asarray(speed, dtype=float), (self.n,)).copy()
        if not np.all(self.speed > 0):
            raise ValueError('speed must be positive')
        self.planner_name = planner
        self.motions = 0
        self.state_count = 0

    # ------------------------------------------------------------------------------------------ checks
    def states(self, a: np.ndarray, b: np.ndarray) -> int:
        """How many configurations check the straight motion a -> b, both ends counted."""
        return 1 + max(1, math.ceil(float(np.abs(b - a) @ self.sweep) / self.spacing))

    def _clear(self, q: np.ndarray) -> np.ndarray:
        self.state_count += len(q)
        return np.asarray(self.clear(q), dtype=bool)

    def motions_clear(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(m,) bool: the straight motions starts[i] -> ends[i] ((m, n) each) are clear at every checked state, in
        one call of the check."""
        starts, ends = np.atleast_2d(starts), np.atleast_2d(ends)
        counts = [self.states(a, b) for a, b in zip(starts, ends)]
        if not counts:
            return np.zeros(0, dtype=bool)
        self.motions += len(counts)
        q = np.concatenate([a + np.linspace(0.0, 1.0, c)[:, None] * (b - a)
                            for a, b, c in zip(starts, ends, counts)])
        ok = self._clear(q)
        bounds = np.cumsum([0] + counts)
        return np.array([ok[bounds[i]:bounds[i + 1]].all() for i in range(len(counts))], dtype=bool)

    def path_clear(self, waypoints: np.ndarray) -> bool:
        """Every segment of a path clear, in one call: motions_clear's states, each waypoint checked once (not as
        the end of one segment and the start of the next: a finely sampled timed motion is half such points)."""
        w = np.atleast_2d(np.asarray(waypoints, dtype=float))
        if len(w) < 2:
            return bool(self._clear(w).all())
        counts = [self.states(a, b) for a, b in zip(w[:-1], w[1:])]
        self.motions += len(counts)
        q = np.concatenate([w[:1]] + [a + np.linspace(0.0, 1.0, c)[1:, None] * (b - a)
                                      for a, b, c in zip(w[:-1], w[1:], counts)])
        return bool(self._clear(q).all())

    # ------------------------------------------------------------------------------------------ OMPL
    def _space(self):
        """OMPL's space information: the joint box, a state check and the batched motion check. Made for each search
        and dropped after it: kept, the validator (a Python object that OMPL holds) outlives the interpreter's
        teardown and nanobind reports it as a leak at exit. OMPL's states are the joints divided by their speed,
        so that its distances (its nearest neighbours, its step, its shortcuts) are times."""
        ob, og, ou = _ompl()
        space = ob.RealVectorStateSpace(self.n)
        bounds = ob.RealVectorBounds(self.n)
        low, high = self.lower / self.speed, self.upper / self.speed
        for i in range(self.n):
            bounds.setLow(i, float(low[i]))
            bounds.setHigh(i, float(high[i]))
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        planner = self
        n, speed = self.n, self.speed

        def valid(state) -> bool:
            return bool(planner._clear(np.array([[state[i] for i in range(n)]]) * speed)[0])

        class BatchedMotions(ob.MotionValidator):
            def checkMotion(self, s1, s2, *last):
                a = np.array([s1[i] for i in range(n)]) * speed
                b = np.array([s2[i] for i in range(n)]) * speed
                return bool(planner.motions_clear(a[None], b[None])[0])

        si.setStateValidityChecker(valid)
        validator = BatchedMotions(si)
        si.setMotionValidator(validator)
        si.setup()
        return space, si, validator

    @staticmethod
    def _state(space, q: np.ndarray):
        s = space.allocState()
        for i, v in enumerate(q):
            s[i] = float(v)
        return s

    def _tree_search(self, start: np.ndarray, goals: np.ndarray, time_limit: float,
                     budget: int | None) -> tuple[np.ndarray | None, str]:
        with _search_lock:
            return self._seeded_search(start, goals, time_limit, budget)

    def _seeded_search(self, start: np.ndarray, goals: np.ndarray, time_limit: float,
                       budget: int | None) -> tuple[np.ndarray | None, str]:
        ob, og, ou = _ompl()
        _reseed(ou, _seed_from(start, goals, np.array([-1 if budget is None else budget])))
        space, si, validator = self._space()        # the validator held here for the search: OMPL calls it
        ss = og.SimpleSetup(si)
        ss.setStartState(self._state(space, start / self.speed))
        goal = ob.GoalStates(si)
        for q in goals:
            goal.addState(self._state(space, q / self.speed))
        ss.setGoal(goal)
        ss.setPlanner(getattr(og, self.planner_name)(si))      # its step: OMPL's, a fifth of the box's diagonal
        began, checked = time.monotonic(), self.motions
        done = ob.timedPlannerTerminationCondition(float(time_limit))
        if budget is not None:          # a budget of motion checks: the same answer on a loaded machine
            spent = ob.PlannerTerminationCondition(lambda: self.motions - checked >= budget)
            done = ob.plannerOrTerminationCondition(spent, done)
        ss.solve(done)
        if not ss.haveExactSolutionPath():
            return None, (f'no path found in {budget} motion checks' if budget is not None
                          and self.motions - checked >= budget else f'no path found in {time_limit:g} s')
        if budget is None:
            ss.simplifySolution(max(SIMPLIFY_LEAST, SIMPLIFY_SHARE * (time.monotonic() - began)))
        else:                           # shortened by a fixed count of tries: no clock in the answer
            simplifier = og.PathSimplifier(si)
            simplifier.reduceVertices(ss.getSolutionPath())
            simplifier.ropeShortcutPath(ss.getSolutionPath())
        path = ss.getSolutionPath()
        waypoints = np.array([[path.getState(k)[i] for i in range(self.n)] for k in range(path.getStateCount())])
        return waypoints * self.speed, ''

    # ------------------------------------------------------------------------------------------ planning
    def plan(self, start, goals, time_limit: float = DEFAULT_TIME_LIMIT, budget: int | None = None) -> PlannedPath:
        """A path from start (n,) to one of goals ((m, n): configurations that reach the same target, nearest
        first is best), or the reason there is none: the start or every goal in contact, or no path in the time
        (or, with budget, in that many motion checks: an answer that a loaded machine does not change)."""
        began = time.monotonic()
        motions, states = self.motions, self.state_count
        start = np.asarray(start, dtype=float).reshape(self.n)
        goals = np.atleast_2d(np.asarray(goals, dtype=float))

        def answer(waypoints, goal, reason, how):
            return PlannedPath(waypoints, goal, reason, how, time.monotonic() - began, self.motions - motions,
                               self.state_count - states)
        if not len(goals):
            return answer(None, -1, 'no goal configuration given', '')
        if not self._clear(start[None])[0]:
            return answer(None, -1, 'the start is in contact (or within the margin)', '')
        clear = self._clear(goals)
        if not clear.any():
            return answer(None, -1, 'every goal configuration is in contact (or within the margin)', '')
        index = np.flatnonzero(clear)
        index = index[np.argsort(np.linalg.norm((goals[index] - start) / self.speed, axis=1), kind='stable')]
        straight = self.motions_clear(np.repeat(start[None], len(index), axis=0), goals[index])
        if straight.any():
            k = int(index[straight.argmax()])
            return answer(np.array([start, goals[k]]), k, '', 'straight')
        chosen = index[:MAX_GOALS]
        waypoints, reason = self._tree_search(start, goals[chosen], time_limit, budget)
        if waypoints is None:
            return answer(None, -1, reason, self.planner_name)
        k = int(chosen[np.linalg.norm((goals[chosen] - waypoints[-1]) / self.speed, axis=1).argmin()])
        waypoints[0], waypoints[-1] = start, goals[k]
        return answer(waypoints, k, '', self.planner_name)
