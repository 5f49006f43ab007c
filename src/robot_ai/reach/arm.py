"""The arm of a reach task: the chain of a robot from its base to a tip link, batched over many arms. No rospy.

    arm = Arm(KinematicTree.from_file('ur5.urdf'), tip='tool0')
    arm.joints, arm.lower, arm.upper, arm.home     # the chain's active joints in chain order, limits, home
    arm.tip_positions(q)                           # (N, 3) in the base frame for q (N, n)
    arm.jacobian(q)                                # (N, 3, n): d tip / d q, analytic from the joint axes
    arm.move_tip(q, dx, damping)                   # joint positions after a tip displacement (damped least squares)

The chain runs from the robot's root (or, below a floating joint, from that joint's child: a mobile base's body) to
the tip. Its active joints are its moving joints that follow no other (a mimic joint follows its source, which is
then one of the arm's joints even where it is off the chain, as a gripper's other finger); continuous joints, and
revolute ones whose URDF gives no range, are taken within [-pi, pi].

Every batched computation is a sequence of element-wise numpy operations on arrays whose last axis is the batch (no
matrix product, no reduction), so that an arm's numbers are the same bit for bit whether it is computed alone or as
one of thousands: ReachVectorEnv equals gymnasium's SyncVectorEnv over ReachEnvs exactly.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from robot_ai.kinematics import KinematicTree

UNLIMITED = math.pi          # continuous and unlimited joints: [-pi, pi]
DEFAULT_VELOCITY = 1.0       # rad/s (or m/s) where the URDF gives no velocity limit
CLAMP_PASSES = 3             # damped least squares solved again after locking joints at their limits
NULL_DAMPING = 0.01          # the null-space projection's damping, in the task's damping
LIMIT_TOLERANCE = 1e-3       # rad (or m): a joint this near a limit is at it
_NEXT = np.array([1, 2, 0])  # cross products and cofactors: the index after i, and the one after that (mod 3)
_AFTER = np.array([2, 0, 1])


class ReachError(ValueError):
    """A robot, tip or setting a reach task cannot use; the message is one line that says what is wrong."""


def joint_limits(joint) -> tuple[float, float, str]:
    """(lower, upper, why they were assumed or '') of a moving kinematics.Joint: its URDF range; [-pi, pi] for a
    continuous joint, or one whose URDF gives no range."""
    if joint.type == 'continuous':
        return -UNLIMITED, UNLIMITED, ''
    lower, upper = joint.lower, joint.upper
    if lower is None or upper is None or not (math.isfinite(lower) and math.isfinite(upper)) or upper <= lower:
        return -UNLIMITED, UNLIMITED, (f'joint {joint.name!r} has no range in the URDF ({lower} to {upper}): taken '
                                       f'within [-pi, pi]')
    return float(lower), float(upper), ''


def joint_velocity(joint) -> float:
    """A moving joint's URDF velocity limit (rad/s or m/s), DEFAULT_VELOCITY where it gives none."""
    return float(joint.velocity) if (joint.velocity or 0) > 0 else DEFAULT_VELOCITY


def _listed(names: list[str], most: int = 12) -> str:
    shown = ', '.join(names[:most])
    return shown + (f' and {len(names) - most} more' if len(names) > most else '')


_SIDES = {'left': re.compile(r'(^|[_/])(left|l)([_/]|$)|^L(?=[A-Z])|Left'),
          'right': re.compile(r'(^|[_/])(right|r)([_/]|$)|^R(?=[A-Z])|Right')}


def arm_side(tree: KinematicTree, link: str) -> str | None:
    """'left' or 'right' when the link's name or its chain's moving joints say which side (right_gripper,
    l_wrist, LShoulderPitch, ...), else None."""
    chain = tree.chain_to(link)[1] if link in tree.links else []
    for name in [link] + [j for j in reversed(chain) if tree.joints[j].moving]:
        said = [side for side, pattern in _SIDES.items() if pattern.search(name)]
        if len(said) == 1:
            return said[0]
    return None


def _rotation_to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation A (3x3) with A @ e_z = axis (a unit vector): a joint about axis is A Rz(v) A^T."""
    z = np.asarray(axis, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack((x, y, z))


@dataclass(frozen=True)
class _Segment:
    """A moving joint of the chain, seen from the frame of the moving joint before it (after its motion): a
    constant rotation and translation to the joint's own frame, turned so that its axis is z; its value is
    multiplier * q[source] + offset. r and t: the same as tuples of floats, for the one-arm path."""
    name: str
    revolute: bool
    rotation: np.ndarray      # (3, 3)
    translation: np.ndarray   # (3,)
    source: int               # index in Arm.joints
    multiplier: float
    offset: float
    r: tuple = ()             # rotation's rows as floats
    t: tuple = ()             # translation as floats


class Arm:
    """The chain from the base to tip, its active joints and their limits, and its batched kinematics.

    Attributes: tree, tip, base (the frame of every position: the root, or the child of a floating joint above the
    tip), chain (every joint from base to tip), joints (active joint names, in chain order), n, lower, upper and
    home (the middle of each range) and velocity (URDF velocity limits, DEFAULT_VELOCITY where none) as arrays
    (n,), length (the offsets summed from the first moving joint to the tip, plus prismatic travel), radius (no tip
    position is farther than this from the base), warnings (limits that had to be assumed; the other arms' ends
    when no tip was given on a robot with several)."""

    def __init__(self, tree: KinematicTree, tip: str | None = None):
        self.tree = tree
        self.warnings: list[str] = []
        if tip is None:
            ends = tree.end_effectors()
            self.tip = ends[0]
            if len(ends) > 1:
                side = arm_side(tree, self.tip)
                which = f'the {side} arm' if side else f'one of {len(ends)} arms'
                others = [f'{end} ({s} arm)' if (s := arm_side(tree, end)) else end for end in ends[1:]]
                self.warnings.append(f'no tip given: {self.tip}, the end of {which}; the other arm'
                                     f'{"s end" if len(others) > 1 else " ends"} at {_listed(others)}: give tip '
                                     f'(--tip, tip:=) to reach with {"one" if len(others) > 1 else "it"}')
        else:
            self.tip = str(tip)
        if self.tip not in tree.links:
            raise ReachError(f'tip {self.tip!r} is not a link of {tree.name or "the robot"}: it could be '
                             f'{_listed(self.candidate_tips(tree))}')
        self.base, self.chain = tree.chain_to(self.tip)
        moving = [n for n in self.chain if tree.joints[n].moving]
        if not moving:
            raise ReachError(f'tip {self.tip!r} has no moving joint between {self.base!r} and it: it could be '
                             f'{_listed(self.candidate_tips(tree))}')
        self.joints: list[str] = []
        sources = {}
        for name in moving:
            source, multiplier, offset = self._source(tree, name)
            if source not in self.joints:
                self.joints.append(source)
            sources[name] = (self.joints.index(source), multiplier, offset)
        self.n = len(self.joints)
        limits = [self._limits(tree.joints[n]) for n in self.joints]
        self.lower = np.array([lo for lo, _ in limits])
        self.upper = np.array([hi for _, hi in limits])
        self.home = (self.lower + self.upper) / 2.0
        self.velocity = np.array([joint_velocity(tree.joints[n]) for n in self.joints])
        self.revolute_joints = np.array([tree.joints[n].type != 'prismatic' for n in self.joints])
        self._build(tree, sources)
        first = self.chain.index(moving[0])
        travel = sum(max(abs(tree.joints[n].lower or 0.0), abs(tree.joints[n].upper or 0.0))
                     for n in moving if tree.joints[n].type == 'prismatic')
        spans = sum(float(self.upper[self.joints.index(n)] - self.lower[self.joints.index(n)])
                    for n in moving if tree.joints[n].type == 'prismatic' and n in self.joints)
        self.length = float(sum(np.linalg.norm(tree.joints[n].xyz) for n in self.chain[first + 1:]) + spans)
        self.radius = float(sum(np.linalg.norm(tree.joints[n].xyz) for n in self.chain) + travel)
        if self.length <= 1e-9:
            raise ReachError(f'tip {self.tip!r} does not move when its joints move (it lies on the axis of '
                             f'{moving[0]!r}): pick a link farther from the base')

    # ------------------------------------------------------------------------------------------- the chain
    @staticmethod
    def candidate_tips(tree: KinematicTree) -> list[str]:
        """Links with a moving joint above them (below a floating joint too): what a tip can be, the deepest first."""
        below_moving = {tree.root: 0}
        below_moving.update({tree.floating_links(n)[1]: 0 for n in tree.floating_joints})
        for name in tree.joint_order:
            j = tree.joints[name]
            if j.parent in below_moving:
                below_moving[j.child] = below_moving[j.parent] + j.moving
        return sorted((link for link, k in below_moving.items() if k), key=lambda link: -below_moving[link])

    @staticmethod
    def _source(tree: KinematicTree, name: str) -> tuple[str, float, float]:
        """The joint that drives name (itself unless it is a mimic), and the value's multiplier and offset."""
        multiplier, offset = 1.0, 0.0
        while tree.joints[name].mimic is not None:
            source, m, o = tree.joints[name].mimic
            multiplier, offset = multiplier * m, multiplier * o + offset
            name = source
        return name, multiplier, offset

    def _limits(self, joint) -> tuple[float, float]:
        lower, upper, assumed = joint_limits(joint)
        if assumed:
            self.warnings.append(assumed)
        return lower, upper

    def _build(self, tree: KinematicTree, sources: dict) -> None:
        """The chain as segments between moving joints (fixed joints folded in), each joint's axis turned onto z."""
        segments, rotation, translation = [], np.identity(3), np.zeros(3)
        for name in self.chain:
            j = tree.joints[name]
            origin = j.matrix[:3, :3]
            translation = translation + rotation @ j.xyz
            rotation = rotation @ origin
            if not j.moving:
                continue
            turn = _rotation_to_z(j.axis)
            source, multiplier, offset = sources[name]
            rot = rotation @ turn
            segments.append(_Segment(name, j.type != 'prismatic', rot, translation, source, multiplier, offset,
                                     tuple(tuple(float(v) for v in row) for row in rot),
                                     tuple(float(v) for v in translation)))
            rotation, translation = turn.T, np.zeros(3)
        self._segments = segments
        self._tip_offset = translation        # the tip's origin in the last moving joint's (turned) frame
        self._tip_rotation = rotation         # and its orientation there
        self._tip_t = tuple(float(v) for v in translation)
        self._lower, self._upper = self.lower.tolist(), self.upper.tolist()
        self._half = (self.upper - self.lower) / 2.0
        self._home_list, self._half_list = self.home.tolist(), self._half.tolist()

    # ----------------------------------------------------------------------------------- batched kinematics
    def forward(self, q_t: np.ndarray, with_axes: bool = True):
        """The tip (3, N) for joint positions q_t (n, N) (the batch last); with_axes, also every moving joint's axis
        and origin in the base frame, as lists of (3, N) arrays, or (3, 1) where they do not depend on q."""
        pos, cols, axes, origins = self._last_frame(q_t, with_axes)
        t = self._tip_offset
        tip = pos + (cols[0] * t[0] + cols[1] * t[1] + cols[2] * t[2])
        return tip, axes, origins

    def _last_frame(self, q_t: np.ndarray, with_axes: bool):
        """The last moving joint's frame (its origin (3, N), its rotation's columns cols[j] (3, N) each) for q_t, and
        with_axes every moving joint's axis and origin (forward's lists)."""
        cols = np.identity(3)[:, :, None]        # the frame's rotation, column j = cols[j]: (3, 3, 1), then (3, 3, N)
        pos = np.zeros((3, 1))
        axes, origins = [], []
        for seg in self._segments:
            t, r = seg.translation, seg.rotation
            pos = pos + (cols[0] * t[0] + cols[1] * t[1] + cols[2] * t[2])
            mid = cols[0][None] * r[0][:, None, None] + cols[1][None] * r[1][:, None, None] \
                + cols[2][None] * r[2][:, None, None]
            v = q_t[seg.source]
            if seg.multiplier != 1.0 or seg.offset != 0.0:
                v = v * seg.multiplier + seg.offset
            if with_axes:
                axes.append(mid[2])
                origins.append(pos)
            if seg.revolute:
                c, s = np.cos(v), np.sin(v)
                cols = np.empty((3, 3, len(v)))
                cols[0] = mid[0] * c + mid[1] * s
                cols[1] = mid[1] * c - mid[0] * s
                cols[2] = mid[2]
            else:
                pos = pos + mid[2] * v
                cols = mid
        return pos, cols, axes, origins

    def pose_t(self, q_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, list, list]:
        """(tip (3, N), the tip's rotation (3, 3, N) in the base frame (rows, columns, batch), axes, origins) for
        joint positions q_t (n, N): forward's with the orientation."""
        pos, cols, axes, origins = self._last_frame(q_t, True)
        t, r = self._tip_offset, self._tip_rotation
        tip = pos + (cols[0] * t[0] + cols[1] * t[1] + cols[2] * t[2])
        rotation = np.stack([cols[0] * r[0, k] + cols[1] * r[1, k] + cols[2] * r[2, k] for k in range(3)], axis=1)
        return tip, np.broadcast_to(rotation, (3, 3, q_t.shape[1])), axes, origins

    def jacobian6_t(self, tip: np.ndarray, axes: list, origins: list, angular_weight: float = 1.0) -> np.ndarray:
        """(6, n, N): jacobian_t's three rows, then the tip's angular velocity per joint (a revolute joint's axis,
        times a mimic's multiplier; nothing for a prismatic one) times angular_weight (metres per radian)."""
        n_batch = tip.shape[1]
        out = np.zeros((6, self.n, n_batch))
        out[:3] = self.jacobian_t(tip, axes, origins)
        for seg, a in zip(self._segments, axes):
            if seg.revolute:
                out[3:, seg.source] += np.broadcast_to(a, (3, n_batch)) * (seg.multiplier * angular_weight)
        return out

    def jacobian_t(self, tip: np.ndarray, axes: list, origins: list) -> np.ndarray:
        """d tip / d q as (3, n, N) from forward()'s results: revolute joints axis x (tip - origin), prismatic
        ones their axis, times a mimic's multiplier, summed where several chain joints follow one source."""
        n_batch = tip.shape[1]
        out = np.zeros((3, self.n, n_batch))
        for seg, a, origin in zip(self._segments, axes, origins):
            if seg.revolute:
                d = tip - origin
                column = a[_NEXT] * d[_AFTER] - a[_AFTER] * d[_NEXT]
            else:
                column = np.broadcast_to(a, (3, n_batch))
            if seg.multiplier != 1.0:
                column = column * seg.multiplier
            out[:, seg.source] += column
        return out

    def tip_rotations(self, q) -> np.ndarray:
        """The tip's orientation (N, 3, 3) in the base frame for joint positions q (N, n); (3, 3) for one
        configuration (n,)."""
        q = np.asarray(q, dtype=float)
        q_t = np.ascontiguousarray(np.atleast_2d(q).T)
        _, cols, _, _ = self._last_frame(q_t, with_axes=False)
        frame = np.broadcast_to(cols, (3, 3, q_t.shape[1])).transpose(2, 1, 0)     # (N, 3, 3), columns cols[j]
        out = frame @ self._tip_rotation
        return out if q.ndim == 2 else out[0].copy()

    def angular_jacobian(self, q) -> np.ndarray:
        """d(tip orientation)/dq as angular velocity per joint (N, 3, n) in the base frame: a revolute joint's axis,
        nothing for a prismatic one, times a mimic's multiplier, summed where several follow one source; (3, n) for
        one configuration (n,)."""
        q = np.asarray(q, dtype=float)
        q_t = np.ascontiguousarray(np.atleast_2d(q).T)
        _, axes, _ = self.forward(q_t)
        out = np.zeros((q_t.shape[1], 3, self.n))
        for seg, a in zip(self._segments, axes):
            if seg.revolute:
                out[:, :, seg.source] += np.broadcast_to(a, (3, q_t.shape[1])).T * seg.multiplier
        return out if q.ndim == 2 else out[0].copy()

    def tip_positions(self, q) -> np.ndarray:
        """Tip positions (N, 3) in the base frame for joint positions q (N, n); (3,) for one configuration (n,)."""
        q = np.asarray(q, dtype=float)
        tip, _, _ = self.forward(np.ascontiguousarray(np.atleast_2d(q).T), with_axes=False)
        return tip.T.copy() if q.ndim == 2 else tip[:, 0].copy()

    def jacobian(self, q) -> np.ndarray:
        """The tip's Jacobian (N, 3, n) for joint positions q (N, n); (3, n) for one configuration."""
        q = np.asarray(q, dtype=float)
        j = self.jacobian_t(*self.forward(np.ascontiguousarray(np.atleast_2d(q).T)))
        return np.ascontiguousarray(j.transpose(2, 0, 1)) if q.ndim == 2 else j[:, :, 0].copy()

    # ------------------------------------------------------------------------------------ damped least squares
    @staticmethod
    def damped_least_squares(jac_t: np.ndarray, dx_t: np.ndarray, damping: float) -> np.ndarray:
        """dq (n, N) = J^T (J J^T + damping^2 I)^-1 dx for J (3, n, N) and dx (3, N): the joint motion that moves
        the tip by dx as well as it can, bounded near singular configurations. Six rows (a pose: jacobian6_t) are
        solved by Cholesky, element-wise over the batch as well."""
        if jac_t.shape[0] != 3:
            return Arm._damped_least_squares_rows(jac_t, dx_t, damping)
        products = jac_t[:, None] * jac_t[None, :]            # (3, 3, n, N)
        a = products[:, :, 0].copy()
        for k in range(1, jac_t.shape[1]):
            a += products[:, :, k]
        lam2 = damping * damping
        for i in range(3):
            a[i, i] += lam2
        cof = a[_NEXT][:, _NEXT] * a[_AFTER][:, _AFTER] - a[_NEXT][:, _AFTER] * a[_AFTER][:, _NEXT]
        det = a[0, 0] * cof[0, 0] + a[0, 1] * cof[0, 1] + a[0, 2] * cof[0, 2]
        y = (cof[:, 0] * dx_t[0] + cof[:, 1] * dx_t[1] + cof[:, 2] * dx_t[2]) / det
        return jac_t[0] * y[0] + jac_t[1] * y[1] + jac_t[2] * y[2]

    @staticmethod
    def _damped_least_squares_rows(jac_t: np.ndarray, dx_t: np.ndarray, damping: float) -> np.ndarray:
        """damped_least_squares for any number of rows r: (J J^T + damping^2 I) y = dx by Cholesky, one element-wise
        operation over the batch at a time (an arm's numbers do not depend on its batch)."""
        r, n = jac_t.shape[0], jac_t.shape[1]
        lam2 = damping * damping
        a = [[None] * r for _ in range(r)]
        for i in range(r):
            for j in range(i + 1):
                total = jac_t[i, 0] * jac_t[j, 0]
                for k in range(1, n):
                    total = total + jac_t[i, k] * jac_t[j, k]
                a[i][j] = total + lam2 if i == j else total
        low = [[None] * r for _ in range(r)]
        for j in range(r):
            s = a[j][j]
            for k in range(j):
                s = s - low[j][k] * low[j][k]
            low[j][j] = np.sqrt(s)
            for i in range(j + 1, r):
                s = a[i][j]
                for k in range(j):
                    s = s - low[i][k] * low[j][k]
                low[i][j] = s / low[j][j]
        y = []
        for i in range(r):
            s = dx_t[i]
            for k in range(i):
                s = s - low[i][k] * y[k]
            y.append(s / low[i][i])
        x = [None] * r
        for i in reversed(range(r)):
            s = y[i]
            for k in range(i + 1, r):
                s = s - low[k][i] * x[k]
            x[i] = s / low[i][i]
        out = jac_t[0] * x[0]
        for i in range(1, r):
            out = out + jac_t[i] * x[i]
        return out

    def clip(self, q_t: np.ndarray) -> np.ndarray:
        """q_t (n, N) within the joint limits."""
        return np.minimum(np.maximum(q_t, self.lower[:, None]), self.upper[:, None])

    def limit_gradient_t(self, q_t: np.ndarray, gain: float) -> np.ndarray:
        """(n, N): each joint's step away from its nearer limit, gain x u |u| (rad or m), u = (q - middle) / half
        range in [-1, 1]: nothing at mid-range, gain at a limit (Liegeois 1977's gradient of the distance to the
        limits, steeper near them)."""
        u = (q_t - self.home[:, None]) / self._half[:, None]
        return -gain * (u * np.abs(u))

    def null_space_t(self, jac_t: np.ndarray, g_t: np.ndarray, damping: float) -> np.ndarray:
        """(n, N): g_t projected onto the Jacobian's null space, g - J^T (J J^T + damping^2 I)^-1 J g: joint motion
        that leaves the tip where it is (up to damping^2 / sigma^2 along a singular value sigma of J)."""
        jg = jac_t[:, 0] * g_t[0]
        for k in range(1, self.n):
            jg = jg + jac_t[:, k] * g_t[k]
        return g_t - self.damped_least_squares(jac_t, jg, damping)

    def move_t(self, q_t: np.ndarray, jac_t: np.ndarray, dx_t: np.ndarray, damping: float,
               passes: int = CLAMP_PASSES, limit_gain: float = 0.0, weights: np.ndarray | None = None) -> np.ndarray:
        """Joint positions (n, N) after moving the tip by dx_t (3, N) from q_t (n, N), within the limits (or its pose
        by dx_t (6, N), with jacobian6_t's rows and weight).

        Damped least squares, clamped: a joint the solution would take past a limit goes to that limit and is locked,
        and the rest of the displacement is solved again with the other joints (up to `passes` times), so that a
        joint stuck at a limit (a finger's 4 cm slide, which least squares favours) does not swallow every step.
        A pass changes nothing for an arm that locks no new joint, so an arm's result does not depend on its batch.
        limit_gain > 0 (rad or m per step at a limit): plus the joints' steps away from their limits
        (limit_gradient_t) in the Jacobian's null space (null_space_t, damped by NULL_DAMPING x damping), which the
        tip does not feel. weights (n,) in (0, 1]: each joint's share of the motion, least squares of dq_k / w_k (a
        joint of weight w moves as if its column of the Jacobian were w times as long, then w times what it is
        solved for): joints that move slowly (through a safety layer, each within its own velocity limit) are asked
        for less; None: all alike (weights of 1 are the same numbers to the bit)."""
        w = None if weights is None else np.asarray(weights, dtype=float)[:, None]
        scaled = jac_t if w is None else jac_t * w[None]
        dq = self.damped_least_squares(scaled, dx_t, damping)
        if w is not None:
            dq = dq * w
        if limit_gain > 0:
            g_t = self.limit_gradient_t(q_t, limit_gain)
            if w is None:
                dq = dq + self.null_space_t(jac_t, g_t, damping * NULL_DAMPING)
            else:
                dq = dq + self.null_space_t(scaled, g_t / w, damping * NULL_DAMPING) * w
        lower, upper = self.lower[:, None], self.upper[:, None]
        locked = np.zeros(q_t.shape, dtype=bool)
        fixed = np.zeros(q_t.shape)               # the locked joints' motion, to their limit
        for _ in range(passes):
            target = q_t + dq
            newly = ((target < lower) | (target > upper)) & ~locked
            if not newly.any():
                break
            locked |= newly
            fixed = np.where(newly, np.minimum(np.maximum(target, lower), upper) - q_t, fixed)
            free = scaled * ~locked[None]
            done = jac_t[:, 0] * fixed[0]
            for k in range(1, self.n):
                done = done + jac_t[:, k] * fixed[k]
            step = self.damped_least_squares(free, dx_t - done, damping)
            solved = np.where(locked, fixed, step if w is None else step * w)
            dq = np.where(locked.any(axis=0), solved, dq)    # an arm with no joint locked keeps its step as it was
        return self.clip(q_t + dq)

    def move_tip(self, q, dx, damping: float, limit_gain: float = 0.0) -> np.ndarray:
        """Joint positions (N, n) after moving the tip by dx (N, 3) from q (N, n) (see move_t)."""
        q_t = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float)).T)
        dx_t = np.ascontiguousarray(np.atleast_2d(np.asarray(dx, dtype=float)).T)
        return self.move_t(q_t, self.jacobian_t(*self.forward(q_t)), dx_t, damping,
                           limit_gain=limit_gain).T.copy()

    # ------------------------------------------------------------------------------------------------ one arm
    # The same operations as forward, jacobian_t, damped_least_squares and move_t, in the same order, on plain
    # floats: one arm's step costs a fifth of a batch of one's (numpy's overhead per call dominates there), and its
    # numbers are the batch's bit for bit (IEEE operations, cos and sin from the same numpy loop).
    def forward_one(self, q) -> tuple[list[float], list, list]:
        """(tip, axes, origins) of one configuration q (n floats), as forward's column 0."""
        values = []
        for seg in self._segments:
            v = q[seg.source]
            if seg.multiplier != 1.0 or seg.offset != 0.0:
                v = v * seg.multiplier + seg.offset
            values.append(float(v))
        revolute = [v for seg, v in zip(self._segments, values) if seg.revolute]
        cosines, sines = np.cos(np.array(revolute)).tolist(), np.sin(np.array(revolute)).tolist()
        c0, c1, c2 = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]
        p = [0.0, 0.0, 0.0]
        axes, origins, k = [], [], 0
        for seg, v in zip(self._segments, values):
            t0, t1, t2 = seg.t
            p = [p[i] + (c0[i] * t0 + c1[i] * t1 + c2[i] * t2) for i in range(3)]
            r0, r1, r2 = seg.r
            m0, m1, m2 = ([c0[i] * r0[j] + c1[i] * r1[j] + c2[i] * r2[j] for i in range(3)] for j in range(3))
            axes.append(m2)
            origins.append(p)
            if seg.revolute:
                c, s = cosines[k], sines[k]
                k += 1
                c0 = [m0[i] * c + m1[i] * s for i in range(3)]
                c1 = [m1[i] * c - m0[i] * s for i in range(3)]
                c2 = m2
            else:
                p = [p[i] + m2[i] * v for i in range(3)]
                c0, c1, c2 = m0, m1, m2
        t0, t1, t2 = self._tip_t
        return [p[i] + (c0[i] * t0 + c1[i] * t1 + c2[i] * t2) for i in range(3)], axes, origins

    def jacobian_one(self, tip: list, axes: list, origins: list) -> list[list[float]]:
        """As jacobian_t's column 0: rows x, y, z of n floats."""
        out = [[0.0] * self.n for _ in range(3)]
        for seg, a, origin in zip(self._segments, axes, origins):
            if seg.revolute:
                d = [tip[i] - origin[i] for i in range(3)]
                column = [a[(i + 1) % 3] * d[(i + 2) % 3] - a[(i + 2) % 3] * d[(i + 1) % 3] for i in range(3)]
            else:
                column = a
            if seg.multiplier != 1.0:
                column = [x * seg.multiplier for x in column]
            for i in range(3):
                out[i][seg.source] = out[i][seg.source] + column[i]
        return out

    @staticmethod
    def damped_least_squares_one(jac: list, dx: list, damping: float) -> list[float]:
        """As damped_least_squares for one arm: jac rows x, y, z of n floats, dx 3 floats."""
        n = len(jac[0])
        a = [[0.0] * 3 for _ in range(3)]
        for i in range(3):
            for j in range(3):
                total = jac[i][0] * jac[j][0]
                for k in range(1, n):
                    total = total + jac[i][k] * jac[j][k]
                a[i][j] = total
        lam2 = damping * damping
        for i in range(3):
            a[i][i] = a[i][i] + lam2
        cof = [[a[(i + 1) % 3][(j + 1) % 3] * a[(i + 2) % 3][(j + 2) % 3]
                - a[(i + 1) % 3][(j + 2) % 3] * a[(i + 2) % 3][(j + 1) % 3] for j in range(3)] for i in range(3)]
        det = a[0][0] * cof[0][0] + a[0][1] * cof[0][1] + a[0][2] * cof[0][2]
        y = [(cof[i][0] * dx[0] + cof[i][1] * dx[1] + cof[i][2] * dx[2]) / det for i in range(3)]
        return [jac[0][k] * y[0] + jac[1][k] * y[1] + jac[2][k] * y[2] for k in range(n)]

    def move_one(self, q: list, jac: list, dx: list, damping: float, passes: int = CLAMP_PASSES,
                 limit_gain: float = 0.0, weights: list | None = None) -> list[float]:
        """As move_t for one arm (weights: n floats, or None)."""
        n, lower, upper = self.n, self._lower, self._upper
        actual, w = jac, weights
        if w is not None:
            jac = [[row[k] * w[k] for k in range(n)] for row in jac]
        dq = self.damped_least_squares_one(jac, dx, damping)
        if w is not None:
            dq = [dq[k] * w[k] for k in range(n)]
        if limit_gain > 0:
            middle, half = self._home_list, self._half_list
            u = [(q[k] - middle[k]) / half[k] for k in range(n)]
            g = [-limit_gain * (u[k] * abs(u[k])) for k in range(n)]
            if w is not None:
                g = [g[k] / w[k] for k in range(n)]
            jg = [jac[i][0] * g[0] for i in range(3)]
            for k in range(1, n):
                jg = [jg[i] + jac[i][k] * g[k] for i in range(3)]
            back = self.damped_least_squares_one(jac, jg, damping * NULL_DAMPING)
            if w is None:
                dq = [dq[k] + (g[k] - back[k]) for k in range(n)]
            else:
                dq = [dq[k] + (g[k] - back[k]) * w[k] for k in range(n)]
        locked, fixed = [False] * n, [0.0] * n
        for _ in range(passes):
            target = [q[k] + dq[k] for k in range(n)]
            newly = [(target[k] < lower[k] or target[k] > upper[k]) and not locked[k] for k in range(n)]
            if not any(newly):
                break
            locked = [locked[k] or newly[k] for k in range(n)]
            fixed = [min(max(target[k], lower[k]), upper[k]) - q[k] if newly[k] else fixed[k] for k in range(n)]
            keep = [0.0 if locked[k] else 1.0 for k in range(n)]
            free = [[row[k] * keep[k] for k in range(n)] for row in jac]
            done = [actual[i][0] * fixed[0] for i in range(3)]
            for k in range(1, n):
                done = [done[i] + actual[i][k] * fixed[k] for i in range(3)]
            solved = self.damped_least_squares_one(free, [dx[i] - done[i] for i in range(3)], damping)
            if w is not None:
                solved = [solved[k] * w[k] for k in range(n)]
            dq = [fixed[k] if locked[k] else solved[k] for k in range(n)]
        return [min(max(q[k] + dq[k], lower[k]), upper[k]) for k in range(n)]

    # -------------------------------------------------------------------------------------------- the robot
    def at_limits(self, q, tolerance: float = LIMIT_TOLERANCE) -> list[str]:
        """The joints of one configuration q (n,) at one of their limits (within tolerance, rad or m)."""
        q = np.asarray(q, dtype=float)
        at = (q <= self.lower + tolerance) | (q >= self.upper - tolerance)
        return [name for name, flag in zip(self.joints, at) if flag]

    def positions(self, q) -> dict[str, float]:
        """{joint: position} of the arm's joints for one configuration (n,), as joint_states carries them."""
        return {name: float(v) for name, v in zip(self.joints, np.asarray(q, dtype=float))}

    def describe(self) -> str:
        return (f'{self.tree.name or "robot"}: {self.n} joints from {self.base} to {self.tip} '
                f'({", ".join(self.joints)}), {self.length:.3f} m of chain')

