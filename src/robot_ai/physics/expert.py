"""A scripted expert for Push-v0 and PickAndPlace-v0: what the task asks, written as waypoints, read from the
observation alone (so that it acts in any world, batched, and a learner can imitate it). No rospy.

    actions = expert_actions(obs['observation'], obs['desired_goal'], task)     # (N, 4) for N observations

Push: the closed fingertips go behind the cube (opposite the goal) above it, down to its middle's height, and push
it along the line to the goal, steered back onto the line as the cube turns aside, stopping when it is there. Pick
and place: the open gripper (wide enough for the cube, no wider) goes over the cube, down around it, closes, and
carries it to the goal once the fingers hold it (the opening stopped short of closed), the cube (not the grip point)
to the goal; fingers that have begun to close go on closing, however the hand has moved since, until they stop.
"""
from __future__ import annotations

import numpy as np

GAIN = 10.0                 # action per metre of error (saturates at 1 beyond 0.1 m: EE_STEP x 2)
ABOVE = 0.06                # m: the approach height over the cube
TIPS_ABOVE = 0.035          # m: and the fingertips at least this above its middle there (a long gripper's tips
                            # reach past the grip point: the Robotiq 2F-140's 6 cm swept the cube aside)
BEHIND = 0.05               # m: where the push starts, behind the cube's middle
NEAR = 0.012                # m: near enough to a waypoint to go on
THERE = 0.015               # m: a pushed cube this near its goal is left alone
KEEP = 0.03                 # m: a push under way goes on while the grip point is this near the line to the goal
HOLD_RADIUS = 0.03          # m: a cube held this near the grip point (in the plane) is carried (three fingers hold it
                            # off the point between their tips)
HELD = 0.04                 # the gripper's opening (0 closed, 1 open) above which its stopped fingers hold the cube
HELD_BELOW = 0.1            # ... and below which: this short of how far the expert opens it (ajar), 0.9 at most
HOLD_HEIGHT = 0.06          # m: a cube held no farther below (or above) the grip point than this, or than the fingers
                            # reach past it and 2 cm (a long gripper holds it at its tips: the Robotiq 2F-140 6 cm
                            # below)
LEAD = 0.6                  # the least action toward a waypoint farther than SETTLED (3 cm of target ahead): a servo
                            # sagging under gravity, or a joint near its limit, stalls short of it with less (the
                            # Fetch's hand stayed 7-16 mm off the cube's middle)
SETTLED = 0.003             # m: a waypoint this near is reached


def _towards(grip: np.ndarray, target: np.ndarray, lead: np.ndarray | bool = False) -> np.ndarray:
    """GAIN x the error, each component within [-1, 1]: a far target's step leans toward a diagonal (a cube held low
    is lifted clear of the table as it is carried, not dragged along it). Where lead (N,), the step is first
    lengthened to LEAD short of SETTLED: a near target is reached, not stalled short of (a cube being carried is not:
    it would swing past the goal)."""
    error = target - grip
    step = GAIN * error
    size = np.linalg.norm(step, axis=-1, keepdims=True)
    longer = np.asarray(lead)[..., None] & (np.linalg.norm(error, axis=-1, keepdims=True) > SETTLED)
    return np.clip(np.where(longer, step * np.maximum(LEAD / np.maximum(size, 1e-9), 1.0), step), -1.0, 1.0)


def _along(grip: np.ndarray, target: np.ndarray) -> np.ndarray:
    """GAIN x the error, shortened as a whole where a component passes 1: the grip point moves straight at the
    target (a push clipped component by component drifts off the line behind the cube)."""
    step = GAIN * (target - grip)
    return step / np.maximum(np.max(np.abs(step), axis=-1, keepdims=True), 1.0)


def expert_actions(observation, desired_goal, task: str, behind: float = BEHIND,
                   lowest: float = -np.inf, sink: float = 0.0, reach: float = 0.0, ajar: float = 1.0) -> np.ndarray:
    """(N, 4) actions for observations (N, 23) (or one: (23,) -> (4,)) and their goals (N, 3). behind: where a push
    starts, behind the cube's middle; lowest: the grip point's lowest target; sink: how far under the cube's middle
    the grip point pushes; reach: how far the fingers reach past the grip point (ManipulationSetup.expert passes the
    arm's own: its hand clear of the cube, its fingertips above the table, a hand whose closed fingers curl up above
    the grip point pushing with their backs, a long gripper holding the cube at its tips); ajar: how far the open
    gripper opens (0 closed, 1 open: wide enough for the cube, no wider, so that it closes on it sooner)."""
    obs = np.atleast_2d(np.asarray(observation, dtype=float))
    goal = np.atleast_2d(np.asarray(desired_goal, dtype=float))
    grip, cube, opening = obs[:, 0:3], obs[:, 3:6], obs[:, 9]
    actions = np.zeros((len(obs), 4))
    # the height to grasp at: the cube's middle, if it can; to push at: sink under it
    level = np.maximum(cube[:, 2] - (sink if task == 'push' else 0.0), lowest)
    low = grip[:, 2] < level + NEAR
    if task == 'push':
        line = goal[:, :2] - cube[:, :2]
        distance = np.linalg.norm(line, axis=1, keepdims=True)
        direction = np.where(distance > 1e-6, line / np.maximum(distance, 1e-9), 0.0)
        start = cube.copy()
        start[:, :2] -= direction * behind
        start[:, 2] = level
        over = start.copy()
        over[:, 2] += ABOVE
        # behind the cube (in the plane) and low enough: push; otherwise come over the point behind it, then down
        offset = grip[:, :2] - cube[:, :2]
        along = np.sum(offset * direction, axis=1)
        lateral = offset - along[:, None] * direction      # the grip point's offset from the line
        across = np.linalg.norm(lateral, axis=1)
        placed = (along < -0.02) & (across < 0.015)
        pushing = low & (along < -0.02) & (across < KEEP)  # under way: a cube turned aside a little is steered back
        push = goal.copy()
        push[:, :2] -= direction * (behind - 0.025)       # the fingertips' side, not their middle, at the goal
        push[:, 2] = level
        # along the line toward the push point, and back onto it (the line from the cube to the goal turns as the
        # cube is pushed aside)
        ahead = np.clip(np.sum((push[:, :2] - grip[:, :2]) * direction, axis=1), 0.0, 1.0 / GAIN)
        steer = push.copy()
        steer[:, :2] = grip[:, :2] + direction * ahead[:, None] - lateral
        target = np.where(pushing[:, None], steer,
                          np.where(placed[:, None] | (np.linalg.norm(grip - over, axis=1) < NEAR)[:, None],
                                   start, over))
        actions[:, :3] = _along(grip, target)
        actions[:, 3] = -1.0
        there = distance[:, 0] < THERE        # pushed home: the fingers leave it where it is
        actions[there, :3] = 0.0
    else:
        over = cube.copy()
        over[:, 2] += max(ABOVE, reach + TIPS_ABOVE)
        down = cube.copy()
        down[:, 2] = level
        horizontal = np.linalg.norm(grip[:, :2] - cube[:, :2], axis=1)
        still = np.abs(obs[:, 22]) < 0.5          # the fingers stopped: on the cube, or closed on nothing
        held = (horizontal < HOLD_RADIUS) & (np.abs(grip[:, 2] - cube[:, 2]) < max(HOLD_HEIGHT, reach + 0.02)) & \
            (opening > HELD) & (opening < min(0.9, ajar - HELD_BELOW)) & still
        closing = (horizontal < HOLD_RADIUS) & low & (obs[:, 22] < -0.5)    # under way: not given up half-closed
        around = ((horizontal < 0.01) & low) | closing
        target = np.where(held[:, None], goal + grip - cube, np.where((horizontal < 0.01)[:, None], down, over))
        actions[:, :3] = _towards(grip, target, lead=~held)
        actions[:, 3] = np.where(held | around, -1.0, 2.0 * ajar - 1.0)
        actions[~held & around, :3] = 0.0                  # closing: the arm waits
    return actions[0] if np.ndim(observation) == 1 else actions
