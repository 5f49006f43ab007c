"""Forward kinematics of a URDF robot, with robot_state_publisher's semantics. No rospy.

    tree = KinematicTree.from_xml_string(open('ur5.urdf').read())
    tree.joint_transform('shoulder_pan_joint', 0.3)        # 4x4, parent link -> child link
    tree.link_poses({'shoulder_pan_joint': 0.3})           # {link: 4x4 in the root frame}
    tree.link_poses_batch(q, names)                        # {link: (N, 4, 4)} for N configurations
    plan = tree.transform_plan()                           # the node's vectorised hot path, per message:
    data = plan.message_transforms(plan.message_layout(names), positions)

Semantics (those of robot_state_publisher + kdl_parser):
- revolute and continuous rotate about the normalised axis, prismatic translates along it, both after the
  joint's fixed origin (xyz, then rpy = fixed-axis roll, pitch, yaw); limits are never clamped;
- fixed and planar joints are static (planar is treated as fixed); floating joints are skipped;
- a mimic joint takes ``multiplier * source + offset`` (defaults 1 and 0), following chains of mimics;
  a value given explicitly for a mimic joint wins.

Only the elements kinematics uses are read (link names; each joint's type, parent, child, origin, axis,
limit, mimic), so old or unusual elements elsewhere (PR2's ``<transmission>`` blocks, gazebo tags) cannot
stop a robot from loading.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
from tf import transformations as tft
from urdf_parser_py import xml_reflection
from urdf_parser_py.urdf import URDF

MOVING_TYPES = ('revolute', 'continuous', 'prismatic')
STATIC_TYPES = ('fixed', 'planar')  # planar is published as fixed, as robot_state_publisher does
SKIPPED_TYPES = ('floating',)
JOINT_CHILD_TAGS = ('parent', 'child', 'origin', 'axis', 'limit', 'mimic')
# A moving joint whose name has one of these words is part of a hand or a gripper, not of the arm (end_effectors)
FINGER_WORDS = frozenset(('finger', 'thumb', 'index', 'middle', 'ring', 'pinky', 'little', 'knuckle', 'gripper',
                          'claw', 'jaw', 'palm', 'hand', 'digit', 'phalanx'))
# The names of an arm's end, best first (end_effectors): a tool centre point, ROS-Industrial's tool0, an end
# effector, a tool frame, a grasp frame, a flange, a gripper's or a hand's base; a sensor's frame (a camera's, a touch
# sensor's) only where nothing else is left
TIP_NAMES = tuple(re.compile(p) for p in (
    r'(^|_)tcp(_|$)|tool_?cent(er|re)_?point', r'(^|_)tool0$', r'end_?effector|(^|_)eef?(_link)?$|(^|_)ee_link',
    r'(^|_)tool(_?frame|_?link)?$', r'(^|_)grasp(ing)?(_?frame|_?link|_?point)?$', r'(^|_)flange(_link)?$',
    r'gripper(_base)?(_link)?$|(^|_)hand(_link)?$'))
SENSOR_NAME = re.compile(r'camera|optical|imu|laser|lidar|depth|rgb|kinect|realsense|sensor|accelerometer|led|'
                         r'touch|tactile|bumper|sonar|microphone|speaker|button|skin')


class URDFError(ValueError):
    """The robot description cannot be turned into a kinematic tree."""


class Joint:
    """One URDF joint with its fixed part precomputed.

    Attributes: name, type, parent, child (link names); xyz (3,), quat (4, x y z w) and matrix (4x4) of the
    origin; axis (3,), normalised; lower, upper (limits or None); velocity (the limit's velocity, rad/s or m/s, or
    None); mimic: (source, multiplier, offset) or None.
    """

    __slots__ = ('name', 'type', 'parent', 'child', 'xyz', 'rpy', 'quat', 'matrix', 'axis', 'lower', 'upper',
                 'velocity', 'mimic')

    def __init__(self, name: str, jtype: str, parent: str, child: str, xyz, rpy, axis, lower: float | None = None,
                 upper: float | None = None, mimic: tuple[str, float, float] | None = None,
                 velocity: float | None = None):
        self.name, self.type, self.parent, self.child = name, jtype, parent, child
        self.xyz = np.array(xyz, dtype=float)
        self.rpy = np.array(rpy, dtype=float)
        self.quat = tft.quaternion_from_euler(*self.rpy)  # URDF rpy = static x, then y, then z ('sxyz')
        self.matrix = tft.concatenate_matrices(tft.translation_matrix(self.xyz), tft.quaternion_matrix(self.quat))
        axis = np.array(axis, dtype=float)
        norm = np.linalg.norm(axis)
        if jtype in MOVING_TYPES and not (norm > 0.0 and np.all(np.isfinite(axis))):
            raise URDFError(f'joint {name!r} has an invalid axis {list(axis)}')
        self.axis = axis / norm if norm > 0.0 else axis
        self.lower, self.upper = lower, upper
        self.velocity = velocity
        self.mimic = mimic

    @property
    def moving(self) -> bool:
        return self.type in MOVING_TYPES

    def transform(self, position: float = 0.0) -> np.ndarray:
        """4x4 transform parent link -> child link at this joint position (tf.transformations)."""
        if self.type in ('revolute', 'continuous'):
            return np.dot(self.matrix, tft.rotation_matrix(position, self.axis))
        if self.type == 'prismatic':
            return np.dot(self.matrix, tft.translation_matrix(self.axis * position))
        return self.matrix.copy()


def _kinematic_subset(xml_string):
    """The robot element with only link names and joints' kinematic children, as an XML string."""
    try:
        root = ET.fromstring(xml_string)
    except ET.ParseError as e:
        raise URDFError(f'robot_description is not valid XML: {e}')
    if root.tag != 'robot':
        raise URDFError(f'robot_description has root element <{root.tag}>, expected <robot>')
    out = ET.Element('robot', {'name': root.get('name', '')})
    for el in root:
        if el.tag == 'link':
            ET.SubElement(out, 'link', {'name': el.get('name', '')})
        elif el.tag == 'joint':
            joint = ET.SubElement(out, 'joint', dict(el.attrib))
            for child in el:
                if child.tag in JOINT_CHILD_TAGS:
                    joint.append(child)
    return ET.tostring(out, encoding='unicode')


def _parse_quietly(xml_string):
    """URDF.from_xml_string without urdf_parser_py's stderr warnings (about elements it does not know, which
    kinematics does not use)."""
    saved = xml_reflection.core.on_error
    xml_reflection.core.on_error = lambda message: None
    try:
        return URDF.from_xml_string(xml_string)
    except Exception as e:  # urdf_parser_py raises ParseError, AssertionError, ValueError, ...
        raise URDFError(f'cannot parse the URDF: {str(e).strip().splitlines()[0]}')
    finally:
        xml_reflection.core.on_error = saved


def _check_finite(joint, *values):
    """URDFError naming the joint and the element, as robot_state_publisher refuses such a file."""
    for what, v in values:
        try:
            numbers = [float(x) for x in v]
        except (TypeError, ValueError):
            raise URDFError(f'joint {joint!r}: {what} must be numbers, got {v!r}')
        if not all(math.isfinite(x) for x in numbers):
            raise URDFError(f'joint {joint!r}: {what} must be finite numbers, got '
                            f'{" ".join(repr(x) for x in numbers)}')


class KinematicTree:
    """The kinematic tree of a URDF: joints in parent-before-child order from the single root link."""

    def __init__(self, name: str, root: str, links: list[str], joints: dict[str, Joint], floating_joints=()):
        self.name = name
        self.root = root
        self.links = links                      # every link, parents before children
        self.joints = joints                    # {name: Joint} but floating ones, insertion order = topological
        self.floating_joints = list(floating_joints)
        self._floating_child = {}               # floating joint -> its child link (from_urdf fills it)
        self._floating_parent = {}              # floating joint -> its parent link
        self.warnings = []
        self.joint_order = list(joints)
        self.moving_joints = [n for n, j in joints.items() if j.moving]
        self.static_joints = [n for n, j in joints.items() if j.type in STATIC_TYPES]
        self.mimic_joints = [n for n, j in joints.items() if j.mimic is not None and j.moving]
        # joints a user (or joint_state_publisher) drives: moving and not mimic
        self.active_joints = [n for n in self.moving_joints if joints[n].mimic is None]

    # ----------------------------------------------------------------------------------------- loading
    @classmethod
    def from_xml_string(cls, xml_string: str) -> KinematicTree:
        if not xml_string or not xml_string.strip():
            raise URDFError('robot_description is empty')
        return cls.from_urdf(_parse_quietly(_kinematic_subset(xml_string)))

    @classmethod
    def from_file(cls, path: str) -> KinematicTree:
        with open(path) as f:
            return cls.from_xml_string(f.read())

    @classmethod
    def from_urdf(cls, robot) -> KinematicTree:
        """Build from a urdf_parser_py URDF object."""
        link_names = [l.name for l in robot.links]
        if not link_names:
            raise URDFError(f'the robot {robot.name!r} has no link')
        if len(set(link_names)) != len(link_names):
            raise URDFError(f'the robot {robot.name!r} names a link twice')
        joint_names = [j.name for j in robot.joints]
        if len(set(joint_names)) != len(joint_names):
            raise URDFError(f'the robot {robot.name!r} names a joint twice')
        by_child, children, known = {}, {}, set(link_names)     # a set: 40,000 links must not cost 40,000**2
        for j in robot.joints:
            for end in (j.parent, j.child):
                if end not in known:
                    raise URDFError(f'joint {j.name!r} refers to the unknown link {end!r}')
            if j.child in by_child:
                raise URDFError(f'link {j.child!r} is the child of two joints')
            by_child[j.child] = j
            children.setdefault(j.parent, []).append(j)
        roots = [l for l in link_names if l not in by_child]
        if len(roots) != 1:
            raise URDFError(f'a robot needs exactly one root link, found {len(roots)}: {roots[:5]}')
        root = roots[0]

        joints, links, floating = {}, [root], []
        stack = [root]
        while stack:  # depth-first from the root: every joint after its parent's joint
            parent = stack.pop()
            for j in reversed(children.get(parent, [])):
                links.append(j.child)
                stack.append(j.child)
                if j.type in SKIPPED_TYPES:
                    # robot_state_publisher cannot publish a floating joint from joint_states; the joints
                    # below it are still published, relative to its child link
                    floating.append(j.name)
                    continue
                if j.type not in MOVING_TYPES + STATIC_TYPES:
                    raise URDFError(f'joint {j.name!r} has the unknown type {j.type!r}')
                origin = j.origin
                xyz = origin.xyz if origin is not None and origin.xyz is not None else [0.0, 0.0, 0.0]
                rpy = origin.rpy if origin is not None and origin.rpy is not None else [0.0, 0.0, 0.0]
                axis = j.axis if j.axis is not None else [1.0, 0.0, 0.0]
                lower = upper = velocity = None
                if j.limit is not None:
                    lower, upper, velocity = j.limit.lower, j.limit.upper, j.limit.velocity
                mimic = None
                if j.mimic is not None:
                    mimic = (j.mimic.joint,
                             1.0 if j.mimic.multiplier is None else float(j.mimic.multiplier),
                             0.0 if j.mimic.offset is None else float(j.mimic.offset))
                _check_finite(j.name, ('origin xyz', xyz), ('origin rpy', rpy), ('axis', axis),
                              ('mimic multiplier and offset', mimic[1:] if mimic else ()))
                joints[j.name] = Joint(j.name, j.type, j.parent, j.child, xyz, rpy, axis, lower, upper, mimic,
                                       velocity)
        tree = cls(robot.name, root, links, joints, floating)
        floating_set = set(floating)
        tree._floating_child = {j.name: j.child for j in robot.joints if j.name in floating_set}
        tree._floating_parent = {j.name: j.parent for j in robot.joints if j.name in floating_set}
        tree._check_mimics()
        return tree

    def _check_mimics(self) -> None:
        """A mimic joint must follow a moving joint, through a chain without cycles. robot_state_publisher
        loads such a file anyway, so an invalid mimic is dropped with a warning, not a load failure.
        Linear in the number of joints, however long the chains (each joint is walked once)."""
        self.warnings, dropped = [], []
        verdict = {}  # mimic name -> None (valid) or the problem
        for name in self.mimic_joints:
            chain, on_chain, src, problem = [name], {name}, self.joints[name].mimic[0], None
            while True:
                if src in verdict:
                    problem = None if verdict[src] is None else f'follows {src!r}, which is an invalid mimic'
                    break
                if src not in self.joints or not self.joints[src].moving:
                    problem = f'follows {src!r}, which is not a moving joint'
                    break
                if src in on_chain:
                    problem = f'is part of a cycle of mimics: {" -> ".join(chain[chain.index(src):] + [src])}'
                    break
                if self.joints[src].mimic is None:
                    break
                chain.append(src)
                on_chain.add(src)
                src = self.joints[src].mimic[0]
            for n in chain:
                verdict.setdefault(n, problem)
        for name in self.mimic_joints:
            if verdict[name] is not None:
                self.warnings.append(f'mimic joint {name!r} {verdict[name]}; it is treated as an ordinary joint')
                dropped.append(name)
        for name in dropped:
            self.joints[name].mimic = None
        self.mimic_joints = [n for n in self.mimic_joints if self.joints[n].mimic is not None]
        self.active_joints = [n for n in self.moving_joints if self.joints[n].mimic is None]

    # ---------------------------------------------------------------------------------- single form
    def resolve_positions(self, positions: dict) -> dict:
        """Positions of every joint that has one: the given ones, plus mimic joints whose source (or source's
        source, ...) is given. A value given for a mimic joint wins over the computed one."""
        resolved = dict(positions)
        for name in self.mimic_joints:
            if name in resolved:
                continue
            value = self._mimic_value(name, positions)
            if value is not None:
                resolved[name] = value
        return resolved

    def _mimic_value(self, name, positions):
        """The value of a (mimic) joint: given, or its source's through the chain; None if nothing is given.
        A loop, not recursion: chains may be thousands of joints long."""
        steps = []
        while name not in positions:
            joint = self.joints[name]
            if joint.mimic is None:
                return None
            steps.append(joint.mimic)
            name = joint.mimic[0]
        value = positions[name]
        for _, mult, off in reversed(steps):
            value = mult * value + off
        return value

    def joint_transform(self, name: str, position: float = 0.0) -> np.ndarray:
        """4x4 parent link -> child link transform of one joint."""
        return self.joints[name].transform(position)

    def joint_transforms(self, positions: dict) -> dict[str, np.ndarray]:
        """{joint: 4x4} for every moving joint that has a position (mimic joints resolved), as published."""
        resolved = self.resolve_positions(positions)
        return {n: self.joints[n].transform(resolved[n]) for n in self.moving_joints if n in resolved}

    def finger_joints(self) -> set[str]:
        """The moving joints of hands and grippers: those named with a FINGER_WORDS word, and the prismatic, mimic
        and mimicked joints with no arm joint below them (a gripper's slide, its mimicking finger)."""
        mimicked = {j.mimic[0] for j in self.joints.values() if j.mimic is not None}
        below = self._children()
        fingers: set[str] = set()
        for name in reversed(self.joint_order):     # children before parents
            j = self.joints[name]
            if not j.moving:
                continue
            if self._named_finger(name):
                fingers.add(name)
            elif (j.type == 'prismatic' or j.mimic is not None or name in mimicked) and \
                    not self._arm_joint_below(j.child, below, fingers):
                fingers.add(name)
        # a lone slide (not named so, no mimic) is no finger where the link it hangs from carries the arm too: the
        # Fetch's torso bellows, beside its arm on the torso, is not its gripper
        for name in [n for n in fingers if self.joints[n].type == 'prismatic' and self.joints[n].mimic is None
                     and n not in mimicked and not self._named_finger(n)]:
            if self._arm_joint_below(self.joints[name].parent, below, fingers):
                fingers.discard(name)
        return fingers

    @staticmethod
    def _named_finger(name: str) -> bool:
        words = {w.lower() for w in re.findall(r'[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+', name)}
        return bool(words & FINGER_WORDS) or any(w.startswith('finger') for w in words)

    def _children(self) -> dict[str, list[tuple[str, str]]]:
        """{link: [(joint, child link)]}, floating joints included (their names as joints have no entry)."""
        below: dict[str, list[tuple[str, str]]] = {}
        for name in self.joint_order:
            below.setdefault(self.joints[name].parent, []).append((name, self.joints[name].child))
        for name in self.floating_joints:
            below.setdefault(self._floating_parent[name], []).append((name, self._floating_child[name]))
        return below

    def subtree(self, link: str) -> list[str]:
        """link and every link below it (through floating joints too), depth first."""
        below = self._children()
        out, todo = [], [link]
        while todo:
            here = todo.pop()
            if here not in out:
                out.append(here)
                todo.extend(child for _, child in below.get(here, []))
        return out

    def _arm_joint_below(self, link: str, below: dict, fingers: set[str]) -> bool:
        todo = [link]
        while todo:
            for joint, child in below.get(todo.pop(), []):
                j = self.joints.get(joint)
                if j is not None and j.moving and j.mimic is None and joint not in fingers:
                    return True
                todo.append(child)
        return False

    def end_effectors(self) -> list[str]:
        """The ends of the robot's arms, the first being end_effector(): of the links below the most arm joints
        (moving, not mimic, not finger_joints(); through floating joints too, which do not count), one per arm
        (per last arm joint), named as an arm's end is (TIP_NAMES), else the deepest; fingers' links are never
        one. A robot with no arm joint: [its root]."""
        fingers = self.finger_joints()
        below = self._children()
        count = {self.root: (0, None, 0)}        # link: (arm joints above, the last of them, joints since it)
        order = [self.root]
        for link in order:
            arm, last, since = count[link]
            for joint, child in below.get(link, []):
                j = self.joints.get(joint)
                if j is not None and j.moving and joint in fingers:
                    continue                     # a hand's or a gripper's links
                if j is not None and j.moving and j.mimic is None:
                    count[child] = (arm + 1, joint, 0)
                else:
                    count[child] = (arm, last, since + 1)
                order.append(child)
        most = max(arm for arm, _, _ in count.values())
        if most == 0:
            return [self.root]
        index = {link: i for i, link in enumerate(self.links)}
        arms: dict[str, list[str]] = {}
        for link in order:
            if count[link][0] == most:
                arms.setdefault(count[link][1], []).append(link)

        def rank(link):
            lower = link.lower()
            named = next((i for i, pattern in enumerate(TIP_NAMES) if pattern.search(lower)), len(TIP_NAMES))
            if named == len(TIP_NAMES) and SENSOR_NAME.search(lower):
                named += 1
            return named, -count[link][2], index.get(link, len(index))
        return sorted((min(links, key=rank) for links in arms.values()), key=lambda l: index.get(l, len(index)))

    def chain_to(self, link: str) -> tuple[str, list[str]]:
        """(base, joints from base to link): up from link to the root, or to the child of the nearest floating joint
        above it (nothing publishes a floating joint, so that child is the frame link's pose is known in)."""
        parent_joint = {j.child: n for n, j in self.joints.items()}
        floating_children = {self._floating_child[n] for n in self.floating_joints}
        chain = []
        while link in parent_joint and link not in floating_children:
            chain.append(parent_joint[link])
            link = self.joints[chain[-1]].parent
        return link, chain[::-1]

    def frame_above(self, link: str) -> str:
        """The frame link's pose is known in from joint_states: chain_to(link)'s base."""
        return self.chain_to(link)[0]

    def end_effector(self) -> str:
        """A tip link for a robot nobody named one for: the first of end_effectors(), the end of its arm (a tool
        frame such as tool0 or a TCP, else the deepest link below the last arm joint), not a finger."""
        return self.end_effectors()[0]

    def static_transforms(self) -> dict[str, np.ndarray]:
        """{joint: 4x4} for the fixed (and planar) joints."""
        return {n: self.joints[n].transform(0.0) for n in self.static_joints}

    def floating_links(self, name: str) -> tuple[str, str]:
        """(parent, child) of the floating joint name."""
        return self._floating_parent[name], self._floating_child[name]

    def floating_base(self) -> str | None:
        """The child of the floating joint that carries the most links (a humanoid's pelvis, a mobile base's
        body): joint_states cannot place it, but everything below it moves with the joints. None without one."""
        if not self.floating_joints:
            return None
        below = {}
        for name in self.joint_order:
            j = self.joints[name]
            below.setdefault(j.parent, []).append(j.child)

        def size(link):
            return 1 + sum(size(c) for c in below.get(link, []))
        children = [self._floating_child[n] for n in self.floating_joints]
        return max(children, key=size)

    def link_poses(self, positions: dict | None = None, base: str | None = None) -> dict[str, np.ndarray]:
        """{link: 4x4 pose in the frame of base (the root by default)} of every link connected to base through
        joints other than floating ones; moving joints without a position are taken at 0."""
        resolved = self.resolve_positions(positions or {})
        poses = {self.root if base is None else base: np.identity(4)}
        for name in self.joint_order:
            j = self.joints[name]
            if j.parent in poses:
                poses[j.child] = np.dot(poses[j.parent], j.transform(resolved.get(name, 0.0)))
        return poses

    # ----------------------------------------------------------------------------------- batch form
    def link_poses_batch(self, q, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Poses of every link for N configurations at once.

        q: (N, len(names)) array; names defaults to ``active_joints``. Mimic joints follow their sources;
        moving joints not named are at 0. Returns {link: (N, 4, 4)} in the root frame, for the links that
        link_poses returns.
        """
        names = list(self.active_joints if names is None else names)
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != len(names):
            raise ValueError(f'q must have shape (N, {len(names)}), got {q.shape}')
        unknown = [n for n in names if n not in self.joints or not self.joints[n].moving]
        if unknown:
            raise ValueError(f'not moving joints of this robot: {unknown}')
        n = q.shape[0]
        # the single form's mimic resolution works on columns as well as on numbers
        cols = self.resolve_positions({name: q[:, i] for i, name in enumerate(names)})
        poses = {self.root: np.broadcast_to(np.identity(4), (n, 4, 4))}
        for name in self.joint_order:
            j = self.joints[name]
            if j.parent in poses:
                local = _batch_joint_matrices(j, cols.get(name, np.zeros(n)) if j.moving else None, n)
                poses[j.child] = np.matmul(poses[j.parent], local)
        poses[self.root] = np.array(poses[self.root])
        return poses

    # ------------------------------------------------------------------------------ node's hot path
    def transform_plan(self, tf_prefix: str = '') -> TransformPlan:
        return TransformPlan(self, tf_prefix)


def _batch_joint_matrices(joint, values, n):
    """(n, 4, 4) parent -> child transforms of one joint for n values (Rodrigues' formula, vectorised)."""
    out = np.empty((n, 4, 4))
    out[:] = joint.matrix
    if values is None or not joint.moving:
        return out
    k = joint.axis
    if joint.type == 'prismatic':
        out[:, :3, 3] += np.outer(values, np.dot(joint.matrix[:3, :3], k))
        return out
    c, s = np.cos(values), np.sin(values)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rot = (c[:, None, None] * np.identity(3) + s[:, None, None] * kx
           + (1.0 - c)[:, None, None] * np.outer(k, k))
    out[:, :3, :3] = np.matmul(joint.matrix[:3, :3], rot)
    return out


def prefix_frame(tf_prefix: str, frame: str) -> str:
    """robot_state_publisher's frame naming: a frame with a leading slash loses it and gets no prefix;
    otherwise a non-empty prefix (without its own leading slash) and '/' are put before it."""
    if frame.startswith('/'):
        return frame[1:]
    if not tf_prefix:
        return frame
    return (tf_prefix[1:] if tf_prefix.startswith('/') else tf_prefix) + '/' + frame


class TransformPlan:
    """Precomputed arrays that turn a JointState's positions into every published joint's parent -> child
    transform with a few numpy operations (no per-joint Python loop). Used by the node for each message:

        layout = plan.message_layout(names)            # once per tuple of names
        data = plan.message_transforms(layout, positions)   # (K, 7): xyz, quaternion xyzw

    Moving joints are indexed 0..M-1 in ``names``; static joints are in ``static_*``.
    """

    def __init__(self, tree: KinematicTree, tf_prefix: str = ''):
        self.tree = tree
        self.names = list(tree.moving_joints)
        self.index = {n: i for i, n in enumerate(self.names)}
        joints = [tree.joints[n] for n in self.names]
        self.parent_frames = [prefix_frame(tf_prefix, j.parent) for j in joints]
        self.child_frames = [prefix_frame(tf_prefix, j.child) for j in joints]
        m = len(joints)
        self.origin_xyz = np.array([j.xyz for j in joints]).reshape(m, 3)
        self.origin_quat = np.array([j.quat for j in joints]).reshape(m, 4)
        self.revolute = np.array([j.type != 'prismatic' for j in joints], dtype=bool)
        self.axis = np.array([j.axis for j in joints]).reshape(m, 3)
        # prismatic: child origin moves by value * (R_origin . axis) in the parent frame
        self.slide = np.array([np.dot(j.matrix[:3, :3], j.axis) for j in joints]).reshape(m, 3)
        self.slide[self.revolute] = 0.0
        # mimic joints in an order where every source comes before the mimics that follow it
        order, placed = [], set()
        for name in tree.mimic_joints:  # a loop, not recursion: chains may be thousands of joints long
            pending = []
            while name not in placed and tree.joints[name].mimic is not None:
                pending.append(name)
                placed.add(name)
                name = tree.joints[name].mimic[0]
            order.extend(reversed(pending))
        self.mimic_steps = [(self.index[n], self.index[tree.joints[n].mimic[0]],
                             tree.joints[n].mimic[1], tree.joints[n].mimic[2]) for n in order]
        self.static_names = list(tree.static_joints)
        static = [tree.joints[n] for n in self.static_names]
        self.static_parent_frames = [prefix_frame(tf_prefix, j.parent) for j in static]
        self.static_child_frames = [prefix_frame(tf_prefix, j.child) for j in static]
        self.static_xyz = np.array([j.xyz for j in static]).reshape(len(static), 3)
        self.static_quat = np.array([j.quat for j in static]).reshape(len(static), 4)

    def message_layout(self, names) -> MessageLayout:
        """Everything about a JointState's tuple of names that does not depend on its positions, so that
        a stream of messages with the same names costs a few numpy operations each (MessageLayout)."""
        return MessageLayout(self, names)

    def message_transforms(self, layout: MessageLayout, positions: np.ndarray) -> np.ndarray:
        """(K, 7) array: translation xyz and rotation xyzw of the layout's K joints (layout.out_idx) for one
        message's positions, with the mimic joints whose source has a value."""
        v = positions[layout.gather]
        if layout.affine:
            v = v * layout.scale + layout.shift  # explicit: v * 1 + 0 == v; mimic: source * multiplier + offset
        for k, src, mult, off in layout.chain:
            v[k] = mult * v[src] + off
        half = v * layout.half  # 0.5 for revolute joints, 0 for prismatic ones (their rotation is the origin's)
        out = np.empty((len(v), 7))
        np.multiply(layout.slide, v[:, None], out=out[:, :3])
        out[:, :3] += layout.xyz
        np.multiply(layout.p, np.sin(half)[:, None], out=out[:, 3:])
        out[:, 3:] += layout.q * np.cos(half)[:, None]
        return out


def _left_matrix(q):
    """4x4 L with L . b == quaternion_multiply(q, b) for (x, y, z, w) quaternions."""
    x, y, z, w = q
    return np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


class MessageLayout:
    """Precomputed for one tuple of joint names (see TransformPlan.message_layout).

    out_idx: plan indices of the joints published (explicit first occurrences of moving joints, then the mimic
    joints whose source has a value); gather: for each, the message position its value comes from (a mimic's
    explicit source); scale/shift: the mimic affine terms (affine is False when there is none); chain: mimics
    of mimics, applied in order; unknown: names not in the URDF; xyz, slide, p, q: per published joint, so
    that translation = xyz + slide * v and rotation = p * sin(v / 2) + q * cos(v / 2) (revolute: the origin's
    quaternion times the rotation about the axis; prismatic: p = 0)."""

    def __init__(self, plan: TransformPlan, names):
        tree = plan.tree
        value_of, unknown, seen = {}, [], set()   # plan index -> message index, first occurrence wins
        floating = set(tree.floating_joints)
        for i, name in enumerate(names):
            k = plan.index.get(name)
            if k is not None:
                value_of.setdefault(k, i)
            elif name not in tree.joints and name not in floating and name not in seen:
                seen.add(name)
                unknown.append(name)
        self.unknown = unknown
        out, gather, scale, shift = [], [], [], []
        for k in sorted(value_of):
            out.append(k)
            gather.append(value_of[k])
            scale.append(1.0)
            shift.append(0.0)
        pos_of = {k: j for j, k in enumerate(out)}
        chain = []
        for idx, src, mult, off in plan.mimic_steps:   # sources before the mimics that follow them
            if idx in pos_of or src not in pos_of:
                continue
            j = len(out)
            out.append(idx)
            pos_of[idx] = j
            if src in value_of:                         # the source is given: one affine term
                gather.append(value_of[src])
                scale.append(mult)
                shift.append(off)
            else:                                       # the source is itself a mimic: computed after
                gather.append(0)
                scale.append(1.0)
                shift.append(0.0)
                chain.append((j, pos_of[src], mult, off))
        self.out_idx = np.array(out, dtype=np.intp)
        self.gather = np.array(gather, dtype=np.intp)
        self.scale = np.array(scale)
        self.shift = np.array(shift)
        self.affine = bool(len(out) > len(value_of))
        self.chain = chain
        idx = self.out_idx
        self.xyz = plan.origin_xyz[idx]
        self.slide = plan.slide[idx]
        left = np.array([_left_matrix(qo) for qo in plan.origin_quat[idx]]).reshape(len(idx), 4, 4)
        rev = plan.revolute[idx]
        axis = np.concatenate((plan.axis[idx], np.zeros((len(idx), 1))), axis=1)
        self.p = np.einsum('kij,kj->ki', left, axis) * rev[:, None]
        self.q = left[:, :, 3]
        self.half = 0.5 * rev
