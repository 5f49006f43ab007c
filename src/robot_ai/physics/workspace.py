"""Where a manipulation task is laid out for any arm with a gripper: the grip point (between the fingertips), the
ready configuration (the gripper pointing down over the table, in front of the arm) and the table, worked out from
the robot itself, so that an arm the package has never seen gets a task without numbers written for it. No rospy.

    space = workspace(arm, physics)          # arm: reach.arm.Arm; physics: physics.model.Physics (its gripper)
    space.ready, space.rotation, space.grip_offset, space.centre, space.table_top

- The grip point: the fingers' collision geometry (every link below a gripper joint), seen from the tip at home; it
  lies along the approach axis (from the wrist toward the fingers' middle), halfway between their middle and their far
  end, where the pads of a parallel gripper are.
- The hand closed: every gripper joint at its closing end (each finger on its own joint, as a Kinova's three, closes
  too), what a push keeps clear of the cube and how far it reaches past the grip point (curled fingers stop above);
  and how deep an object goes between the fingers: to the palm (the hand's geometry that is not a finger).
- The ready configuration: the grip point READY_REACH of the arm's length (less a torso's lift; nearer, down to
  0.6 of that, where the arm, pointing down, falls short of the workspace's corners) in front of its shoulder (the
  first joint of the chain whose axis is level), at the shoulder's height, the approach axis straight down and the
  fingers closing along y; found by damped least squares (Arm.move_t on the grip point's 6-row Jacobian) from the
  middle of every range, or where that ends short, from random configurations. Where none reaches all four corners,
  the one that reaches the most, said in Workspace.note.
- The table: its top READY_HEIGHT below the ready grip point, under the whole workspace, clear of the arm's base.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from robot_ai.physics.model import Physics, PhysicsError, geom_points
from robot_ai.reach.arm import Arm

READY_REACH = 0.55          # the ready grip point's distance in front of the shoulder, a share of the arm's length
READY_HEIGHT = 0.2          # m: the ready grip point above the table (panda-gym's and Fetch's gripper start so)
READY_ITERATIONS = 400      # damped least squares steps to the ready configuration
READY_TOLERANCE = (0.005, 0.02)     # m and rad: how near the ready pose must come
CORNER = 0.17               # m: the workspace's corners from its centre, along x and y (the envs' 0.3 m square of
                            # objects and goals, and a grasp's reach round it)
READY_DECIMALS = 9          # rad or m: the ready configuration's last digit
BETWEEN_TOLERANCE = 0.001   # m: the hand's geometry this far past the grip point, between the fingers, is in the way
GAP_SAMPLES = 10            # the fingers' gap is measured at openings 0, 0.1, ... 1
READY_STARTS = 16           # damped least squares from the middle of every range, then from random configurations
DOWN = np.array([0.0, 0.0, -1.0])


@dataclasses.dataclass(frozen=True)
class Workspace:
    """ready (the arm's joints, Arm.joints order, at each episode's start), rotation (3x3: the tip's orientation
    there, held through the task), grip (the gripper seen from the tip), centre (the ready grip point in the base
    frame), table_top (z of the table's top), note (what of the workspace the arm cannot reach; '' where all)."""
    ready: np.ndarray
    rotation: np.ndarray
    grip: Grip
    centre: np.ndarray
    table_top: float
    note: str = ''


def finger_links(tree, joints) -> list[str]:
    """Every link below the joints (a gripper's fingers and what they carry), once each."""
    return list(dict.fromkeys(link for n in joints for link in tree.subtree(tree.joints[n].child)))


@dataclasses.dataclass(frozen=True)
class Grip:
    """A gripper seen from the tip: offset (the grip point), approach and closing (axes), beyond (how far the
    fingertips reach past the grip point along the approach, m), open_high (whether the first gripper joint opens
    toward its upper limit: the Panda's slide does, a Robotiq's knuckle closes that way), hand (the points of the
    hand's geometry closed, every link below the tip, in the tip's frame: what a push must keep clear of) and
    closed_beyond (how far the closed hand reaches past the grip point along the approach, m: below zero for a hand
    whose closed fingers curl up above it, as a Kinova's three do), depth (how far above the grip point an object
    between the fingers reaches before it meets the palm, the hand's geometry that is not a finger, m) and spans
    (the fingers' points in the tip's frame at openings 0, 1 / GAP_SAMPLES, ... 1: every gripper joint at that share
    of its range; opening, gaps and ajar read them) and between (the hand's links, not fingers, whose geometry
    stands past the grip point between the open fingers: what an object there would meet)."""
    offset: np.ndarray
    approach: np.ndarray
    closing: np.ndarray
    beyond: float
    open_high: bool
    hand: np.ndarray = dataclasses.field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    closed_beyond: float = 0.0
    depth: float = np.inf
    spans: tuple[np.ndarray, ...] = dataclasses.field(repr=False, default=())
    between: tuple[str, ...] = ()

    @property
    def opening(self) -> float:
        """How far apart the open fingers stand across the closing axis, from the grip point to their tips (m; inf
        where that cannot be measured)."""
        return float(self.gaps()[-1]) if self.spans else np.inf

    def gaps(self, above: float = 0.0) -> np.ndarray:
        """How far apart the fingers stand across the closing axis, from above over the grip point to their tips, at
        openings 0, 1 / GAP_SAMPLES, ... 1 (m; 0 where they meet, inf where none stands on one side)."""
        top = float(self.offset @ self.approach) - above
        return np.array([_gap(points, self.approach, self.closing, top) for points in self.spans])

    def ajar(self, width: float, above: float = 0.0) -> float:
        """The least opening (0 closed, 1 open) at which the fingers, from above over the grip point to their tips,
        stand at least width apart (read between the gaps' samples); 1 where they never do, or cannot be measured."""
        gaps = self.gaps(above)
        if len(gaps) < 2 or not np.isfinite(gaps).all() or gaps[-1] <= width:
            return 1.0
        k = int(np.flatnonzero(gaps >= width)[0])
        if k == 0:
            return 0.0
        share = (width - gaps[k - 1]) / (gaps[k] - gaps[k - 1])
        return float((k - 1 + share) / (len(gaps) - 1))

    def radius(self, height: float) -> float:
        """How far the closed hand reaches from the approach axis (m), of its geometry less than height above the
        grip point."""
        along = self.hand @ self.approach
        low = self.hand[self.offset @ self.approach - along < height]
        if not len(low):
            return 0.0
        return float(np.linalg.norm(low - np.outer(low @ self.approach, self.approach), axis=1).max())


def _finger_points(arm: Arm, physics: Physics, data, links: list[str]) -> list[np.ndarray]:
    """The links' collision geometry as points in the tip's frame (a mesh's vertices, a primitive's box's corners),
    one array per geom."""
    import mujoco
    model = physics.model
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, arm.tip)
    out = []
    for link in links:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, link)
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body] if body >= 0 else []
        for g in geoms:
            out.append((geom_points(model, data, g) - data.xpos[tip]) @ data.xmat[tip].reshape(3, 3))
    return out


def hand_gripper(arm: Arm, physics: Physics) -> tuple[str, ...]:
    """The actuated gripper joints of the arm's own hand (below its tip: a two-armed robot's other hand is not it);
    PhysicsError of one line where there are none."""
    hand = set(arm.tree.subtree(arm.tip))
    mine = tuple(n for n in physics.gripper if arm.tree.joints[n].child in hand)
    if not mine:
        others = f' (the robot\'s grippers, {", ".join(physics.gripper)}, are not below {arm.tip})' \
            if physics.gripper else ''
        raise PhysicsError(f'{arm.tree.name}: the arm has no gripper (no actuated finger joints below '
                           f'{arm.tip}){others}: a manipulation task needs one')
    return mine


def grip_geometry(arm: Arm, physics: Physics) -> Grip:
    """The gripper from its fingers' geometry (see the module's text): the grip point and the approach at home (the
    middle of the gripper's range); the closing axis from the middle toward the first gripper joint's finger (along
    the joint's axis for a slide), square to the approach; which way it opens, from that finger's distance to the
    approach axis at either end of its range. PhysicsError for an arm without a gripper or fingers without geometry."""
    import mujoco
    tree = arm.tree
    gripper = hand_gripper(arm, physics)
    hand = tree.subtree(arm.tip)
    fingers = finger_links(tree, [n for n in tree.finger_joints() if tree.joints[n].child in hand])
    first = finger_links(tree, [gripper[0]])
    model, data = physics.model, physics.data()
    corners = _finger_points(arm, physics, data, fingers)
    if not corners:
        raise PhysicsError(f'{tree.name}: the fingers ({", ".join(sorted(tree.finger_joints()))}) have no geometry '
                           f'to grip with')
    points = np.concatenate(corners)
    middle = points.mean(axis=0)
    # the approach: from the wrist (the arm's last joint) toward the fingers' middle, not from the tip, which may
    # stand among the fingers (Interbotix's fingers_link does, its fingers' middle 1 mm behind it)
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, arm.tip)
    wrist = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, arm.joints[-1])
    toward = middle - (data.xanchor[wrist] - data.xpos[tip]) @ data.xmat[tip].reshape(3, 3)
    if np.linalg.norm(toward) < 1e-6:
        raise PhysicsError(f'{tree.name}: the fingers lie around the wrist ({arm.joints[-1]}): no way to approach with '
                           f'them')
    approach = toward / np.linalg.norm(toward)
    far = float((points @ approach).max())
    closing = np.concatenate(_finger_points(arm, physics, data, first) or [middle[None]]).mean(axis=0) - middle
    joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, gripper[0])
    if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_SLIDE:     # a slide closes along its axis (a mesh's middle
        axis = data.xaxis[joint] @ data.xmat[tip].reshape(3, 3)
        closing = axis if axis @ closing >= 0 else -axis         # is a little off it)
    closing -= approach * (closing @ approach)
    if np.linalg.norm(closing) < 1e-6:          # one finger, or fingers around the axis: any axis square to it
        closing = np.cross(approach, [1.0, 0.0, 0.0] if abs(approach[0]) < 0.9 else [0.0, 1.0, 0.0])
    closing /= np.linalg.norm(closing)
    # the palm: the hand's geometry that is not a finger, which the gripper's joints do not move
    palm_of = {link: _finger_points(arm, physics, data, [link]) for link in hand if link not in fingers}
    palm = [piece for pieces in palm_of.values() for piece in pieces]
    ranges = [model.actuator_ctrlrange[k] if model.actuator_ctrllimited[k] else (-0.01, 0.01)
              for k in (physics.actuated.index(name) for name in gripper)]

    def fingers_at(share: float) -> np.ndarray:
        """The fingers' points with every gripper joint at share of its range from its low end (the mimic joints
        with them)."""
        for name, (low, high) in zip(gripper, ranges):
            data.qpos[physics.qpos_address(name)] = low + share * (high - low)
        physics.follow_mimics(data)
        mujoco.mj_kinematics(model, data)
        return np.concatenate(_finger_points(arm, physics, data, fingers))

    distances, hands = [], []
    for end in (0, 1):                        # every gripper joint at the low end of its range, then the high
        hands.append(np.concatenate([fingers_at(end), *palm]))
        finger = np.concatenate(_finger_points(arm, physics, data, first) or [middle[None]]).mean(axis=0)
        distances.append(float(np.linalg.norm(finger - approach * (finger @ approach))))
    grip = (float(middle @ approach) + far) / 2.0
    open_high = distances[1] >= distances[0]
    fixed = lambda v: np.round(v, READY_DECIMALS)      # noqa: E731  the same in every process (see workspace())
    closed = hands[0 if open_high else 1]
    depth = grip - float(np.concatenate(palm).dot(approach).max()) if palm else np.inf

    shares = [k / GAP_SAMPLES if open_high else 1.0 - k / GAP_SAMPLES for k in range(GAP_SAMPLES + 1)]
    spans = tuple(fixed(fingers_at(share)) for share in shares)       # from closed to open
    made = Grip(fixed(approach * grip), fixed(approach), fixed(closing), float(fixed(far - grip)), open_high, closed,
                float(fixed((closed @ approach).max() - grip)), float(fixed(depth)), spans)
    # the hand's own geometry past the grip point, between the open fingers: what an object there meets
    between = tuple(link for link, pieces in palm_of.items()
                    if any(_between(piece, approach, closing, grip, made.opening) for piece in pieces))
    return dataclasses.replace(made, between=between)


def _between(piece: np.ndarray, approach: np.ndarray, closing: np.ndarray, grip: float, opening: float) -> bool:
    """Whether a convex piece of geometry (its points in the tip's frame) reaches past the grip point along the
    approach and spans some of the gap between fingers opening apart across the closing axis."""
    past = piece[piece @ approach > grip + BETWEEN_TOLERANCE] @ closing
    return bool(len(past)) and past.min() < opening / 2 and past.max() > -opening / 2


def _gap(points: np.ndarray, approach: np.ndarray, closing: np.ndarray, top: float) -> float:
    """How far apart fingers (points in the tip's frame) stand across the closing axis, from top (along the
    approach) to their tips (m; 0 where they meet, inf where none stands on one side)."""
    across = points[points @ approach >= top] @ closing
    if not (across > 0).any() or not (across < 0).any():
        return np.inf
    return max(0.0, float(across[across > 0].min() - across[across < 0].max()))


def _shoulder(arm: Arm, q: np.ndarray) -> np.ndarray:
    """The origin of the chain's first joint whose axis is level at q (the base's origin if none)."""
    _, axes, origins = arm.forward(q[:, None])
    for axis, origin in zip(axes, origins):
        a = np.asarray(axis).reshape(3, -1)[:, 0]
        if abs(a[2]) < 0.5:
            return np.asarray(origin).reshape(3, -1)[:, 0]
    return np.zeros(3)


def ready_pose(arm: Arm, offset: np.ndarray, approach: np.ndarray, closing: np.ndarray, target: np.ndarray,
               start: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """(joint positions, position error m, angle error rad): the grip point at target, the approach axis down and
    the closing axis along the base's y (the way nearer at start), by damped least squares from start (the middle
    of every range)."""
    q = (arm.home if start is None else np.asarray(start, dtype=float)).copy()[:, None]
    side = np.array([0.0, 1.0 if (arm.pose_t(q)[1][:, :, 0] @ closing)[1] >= 0 else -1.0, 0.0])
    for _ in range(READY_ITERATIONS):
        tip, rotation, axes, origins = arm.pose_t(q)
        r = rotation[:, :, 0]
        grip = tip[:, 0] + r @ offset
        pointing = r @ approach
        error = target - grip
        turn = np.cross(pointing, DOWN) + np.cross(r @ closing, side)   # the turn to the ready orientation
        if np.linalg.norm(error) < READY_TOLERANCE[0] / 10 and np.linalg.norm(turn) < READY_TOLERANCE[1] / 10:
            break
        jac = arm.jacobian6_t(grip[:, None], axes, origins, angular_weight=0.2)
        dx = np.concatenate([np.clip(error, -0.05, 0.05), 0.2 * np.clip(turn, -0.2, 0.2)])[:, None]
        q = arm.move_t(q, jac, dx, damping=0.05)
    tip, rotation, _, _ = arm.pose_t(q)
    r = rotation[:, :, 0]
    grip = tip[:, 0] + r @ offset
    angle = max(float(np.arccos(np.clip((r @ approach) @ DOWN, -1.0, 1.0))),
                float(np.arccos(np.clip((r @ closing) @ side, -1.0, 1.0))))
    return q[:, 0].copy(), float(np.linalg.norm(target - grip)), angle


def _corners_reached(arm: Arm, grip: Grip, ready: np.ndarray, centre: np.ndarray, height: float) -> int:
    """How many of the workspace's four corners (CORNER from the centre) the gripper reaches pointing down as at
    ready, low, at a grasp's height over the table (the Fetch pointing down could not reach its far side)."""
    low = centre[2] - height + grip.beyond + 0.02
    reached = 0
    for dx in (CORNER, -CORNER):
        for dy in (CORNER, -CORNER):
            q, miss, angle = ready_pose(arm, grip.offset, grip.approach, grip.closing,
                                        np.array([centre[0] + dx, centre[1] + dy, low]), ready)
            reached += miss <= READY_TOLERANCE[0] and angle <= READY_TOLERANCE[1]
    return reached


def workspace(arm: Arm, physics: Physics, reach: float = READY_REACH, height: float = READY_HEIGHT) -> Workspace:
    """The task's layout for arm (see the module's text); PhysicsError of one line where the arm cannot point its
    gripper down in front of itself."""
    grip = grip_geometry(arm, physics)
    shoulder = _shoulder(arm, arm.home)
    forward = np.array([1.0, 0.0, 0.0])
    travel = sum(float(arm.upper[k] - arm.lower[k]) for k in range(arm.n) if not arm.revolute_joints[k])
    length = arm.length - travel          # a torso's lift (the Fetch's) reaches no farther forward
    best, fallback = None, None
    for share in (reach, 0.8 * reach, 0.6 * reach):     # nearer where the wrist's height above the grip point
        target = shoulder + forward * share * length    # leaves the arm short (the Fetch's)
        target[2] = shoulder[2]
        rng = np.random.default_rng(0)
        for attempt in range(READY_STARTS):   # from the middle of every range; where that ends short, elsewhere
            start = None if attempt == 0 else rng.uniform(arm.lower, arm.upper)
            q, miss, angle = ready_pose(arm, grip.offset, grip.approach, grip.closing, target, start)
            score = miss / READY_TOLERANCE[0] + angle / READY_TOLERANCE[1]
            if best is None or score < best[0]:
                best = (score, q, miss, angle, target)
            if miss <= READY_TOLERANCE[0] and angle <= READY_TOLERANCE[1]:
                break
        if best[2] <= READY_TOLERANCE[0] and best[3] <= READY_TOLERANCE[1]:
            corners = _corners_reached(arm, grip, best[1], target, height)
            if corners == 4:
                break
            if fallback is None or corners > fallback[0]:
                fallback = (corners, best)
            best = None
    note = ''
    if best is None:            # no share reaches every corner: the ready pose that reaches the most
        corners, best = fallback
        note = (f'{arm.tree.name}: pointing down, the gripper reaches {corners} of the workspace\'s 4 corners '
                f'({CORNER:g} m either way of its middle, low over the table): objects and goals out there are out '
                f'of its reach')
    _, q, miss, angle, target = best
    if miss > READY_TOLERANCE[0] or angle > READY_TOLERANCE[1]:
        raise PhysicsError(f'{arm.tree.name}: no configuration points the gripper down in front of the shoulder, '
                           f'{0.6 * reach * length:.2f} to {reach * length:.2f} m out (closest: {miss:.3f} m and '
                           f'{angle:.2f} rad off)')
    q = np.round(q, READY_DECIMALS)     # two processes lay out the same task (BLAS's sums differ in their last bit
    tip, rotation, _, _ = arm.pose_t(q[:, None])     # with memory alignment): an env over ROS and its sim agree
    return Workspace(ready=q, rotation=rotation[:, :, 0].copy(), grip=grip, centre=target,
                     table_top=float(target[2] - height), note=note)
