"""An arm's body and its world, for collision checks of many configurations at once in numpy. No rospy.

The body comes from the URDF's ``<collision>`` elements (box, cylinder, sphere, and meshes read by trimesh where their
file resolves: ``package://`` through ROS_PACKAGE_PATH, ``file://``, or a path beside the URDF), each link's geometry
covered by a few spheres fitted to it (as cuRobo approximates a robot): the geometry's surface is cut into slabs
along its longest axis and each slab's surface points lie in the least ball around them, so that the spheres cover
the surface and a contact of the geometry is always a contact of the spheres. What the spheres add beyond the
geometry is each link's `margin`, measured at fit time.

The link pairs that are checked are those MoveIt's Setup Assistant would keep: not adjacent (joined by a joint, or
one rigid body through fixed joints), not in contact at the arm's home, and not always or never in contact over
`samples` random configurations within the limits, decided with wider spheres (each slab's centred on the shape's
middle line), as they were decided before the least balls.

The world: obstacles in the arm's base frame, each ``{box: [sx, sy, sz], position: [x, y, z], rpy: [r, p, y]}`` or
``{sphere: r, position: [x, y, z]}`` (a table is a box), given as such a list, or a YAML file or text of one.

    body = CollisionModel(tree, urdf_text, arm, obstacles=[{'box': [1, 1, 0.05], 'position': [0, 0, -0.03]}])
    hits = body.in_collision(q)            # (N,) bool for (N, arm.n) configurations
    body.contacts(q[0])                    # ['lwr_arm_2_link - lwr_arm_5_link', 'lwr_arm_6_link - obstacle 0 (box)']
"""
from __future__ import annotations

import math
import os
import re
import stat
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from robot_ai.kinematics import KinematicTree

SURFACE_POINTS = 600        # points of a shape's surface the spheres are fitted to
MAX_SPHERES = 8             # spheres per shape at most
PAIR_SAMPLES = 2000         # random configurations that decide which link pairs can ever touch
ALWAYS = 0.95               # a pair in contact in this share of them is always in contact: not checked
BROAD_PHASE = 2000          # sphere pairs checked beyond which a link pair's spheres are compared only where the
                            # links' bounds meet (the PR2's 12,393 pairs: 3-4x faster; the UR5's 249: dense is)
BOUND_SLACK = 1e-6          # m added to a link's bound: its rounding never hides a contact


@dataclass(frozen=True)
class Obstacle:
    """A box (size: its 3 edges) or a sphere (size: its radius, 1 value) at pose (4x4) in the arm's base frame; spec:
    the obstacle as it was given, numbers as floats (what a policy file records of the world it learned in)."""
    kind: str
    size: tuple[float, ...]
    pose: np.ndarray = field(compare=False)
    name: str = ''
    spec: dict = field(compare=False, default_factory=dict)

    def contains(self, point) -> bool:
        """Whether a point (x, y, z in the arm's base frame) lies inside the obstacle."""
        local = (np.asarray(point, dtype=float) - self.pose[:3, 3]) @ self.pose[:3, :3]
        if self.kind == 'box':
            return bool(np.all(np.abs(local) <= np.array(self.size) / 2.0))
        return bool(np.linalg.norm(local) <= self.size[0])




class BodyError(ValueError):
    """A body, a world or a file of one that cannot be used; the message is one line that says what is wrong."""


class Chain(Protocol):
    """The moving chain a body is built for (reach.arm.Arm is one): its joints in order, the link its
    configurations are given from, where it stands at home, and its limits."""
    joints: list[str]
    base: str
    n: int
    home: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

def obstacle_distance(o: Obstacle) -> float:
    """The distance from the arm's base frame's origin to the obstacle (0 inside it)."""
    local = -o.pose[:3, 3] @ o.pose[:3, :3]
    if o.kind == 'box':
        return float(np.linalg.norm(np.maximum(np.abs(local) - np.array(o.size) / 2.0, 0.0)))
    return max(0.0, float(np.linalg.norm(local)) - o.size[0])


def rpy_matrix(rpy) -> np.ndarray:
    """The rotation of URDF's roll, pitch, yaw (fixed x, then y, then z)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def numbers(value, count: int, what: str) -> tuple[float, ...]:
    """count finite numbers of value (one number, or a list of them); BodyError of one line naming what."""
    try:
        values = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
    except (TypeError, ValueError):
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise BodyError(f'{what} must be {count} finite number{"s" if count > 1 else ""}, got {value!r}')
    return values


YAML_BYTES = 1 << 20        # a YAML file (obstacles, joint limits) is at most this; a larger one is refused, never cut
YAML_ALIASES = 100          # aliases (*name) a YAML text may use: nested ones make a few bytes into gigabytes
YAML_NODES = 1_000_000      # and the nodes it holds with every alias expanded (450 bytes of nested aliases took 100 s
                            # and 3.6 GB to walk)


def read_yaml(value: str, what: str):
    """A YAML file's contents (a path: one line that names a file, or ends in .yaml or .yml) or YAML text's; BodyError
    of one line naming `what`, at once, for anything else: a file that cannot be read, is not a regular file (a FIFO
    would block), or holds more than YAML_BYTES; text that is not YAML or uses more than YAML_ALIASES aliases.
    `!degrees x` is x degrees in radians (ur_description's joint_limits.yaml), `!radians x` is x."""
    import yaml
    text = value
    if '\n' not in value and (value.endswith(('.yaml', '.yml')) or os.path.isfile(value)):
        text = _read_regular(value, what)
    try:
        return _bounded_yaml(text)
    except RecursionError:
        raise BodyError(f'{what}: not YAML we read: nested too deep') from None
    except yaml.YAMLError as e:
        raise BodyError(f'{what}: not YAML: {str(e).splitlines()[0]}') from None


def _read_regular(path: str, what: str) -> str:
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise BodyError(f'{what}: {path} is not a regular file (a FIFO, a device or a folder is not read)')
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)     # swapped for a FIFO since: no wait for a writer
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise BodyError(f'{what}: {path} is not a regular file (a FIFO, a device or a folder is not read)')
            data = b''
            while len(data) <= YAML_BYTES:
                chunk = os.read(fd, YAML_BYTES + 1 - len(data))
                if not chunk:
                    break
                data += chunk
        finally:
            os.close(fd)
    except OSError as e:
        raise BodyError(f'{what}: cannot read {path}: {e.strerror}') from None
    if len(data) > YAML_BYTES:
        raise BodyError(f'{what}: {path} holds more than {YAML_BYTES >> 20} MiB: refused, not read in part')
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError:
        raise BodyError(f'{what}: {path} is not UTF-8 text') from None


def _bounded_yaml(text: str):
    """yaml.safe_load with at most YAML_ALIASES aliases, and the !degrees and !radians tags."""
    import yaml

    class Loader(yaml.SafeLoader):
        aliases, sizes = 0, {}

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                Loader.aliases += 1
                if Loader.aliases > YAML_ALIASES:
                    raise yaml.YAMLError(f'more than {YAML_ALIASES} aliases (*name): refused')
            node = super().compose_node(parent, index)
            if self.size(node) > YAML_NODES:
                raise yaml.YAMLError(f'more than {YAML_NODES:,} nodes with its aliases expanded: refused')
            return node

        def size(self, node) -> int:
            """The nodes under node, aliases expanded (its children's sizes are known: composed before it)."""
            known = Loader.sizes.get(id(node))
            if known is None:
                if isinstance(node, yaml.SequenceNode):
                    known = 1 + sum(self.size(c) for c in node.value)
                elif isinstance(node, yaml.MappingNode):
                    known = 1 + sum(self.size(k) + self.size(v) for k, v in node.value)
                else:
                    known = 1
                Loader.sizes[id(node)] = known
            return known

    def angle(factor):
        def construct(loader, node):
            text = loader.construct_scalar(node)
            try:
                return float(text) * factor
            except ValueError:
                raise yaml.YAMLError(f'{node.tag} {text!r} is not a number') from None
        return construct
    Loader.add_constructor('!degrees', angle(math.pi / 180.0))
    Loader.add_constructor('!radians', angle(1.0))
    return yaml.load(text, Loader=Loader)


def parse_obstacles(value) -> tuple[Obstacle, ...]:
    """Obstacles from a list of dicts, a YAML file's path, or YAML text of such a list (None or empty: none);
    BodyError of one line for anything else."""
    if value is None or (isinstance(value, (str, list, tuple)) and len(value) == 0):
        return ()
    if isinstance(value, str):
        value = read_yaml(value, 'obstacles')
        if isinstance(value, dict) and 'obstacles' in value:
            value = value['obstacles']
    if not isinstance(value, (list, tuple)):
        raise BodyError(f'obstacles must be a list of {{box: [sx, sy, sz], position: [x, y, z]}} or {{sphere: r, '
                         f'position: [x, y, z]}}, got {type(value).__name__}')
    out = []
    for i, spec in enumerate(value):
        if isinstance(spec, str):         # one obstacle as JSON or YAML text (how a policy file keeps it)
            import yaml
            try:
                spec = yaml.safe_load(spec)
            except yaml.YAMLError:
                pass
        if not isinstance(spec, dict) or ('box' in spec) == ('sphere' in spec):
            raise BodyError(f'obstacle {i}: give one of box: [sx, sy, sz] and sphere: r, with position: [x, y, z]')
        unknown = sorted(set(spec) - {'box', 'sphere', 'position', 'rpy', 'name'})
        if unknown:
            raise BodyError(f'obstacle {i}: unknown keys {unknown} (box, sphere, position, rpy, name)')
        pose = np.identity(4)
        position = numbers(spec.get('position', [0, 0, 0]), 3, f'obstacle {i}: position')
        pose[:3, 3] = position
        given = {'position': list(position)}
        if 'box' in spec:
            size = numbers(spec['box'], 3, f'obstacle {i}: box')
            rpy = numbers(spec.get('rpy', [0, 0, 0]), 3, f'obstacle {i}: rpy')
            pose[:3, :3] = rpy_matrix(rpy)
            kind = 'box'
            given.update(box=list(size), rpy=list(rpy))
        else:
            if 'rpy' in spec:
                raise BodyError(f'obstacle {i}: a sphere has no rpy')
            size = numbers(spec['sphere'], 1, f'obstacle {i}: sphere')
            kind = 'sphere'
            given.update(sphere=size[0])
        if min(size) <= 0:
            raise BodyError(f'obstacle {i}: its size must be positive, got {list(size)}')
        name = str(spec.get('name', f'obstacle {i} ({kind})'))
        out.append(Obstacle(kind, size, pose, name, dict(given, name=name)))
    return tuple(out)


# ------------------------------------------------------------------------------------------------ the body
def resolve_mesh(filename: str, urdf_dir: str = '') -> str:
    """A mesh file's path on this machine ('' when it is not here): package:// through ROS_PACKAGE_PATH, file://,
    or a path relative to the URDF's folder."""
    if filename.startswith('package://'):
        package, _, rest = filename[len('package://'):].partition('/')
        for root in os.environ.get('ROS_PACKAGE_PATH', '').split(os.pathsep):
            for candidate in (os.path.join(root, package, rest), os.path.join(root, rest)
                              if os.path.basename(root.rstrip('/')) == package else ''):
                if candidate and os.path.isfile(candidate):
                    return candidate
        return ''
    path = filename[len('file://'):] if filename.startswith('file://') else filename
    if not os.path.isabs(path) and urdf_dir:
        path = os.path.join(urdf_dir, path)
    return path if os.path.isfile(path) else ''


def origin_pose(element) -> np.ndarray:
    """4x4: the pose of a URDF element's <origin> (identity without one)."""
    pose = np.identity(4)
    origin = element.find('origin')
    if origin is not None:
        pose[:3, 3] = [float(v) for v in (origin.get('xyz') or '0 0 0').split()]
        pose[:3, :3] = rpy_matrix([float(v) for v in (origin.get('rpy') or '0 0 0').split()])
    return pose


def link_shapes(urdf: str, urdf_dir: str = '') -> tuple[dict, list[str]]:
    """({link: [trimesh.Trimesh in the link's frame, ...]}, warnings: the geometry that is not on this machine or
    cannot be read, each 'link: what')."""
    import xml.etree.ElementTree as ET
    shapes, missing = {}, []
    for link in ET.fromstring(urdf).iter('link'):
        for collision in link.findall('collision'):
            mesh, why = _geometry(collision, urdf_dir)
            if why:
                missing.append(f'{link.get("name")}: {why}')
            if mesh is not None:
                shapes.setdefault(link.get('name'), []).append(mesh)
    return shapes, missing


def collada_unit(path: str) -> float:
    """Metres per unit of a COLLADA file (its asset's <unit meter=...>, 1 where it gives none): rviz and MoveIt
    (assimp) scale a .dae by it, trimesh does not (a Kinova's meshes in millimetres would be a thousand times too
    large)."""
    with open(path, 'rb') as f:
        head = f.read(65536).decode('utf-8', 'replace')
    found = re.search(r'<unit\b[^>]*\bmeter\s*=\s*["\']([^"\']+)["\']', head)
    try:
        unit = float(found.group(1)) if found else 1.0
    except ValueError:
        return 1.0
    return unit if math.isfinite(unit) and unit > 0 else 1.0


def _geometry(element, urdf_dir: str):
    """(trimesh.Trimesh in the link's frame or None, why it is missing ('' when read or when there is none)) of a
    <collision> or <visual> element."""
    import trimesh
    geometry = element.find('geometry')
    if geometry is None or len(geometry) == 0:
        return None, ''
    g = geometry[0]
    try:
        pose = origin_pose(element)
        if g.tag == 'box':
            mesh = trimesh.creation.box(extents=[float(v) for v in g.get('size').split()])
        elif g.tag == 'cylinder':
            mesh = trimesh.creation.cylinder(radius=float(g.get('radius')), height=float(g.get('length')),
                                             sections=24)
        elif g.tag == 'sphere':
            mesh = trimesh.creation.icosphere(subdivisions=2, radius=float(g.get('radius')))
        elif g.tag == 'mesh':
            path = resolve_mesh(g.get('filename', ''), urdf_dir)
            if not path:
                return None, g.get('filename') or 'a mesh with no filename'
            mesh = trimesh.load(path, force='mesh')
            if not len(getattr(mesh, 'vertices', ())):
                return None, f'{g.get("filename")} (no triangles read)'
            mesh.apply_scale([float(v) for v in (g.get('scale') or '1 1 1').split()])
            if path.lower().endswith('.dae'):
                mesh.apply_scale(collada_unit(path))
        else:
            return None, ''
    except (TypeError, ValueError, AttributeError, OSError, IndexError) as e:
        return None, f'a {g.tag} that cannot be read ({type(e).__name__})'
    mesh.apply_transform(pose)
    mesh.metadata['primitive'] = (g.tag, pose) if g.tag == 'sphere' else None
    if g.tag == 'sphere':
        mesh.metadata['radius'] = float(g.get('radius'))
    return mesh, ''


STAND_IN_RADIUS = 0.05      # m: a stand-in's radius where neither the link's visual geometry nor its inertia tells
STAND_IN_DENSITY = 1000.0   # kg/m^3: a stand-in's radius from the link's mass, as if it were a solid rod of water
                            # (hollow aluminium arms weigh about that for their size)


def stand_ins(urdf: str, tree: KinematicTree, links, urdf_dir: str = '') -> tuple[dict, dict]:
    """({link: [trimesh.Trimesh]}, {link: how its radius was chosen}) for links whose collision geometry cannot be
    read: a capsule along each segment from the link's origin to a child joint's origin (a sphere at the origin if
    it has none), its radius from the link's readable visual geometry (half the second largest extent of its
    bounds), else from its mass (a solid rod of STAND_IN_DENSITY along its segments), else STAND_IN_RADIUS."""
    import xml.etree.ElementTree as ET

    import trimesh
    elements = {link.get('name'): link for link in ET.fromstring(urdf).iter('link')}
    children = {}
    for j in tree.joints.values():
        children.setdefault(j.parent, []).append(np.asarray(j.xyz, dtype=float))
    shapes, how = {}, {}
    for name in links:
        segments = [p for p in children.get(name, []) if np.linalg.norm(p) > 1e-6]
        length = sum(float(np.linalg.norm(p)) for p in segments)
        radius, source = STAND_IN_RADIUS, f'a default radius of {STAND_IN_RADIUS:g} m'
        visuals = [m for m, _ in (_geometry(v, urdf_dir) for v in elements[name].findall('visual')) if m is not None]
        inertial = elements[name].find('inertial')
        mass = inertial.find('mass') if inertial is not None else None
        if visuals:
            extents = np.sort(trimesh.util.concatenate(visuals).extents)
            radius, source = max(float(extents[1]) / 2.0, 0.005), 'its visual geometry'
        elif mass is not None and length > 0:
            try:
                kg = float(mass.get('value'))
            except (TypeError, ValueError):
                kg = 0.0
            if kg > 0:
                radius = float(np.clip(math.sqrt(kg / STAND_IN_DENSITY / (math.pi * length)), 0.01, 0.3))
                source = f'its mass ({kg:g} kg)'
        pieces = []
        for p in segments:
            capsule = trimesh.creation.capsule(height=float(np.linalg.norm(p)), radius=radius, count=[12, 12])
            # trimesh's capsule lies along z, centred: turn z onto the segment and move its middle there
            turn = trimesh.geometry.align_vectors([0, 0, 1], p / np.linalg.norm(p))
            turn[:3, 3] = p / 2.0
            capsule.apply_transform(turn)
            pieces.append(capsule)
        if not pieces:
            ball = trimesh.creation.icosphere(subdivisions=2, radius=radius)
            ball.metadata['primitive'], ball.metadata['radius'] = ('sphere', np.identity(4)), radius
            pieces.append(ball)
        for piece in pieces:
            piece.metadata.setdefault('primitive', None)
        shapes[name] = pieces
        how[name] = f'{len(segments) or 1} {"capsule" if segments else "sphere"}{"s" if len(segments) > 1 else ""} ' \
                    f'of {radius:.3f} m from {source}'
    return shapes, how


def fit_spheres(mesh, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres (k, 3), radii (k,)) that cover the shape's surface: a sphere primitive is itself; otherwise
    the shape is cut across its longest principal axis into slabs (two per width; a plate also across its second
    axis), each slab's surface points (its vertices, the corners of its cuts and points sampled on it) in the least
    ball around them, as a chain of spheres along a link."""
    return _fit(mesh, rng)[0]


def _enclosing_centre(points: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The centre of the least ball around points (m, 3) (SLSQP from start over their convex hull's vertices: the
    least radius r with every |p - c|^2 <= r^2), or start where that finds no smaller one."""
    from scipy.optimize import minimize
    from scipy.spatial import ConvexHull, QhullError
    try:
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):       # flat or too few: all of them
        pass
    radius2 = lambda c: ((points - c) ** 2).sum(axis=1)          # noqa: E731
    found = minimize(lambda x: x[3], np.append(start, radius2(start).max()), method='SLSQP',
                     jac=lambda x: np.array([0.0, 0.0, 0.0, 1.0]),
                     constraints=[{'type': 'ineq', 'fun': lambda x: x[3] - radius2(x[:3]),
                                   'jac': lambda x: np.hstack((2.0 * (points - x[:3]), np.ones((len(points), 1))))}],
                     options={'maxiter': 200, 'ftol': 1e-12})
    centre = found.x[:3]
    if not np.isfinite(centre).all() or radius2(centre).max() >= radius2(start).max():
        return start
    return centre


def _fit(mesh, rng: np.random.Generator) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """(fit_spheres's spheres, the same slabs' spheres centred on the shape's middle line (or plane) within their
    slab, wider: what decides which pairs are checked, as it did before the least balls)."""
    if mesh.metadata.get('primitive') is not None:
        one = mesh.metadata['primitive'][1][:3, 3][None].copy(), np.array([mesh.metadata['radius']])
        return one, one
    import trimesh
    points, _ = trimesh.sample.sample_surface(mesh, SURFACE_POINTS, seed=int(rng.integers(2 ** 31)))
    points = np.concatenate([points, mesh.vertices])
    middle = (points.min(axis=0) + points.max(axis=0)) / 2.0
    _, _, axes = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    local = (points - middle) @ axes.T                       # coordinates along the principal axes
    low, high = local.min(axis=0), local.max(axis=0)
    extents = high - low
    order = np.argsort(-extents)
    cuts = [1, 1, 1]
    cuts[order[0]] = math.ceil(2 * extents[order[0]] / max(extents[order[1]], 1e-9))
    if extents[order[2]] < 0.5 * extents[order[1]]:        # a plate
        cuts[order[1]] = math.ceil(2 * extents[order[1]] / max(extents[order[2]], 1e-9))
    while cuts[0] * cuts[1] * cuts[2] > MAX_SPHERES:
        big = int(np.argmax(cuts))
        cuts[big] -= 1
    # the cut planes' sections of the surface belong to the slabs on both sides: a slab's farthest points are the
    # shape's vertices in it and the corners of its cuts (exactly so for a convex shape)
    extra = []
    for axis in range(3):
        step = extents[axis] / cuts[axis]
        for m in range(1, cuts[axis]):
            section = mesh.section(plane_origin=middle + axes[axis] * (low[axis] + m * step), plane_normal=axes[axis])
            if section is not None and len(section.vertices):
                extra += [section.vertices + axes[axis] * 1e-9, section.vertices - axes[axis] * 1e-9]
    if extra:
        points = np.concatenate([points] + extra)
        local = (points - middle) @ axes.T
    cells = np.zeros(len(points), dtype=int)
    for axis in range(3):
        step = extents[axis] / cuts[axis] if extents[axis] > 0 else 1.0
        index = np.clip(((local[:, axis] - low[axis]) / step).astype(int), 0, cuts[axis] - 1)
        cells = cells * cuts[axis] + index
    centres, radii, least, least_radii = [], [], [], []
    for cell in np.unique(cells):
        members = local[cells == cell]
        centre = np.zeros(3)
        for axis in range(3):             # the middle of the slab along cut axes, the shape's middle across the others
            if cuts[axis] > 1:
                centre[axis] = (members[:, axis].min() + members[:, axis].max()) / 2.0
            else:
                centre[axis] = (low[axis] + high[axis]) / 2.0
        centres.append(centre)
        radii.append(np.linalg.norm(members - centre, axis=1).max())
        # the least ball around the same points covers them as surely (its radius is their farthest from its
        # centre) and reaches less far beyond the shape: the UR5's margins of 3-7 cm came down to 2-4 cm
        least.append(_enclosing_centre(members, centre))
        least_radii.append(np.linalg.norm(members - least[-1], axis=1).max())
    return ((np.array(least) @ axes + middle, np.array(least_radii)),
            (np.array(centres) @ axes + middle, np.array(radii)))


def _stacked(spheres: list) -> tuple[np.ndarray, np.ndarray]:
    """(centres (K, 3), radii (K,)) of a list of (centres, radii)."""
    if not spheres:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate([c for c, _ in spheres]), np.concatenate([r for _, r in spheres])


# Rodrigues' rotation about a unit axis k by an angle (c = cos, s = sin, v = 1 - cos), entry by entry: the formulas of
# CollisionModel._moving_poses, c I + s [k]x + v k k^T
_RODRIGUES = {
    (0, 0): lambda k, c, s, v: c + k[0] * k[0] * v, (0, 1): lambda k, c, s, v: k[0] * k[1] * v - k[2] * s,
    (0, 2): lambda k, c, s, v: k[0] * k[2] * v + k[1] * s, (1, 0): lambda k, c, s, v: k[1] * k[0] * v + k[2] * s,
    (1, 1): lambda k, c, s, v: c + k[1] * k[1] * v, (1, 2): lambda k, c, s, v: k[1] * k[2] * v - k[0] * s,
    (2, 0): lambda k, c, s, v: k[2] * k[0] * v - k[1] * s, (2, 1): lambda k, c, s, v: k[2] * k[1] * v + k[0] * s,
    (2, 2): lambda k, c, s, v: c + k[2] * k[2] * v,
}


def _live_entries(axis) -> set[tuple[int, int]]:
    """The entries of the rotation about axis that are not 0 at every angle (the diagonal always; off it, where a
    product of the axis's components or the component that multiplies s is not 0)."""
    k = [float(x) for x in axis]
    live = {(0, 0), (1, 1), (2, 2)}
    for a, b in ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)):
        other = 3 - a - b
        if k[a] * k[b] != 0.0 or k[other] != 0.0:
            live.add((a, b))
    return live


_WARNED: set = set()


def mesh_distance(mesh, points: np.ndarray, chunk: int = 4_000_000) -> np.ndarray:
    """The distance from each point (P, 3) to the surface of mesh (a trimesh), exactly as trimesh's
    closest_point_naive gives it, without its pass over every triangle for every point: a triangle is measured only
    where its bounding sphere comes nearer the point than the point's nearest vertex (the kortex Gen3's meshes have
    10,000 to 27,000 triangles: its body took 13 s to build, most of it here)."""
    from trimesh.triangles import closest_point
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    triangles = np.asarray(mesh.triangles, dtype=float)
    centres = triangles.mean(axis=1)
    radii = np.linalg.norm(triangles - centres[:, None], axis=2).max(axis=1)
    vertices = np.asarray(mesh.vertices, dtype=float)
    out = np.empty(len(points))
    step = max(1, chunk // max(1, len(triangles)))
    for start in range(0, len(points), step):
        p = points[start:start + step]
        bound = np.sqrt(np.min(np.einsum('pvk,pvk->pv', p[:, None] - vertices[None], p[:, None] - vertices[None]),
                               axis=1))                       # a vertex's distance: the nearest point is no farther
        gap = np.linalg.norm(p[:, None] - centres[None], axis=2) - radii[None]
        rows, cols = np.nonzero(gap <= bound[:, None] + 1e-12)
        nearest = np.linalg.norm(closest_point(triangles[cols], p[rows]) - p[rows], axis=1)
        best = np.full(len(p), np.inf)
        np.minimum.at(best, rows, nearest)
        out[start:start + step] = best
    return out


def _say_once(key, text: str) -> None:
    """A warning said once per key in this process: a vector env of 64 arms says it once."""
    if key in _WARNED:
        return
    _WARNED.add(key)
    import logging
    logging.getLogger('robot_ai.motion.body').warning(text)


def _warn_once(robot: str, stand_in: dict, missing: list[str]) -> None:
    """The stand-ins, said once per robot and set of links in this process."""
    links = '; '.join(f'{link}: {how}' for link, how in list(stand_in.items())[:6])
    more = f' and {len(stand_in) - 6} more' if len(stand_in) > 6 else ''
    _say_once((robot, tuple(sorted(stand_in))),
              f'{robot}: collision geometry not on this machine or unreadable '
              f'({missing[0]}{" ..." if len(missing) > 1 else ""}), stood in for: {links}{more}. Put the meshes\' '
              f'package on ROS_PACKAGE_PATH for the real body.')


class CollisionModel:
    """The arm's body as spheres per link, the pairs checked, and the world's obstacles (see the module)."""

    def __init__(self, tree: KinematicTree, urdf: str, arm: Chain, obstacles=(), urdf_dir: str = '',
                 samples: int = PAIR_SAMPLES, seed: int = 0):
        self.tree, self.arm = tree, arm
        self.obstacles = parse_obstacles(obstacles) if not (isinstance(obstacles, tuple) and all(
            isinstance(o, Obstacle) for o in obstacles)) else obstacles
        shapes, self.missing = link_shapes(urdf, urdf_dir)
        self._sweep = None          # sweep()'s answer, once asked
        rng = np.random.default_rng(seed)
        # the links the arm's base carries: from the root, or (a floating base: the root's floating joint is skipped,
        # as robot_state_publisher skips it) from the arm's base down
        reachable = set(tree.link_poses())
        self.floating = arm.base not in reachable
        if self.floating:
            reachable = set(tree.link_poses(base=arm.base))
        # a link whose geometry cannot be read is never left empty: it gets a stand-in, said once per process
        unread = sorted({m.split(': ')[0] for m in self.missing} & reachable)
        for link in unread:
            shapes.pop(link, None)
        more, self.stand_ins = stand_ins(urdf, tree, unread, urdf_dir)
        shapes.update(more)
        if self.stand_ins:
            _warn_once(tree.name, self.stand_ins, self.missing)
        self.links = sorted(link for link in shapes if link in reachable)
        self.meshes = {}
        tight, loose, owner = [], [], []
        import trimesh
        for i, link in enumerate(self.links):
            self.meshes[link] = trimesh.util.concatenate(shapes[link])
            for mesh in shapes[link]:
                spheres, wider = _fit(mesh, rng)
                tight.append(spheres)
                loose.append(wider)
                owner += [i] * len(spheres[1])
        self.owner = np.array(owner, dtype=int)
        moving = self._moving_links()
        self.moving = np.array([link in moving for link in self.links], dtype=bool)
        self.moving_spheres = np.flatnonzero(self.moving[self.owner]) if len(self.owner) else np.zeros(0, int)
        # the pairs checked are chosen with the wider spheres, as before the least balls: with the tight ones, pairs
        # of the Panda that touch at home (left unchecked, as MoveIt's 'default') came apart there and were checked,
        # refusing more configurations whose meshes are centimetres apart, not fewer (6.6 % -> 14.6 %)
        self.centres, self.radii = _stacked(loose)
        self._prepare_poses()
        self.link_pairs, self.excluded = self._choose_pairs(samples, rng)
        self.centres, self.radii = _stacked(tight)
        self._place_still()
        self.pair_a, self.pair_b = self._sphere_pairs(self.link_pairs)
        self._prepare_bounds()
        self.margins = {link: self._margin(i, shapes[link], rng) for i, link in enumerate(self.links)}
        self.beyond = self._cull()
        if not len(self.moving_spheres):      # never silently empty: said once per process, as the node says it
            _say_once((tree.name, 'empty'),
                      f'{tree.name} has no collision geometry on its moving links: its body is empty, and nothing '
                      f'but the limits keeps the arm from itself and the obstacles (give its links <collision> '
                      f'elements)')

    def reach(self) -> float:
        """A bound on how far from the arm's base frame any of its moving spheres can be, in any configuration: the
        joints' offsets from the base down to each sphere's link (a prismatic joint's travel added), the sphere's
        centre in its link and its radius. inf where a link is not below the base (nothing is culled then)."""
        parent_joint = {j.child: j for j in self.tree.joints.values()}
        worst = 0.0
        for k in self.moving_spheres:
            _, bound = self._up_from(k, parent_joint)
            if bound == math.inf:
                return math.inf
            worst = max(worst, bound)
        return worst

    def sweep(self) -> np.ndarray:
        """(n,): a bound on how far (m) any point of a moving sphere moves per radian (or metre) of each of the arm's
        joints: for a revolute joint, the longest way from its origin to a sphere's far side below it (the offsets of
        the joints between, prismatic travel added); for a prismatic one, 1; a mimic joint adds its multiplier's share
        to its source's. A motion's checks are spaced by it (motion.JointPlanner). Worked out once."""
        if self._sweep is not None:
            return self._sweep.copy()
        parent_joint = {j.child: j for j in self.tree.joints.values()}
        index = {name: k for k, name in enumerate(self.arm.joints)}
        out = np.zeros(self.arm.n)
        for k in self.moving_spheres:
            share = np.zeros(self.arm.n)
            for joint, below in self._up_from(k, parent_joint)[0]:
                source, factor = joint.name, 1.0
                if joint.mimic is not None:
                    source, factor = joint.mimic[0], abs(float(joint.mimic[1]))
                if source in index:
                    share[index[source]] += factor * (1.0 if joint.type == 'prismatic' else below)
            out = np.maximum(out, share)
        self._sweep = np.maximum(out, 1e-3)
        return self._sweep.copy()

    def _up_from(self, k: int, parent_joint: dict) -> tuple[list, float]:
        """The joints from moving sphere k's link up to the arm's base, each with the longest way from its origin to
        the sphere's far side (the offsets of the joints between, prismatic travel added, the sphere's centre and
        radius), and that way from the base (inf where the link is not below the base)."""
        link, length = self.links[self.owner[k]], 0.0
        centre, radius = float(np.linalg.norm(self.centres[k])), float(self.radii[k])
        steps = []
        while link != self.arm.base:
            joint = parent_joint.get(link)
            if joint is None:
                return steps, math.inf
            steps.append((joint, length + centre + radius))
            length += float(np.linalg.norm(joint.xyz))
            if joint.type == 'prismatic':
                length += max(abs(joint.lower or 0.0), abs(joint.upper or 0.0)) or 1.0
            link = joint.parent
        return steps, length + centre + radius

    def _cull(self, padding: float = 1.0) -> int:
        """Obstacles no moving sphere can come within padding of (1 m: any ~collision_margin) are left out of the
        checks, which run an obstacle at a time (5,000 small ones far from the arm kept a node silent for minutes);
        how many."""
        if not self.obstacles or not len(self.moving_spheres):
            return 0
        reach = self.reach() + padding
        near = tuple(o for o in self.obstacles if obstacle_distance(o) <= reach)
        beyond, self.obstacles = len(self.obstacles) - len(near), near
        return beyond

    def _margin(self, i: int, parts: list, rng: np.random.Generator, per_sphere: int = 100, rounds: int = 4) -> float:
        """How far link i's spheres reach beyond its geometry (parts: its shapes): the largest distance from a point
        of their union's surface outside the convex hull of each shape to the geometry (a contact of the spheres is a
        contact of the geometry enlarged by this much), sought from per_sphere random points of each sphere, then
        `rounds` times nearer the farthest ones found (random points alone fell 1.7 mm short on a fingertip)."""
        idx = np.flatnonzero(self.owner == i)
        mesh = self.meshes[self.links[i]]
        hulls = [part.convex_hull for part in parts]       # each shape's (a stand-in's capsules: their union's hull
                                                            # hid 1.2 mm)

        def beyond(owner: np.ndarray, directions: np.ndarray) -> np.ndarray:
            """The distance to the geometry of each point (sphere idx[owner], unit direction), 0 where it lies
            inside another sphere of the link or the hull."""
            points = self.centres[idx][owner] + self.radii[idx][owner][:, None] * directions
            out = np.zeros(len(points))
            keep = ~np.any(np.linalg.norm(points[:, None] - self.centres[idx][None], axis=2)
                           < self.radii[idx][None] - 1e-9, axis=1)
            for hull in hulls:
                if keep.any():
                    signed = np.einsum('fj,pfj->pf', hull.face_normals,
                                       points[keep][:, None] - hull.triangles[:, 0][None])
                    keep[keep] = signed.max(axis=1) > 0
            if keep.any():
                out[keep] = mesh_distance(mesh, points[keep])
            return out

        unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)      # noqa: E731
        owner = np.repeat(np.arange(len(idx)), per_sphere)
        directions = unit(rng.normal(size=(len(owner), 3)))
        distance = beyond(owner, directions)
        for spread in np.geomspace(0.3, 0.3 ** rounds, rounds):          # about the farthest few, ever closer
            best = np.argsort(-distance)[:8]
            best = best[distance[best] > 0]
            if not len(best):
                break
            near_owner = np.repeat(owner[best], 25)
            near = unit(np.repeat(directions[best], 25, axis=0) + spread * rng.normal(size=(len(near_owner), 3)))
            owner = np.concatenate((owner, near_owner))
            directions = np.concatenate((directions, near))
            distance = np.concatenate((distance, beyond(near_owner, near)))
        return float(distance.max())

    # --------------------------------------------------------------------------------------- structure
    def _moving_links(self) -> set[str]:
        """The links whose pose follows a joint of the arm (its chain's links and what hangs below them)."""
        below = {}
        for j in self.tree.joints.values():
            below.setdefault(j.parent, []).append(j.child)
        out, stack = set(), [self.tree.joints[name].child for name in self.arm.joints]
        while stack:
            link = stack.pop()
            if link not in out:
                out.add(link)
                stack += below.get(link, [])
        return out

    def _rigid_groups(self) -> dict[str, str]:
        """{link: the link at the top of its rigid body}: links joined by fixed joints (or joints of no arm and no
        mimic of one, which stay where they are) move as one."""
        parent = {j.child: j for j in self.tree.joints.values()}
        moving = set(self.arm.joints) | {j.name for j in self.tree.joints.values()
                                         if j.mimic is not None and j.mimic[0] in self.arm.joints}

        def top(link):
            while link in parent and (parent[link].type == 'fixed' or parent[link].name not in moving):
                link = parent[link].parent
            return link
        return {link: top(link) for link in self.links}

    def _choose_pairs(self, samples: int, rng: np.random.Generator):
        """(link index pairs checked, {reason: [link name pairs]} of those excluded)."""
        parent = {j.child: j.parent for j in self.tree.joints.values()}
        groups = self._rigid_groups()
        excluded = {'adjacent': [], 'default': [], 'always': [], 'never': []}
        candidates = []
        for i, la in enumerate(self.links):
            for j in range(i + 1, len(self.links)):
                lb = self.links[j]
                if not (self.moving[i] or self.moving[j]):
                    continue
                if parent.get(la) == lb or parent.get(lb) == la or groups[la] == groups[lb]:
                    excluded['adjacent'].append((la, lb))
                    continue
                candidates.append((i, j))
        if not candidates:
            return [], excluded
        home = self.arm.home[None]
        at_home = self._pair_contacts(home, candidates)[0]
        q = rng.uniform(self.arm.lower, self.arm.upper, size=(samples, self.arm.n))
        counts = np.zeros(len(candidates))
        for start in range(0, samples, 250):
            counts += self._pair_contacts(q[start:start + 250], candidates).sum(axis=0)
        kept = []
        for k, (i, j) in enumerate(candidates):
            names = (self.links[i], self.links[j])
            if at_home[k]:
                excluded['default'].append(names)
            elif counts[k] >= ALWAYS * samples:
                excluded['always'].append(names)
            elif counts[k] == 0:
                excluded['never'].append(names)
            else:
                kept.append((i, j))
        return kept, excluded

    def _sphere_pairs(self, link_pairs: list) -> tuple[np.ndarray, np.ndarray]:
        """(a, b): the sphere index pairs of link index pairs, every sphere of one link against every one of the
        other."""
        a, b = [], []
        for i, j in link_pairs:
            ia, ib = np.flatnonzero(self.owner == i), np.flatnonzero(self.owner == j)
            a += list(np.repeat(ia, len(ib)))
            b += list(np.tile(ib, len(ia)))
        return np.array(a, dtype=int), np.array(b, dtype=int)

    def _prepare_bounds(self) -> None:
        """Each link's bound for the broad phase: a ball about one of its spheres' centres (the one nearest their
        middle: a point the check places anyway) holding all its spheres; the checked link pairs' bounds, and where
        each link pair's sphere pairs start among pair_a and pair_b (_sphere_pairs' order)."""
        anchor, bound = np.zeros(len(self.links), dtype=int), np.zeros(len(self.links))
        for i in range(len(self.links)):
            idx = np.flatnonzero(self.owner == i)
            if not len(idx):
                continue
            c = self.centres[idx]
            k = idx[np.linalg.norm(c - c.mean(axis=0), axis=1).argmin()]
            anchor[i] = k
            bound[i] = (np.linalg.norm(c - self.centres[k], axis=1) + self.radii[idx]).max() + BOUND_SLACK
        pairs = np.array(self.link_pairs, dtype=int).reshape(-1, 2)
        self._bound_a, self._bound_b = anchor[pairs[:, 0]], anchor[pairs[:, 1]]
        self._bound_reach = bound[pairs[:, 0]] + bound[pairs[:, 1]]
        sizes = np.array([np.count_nonzero(self.owner == i) * np.count_nonzero(self.owner == j) for i, j in pairs],
                         dtype=np.intp)
        self._group_size, self._group_start = sizes, np.cumsum(sizes) - sizes

    def _self_contacts(self, x, y, z, padding: float = 0.0) -> np.ndarray:
        """(N,) bool: some checked pair of spheres touches (or comes within padding), for centres given as (K, N)
        x, y and z. Beyond BROAD_PHASE pairs, only the pairs of links whose bounds meet in a configuration are
        compared there, with _touching's numbers in its order (the same answers to the bit)."""
        if len(self.pair_a) <= BROAD_PHASE:
            return self._touching(x, y, z, self.pair_a, self.pair_b, padding).any(axis=0)
        a, b = self._bound_a, self._bound_b
        d2 = (x[a] - x[b]) ** 2 + (y[a] - y[b]) ** 2 + (z[a] - z[b]) ** 2
        group, column = np.nonzero(d2 <= ((self._bound_reach + padding)[:, None] ** 2))
        hit = np.zeros(x.shape[1], dtype=bool)
        if not len(group):
            return hit
        sizes = self._group_size[group]
        ends = np.cumsum(sizes)
        pair = np.repeat(self._group_start[group] - ends + sizes, sizes) + np.arange(ends[-1])
        column = np.repeat(column, sizes)
        a, b = self.pair_a[pair], self.pair_b[pair]
        d2 = x[a, column]
        d2 -= x[b, column]
        d2 *= d2
        for coordinate in (y, z):
            d = coordinate[a, column]
            d -= coordinate[b, column]
            d *= d
            d2 += d
        hit[column[d2 < (self.radii[a] + self.radii[b] + padding) ** 2]] = True
        return hit

    def _pair_contacts(self, q: np.ndarray, pairs: list) -> np.ndarray:
        """(N, len(pairs)) bool: whether the spheres of link pair k touch in configuration n."""
        x, y, z = self._centres_by_coordinate(np.atleast_2d(q))
        out = np.zeros((x.shape[1], len(pairs)), dtype=bool)
        for k, pair in enumerate(pairs):
            out[:, k] = self._touching(x, y, z, *self._sphere_pairs([pair])).any(axis=0)
        return out

    # ------------------------------------------------------------------------------------------ checks
    def link_poses(self, q) -> dict[str, np.ndarray]:
        """{link: (N, 4, 4)} of the body's links in the arm's base frame."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if self.floating:           # below a floating joint: configuration by configuration, from the arm's base
            each = [self.tree.link_poses(dict(zip(self.arm.joints, row)), base=self.arm.base) for row in q]
            return {link: np.stack([p[link] for p in each]) for link in self.links}
        poses = self.tree.link_poses_batch(q, names=self.arm.joints)
        if self.arm.base == self.tree.root:
            return {link: poses[link] for link in self.links}
        base = np.linalg.inv(poses[self.arm.base])
        return {link: np.matmul(base, poses[link]) for link in self.links}

    def sphere_centres(self, q) -> np.ndarray:
        """(N, K, 3) the spheres' centres in the arm's base frame."""
        return np.stack(self._centres_by_coordinate(np.atleast_2d(np.asarray(q, dtype=float))), axis=2) \
            .transpose(1, 0, 2)

    def in_collision(self, q, padding: float = 0.0) -> np.ndarray:
        """(N,) bool: the arm touches itself (a checked pair) or an obstacle, for (N, arm.n) configurations; with
        padding (m), coming nearer than that counts as touching (a safety margin). The numbers run coordinate by
        coordinate over (spheres, N) arrays: the batch is the fast axis."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        x, y, z = self._centres_by_coordinate(q)
        hit = np.zeros(len(q), dtype=bool)
        if len(self.pair_a):
            hit |= self._self_contacts(x, y, z, padding)
        if self.obstacles and len(self.moving_spheres):
            for touching in self._obstacle_contacts(x, y, z, padding):
                hit |= touching.any(axis=0)
        return hit

    def _touching(self, x, y, z, a: np.ndarray, b: np.ndarray, padding: float = 0.0) -> np.ndarray:
        """(len(a), N) bool: sphere a[p] touches sphere b[p] (or comes within padding), for centres given as (K, N)
        x, y and z."""
        d2 = x[a]
        d2 -= x[b]
        d2 *= d2
        for coordinate in (y, z):           # in place: the same numbers, without a temporary array each
            d = coordinate[a]
            d -= coordinate[b]
            d *= d
            d2 += d
        return d2 < ((self.radii[a] + self.radii[b] + padding)[:, None] ** 2)

    def _touching_obstacles(self, x, y, z, padding: float = 0.0) -> np.ndarray:
        """(len(obstacles), K_moving, N) bool: the moving spheres that touch each obstacle (or come within
        padding)."""
        return np.array(list(self._obstacle_contacts(x, y, z, padding)), dtype=bool).reshape(
            len(self.obstacles), len(self.moving_spheres), x.shape[1])

    def _obstacle_contacts(self, x, y, z, padding: float = 0.0):
        """For each obstacle in turn, (K_moving, N) bool: the moving spheres (centres given as (K, N) x, y and z)
        that touch it or come within padding. The numbers run in place, an obstacle at a time; an axis-aligned box
        skips its rotation's products, which are exact there (x 1 + y 0 + z 0 is x)."""
        m = self.moving_spheres
        xs, ys, zs = x[m], y[m], z[m]
        reach = self.radii[m][:, None] + padding
        limit = reach ** 2
        d, d2 = np.empty_like(xs), np.empty_like(xs)
        for o in self.obstacles:
            rot, centre = o.pose[:3, :3], o.pose[:3, 3]
            if o.kind != 'box':
                np.subtract(xs, centre[0], out=d2)
                np.multiply(d2, d2, out=d2)
                for coordinate, t in ((ys, centre[1]), (zs, centre[2])):
                    np.subtract(coordinate, t, out=d)
                    d2 += d * d
                yield d2 < (reach + o.size[0]) ** 2
                continue
            aligned = np.array_equal(rot, np.identity(3))
            deltas = (xs, ys, zs) if aligned else (xs - centre[0], ys - centre[1], zs - centre[2])
            d2.fill(0.0)
            for axis in range(3):          # the sphere's centre in the box's frame, clamped outside it
                if aligned:
                    np.subtract(deltas[axis], centre[axis], out=d)
                else:
                    np.multiply(deltas[0], rot[0, axis], out=d)
                    d += rot[1, axis] * deltas[1]
                    d += rot[2, axis] * deltas[2]
                np.abs(d, out=d)
                d -= o.size[axis] / 2.0
                np.maximum(d, 0.0, out=d)
                np.multiply(d, d, out=d)
                d2 += d
            yield d2 < limit

    def _centres_by_coordinate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The spheres' centres as three (K, N) arrays, x, y and z in the arm's base frame."""
        out = np.empty((3, len(self.radii), len(q)))
        out[:] = self._still[:, :, None]
        poses = self._moving_poses(q)
        for i, link in enumerate(self.links):
            if not self.moving[i]:
                continue
            idx = np.flatnonzero(self.owner == i)
            rot, pos = poses[link]
            c = self.centres[idx]                                  # (k, 3) in the link's frame
            for row in range(3):
                out[row, idx] = (c[:, 0:1] * rot[row, 0] + c[:, 1:2] * rot[row, 1] + c[:, 2:3] * rot[row, 2]
                                 + pos[row])
        return out[0], out[1], out[2]

    def _prepare_poses(self) -> None:
        """What every check reuses: the joints from the arm's base down to the moving links (in the tree's order),
        every link's pose at home (those that do not move stay there) and the spheres of the links that do not move
        (_place_still)."""
        below_arm = {link for link, m in zip(self.links, self.moving) if m}
        parent = {j.child: j for j in self.tree.joints.values()}
        needed = set()
        for link in below_arm:
            while link in parent and link != self.arm.base:
                needed.add(parent[link].name)
                link = parent[link].parent
        self._plan = [self.tree.joints[name] for name in self.tree.joint_order if name in needed]
        self._turned_origins = {j.name for j in self._plan if not np.array_equal(j.matrix[:3, :3], np.identity(3))}
        self._moved_origins = {j.name for j in self._plan if j.matrix[:3, 3].any()}
        self._live_entries = {j.name: _live_entries(j.axis) for j in self._plan if j.axis is not None}
        self._wanted = below_arm
        if self.floating:
            self._at_home = self.tree.link_poses(dict(zip(self.arm.joints, self.arm.home)), base=self.arm.base)
        else:
            at_home = self.tree.link_poses_batch(self.arm.home[None], names=self.arm.joints)
            base = np.linalg.inv(at_home[self.arm.base][0])
            self._at_home = {link: base @ p[0] for link, p in at_home.items()}
        self._place_still()

    def _place_still(self) -> None:
        """The spheres of the links that do not move, where they stay (3, K) (the moving ones' columns are
        overwritten by each check)."""
        self._still = np.zeros((3, len(self.radii)))
        for i, link in enumerate(self.links):
            idx = np.flatnonzero(self.owner == i)
            if not self.moving[i] and len(idx):
                pose = self._at_home[link]
                self._still[:, idx] = pose[:3, :3] @ self.centres[idx].T + pose[:3, 3:4]

    def _moving_poses(self, q: np.ndarray) -> dict:
        """{moving body link: (rotation (3, 3, N), position (3, N))} in the arm's base frame: the joints' transforms
        composed coordinate by coordinate (the batch the fast axis: twice as fast as numpy's matmul of (N, 4, 4))."""
        n = len(q)
        values = self.tree.resolve_positions({name: q[:, i] for i, name in enumerate(self.arm.joints)})
        poses = {}

        def pose_of(link):
            if link not in poses:
                p = self._at_home[link]
                poses[link] = (np.repeat(p[:3, :3, None], n, axis=2), np.repeat(p[:3, 3, None], n, axis=1))
            return poses[link]
        poses[self.arm.base] = (np.repeat(np.identity(3)[:, :, None], n, axis=2), np.zeros((3, n)))
        for j in self._plan:
            rot, pos = pose_of(j.parent)
            fixed = j.matrix
            # the origin: R' = R Ro, p' = p + R to (an identity Ro or a zero to changes nothing: skipped, exactly)
            turned, moved = j.name in self._turned_origins, j.name in self._moved_origins
            r_origin = np.einsum('ijn,jk->ikn', rot, fixed[:3, :3]) if turned else rot
            p_origin = pos + np.einsum('ijn,j->in', rot, fixed[:3, 3]) if moved else pos
            theta = values.get(j.name) if j.type in ('revolute', 'continuous', 'prismatic') else None
            if theta is None:
                poses[j.child] = (r_origin, p_origin)
                continue
            theta = np.broadcast_to(np.asarray(theta, dtype=float), (n,))
            k = j.axis
            if j.type == 'prismatic':
                poses[j.child] = (r_origin, p_origin + np.einsum('ijn,j->in', r_origin, k) * theta)
                continue
            c, s_, v = np.cos(theta), np.sin(theta), 1.0 - np.cos(theta)
            # Rodrigues: c I + s [k]x + (1 - c) k k^T, the entries an axis's zeros make 0 left out (a product with an
            # exact 0 adds nothing to a finite sum: the numbers are the full product's)
            entries = {}
            for (a, b), formula in _RODRIGUES.items():
                if (a, b) in self._live_entries[j.name]:
                    entries[a, b] = formula(k, c, s_, v)
            rot_child = np.empty((3, 3, n))
            for a in range(3):
                for b in range(3):
                    total = None
                    for m in range(3):
                        if (m, b) in entries:
                            term = r_origin[a, m] * entries[m, b]
                            total = term if total is None else total + term
                    rot_child[a, b] = 0.0 if total is None else total
            poses[j.child] = (rot_child, p_origin)
        return {link: poses[link] for link in self._wanted if link in poses}

    def contacts(self, q, padding: float = 0.0) -> list[str]:
        """The pairs in contact (or within padding) in one configuration, by name ('link_a - link_b',
        'link - <obstacle>')."""
        x, y, z = self._centres_by_coordinate(np.asarray(q, dtype=float)[None])
        out = [f'{self.links[i]} - {self.links[j]}' for i, j in self.link_pairs
               if self._touching(x, y, z, *self._sphere_pairs([(i, j)]), padding).any()]
        if self.obstacles and len(self.moving_spheres):
            hits = self._touching_obstacles(x, y, z, padding)[:, :, 0].T          # (K_moving, obstacles)
            for k, m in zip(*np.nonzero(hits)):
                name = f'{self.links[self.owner[self.moving_spheres[k]]]} - {self.obstacles[m].name}'
                if name not in out:
                    out.append(name)
        return out
