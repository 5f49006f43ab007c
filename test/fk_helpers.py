"""Test helpers for forward kinematics: random URDF trees and an independent reference implementation.

The reference below uses neither robot_ai.kinematics nor tf.transformations: rotations are written out
from their definitions, so agreement is a real check, not the same code run twice.
"""
import math
import os

import numpy as np

ROBOTS_DIR = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', 'shared', 'robots'))
if not os.path.isdir(ROBOTS_DIR):  # inside a catkin workspace: .catkin_ws/src/robot_ai -> repository
    ROBOTS_DIR = os.path.abspath(os.path.join(os.path.realpath(os.path.dirname(__file__)), '..', '..',
                                              'shared', 'robots'))
REFERENCE_ROBOTS = ['ur5.urdf', 'kuka_lwr_arm.urdf', 'panda.urdf', 'pr2.urdf',
                    'fixtures/one_link.urdf', 'fixtures/two_links_fixed_joint.urdf',
                    'fixtures/two_links_moving_joint.urdf', 'fixtures/frames_and_slashes.urdf']


def robot_path(name):
    return os.path.join(ROBOTS_DIR, name)


def _fmt(v):
    return ' '.join(repr(float(x)) for x in v)


def random_urdf(seed, n_links=12, mimic_chains=False, types=None):
    """A random URDF tree as an XML string.

    Every new link hangs from a random earlier one (forks), joints of every type (revolute, continuous,
    prismatic, fixed, floating, planar), arbitrary origins and non-normalised axes, some rpy with pitch
    near +-pi/2, mimic joints with and without multiplier/offset (with mimic_chains, mimics of mimics too).
    """
    rng = np.random.default_rng(seed)
    types = types or ['revolute', 'continuous', 'prismatic', 'revolute', 'continuous', 'prismatic',
                      'fixed', 'floating', 'planar']
    lines = ['<robot name="random_%d">' % seed, '  <link name="base"/>']
    links, moving, mimics = ['base'], [], []
    for i in range(1, n_links):
        name = 'l%d' % i
        parent = links[int(rng.integers(len(links)))]
        jtype = types[int(rng.integers(len(types)))]
        xyz = rng.uniform(-1, 1, 3)
        rpy = rng.uniform(-math.pi, math.pi, 3)
        if rng.random() < 0.25:
            rpy[1] = math.copysign(math.pi / 2, rng.uniform(-1, 1)) + rng.choice([0.0, 1e-9, -1e-7])
        axis = rng.uniform(-1, 1, 3) * rng.uniform(0.2, 5.0)
        jname = 'j%d' % i
        body = ['    <parent link="%s"/>' % parent, '    <child link="%s"/>' % name,
                '    <origin xyz="%s" rpy="%s"/>' % (_fmt(xyz), _fmt(rpy)),
                '    <axis xyz="%s"/>' % _fmt(axis)]
        if jtype in ('revolute', 'prismatic'):
            body.append('    <limit lower="-1" upper="1" effort="1" velocity="1"/>')
        candidates = [m for m in moving if mimic_chains or m not in mimics]
        if jtype in ('revolute', 'continuous', 'prismatic') and candidates and rng.random() < 0.3:
            src = candidates[int(rng.integers(len(candidates)))]
            attrs = 'joint="%s"' % src
            if rng.random() < 0.7:
                attrs += ' multiplier="%r" offset="%r"' % (float(rng.uniform(-2, 2)), float(rng.uniform(-1, 1)))
            body.append('    <mimic %s/>' % attrs)
            mimics.append(jname)
        lines.append('  <link name="%s"/>' % name)
        lines.append('  <joint name="%s" type="%s">' % (jname, jtype))
        lines.extend(body)
        lines.append('  </joint>')
        links.append(name)
        if jtype in ('revolute', 'continuous', 'prismatic'):
            moving.append(jname)
    lines.append('</robot>')
    return '\n'.join(lines)


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def axis_angle(axis, angle):
    """Rotation matrix about a unit axis, from the matrix exponential of the skew matrix (scipy-free)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    # exp(angle * K) by its Taylor series to convergence: independent of Rodrigues' closed form. The angle
    # is first reduced to [-pi, pi] (a full turn is the identity) so that the series does not cancel badly.
    angle = math.remainder(angle, 2 * math.pi)
    out, term = np.identity(3), np.identity(3)
    for n in range(1, 80):
        term = term.dot(k) * (angle / n)
        out = out + term
    return out


def reference_link_poses(xml_string, positions):
    """Link poses in the root frame, computed from the XML directly. Mimic chains followed; floating joints
    cut the tree; unknown moving joints at 0."""
    import xml.etree.ElementTree as ET
    root = ET.fromstring(xml_string)
    joints = {}
    for j in root.findall('joint'):
        origin = j.find('origin')
        xyz = [float(x) for x in origin.get('xyz', '0 0 0').split()] if origin is not None else [0, 0, 0]
        rpy = [float(x) for x in origin.get('rpy', '0 0 0').split()] if origin is not None else [0, 0, 0]
        axis_el = j.find('axis')
        axis = np.array([float(x) for x in axis_el.get('xyz').split()]) if axis_el is not None else np.array(
            [1.0, 0, 0])
        mimic = j.find('mimic')
        joints[j.get('name')] = dict(type=j.get('type'), parent=j.find('parent').get('link'),
                                     child=j.find('child').get('link'), xyz=np.array(xyz), rpy=rpy,
                                     axis=axis / np.linalg.norm(axis) if np.linalg.norm(axis) else axis,
                                     mimic=None if mimic is None else (
                                         mimic.get('joint'), float(mimic.get('multiplier', 1.0)),
                                         float(mimic.get('offset', 0.0))))

    def value(name):
        if name in positions:
            return positions[name]
        m = joints[name]['mimic']
        return 0.0 if m is None else m[1] * value(m[0]) + m[2]

    children = {j['child'] for j in joints.values()}
    base = [l.get('name') for l in root.findall('link') if l.get('name') not in children][0]
    poses = {base: np.identity(4)}
    changed = True
    while changed:
        changed = False
        for name, j in joints.items():
            if j['parent'] in poses and j['child'] not in poses and j['type'] != 'floating':
                t = np.identity(4)
                r, p, y = j['rpy']
                t[:3, :3] = rot_z(y).dot(rot_y(p)).dot(rot_x(r))
                t[:3, 3] = j['xyz']
                motion = np.identity(4)
                if j['type'] in ('revolute', 'continuous'):
                    motion[:3, :3] = axis_angle(j['axis'], value(name))
                elif j['type'] == 'prismatic':
                    motion[:3, 3] = j['axis'] * value(name)
                poses[j['child']] = poses[j['parent']].dot(t).dot(motion)
                changed = True
    return poses


def rotation_angle_between(r1, r2):
    """Angle (rad) of the rotation that takes r1 to r2 (3x3), robust near 0."""
    d = r1.T.dot(r2)
    s = np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2.0
    c = (np.trace(d) - 1.0) / 2.0
    return abs(math.atan2(s, c))


def mimic_chain(n, offset=0.0):
    """A URDF chain of n revolute joints l0 -> l1 -> ... -> ln, each after the first a mimic of the one before
    it (multiplier 1, the given offset)."""
    joints = ['<joint name="j0" type="revolute"><parent link="l0"/><child link="l1"/><axis xyz="0 0 1"/>'
              '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>']
    for i in range(1, n):
        joints.append('<joint name="j%d" type="revolute"><parent link="l%d"/><child link="l%d"/><axis xyz="0 0 1"/>'
                      '<limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="j%d" multiplier="1" '
                      'offset="%r"/></joint>' % (i, i, i + 1, i - 1, offset))
    return '<robot name="chain">%s%s</robot>' % (''.join('<link name="l%d"/>' % i for i in range(n + 1)),
                                                  ''.join(joints))


def write_xacro_package(folder):
    """A description package as users bring one: my_arm_description/urdf/arm.urdf.xacro includes a macro file
    through $(find my_arm_description) and adds a hand with the argument hand:=true."""
    urdf = os.path.join(folder, 'my_arm_description', 'urdf')
    os.makedirs(urdf, exist_ok=True)
    with open(os.path.join(folder, 'my_arm_description', 'package.xml'), 'w') as f:
        f.write('<?xml version="1.0"?><package format="2"><name>my_arm_description</name><version>0.1.0</version>'
                '<description>an arm</description><maintainer email="a@b.c">a</maintainer><license>BSD</license>'
                '<buildtool_depend>catkin</buildtool_depend></package>')
    with open(os.path.join(urdf, 'segment.xacro'), 'w') as f:
        f.write('<?xml version="1.0"?><robot xmlns:xacro="http://www.ros.org/wiki/xacro">'
                '<xacro:macro name="segment" params="name parent z">'
                '<link name="${name}"/><joint name="${name}_joint" type="revolute"><parent link="${parent}"/>'
                '<child link="${name}"/><origin xyz="0 0 ${z}" rpy="0 ${pi/6} 0"/><axis xyz="0 0 1"/>'
                '<limit lower="-2" upper="2" effort="1" velocity="1"/></joint></xacro:macro></robot>')
    with open(os.path.join(urdf, 'arm.urdf.xacro'), 'w') as f:
        f.write('<?xml version="1.0"?><robot name="my_arm" xmlns:xacro="http://www.ros.org/wiki/xacro">'
                '<xacro:arg name="hand" default="false"/>'
                '<xacro:include filename="$(find my_arm_description)/urdf/segment.xacro"/>'
                '<xacro:property name="upper" value="0.4"/><link name="base"/>'
                '<xacro:segment name="shoulder" parent="base" z="0.1"/>'
                '<xacro:segment name="elbow" parent="shoulder" z="${upper}"/>'
                '<xacro:if value="$(arg hand)"><xacro:segment name="hand" parent="elbow" z="0.2"/></xacro:if>'
                '</robot>')
    return os.path.join(urdf, 'arm.urdf.xacro')
