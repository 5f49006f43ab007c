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
from dataclasses import dataclass

import numpy as np

from robot_ai.kinematics import KinematicTree

UNLIMITED = math.pi          # continuous and unlimited joints: [-pi, pi]
DEFAULT_VELOCITY = 1.0       # rad/s (or m/s) where the URDF gives no velocity limit
CLAMP_PASSES = 3             # damped least squares solved again after locking joints at their limits
_NEXT = np.array([1, 2, 0])  # cross products and cofactors: the index after i, and the one after that (mod 3)
_AFTER = np.array([2, 0, 1])


class ReachError(ValueError):
    """A robot, tip or setting a reach task cannot use; the message is one line that says what is wrong."""


def _listed(names: list[str], most: int = 12) -> str:
    shown = ', '.join(names[:most])
    return shown + (f' and {len(names) - most} more' if len(names) > most else '')


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
    multiplier * q[source] + offset."""
    name: str
    revolute: bool
    rotation: np.ndarray      # (3, 3)
    translation: np.ndarray   # (3,)
    source: int               # index in Arm.joints
    multiplier: float
    offset: float


class Arm:
    """The chain from the base to tip, its active joints and their limits, and its batched kinematics.

    Attributes: tree, tip, base (the frame of every position: the root, or the child of a floating joint above the
    tip), chain (every joint from base to tip), joints (active joint names, in chain order), n, lower, upper and
    home (the middle of each range) and velocity (URDF velocity limits, DEFAULT_VELOCITY where none) as arrays
    (n,), length (the offsets summed from the first moving joint to the tip, plus prismatic travel), radius (no tip
    position is farther than this from the base), warnings (limits that had to be assumed)."""

    def __init__(self, tree: KinematicTree, tip: str | None = None):
        self.tree = tree
        self.tip = tree.end_effector() if tip is None else str(tip)
        if self.tip not in tree.links:
            raise ReachError(f'tip {self.tip!r} is not a link of {tree.name or "the robot"}: it could be '
                             f'{_listed(self.candidate_tips(tree))}')
        self.base, self.chain = self._chain(tree, self.tip)
        moving = [n for n in self.chain if tree.joints[n].moving]
        if not moving:
            raise ReachError(f'tip {self.tip!r} has no moving joint between {self.base!r} and it: it could be '
                             f'{_listed(self.candidate_tips(tree))}')
        self.warnings: list[str] = []
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
        self.velocity = np.array([tree.joints[n].velocity if (tree.joints[n].velocity or 0) > 0 else DEFAULT_VELOCITY
                                  for n in self.joints], dtype=float)
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
        """Links with a moving joint above them: what a tip can be, the deepest first."""
        below_moving = {tree.root: 0}
        for name in tree.joint_order:
            j = tree.joints[name]
            if j.parent in below_moving:
                below_moving[j.child] = below_moving[j.parent] + j.moving
        return sorted((link for link, k in below_moving.items() if k), key=lambda link: -below_moving[link])

    @staticmethod
    def _chain(tree: KinematicTree, tip: str) -> tuple[str, list[str]]:
        """(base, joints from base to tip): up from the tip to the root, or to the child of a floating joint."""
        parent_joint = {j.child: name for name, j in tree.joints.items()}
        floating_children = {tree.floating_links(n)[1] for n in tree.floating_joints}
        chain, link = [], tip
        while link in parent_joint and link not in floating_children:
            name = parent_joint[link]
            chain.append(name)
            link = tree.joints[name].parent
        return link, chain[::-1]

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
        if joint.type == 'continuous':
            return -UNLIMITED, UNLIMITED
        lower, upper = joint.lower, joint.upper
        if lower is None or upper is None or not (math.isfinite(lower) and math.isfinite(upper)) or upper <= lower:
            self.warnings.append(f'joint {joint.name!r} has no range in the URDF ({lower} to {upper}): taken within '
                                 f'[-pi, pi]')
            return -UNLIMITED, UNLIMITED
        return float(lower), float(upper)

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
            segments.append(_Segment(name, j.type != 'prismatic', rotation @ turn, translation, source, multiplier,
                                     offset))
            rotation, translation = turn.T, np.zeros(3)
        self._segments = segments
        self._tip_offset = translation        # the tip's origin in the last moving joint's (turned) frame

    # ----------------------------------------------------------------------------------- batched kinematics
    def forward(self, q_t: np.ndarray, with_axes: bool = True):
        """The tip (3, N) for joint positions q_t (n, N) (the batch last); with_axes, also every moving joint's axis
        and origin in the base frame, as lists of (3, N) arrays, or (3, 1) where they do not depend on q."""
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
        t = self._tip_offset
        tip = pos + (cols[0] * t[0] + cols[1] * t[1] + cols[2] * t[2])
        return tip, axes, origins

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
        the tip by dx as well as it can, bounded near singular configurations."""
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

    def clip(self, q_t: np.ndarray) -> np.ndarray:
        """q_t (n, N) within the joint limits."""
        return np.minimum(np.maximum(q_t, self.lower[:, None]), self.upper[:, None])

    def move_t(self, q_t: np.ndarray, jac_t: np.ndarray, dx_t: np.ndarray, damping: float,
               passes: int = CLAMP_PASSES) -> np.ndarray:
        """Joint positions (n, N) after moving the tip by dx_t (3, N) from q_t (n, N), within the limits.

        Damped least squares, clamped: a joint the solution would take past a limit goes to that limit and is locked,
        and the rest of the displacement is solved again with the other joints (up to `passes` times), so that a
        joint stuck at a limit (a finger's 4 cm slide, which least squares favours) does not swallow every step.
        A pass changes nothing for an arm that locks no new joint, so an arm's result does not depend on its batch."""
        dq = self.damped_least_squares(jac_t, dx_t, damping)
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
            free = jac_t * ~locked[None]
            done = jac_t[:, 0] * fixed[0]
            for k in range(1, self.n):
                done = done + jac_t[:, k] * fixed[k]
            dq = np.where(locked, fixed, self.damped_least_squares(free, dx_t - done, damping))
        return self.clip(q_t + dq)

    def move_tip(self, q, dx, damping: float) -> np.ndarray:
        """Joint positions (N, n) after moving the tip by dx (N, 3) from q (N, n) (see move_t)."""
        q_t = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float)).T)
        dx_t = np.ascontiguousarray(np.atleast_2d(np.asarray(dx, dtype=float)).T)
        return self.move_t(q_t, self.jacobian_t(*self.forward(q_t)), dx_t, damping).T.copy()

    # -------------------------------------------------------------------------------------------- the robot
    def positions(self, q) -> dict[str, float]:
        """{joint: position} of the arm's joints for one configuration (n,), as joint_states carries them."""
        return {name: float(v) for name, v in zip(self.joints, np.asarray(q, dtype=float))}

    def describe(self) -> str:
        return (f'{self.tree.name or "robot"}: {self.n} joints from {self.base} to {self.tip} '
                f'({", ".join(self.joints)}), {self.length:.3f} m of chain')

