"""Any robot the package loads, as a MuJoCo model: built from the package's own robot model (its URDF or xacro through
reach.model), not from MuJoCo's URDF import, which refuses links without inertias (the package's UR5 and KUKA files
have none) and cannot read ``package://`` meshes. No rospy.

- Bodies: one per URDF link, named as the link, placed by its joint's origin, so that a body's pose is the link's
  pose (robot_state_publisher's). The root is welded to the world; a ``floating`` joint is a free joint.
- Joints: revolute -> hinge with its range, continuous -> hinge, prismatic -> slide with its range; the URDF's
  ``<dynamics damping friction>``; a mimic joint follows its source by an equality constraint (MuJoCo's joint
  equality: position = offset + multiplier x the source's), as a gripper's second finger does.
- Inertias: the URDF's ``<inertial>``; a link without one gets MuJoCo's estimate from its collision geometry at the
  density of water (said in notes). A moving link with neither gets the body model's stand-in capsules along its
  joint-to-joint segments, and its mass from them (said).
- Geometry: each link's collision geometry, meshes read by trimesh where their file resolves (``package://``
  through ROS_PACKAGE_PATH) and the body model's stand-in capsules where it does not (motion.body: never nothing,
  said). MuJoCo collides meshes by their convex hulls. The arm does not collide with itself here (the body model
  and the safety layer keep it clear of itself); it collides with the world and the objects.
- Actuators: a position servo on every joint a user drives (ros_control's position interface), its force within
  the URDF's effort limit, its gains those of a critically damped joint at POSITION_HZ for the inertia the joint
  moves at home; the arm's weight is held through the actuators (gravity compensation that counts against the
  effort limit), so a payload sags the arm and a held joint shows its tracking error.
- The world: obstacles as motion.body takes them (boxes and spheres in the arm's base frame), static; and loose
  objects (boxes, spheres and cylinders with a mass and a friction, the same file's ``objects`` key: parse_objects),
  each a body with a free joint of its name. Contacts are as stiff as MuJoCo keeps stable at its step.
- The gripper: the actuated joints of hands and grippers (kinematics.finger_joints: the Panda's hand is one servo,
  its second finger following by the mimic constraint); an effort limit that would squeeze with more than
  GRIP_FORCE at the fingertips (a vendor's placeholder) is held to it, and said.

    physics = build_physics(load_model('ur5.urdf'), obstacles='world.yaml', objects='world.yaml')
    data = physics.data()                   # at home, at rest
    data.ctrl[:] = target                   # joint positions, in physics.actuated's order
    mujoco.mj_step(physics.model, data)

Models are kept by content (the URDF text, the meshes' files, the world and the options): building the same robot
again costs a copy.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import os
import xml.etree.ElementTree as ET

import numpy as np

from robot_ai.motion.body import (BodyError, Obstacle, link_shapes, numbers, origin_pose, parse_obstacles, read_yaml,
                                  resolve_mesh, rpy_matrix, stand_ins)
from robot_ai.reach.arm import joint_velocity
from robot_ai.reach.model import Model

TIMESTEP = 0.002            # s: MuJoCo's step (its default), the implicit-fast integrator
POSITION_HZ = 5.0           # a position servo's natural frequency at home, critically damped
GRIP_SQUEEZE = 0.1          # a gripper servo exerts its effort limit this share of its range short of its target
GRIPPER_HZ = 10.0           # a gripper servo's natural frequency, critically damped (its rotor's inertia made enough)
GRIP_FORCE = 250.0          # N: the most a gripper joint squeezes with at its fingertips (a Robotiq 2F-85's own most
                            # is 235 N); a vendor's placeholder effort, 1000 N m on kortex's 2F-85 (9,500 N at the
                            # tips), made a servo whose stiffness and rotor flung the cube up out of the fingers
DENSITY = 1000.0            # kg/m^3: a link's mass where the URDF gives none, from its collision geometry's volume
CONTACT_TIME = 2 * TIMESTEP  # s: contacts' time constant (solref), the stiffest MuJoCo keeps stable at TIMESTEP: an
                            # arm driven down onto a table went 5.6 cm into it at the impact with the default 0.02 s,
                            # 1.4 cm with 0.005 s
ARMATURE = 1e-3             # kg m^2 (or kg) added to each joint's inertia: the rotor's, and steadier small links
ARM_CONTYPE, ARM_CONAFFINITY = 2, 1          # the robot's geoms: collide with the world's, not with each other
WORLD_CONTYPE, WORLD_CONAFFINITY = 1, 2      # the world's: with the robot's, not with each other
OBJECT_CONTYPE, OBJECT_CONAFFINITY = 3, 3    # loose objects': with everything
_CACHE: dict[str, Physics] = {}
_CACHE_SIZE = 8


class PhysicsError(ValueError):
    """A robot or a world MuJoCo cannot be given; the message is one line that says what is wrong."""


@dataclasses.dataclass(frozen=True)
class Object:
    """A loose object: kind ('box', 'sphere' or 'cylinder'), size (a box's 3 edges, a sphere's radius, a cylinder's
    radius and length, m), pose (4x4, where it starts, in the obstacles' frame), mass (kg), friction (sliding, the
    coefficient) and name."""
    kind: str
    size: tuple[float, ...]
    pose: np.ndarray = dataclasses.field(compare=False)
    mass: float
    friction: float
    name: str


OBJECT_SIZES = {'box': 3, 'sphere': 1, 'cylinder': 2}
OBJECT_MASS = 0.1           # kg: an object's mass where none is given (panda-gym's and Fetch's cubes weigh about that)
OBJECT_FRICTION = 1.0       # an object's sliding friction where none is given (MuJoCo's default)


def parse_objects(value) -> tuple[Object, ...]:
    """Loose objects from a list of {box: [sx, sy, sz] | sphere: r | cylinder: [r, length], position: [x, y, z],
    rpy: [r, p, y], mass: kg, friction: mu, name: text}, a YAML file's path or YAML text of one (its `objects` key:
    the obstacles' file may hold both), or Objects parsed already; None or empty: none. PhysicsError of one line for
    anything else."""
    if value is None or (isinstance(value, (str, list, tuple)) and len(value) == 0):
        return ()
    if isinstance(value, (list, tuple)) and all(isinstance(o, Object) for o in value):
        return tuple(value)         # parsed already
    if isinstance(value, str):
        try:
            value = read_yaml(value, 'objects')
        except ValueError as e:
            raise PhysicsError(str(e)) from None
        if isinstance(value, dict):
            value = value.get('objects', [])
    if not isinstance(value, (list, tuple)):
        raise PhysicsError(f'objects must be a list of {{box: [sx, sy, sz], position: [x, y, z], mass: kg}} (or '
                           f'sphere: r, or cylinder: [r, length]), got {type(value).__name__}')
    try:
        return _objects(value)
    except BodyError as e:            # a number that is not one (motion.body's check): this module's error
        raise PhysicsError(str(e)) from None


def _objects(value: list) -> tuple[Object, ...]:
    out, names = [], set()
    for i, spec in enumerate(value):
        kinds = [k for k in OBJECT_SIZES if isinstance(spec, dict) and k in spec]
        if len(kinds) != 1:
            raise PhysicsError(f'object {i}: give one of box: [sx, sy, sz], sphere: r and cylinder: [r, length], '
                               f'with position: [x, y, z]')
        unknown = sorted(set(spec) - {kinds[0], 'position', 'rpy', 'mass', 'friction', 'name'})
        if unknown:
            raise PhysicsError(f'object {i}: unknown keys {unknown} (box, sphere, cylinder, position, rpy, mass, '
                               f'friction, name)')
        kind = kinds[0]
        size = numbers(spec[kind], OBJECT_SIZES[kind], f'object {i}: {kind}')
        position = numbers(spec.get('position', [0, 0, 0]), 3, f'object {i}: position')
        rpy = numbers(spec.get('rpy', [0, 0, 0]), 3, f'object {i}: rpy')
        mass, friction = (numbers(spec.get(k, d), 1, f'object {i}: {k}')[0]
                          for k, d in (('mass', OBJECT_MASS), ('friction', OBJECT_FRICTION)))
        if min(size) <= 0 or mass <= 0 or friction < 0:
            raise PhysicsError(f'object {i}: its size and mass must be positive and its friction not negative')
        name = str(spec.get('name', f'object {i} ({kind})'))
        if name in names:
            raise PhysicsError(f'object {i}: the name {name!r} is taken')
        names.add(name)
        pose = np.identity(4)
        pose[:3, :3], pose[:3, 3] = rpy_matrix(rpy), position
        out.append(Object(kind, tuple(size), pose, float(mass), float(friction), name))
    return tuple(out)


@dataclasses.dataclass(frozen=True)
class Physics:
    """A built model: model (mujoco.MjModel, a copy of its own), actuated (the joints the actuators drive, in
    actuator order), home ({joint: position} it starts at), notes (what was estimated or stood in, one line each),
    gripper (the actuated joints of hands and grippers, kinematics.finger_joints'), objects (the loose objects'
    names: each a body with a free joint, and its geom, of that name), gripper_speed (the gripper joints' URDF
    velocity limits, at which a gripper command moves their targets)."""
    model: object
    actuated: tuple[str, ...]
    home: dict
    notes: tuple[str, ...]
    gripper: tuple[str, ...] = ()
    objects: tuple[str, ...] = ()
    gripper_speed: tuple[float, ...] = ()

    def data(self):
        """A mujoco.MjData at home, at rest, the servos holding it there."""
        import mujoco
        data = mujoco.MjData(self.model)
        for name, value in self.home.items():
            data.qpos[self.qpos_address(name)] = value
        data.ctrl[:] = [self.home.get(name, 0.0) for name in self.actuated]
        mujoco.mj_forward(self.model, data)
        return data

    def follow_mimics(self, data) -> None:
        """Each mimic joint of data at offset + multiplier x its source's position (the joint equalities), as the
        constraint holds it: after its source is placed by hand."""
        import mujoco
        model = self.model
        for k in range(model.neq):
            if model.eq_type[k] == mujoco.mjtEq.mjEQ_JOINT:
                offset, multiplier = model.eq_data[k, :2]
                data.qpos[model.jnt_qposadr[model.eq_obj1id[k]]] = \
                    offset + multiplier * data.qpos[model.jnt_qposadr[model.eq_obj2id[k]]]

    def qpos_address(self, joint: str) -> int:
        """Where a hinge or slide joint's position is in qpos."""
        import mujoco
        j = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, joint)
        if j < 0:
            raise PhysicsError(f'the model has no joint {joint!r}')
        return int(self.model.jnt_qposadr[j])

    def object_addresses(self, name: str) -> tuple[int, int, int]:
        """(its body, its free joint's qpos and qvel addresses) of a loose object; PhysicsError for an unknown one."""
        import mujoco
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if body < 0 or name not in self.objects:
            raise PhysicsError(f'no object {name!r} (the objects: {", ".join(self.objects) or "none"})')
        joint = self.model.body_jntadr[body]
        return body, int(self.model.jnt_qposadr[joint]), int(self.model.jnt_dofadr[joint])

    def object_pose(self, data, name: str) -> np.ndarray:
        """4x4: a loose object's pose in the world (the root's frame) in data."""
        b = self.object_addresses(name)[0]
        out = np.identity(4)
        out[:3, :3], out[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
        return out

    def joint_positions(self, data, joints) -> np.ndarray:
        """(len(joints),) the joints' positions in data."""
        return np.array([data.qpos[self.qpos_address(n)] for n in joints])


def free_velocity(data, body: int, dof: int) -> np.ndarray:
    """(6,) a free body's velocity in the world: linear, then angular (MuJoCo keeps the angular one in the body's
    frame: turned into the world's, as gymnasium-robotics and ROS's twists give it)."""
    v = data.qvel[dof:dof + 6]
    return np.concatenate([v[:3], data.xmat[body].reshape(3, 3) @ v[3:]])


def model_digest(model) -> str:
    """sha256 of a MuJoCo model's binary form: two processes that built the same world agree on it (arm_sim's
    ~world_digest, which the manipulation envs over ROS check)."""
    import mujoco
    buffer = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return hashlib.sha256(buffer.tobytes()).hexdigest()


def build_physics(robot: Model, obstacles=(), objects=(), base: str | None = None, home: dict | None = None,
                  position_hz: float = POSITION_HZ) -> Physics:
    """The MuJoCo model of robot (reach.model.Model: a loaded URDF or xacro) among obstacles (motion.body's: a list,
    YAML text or a file) and loose objects (parse_objects': the same file may hold both), both placed in the frame
    of the link base (the root by default) as it stands at home; its servos holding home ({joint: position}; the
    middle of each limited range, else 0, for the rest). PhysicsError of one line for what cannot be built."""
    try:
        world = parse_obstacles(obstacles)
    except ValueError as e:
        raise PhysicsError(str(e)) from None
    loose = parse_objects(objects)
    taken = sorted({o.name for o in loose} & {o.name for o in world})
    if taken:
        raise PhysicsError(f'an object and an obstacle are both named {taken[0]!r}')
    tree = robot.tree
    base = base or tree.root
    if base not in tree.links:
        raise PhysicsError(f'the obstacles\' frame {base!r} is not a link of {tree.name}')
    if not (isinstance(position_hz, (int, float)) and math.isfinite(position_hz) and position_hz > 0):
        raise PhysicsError(f'position_hz must be a positive number, got {position_hz!r}')
    urdf_dir = os.path.dirname(robot.path) if robot.path else ''
    start = _home(tree, home or {})
    root = ET.fromstring(robot.urdf)      # read once: the key's meshes, the dynamics, the inertials
    key = _key(robot.urdf, root, urdf_dir, world, loose, base, start, float(position_hz))
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = _build(robot, root, urdf_dir, world, loose, base, start, float(position_hz))
    built = _CACHE[key]
    return dataclasses.replace(built, model=copy.deepcopy(built.model))


def _home(tree, given: dict) -> dict:
    """{joint: position} of every moving joint: given, else the middle of its limited range, else 0."""
    unknown = sorted(set(given) - set(tree.moving_joints))
    if unknown:
        raise PhysicsError(f'home names joints the robot does not move: {", ".join(unknown[:5])}')
    out = {}
    for name in tree.moving_joints:
        j = tree.joints[name]
        if name in given:
            out[name] = float(given[name])
        elif _range(j):
            out[name] = 0.5 * (j.lower + j.upper)
        else:
            out[name] = 0.0
    return tree.resolve_positions({n: v for n, v in out.items() if n not in tree.mimic_joints})


def _range(joint) -> list[float] | None:
    """[lower, upper] of a joint MuJoCo limits (a revolute or prismatic one with a range); None: unlimited."""
    if joint.type != 'continuous' and joint.lower is not None and joint.upper is not None \
            and joint.lower < joint.upper:
        return [joint.lower, joint.upper]
    return None


def _listed(items, joiner: str = '; ', most: int = 6) -> str:
    """The first `most` of items, joined, and ' ...' when there are more: a note's list."""
    items = list(items)
    return joiner.join(items[:most]) + (' ...' if len(items) > most else '')


def _key(urdf: str, root, urdf_dir: str, world, loose, base: str, start: dict, hz: float) -> str:
    """A digest of everything the model is built from (root: the URDF's parsed XML), the meshes' files by size and
    time."""
    h = hashlib.sha256(urdf.encode())
    for element in root.iter('mesh'):
        path = resolve_mesh(element.get('filename', ''), urdf_dir)
        st = os.stat(path) if path else None
        h.update(repr((path, st and st.st_size, st and st.st_mtime_ns)).encode())
    h.update(repr(([o.spec for o in world], [(o.kind, o.size, o.pose.round(12).tolist(), o.mass, o.friction, o.name)
                                              for o in loose], base, sorted(start.items()), hz)).encode())
    return h.hexdigest()


def _dynamics(root) -> dict[str, tuple[float, float, float]]:
    """{joint: (damping, friction, effort limit or 0)} from the URDF's (root: its parsed XML) <dynamics> and
    <limit effort>."""
    out = {}
    for j in root.findall('joint'):
        d, lim = j.find('dynamics'), j.find('limit')
        values = []
        for element, attribute in ((d, 'damping'), (d, 'friction'), (lim, 'effort')):
            try:
                v = float(element.get(attribute, 0.0)) if element is not None else 0.0
            except (TypeError, ValueError):
                v = 0.0
            values.append(v if math.isfinite(v) and v > 0 else 0.0)
        out[j.get('name')] = tuple(values)
    return out


def _inertials(root) -> dict[str, tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """{link: (mass, centre (3,), orientation (w, x, y, z), full inertia (6,): ixx iyy izz ixy ixz iyz)} of links
    whose URDF (root: its parsed XML) <inertial> gives a positive mass."""
    out = {}
    for link in root.findall('link'):
        inertial = link.find('inertial')
        if inertial is None or inertial.find('mass') is None:
            continue
        try:
            mass = float(inertial.find('mass').get('value'))
            i = inertial.find('inertia')
            full = np.array([float(i.get(k, 0.0)) for k in ('ixx', 'iyy', 'izz', 'ixy', 'ixz', 'iyz')]) \
                if i is not None else np.zeros(6)
        except (TypeError, ValueError):
            continue
        if not (math.isfinite(mass) and mass > 0 and np.isfinite(full).all()):
            continue
        pose = origin_pose(inertial)
        out[link.get('name')] = (mass, pose[:3, 3], _quaternion(pose[:3, :3]), full)
    return out


def _positive(full: np.ndarray) -> np.ndarray:
    """full (ixx iyy izz ixy ixz iyz) itself where its matrix is positive definite; else the nearest one whose
    eigenvalues are at least a millionth of the largest (a URDF's zero or negative principal moment: the Fetch's)."""
    xx, yy, zz, xy, xz, yz = full
    m = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    values, vectors = np.linalg.eigh(m)
    floor = max(1e-9, 1e-6 * float(np.abs(values).max()))
    if values.min() >= floor:
        return full
    m = vectors @ np.diag(np.maximum(values, floor)) @ vectors.T
    return np.array([m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]])


def _quaternion(r: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix, as MuJoCo orders it."""
    import mujoco
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=float).ravel())
    return q


def _build(robot: Model, root, urdf_dir: str, world: tuple[Obstacle, ...], loose: tuple[Object, ...], base: str,
           start: dict, hz: float) -> Physics:
    import mujoco
    tree, urdf = robot.tree, robot.urdf
    spec = mujoco.MjSpec()
    spec.modelname = tree.name or 'robot'
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
    spec.compiler.degree = False          # angles (joint ranges) in radians, as the URDF's
    spec.compiler.balanceinertia = True   # URDF inertias that break A + B >= C (the PR2's) are made physical
    notes = []
    shapes, missing = link_shapes(urdf, urdf_dir)
    unread = sorted({m.split(': ')[0] for m in missing} - set(shapes))
    stood, how = stand_ins(urdf, tree, unread, urdf_dir) if unread else ({}, {})
    shapes = shapes | stood
    if stood:
        notes.append(f'collision geometry not read for {len(stood)} links, stood in for by capsules: '
                     + _listed(f'{k}: {v}' for k, v in how.items()))
    inertials, dynamics = _inertials(root), _dynamics(root)
    joints = {j.get('name'): j for j in root.findall('joint')}
    parent_joint = {j.child: j for j in tree.joints.values()}
    estimated, repaired = [], []
    # the root, welded to the world (a root named world, as many URDFs have, is MuJoCo's world body itself)
    bodies = {tree.root: spec.worldbody if tree.root == 'world' else spec.worldbody.add_body(name=tree.root)}
    moved_by = {}                         # link -> the joint that moves it (None: fixed to its parent)
    floating_child = {tree.floating_links(n)[1]: n for n in tree.floating_joints}
    for link in tree.links[1:]:
        joint = parent_joint.get(link)
        if joint is None:                 # the child of a floating joint: free, placed by the joint's origin
            name = floating_child[link]
            parent, _ = tree.floating_links(name)
            origin = origin_pose(joints[name])
            body = bodies[parent].add_body(name=link, pos=origin[:3, 3], quat=_quaternion(origin[:3, :3]))
            body.add_freejoint(name=name)
            moved_by[link] = name
        else:
            x, y, z, w = joint.quat
            body = bodies[joint.parent].add_body(name=link, pos=joint.xyz, quat=[w, x, y, z])
            if joint.moving:
                kind = mujoco.mjtJoint.mjJNT_SLIDE if joint.type == 'prismatic' else mujoco.mjtJoint.mjJNT_HINGE
                damping, friction, effort = dynamics.get(joint.name, (0.0, 0.0, 0.0))
                j = body.add_joint(name=joint.name, type=kind, axis=joint.axis, damping=damping,
                                   frictionloss=friction, armature=ARMATURE, ref=0.0)
                if _range(joint):
                    j.limited, j.range = mujoco.mjtLimited.mjLIMITED_TRUE, _range(joint)
                else:
                    j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
                j.actgravcomp = True      # the arm's weight held through the actuator: within the effort
                if effort > 0:            # the joint's whole actuation (servo and weight) within its effort
                    j.actfrclimited, j.actfrcrange = mujoco.mjtLimited.mjLIMITED_TRUE, [-effort, effort]
                moved_by[link] = joint.name
            elif joint.type == 'planar':
                notes.append(f'{joint.name}: a planar joint, welded here')
        bodies[link] = body
    bare = [link for link in bodies if link != tree.root and link not in inertials and not shapes.get(link)
            and moved_by.get(link)]       # a body with a joint needs mass (a welded one does not)
    if bare:
        more, how = stand_ins(urdf, tree, bare, urdf_dir)
        shapes = shapes | more
        notes.append(f'no inertial and no collision geometry for {len(bare)} moving links, stood in for by capsules: '
                     + _listed(f'{k}: {v}' for k, v in how.items()))
    for link, body in bodies.items():
        if link in inertials and body is not spec.worldbody:
            mass, centre, orientation, full = inertials[link]
            body.explicitinertial = True
            body.mass, body.ipos, body.iquat = mass, centre, orientation
            positive = _positive(full) if np.any(full) else None
            body.fullinertia = [1e-6, 1e-6, 1e-6, 0, 0, 0] if positive is None else positive
            if positive is not None and positive is not full:
                repaired.append(link)
        if link != tree.root:
            body.gravcomp = 1.0
        for k, mesh in enumerate(shapes.get(link, [])):
            hull = mesh.convex_hull
            name = f'{link}/collision_{k}'
            spec.add_mesh(name=name, uservert=np.asarray(hull.vertices, dtype=np.float32).ravel(),
                          userface=np.asarray(hull.faces, dtype=np.int32).ravel())
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, density=DENSITY,
                          contype=ARM_CONTYPE, conaffinity=ARM_CONAFFINITY, solref=[CONTACT_TIME, 1.0],
                          rgba=[0.7, 0.7, 0.75, 1.0])
        if link not in inertials and link != tree.root and shapes.get(link):
            estimated.append(link)
    if repaired:
        notes.append(f'inertias that were not positive definite made so (their eigenvalues at least a millionth of '
                     f'the largest) for {len(repaired)} links: ' + _listed(repaired, ', '))
    if estimated:
        notes.append(f'inertias estimated from the collision geometry at {DENSITY:g} kg/m^3 (the URDF gives none) '
                     f'for {len(estimated)} links: ' + _listed(estimated, ', '))
    for name in tree.mimic_joints:        # position = offset + multiplier x the source's
        source, multiplier, offset = tree.joints[name].mimic
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=name, name2=source,
                          data=[offset, multiplier, 0.0, 0.0, 0.0] + [0.0] * 7,
                          solref=[CONTACT_TIME, 1.0])    # as stiff as the contacts: a squeezed linkage holds
    base_pose = tree.link_poses(start).get(base, np.identity(4))
    for o in world:
        pose = base_pose @ o.pose
        kind = mujoco.mjtGeom.mjGEOM_BOX if o.kind == 'box' else mujoco.mjtGeom.mjGEOM_SPHERE
        size = np.array(o.size) / 2.0 if o.kind == 'box' else [o.size[0], 0, 0]
        spec.worldbody.add_geom(name=o.name or None, type=kind, size=size, pos=pose[:3, 3],
                                quat=_quaternion(pose[:3, :3]), contype=WORLD_CONTYPE,
                                conaffinity=WORLD_CONAFFINITY, solref=[CONTACT_TIME, 1.0],
                                rgba=[0.55, 0.45, 0.35, 1.0])
    for o in loose:                       # free bodies: they fall, slide and are pushed
        pose = base_pose @ o.pose
        body = spec.worldbody.add_body(name=o.name, pos=pose[:3, 3], quat=_quaternion(pose[:3, :3]))
        body.add_freejoint(name=o.name)
        if o.kind == 'box':
            kind, size = mujoco.mjtGeom.mjGEOM_BOX, np.array(o.size) / 2.0                  # half edges
        elif o.kind == 'sphere':
            kind, size = mujoco.mjtGeom.mjGEOM_SPHERE, [o.size[0], 0, 0]
        else:
            kind, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [o.size[0], o.size[1] / 2.0, 0]    # radius, half length
        body.add_geom(name=o.name, type=kind, size=size, mass=o.mass, friction=[o.friction, 0.005, 0.0001],
                      contype=OBJECT_CONTYPE, conaffinity=OBJECT_CONAFFINITY, solref=[CONTACT_TIME, 1.0],
                      rgba=[0.2, 0.5, 0.8, 1.0])
    actuated, unlimited = list(tree.active_joints), []
    for name in actuated:
        _, _, effort = dynamics.get(name, (0.0, 0.0, 0.0))
        a = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=1.0, kv=0.0)
        if _range(tree.joints[name]):
            a.ctrllimited, a.ctrlrange = mujoco.mjtLimited.mjLIMITED_TRUE, _range(tree.joints[name])
        if effort > 0:
            a.forcelimited, a.forcerange = mujoco.mjtLimited.mjLIMITED_TRUE, [-effort, effort]
        else:
            unlimited.append(name)
    if unlimited:
        notes.append(f'no effort limit in the URDF for {len(unlimited)} joints, their servos unlimited: '
                     + _listed(unlimited, ', '))
    try:
        model = spec.compile()
    except ValueError as e:
        raise PhysicsError(f'{tree.name}: MuJoCo refused the model: {str(e).splitlines()[0]}') from None
    fingers = tree.finger_joints()
    gripper = tuple(n for n in actuated if n in fingers)
    physics = Physics(model, tuple(actuated), start, tuple(notes), gripper, tuple(o.name for o in loose),
                      tuple(joint_velocity(tree.joints[n]) for n in gripper))
    capped = _cap_grip(physics)
    if capped:
        physics = dataclasses.replace(physics, notes=physics.notes + (
            f'gripper effort limits past {GRIP_FORCE:g} N at the fingertips, capped there: {"; ".join(capped)}',))
    _set_gains(physics, hz)
    touching = _touching(physics)
    if touching:
        physics = dataclasses.replace(physics, notes=physics.notes + (
            f'at home the robot touches {", ".join(touching[:4])}: the world pushes it from the start',))
    return physics


def _touching(physics: Physics) -> list[str]:
    """'link - geom' of the robot's contacts with the world and the objects at home."""
    return robot_contacts(physics.model, physics.data())


def robot_contacts(model, data) -> list[str]:
    """'link - geom' of the robot's contacts with the world and the objects in data (a MuJoCo model's), sorted."""
    import mujoco
    names = []
    for c in data.contact[:data.ncon] if data.ncon else ():
        a, b = (int(g) for g in c.geom)
        for mine, other in ((a, b), (b, a)):
            if model.geom_contype[mine] == ARM_CONTYPE and model.geom_contype[other] != ARM_CONTYPE:
                link = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[mine])
                other_name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, other) or f'geom {other}'
                names.append(f'{link} - {other_name}')
    return sorted(set(names))


def _cap_grip(physics: Physics) -> list[str]:
    """Each gripper servo's effort limit (and its joint's) held to GRIP_FORCE at its fingertips: a slide's force, a
    hinge's torque over its lever (the farthest point of the collision geometry it moves, from its axis, at home);
    what was capped, 'joint: from -> to'."""
    import mujoco
    model, data = physics.model, physics.data()
    mujoco.mj_kinematics(model, data)
    capped = []
    for name in physics.gripper:
        k = physics.actuated.index(name)
        if not model.actuator_forcelimited[k]:
            continue
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        effort, unit = float(model.actuator_forcerange[k, 1]), 'N'
        lever = 1.0
        if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_HINGE:
            lever, unit = _lever(model, data, joint), 'N m'
        most = GRIP_FORCE * lever
        if lever > 0 and effort > most:
            model.actuator_forcerange[k] = (-most, most)
            if model.jnt_actfrclimited[joint]:
                model.jnt_actfrcrange[joint] = (-most, most)
            capped.append(f'{name}: {effort:g} -> {most:.3g} {unit}')
    return capped


def _lever(model, data, joint: int) -> float:
    """m: the farthest point of the collision geometry joint (a hinge) moves, from its axis (data: kinematics)."""
    below = {int(model.jnt_bodyid[joint])}
    for b in range(int(model.jnt_bodyid[joint]) + 1, model.nbody):     # MuJoCo numbers a body after its parent
        if int(model.body_parentid[b]) in below:
            below.add(b)
    anchor, axis, lever = data.xanchor[joint], data.xaxis[joint], 0.0
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) in below:
            arm = geom_points(model, data, g) - anchor
            lever = max(lever, float(np.linalg.norm(arm - np.outer(arm @ axis, axis), axis=1).max()))
    return lever


_CORNERS = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T


def geom_points(model, data, g: int) -> np.ndarray:
    """(k, 3): geom g's collision geometry as points in the world, as data's kinematics place it: a mesh's own
    vertices (its box in its frame can reach far beyond it), a primitive's box's corners."""
    import mujoco
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_dataid[g] >= 0:
        mesh = model.geom_dataid[g]
        start = model.mesh_vertadr[mesh]
        local = model.mesh_vert[start:start + model.mesh_vertnum[mesh]]
    else:
        local = model.geom_aabb[g, :3] + _CORNERS * model.geom_aabb[g, 3:]
    return data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T


def _set_gains(physics: Physics, hz: float) -> None:
    """Each servo critically damped at hz for the inertia its joint moves at home (the joint-space inertia's
    diagonal): kp = m w^2, kv = 2 m w; where the URDF damps the joint (d), kp = m w^2 + d w, its slowest pole still
    w. A gripper's servo grips: it exerts its effort limit GRIP_SQUEEZE of its range short of its target (an object
    between the fingers is squeezed with the force asked for), critically damped at GRIPPER_HZ, its rotor's inertia
    (armature) raised to what that takes (a finger's own is grams: MuJoCo's step
    would not hold so stiff a servo on it)."""
    import mujoco
    model = physics.model
    data = physics.data()
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    w = 2.0 * math.pi * hz
    for k, name in enumerate(physics.actuated):
        dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)]
        m = float(full[dof, dof])
        # the joint's own damping (the URDF's) slows the servo: kp raised by damping * w keeps its slow pole at w
        # (m s^2 + (kv + damping) s + kp has the root -w): the Fetch's wrist roll, damping 5 on grams, lagged 1.7 s
        kp, kv = m * w * w + float(model.dof_damping[dof]) * w, 2.0 * m * w
        lo, hi = model.actuator_ctrlrange[k]
        effort = model.actuator_forcerange[k, 1]
        if name in physics.gripper and model.actuator_ctrllimited[k] and model.actuator_forcelimited[k] and hi > lo:
            kp, grip = effort / (GRIP_SQUEEZE * (hi - lo)), 2.0 * math.pi * GRIPPER_HZ
            model.dof_armature[dof] += max(0.0, kp / grip ** 2 - m)
            kv = 2.0 * max(m, kp / grip ** 2) * grip
        model.actuator_gainprm[k, 0] = kp
        model.actuator_biasprm[k, 1:3] = (-kp, -kv)
