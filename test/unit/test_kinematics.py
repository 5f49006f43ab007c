"""Unit tests of robot_ai.kinematics: no roscore. References: the zero poses of ../shared/robots/SOURCES.md,
an independent implementation written from the URDF definitions (fk_helpers), and the single form for the
batch and vectorised forms."""
import math

import numpy as np
import pytest
from tf import transformations as tft

from fk_helpers import (REFERENCE_ROBOTS, mimic_chain, random_urdf, reference_link_poses, robot_path,
                        rotation_angle_between)
from robot_ai.kinematics import KinematicTree, URDFError, prefix_frame

TOL = 1e-9


def load(name):
    with open(robot_path(name)) as f:
        return f.read()


def assert_poses_equal(got, want, tol=TOL):
    assert set(got) == set(want)
    for link in want:
        assert np.abs(got[link][:3, 3] - want[link][:3, 3]).max() < tol, link
        assert rotation_angle_between(got[link][:3, :3], want[link][:3, :3]) < tol, link


@pytest.mark.parametrize('name, root, tip, xyz', [
    ('ur5.urdf', 'base_link', 'tool0', (0.81725, 0.19145, -0.00549)),
    ('kuka_lwr_arm.urdf', 'world_link', 'lwr_arm_7_link', (0.0, 0.0, 1.3785)),
    ('pr2.urdf', 'base_footprint', 'r_gripper_tool_frame', (0.951, -0.188, 0.79068)),
])
def test_zero_pose_matches_sources(name, root, tip, xyz):
    tree = KinematicTree.from_xml_string(load(name))
    assert tree.root == root
    np.testing.assert_allclose(tree.link_poses()[tip][:3, 3], xyz, atol=1e-5)


def test_pr2_loads_despite_old_transmissions():
    tree = KinematicTree.from_xml_string(load('pr2.urdf'))
    assert len(tree.links) == 83 and len(tree.joints) == 82
    assert len(tree.mimic_joints) == 6
    assert {tree.joints[n].type for n in tree.joints} == {'revolute', 'continuous', 'prismatic', 'fixed'}


@pytest.mark.parametrize('name', REFERENCE_ROBOTS)
def test_reference_robots_against_independent_fk(name):
    xml = load(name)
    tree = KinematicTree.from_xml_string(xml)
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = {n: float(rng.uniform(-3, 3)) for n in tree.active_joints}
        assert_poses_equal(tree.link_poses(q), reference_link_poses(xml, q))


@pytest.mark.parametrize('seed', range(40))
def test_random_trees_against_independent_fk(seed):
    xml = random_urdf(seed, n_links=15, mimic_chains=True)
    tree = KinematicTree.from_xml_string(xml)
    rng = np.random.default_rng(seed)
    for scale in (1.0, 100.0):  # continuous joints at large angles too
        q = {n: float(rng.uniform(-scale, scale)) for n in tree.active_joints}
        assert_poses_equal(tree.link_poses(q), reference_link_poses(xml, q), tol=TOL * scale)


@pytest.mark.parametrize('seed', range(10))
def test_batch_equals_single(seed):
    tree = KinematicTree.from_xml_string(random_urdf(seed, n_links=20, mimic_chains=True))
    q = np.random.default_rng(seed).uniform(-4, 4, (7, len(tree.active_joints)))
    batch = tree.link_poses_batch(q)
    for i in range(q.shape[0]):
        single = tree.link_poses(dict(zip(tree.active_joints, q[i])))
        assert set(batch) == set(single)
        for link in single:
            np.testing.assert_allclose(batch[link][i], single[link], atol=1e-12)


def test_batch_on_pr2_and_bad_shape():
    tree = KinematicTree.from_xml_string(load('pr2.urdf'))
    q = np.random.default_rng(0).uniform(-1, 1, (3, len(tree.active_joints)))
    poses = tree.link_poses_batch(q)
    assert poses['r_gripper_tool_frame'].shape == (3, 4, 4)
    with pytest.raises(ValueError):
        tree.link_poses_batch(q[:, :-1])
    with pytest.raises(ValueError):
        tree.link_poses_batch(q[:, :1], names=['not_a_joint'])


def test_panda_mimic_defaults_and_explicit_value_wins():
    tree = KinematicTree.from_xml_string(load('panda.urdf'))
    assert tree.joints['panda_finger_joint2'].mimic == ('panda_finger_joint1', 1.0, 0.0)
    resolved = tree.resolve_positions({'panda_finger_joint1': 0.03})
    assert resolved['panda_finger_joint2'] == 0.03
    assert tree.resolve_positions({'panda_finger_joint1': 0.03, 'panda_finger_joint2': 0.01})[
        'panda_finger_joint2'] == 0.01
    plan = tree.transform_plan()
    layout = plan.message_layout(('panda_finger_joint1',))
    data = plan.message_transforms(layout, np.array([0.03]))
    got = dict(zip((plan.names[i] for i in layout.out_idx), data[:, :3]))
    # finger 2 slides along -y by the same 0.03
    np.testing.assert_allclose(got['panda_finger_joint2'], [0, -0.03, 0.0584], atol=1e-12)
    layout = plan.message_layout(('panda_finger_joint2', 'panda_finger_joint1'))
    got = dict(zip((plan.names[i] for i in layout.out_idx), plan.message_transforms(layout, np.array([0.01, 0.03]))))
    np.testing.assert_allclose(got['panda_finger_joint2'][:3], [0, -0.01, 0.0584], atol=1e-12)  # explicit wins


MIMIC_CHAIN = """<robot name="chain">
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j2" type="continuous"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>
    <mimic joint="j3" multiplier="2" offset="0.5"/></joint>
  <joint name="j3" type="continuous"><parent link="c"/><child link="d"/><axis xyz="0 0 1"/>
    <mimic joint="j1" multiplier="-1"/></joint>
</robot>"""


def test_mimic_of_mimic_is_followed():
    tree = KinematicTree.from_xml_string(MIMIC_CHAIN)
    assert tree.active_joints == ['j1']
    r = tree.resolve_positions({'j1': 0.2})
    assert r['j3'] == pytest.approx(-0.2) and r['j2'] == pytest.approx(2 * -0.2 + 0.5)
    plan = tree.transform_plan()
    layout = plan.message_layout(('j1',))
    assert len(layout.chain) == 1  # j2 follows j3, which follows j1
    data = plan.message_transforms(layout, np.array([0.2]))
    got = dict(zip((plan.names[i] for i in layout.out_idx), data))
    for name in ('j1', 'j2', 'j3'):
        m = tft.quaternion_matrix(got[name][3:])
        m[:3, 3] = got[name][:3]
        np.testing.assert_allclose(m, tree.joint_transform(name, r[name]), atol=1e-12)


def test_invalid_mimic_is_a_warning_not_a_failure():
    xml = MIMIC_CHAIN.replace('joint="j1" multiplier="-1"', 'joint="j2"')  # j2 <-> j3 cycle
    tree = KinematicTree.from_xml_string(xml)
    assert len(tree.warnings) == 2 and 'cycle' in tree.warnings[0]
    assert sorted(tree.active_joints) == ['j1', 'j2', 'j3']


def test_joint_types_floating_skipped_planar_fixed():
    xml = """<robot name="t"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
      <joint name="f" type="floating"><parent link="a"/><child link="b"/></joint>
      <joint name="p" type="planar"><parent link="a"/><child link="c"/><origin xyz="1 2 3"/></joint>
      <joint name="r" type="revolute"><parent link="b"/><child link="d"/><axis xyz="0 1 0"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"""
    tree = KinematicTree.from_xml_string(xml)
    assert tree.floating_joints == ['f'] and tree.static_joints == ['p'] and tree.moving_joints == ['r']
    assert set(tree.link_poses()) == {'a', 'c'}  # b and d hang below a floating joint
    assert 'r' in tree.joint_transforms({'r': 0.1})  # published relative to b, as robot_state_publisher
    np.testing.assert_allclose(tree.static_transforms()['p'][:3, 3], [1, 2, 3])


def test_limits_are_not_clamped_and_axis_normalised():
    xml = """<robot name="t"><link name="a"/><link name="b"/>
      <joint name="s" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="0 0 5"/>
        <limit lower="0" upper="0.1" effort="1" velocity="1"/></joint></robot>"""
    tree = KinematicTree.from_xml_string(xml)
    np.testing.assert_allclose(tree.link_poses({'s': 2.0})['b'][:3, 3], [0, 0, 2.0])


@pytest.mark.parametrize('xml, message', [
    ('', 'empty'),
    ('<robot', 'not valid XML'),
    ('<notarobot/>', 'expected <robot>'),
    ('<robot name="x"/>', 'no link'),
    ('<robot name="x"><link name="a"/><link name="b"/></robot>', 'exactly one root'),
    ('<robot name="x"><link name="a"/><joint name="j" type="fixed"><parent link="a"/><child link="z"/>'
     '</joint></robot>', 'unknown link'),
    ('<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="revolute"><parent link="a"/>'
     '<child link="b"/><axis xyz="0 0 0"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint>'
     '</robot>', 'invalid axis'),
])
def test_bad_descriptions_raise_clear_errors(xml, message):
    with pytest.raises(URDFError, match=message):
        KinematicTree.from_xml_string(xml)


def test_prefix_frame_like_robot_state_publisher():
    # observed from Debian's robot_state_publisher 1.15 with tf_prefix "pre" on fixtures/frames_and_slashes
    cases = {'link1': 'pre/link1', '/link2': 'link2', '//link3': '/link3', 'link4/': 'pre/link4/',
             '/link6/': 'link6/', '//li/nk10//': '/li/nk10//', 'li//nk13': 'pre/li//nk13'}
    for frame, want in cases.items():
        assert prefix_frame('pre', frame) == want
        assert prefix_frame('/pre', frame) == want
    assert prefix_frame('', 'link1') == 'link1' and prefix_frame('', '/link2') == 'link2'


def test_rpy_is_fixed_axis_xyz():
    xml = """<robot name="t"><link name="a"/><link name="b"/>
      <joint name="j" type="fixed"><parent link="a"/><child link="b"/><origin rpy="0.3 %r -0.7"/></joint>
      </robot>""" % (math.pi / 2 - 1e-9)
    tree = KinematicTree.from_xml_string(xml)
    assert_poses_equal(tree.link_poses(), reference_link_poses(xml, {}))


@pytest.mark.parametrize('seed', range(15))
def test_message_layout_equals_single_form(seed):
    """The node's per-message path: names in any order, duplicates, unknown names, fixed joints, explicit
    mimic values, mimics of mimics, against joint_transforms of the single form."""
    tree = KinematicTree.from_xml_string(random_urdf(seed, n_links=25, mimic_chains=True))
    plan = tree.transform_plan()
    rng = np.random.default_rng(seed)
    names = [n for n in plan.names if rng.random() < 0.7] + ['unknown_a'] + tree.static_joints[:1]
    rng.shuffle(names)
    if names:
        names.append(names[0])  # a duplicate: the first occurrence wins
    positions = rng.uniform(-10, 10, len(names))
    layout = plan.message_layout(tuple(names))
    assert layout.unknown == ['unknown_a']
    given = {}
    for n, v in zip(names, positions):
        if n in plan.index:
            given.setdefault(n, v)
    want = tree.joint_transforms(given)
    out = plan.message_transforms(layout, positions)
    assert sorted(plan.names[i] for i in layout.out_idx) == sorted(want)
    for k, i in enumerate(layout.out_idx):
        m = tft.quaternion_matrix(out[k, 3:])
        m[:3, 3] = out[k, :3]
        np.testing.assert_allclose(m, want[plan.names[i]], atol=1e-12)
        assert abs(np.linalg.norm(out[k, 3:]) - 1.0) < 1e-12


ONE_JOINT = """<robot name="t"><link name="a"/><link name="b"/>
  <joint name="elbow" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"""


@pytest.mark.parametrize('values, message', [
    (dict(rpy='0 inf 0'), "joint 'elbow': origin rpy must be finite numbers, got 0.0 inf 0.0"),
    (dict(xyz='nan 0 0'), "joint 'elbow': origin xyz must be finite numbers"),
    (dict(axis='0 0 -inf'), "joint 'elbow': axis must be finite numbers"),
])
def test_non_finite_numbers_are_refused_naming_the_joint(values, message):
    """Issue 12: rpy="0 inf 0" ended the node with 'math domain error'; NaN was published as NaN frames."""
    fields = dict(dict(xyz='0 0 0', rpy='0 0 0', axis='0 0 1'), **values)
    with pytest.raises(URDFError, match=message.replace('(', r'\(')):
        KinematicTree.from_xml_string(ONE_JOINT.format(**fields))


def test_non_finite_mimic_is_refused():
    xml = MIMIC_CHAIN.replace('multiplier="-1"', 'multiplier="nan"')
    with pytest.raises(URDFError, match="mimic multiplier and offset must be finite numbers"):
        KinematicTree.from_xml_string(xml)


def test_a_1500_joint_mimic_chain_loads_and_resolves():
    """Issue 12: RecursionError in TransformPlan.place (and a cubic mimic check) on such a chain."""
    tree = KinematicTree.from_xml_string(mimic_chain(1500, offset=0.001))
    assert tree.active_joints == ['j0'] and len(tree.mimic_joints) == 1499 and not tree.warnings
    r = tree.resolve_positions({'j0': 0.5})
    assert r['j1499'] == pytest.approx(0.5 + 1499 * 0.001)
    plan = tree.transform_plan()
    layout = plan.message_layout(('j0',))
    data = plan.message_transforms(layout, np.array([0.5]))
    assert len(data) == 1500 and np.isfinite(data).all()


def test_a_message_of_100000_unknown_names():
    """Issue 12: one JointState with 100,000 unknown names took 40 s (a list lookup per name)."""
    tree = KinematicTree.from_file(robot_path('ur5.urdf'))
    names = tuple('ghost_%d' % i for i in range(100000)) + ('shoulder_pan_joint',)
    layout = tree.transform_plan().message_layout(names)
    assert len(layout.unknown) == 100000 and layout.unknown[:2] == ['ghost_0', 'ghost_1']
    assert list(layout.out_idx) == [tree.transform_plan().index['shoulder_pan_joint']]


def _long_chain(n: int) -> str:
    joint = ('<link name="l{i}"/><joint name="j{i}" type="revolute"><parent link="l{p}"/><child link="l{i}"/>'
             '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>')
    joints = ''.join(joint.format(i=i, p=i - 1) for i in range(1, n))
    return f'<robot name="long"><link name="l0"/>{joints}</robot>'


def test_loading_grows_linearly_with_the_links():
    """Issue 40: 10,000 links took 7.7 s, 20,000 took 40.7 s (a membership test against a list). Building the tree of
    four times the links must take about four times as long, not sixteen (urdf_parser_py's own parse apart; this
    process's CPU time, best of three, so that a busy machine's other jobs do not count)."""
    import time
    from urdf_parser_py.urdf import URDF

    def seconds(n):
        robot = URDF.from_xml_string(_long_chain(n))
        best = float('inf')
        for _ in range(3):
            t = time.process_time()
            tree = KinematicTree.from_urdf(robot)
            best = min(best, time.process_time() - t)
        assert len(tree.links) == n
        return best
    small, large = seconds(4000), seconds(16000)
    assert large / small < 10, f'4,000 links {small:.3f} s, 16,000 links {large:.3f} s (quadratic: 16 times)'


def test_a_slide_beside_the_arm_is_no_finger():
    """The Fetch's torso bellows (a prismatic leaf on the torso, which carries the arm) was taken for a gripper joint,
    and arm_sim's gripper action moved it with the fingers; the slides of the hand at the arm's end, named so or not,
    are the fingers."""
    def joint(name, kind, parent, child, axis='0 0 1'):
        limit = '<limit lower="0" upper="0.4" effort="10" velocity="0.1"/>' if kind != 'fixed' else ''
        return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="0 0 0.1"/><axis xyz="{axis}"/>{limit}</joint>')
    links = ['base', 'torso', 'bellows', 'upper', 'fore', 'hand', 'left', 'right']
    xml = ('<robot name="fetchlike">' + ''.join(f'<link name="{n}"/>' for n in links)
           + joint('torso_lift', 'prismatic', 'base', 'torso') + joint('bellows', 'prismatic', 'torso', 'bellows')
           + joint('shoulder', 'revolute', 'torso', 'upper') + joint('elbow', 'revolute', 'upper', 'fore', '0 1 0')
           + joint('wrist', 'revolute', 'fore', 'hand') + joint('left_slide', 'prismatic', 'hand', 'left', '0 1 0')
           + joint('right_slide', 'prismatic', 'hand', 'right', '0 -1 0') + '</robot>')
    assert KinematicTree.from_xml_string(xml).finger_joints() == {'left_slide', 'right_slide'}
