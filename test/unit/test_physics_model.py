"""robot_ai.physics.model: any robot the package loads as a MuJoCo model. Its bodies stand where the package's own
kinematics (proven against robot_state_publisher) puts the links, on the reference robots with their real meshes, a
xacro and robots the package has never seen; inertias and effort limits from the URDF, or estimated and said;
servos that hold and track within the effort limits, gravity, mimic joints, a world. No rospy."""
from __future__ import annotations

import os
import re

import mujoco
import numpy as np
import pytest

from robot_ai.physics import PhysicsError, build_physics
from robot_ai.physics import model as physics_model
from robot_ai.reach.model import load_model

from exact_meshes import MESHES, ROBOTS

HERE = os.path.dirname(os.path.realpath(__file__))
TEST_URDF = os.path.join(HERE, '..', 'urdf')
REFERENCE = ['ur5.urdf', 'panda.urdf', 'kuka_lwr_arm.urdf', 'pr2.urdf']
UNSEEN = ['floating_body_arm.urdf', 'mimic_gripper.urdf', 'tilted_axis_arm.urdf', 'reach_arm7.urdf.xacro']
TABLE = [{'box': [2.0, 2.0, 0.05], 'position': [0, 0, -0.105], 'name': 'table'}]


@pytest.fixture(autouse=True)
def meshes(monkeypatch):
    monkeypatch.setenv('ROS_PACKAGE_PATH', os.pathsep.join((MESHES, os.environ.get('ROS_PACKAGE_PATH', ''))))


def robot(name: str):
    return load_model(os.path.join(ROBOTS if name in REFERENCE else TEST_URDF, name))


def pose(data, model, body: str) -> np.ndarray:
    b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    out = np.identity(4)
    out[:3, :3], out[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
    return out


@pytest.mark.parametrize('name', REFERENCE + UNSEEN)
def test_every_body_stands_where_the_package_kinematics_puts_its_link(name):
    """At 20 random configurations within the limits (mimic joints following their source), each body's pose equals
    the link's pose by the package's kinematics (robot_state_publisher's), relative to the root or to a floating
    base, to 1e-9."""
    r = robot(name)
    tree, physics = r.tree, build_physics(r)
    data = physics.data()
    ref = tree.floating_base() or tree.root
    rng = np.random.default_rng(0)
    for _ in range(20):
        given = {}
        for n in tree.active_joints:
            j = tree.joints[n]
            lo, hi = (j.lower, j.upper) if j.type != 'continuous' and j.lower is not None else (-np.pi, np.pi)
            given[n] = rng.uniform(lo, hi)
        positions = tree.resolve_positions(given)
        for n, v in positions.items():
            data.qpos[physics.qpos_address(n)] = v
        mujoco.mj_kinematics(physics.model, data)
        expected = tree.link_poses(positions, base=ref)
        base = np.linalg.inv(pose(data, physics.model, ref))
        for link, t in expected.items():
            np.testing.assert_allclose(base @ pose(data, physics.model, link), t, atol=1e-9, err_msg=f'{name} {link}')


def test_inertias_are_the_urdfs_else_estimated_from_the_geometry_and_said():
    """The UR5's URDF gives its links' masses: the model has them. The Panda's gives none: estimated from its real
    collision meshes (a link of a few kilograms), said in one note. Moving links with neither (the package's own
    UR5 file) get the body model's stand-in capsules and their mass from them: an arm of kilograms, said."""
    ur5 = build_physics(robot('ur5.urdf'))
    mass = {mujoco.mj_id2name(ur5.model, mujoco.mjtObj.mjOBJ_BODY, b): ur5.model.body_mass[b]
            for b in range(ur5.model.nbody)}
    assert mass['shoulder_link'] == pytest.approx(3.7) and mass['forearm_link'] == pytest.approx(2.275)
    assert not any('estimated' in n for n in ur5.notes)
    panda = build_physics(robot('panda.urdf'))
    link4 = mujoco.mj_name2id(panda.model, mujoco.mjtObj.mjOBJ_BODY, 'panda_link4')
    assert 0.5 < panda.model.body_mass[link4] < 10
    assert [n for n in panda.notes if n.startswith('inertias estimated from the collision geometry')]
    gripper = build_physics(robot('mimic_gripper.urdf'))
    assert any(n.startswith('no inertial and no collision geometry for 3 moving links, stood in for by capsules')
               for n in gripper.notes)
    assert all(gripper.model.body_mass[gripper.model.jnt_bodyid] > 0)
    bare = build_physics(load_model(os.path.join(HERE, '..', '..', 'urdf', 'ur5_arm.urdf')))
    assert any(n.startswith('no inertial and no collision geometry for 6 moving links') for n in bare.notes)
    assert 5 < bare.model.body_mass.sum() < 100


def test_effort_limits_bound_the_servos_and_transmissions_do_not_hide_them():
    """Each servo's force range is its joint's URDF effort; the PR2's <transmission> blocks name the joints again
    (no limit there), which must not hide the limits."""
    pr2 = build_physics(robot('pr2.urdf'))
    torso = pr2.actuated.index('torso_lift_joint')
    np.testing.assert_array_equal(pr2.model.actuator_forcerange[torso], [-10000, 10000])
    assert pr2.model.actuator_forcelimited[torso]
    with open(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf')) as f:
        text = re.sub(r'effort="[^"]*"', 'effort="0"', f.read())
    kuka = build_physics(load_model(urdf=text))                # a URDF with no effort: said, unlimited
    assert any(n.startswith('no effort limit in the URDF for 7 joints') for n in kuka.notes)
    assert not kuka.model.actuator_forcelimited.any() and not kuka.model.jnt_actfrclimited.any()


@pytest.mark.parametrize('name', ['ur5.urdf', 'panda.urdf', 'kuka_lwr_arm.urdf'])
def test_the_servos_hold_home_under_gravity_and_track_a_step_within_the_effort_limits(name):
    physics = build_physics(robot(name))
    model, data = physics.model, physics.data()
    home = physics.joint_positions(data, physics.actuated)
    for _ in range(500):
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(physics.joint_positions(data, physics.actuated), home, atol=1e-3)
    target = np.clip(home + 0.2, model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1])
    target = np.where(model.actuator_ctrllimited, target, home + 0.2)
    data.ctrl[:] = target
    limited = model.actuator_forcelimited.astype(bool)
    for _ in range(1000):                                   # 2 s
        mujoco.mj_step(model, data)
        force = data.actuator_force[limited]
        assert (np.abs(force) <= model.actuator_forcerange[limited, 1] + 1e-9).all()
    np.testing.assert_allclose(physics.joint_positions(data, physics.actuated), target, atol=2e-3)


def test_gravity_pulls_an_arm_whose_joints_are_too_weak():
    """The joints hold the arm's weight within their effort (servo and weight together): with a tenth of a
    newton-metre each, the UR5 stretched out falls."""
    physics = build_physics(robot('ur5.urdf'))
    model, data = physics.model, physics.data()
    assert model.jnt_actfrclimited.all()
    model.jnt_actfrcrange[:] = [-0.1, 0.1]
    home = physics.joint_positions(data, physics.actuated)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.abs(physics.joint_positions(data, physics.actuated) - home).max() > 0.1


def test_a_mimic_joint_follows_its_source():
    """finger_joint2 mimics finger_joint1 with multiplier -1: driven by one servo, it follows by the constraint."""
    physics = build_physics(robot('mimic_gripper.urdf'))
    model, data = physics.model, physics.data()
    assert 'finger_joint2' not in physics.actuated and model.neq == 1
    k = physics.actuated.index('finger_joint1')
    lo, hi = model.actuator_ctrlrange[k]
    data.ctrl[k] = lo + 0.7 * (hi - lo)
    for _ in range(1000):
        mujoco.mj_step(model, data)
    one, two = physics.joint_positions(data, ['finger_joint1', 'finger_joint2'])
    assert one == pytest.approx(data.ctrl[k], abs=2e-3) and two == pytest.approx(-one, abs=1e-3)


def test_the_world_stops_the_arm_and_bad_input_is_one_line():
    """Driven down through the table at its servos' full speed, the UR5's real meshes hit it, 2 cm into it at the
    impact at most, and rest on it (1 mm into it at most), held above where the servos ask it to go."""
    home = {'shoulder_lift_joint': -1.57, 'elbow_joint': 1.57, 'wrist_1_joint': -1.57, 'wrist_2_joint': 1.57}
    physics = build_physics(robot('ur5.urdf'), obstacles=TABLE, home=home)
    model, data = physics.model, physics.data()
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, 'table') >= 0
    data.ctrl[physics.actuated.index('shoulder_lift_joint')] = 0.3       # the upper arm down past level
    data.ctrl[physics.actuated.index('elbow_joint')] = 1.0
    deepest = []
    for _ in range(1500):
        mujoco.mj_step(model, data)
        deepest.append(data.contact.dist.min() if data.ncon else 0.0)
    assert min(deepest) < 0 and min(deepest) > -0.02 and min(deepest[-500:]) > -0.001, min(deepest)
    assert physics.joint_positions(data, ['shoulder_lift_joint'])[0] < 0.3 - 0.1      # held up by the table
    assert not any(n.startswith('at home the robot touches') for n in physics.notes)
    low = build_physics(robot('ur5.urdf'), obstacles=[{'box': [2, 2, 0.05], 'position': [0, 0, 0.0], 'name': 'slab'}],
                        home=home)                          # the table's top through the base: said
    assert any(n.startswith('at home the robot touches shoulder_link - slab') for n in low.notes), low.notes
    with pytest.raises(PhysicsError, match='obstacle 0: give one of') as e:
        build_physics(robot('ur5.urdf'), obstacles=[{'cone': 1}])
    assert '\n' not in str(e.value)
    with pytest.raises(PhysicsError, match='home names joints the robot does not move: nose'):
        build_physics(robot('ur5.urdf'), home={'nose': 1.0})
    with pytest.raises(PhysicsError, match='is not a link'):
        build_physics(robot('ur5.urdf'), obstacles=TABLE, base='nowhere')


def test_a_model_is_kept_by_content_and_each_caller_gets_its_own_copy():
    physics_model._CACHE.clear()
    first = build_physics(robot('kuka_lwr_arm.urdf'), obstacles=TABLE)
    second = build_physics(robot('kuka_lwr_arm.urdf'), obstacles=TABLE)
    assert len(physics_model._CACHE) == 1 and first.notes == second.notes
    first.model.opt.gravity[:] = 0
    assert second.model.opt.gravity[2] == pytest.approx(-9.81)
    build_physics(robot('kuka_lwr_arm.urdf'))                              # another world: another model
    assert len(physics_model._CACHE) == 2


def test_loose_objects_rest_on_the_table_and_the_arm_pushes_them():
    """A block (from the obstacles' own YAML file, its objects key) settles on the table top, and the UR5's pan
    through it knocks it away: the arm's real meshes meet the objects."""
    ur5 = robot('ur5.urdf')
    home = {'shoulder_lift_joint': -1.0, 'elbow_joint': 1.6, 'wrist_1_joint': -2.1, 'wrist_2_joint': -1.57}
    tip = ur5.tree.link_poses(home)['tool0'][:3, 3]
    turn, radius = np.arctan2(tip[1], tip[0]) + 0.4, np.hypot(tip[0], tip[1])
    world = physics_model.read_yaml(
        'obstacles:\n  - {box: [2.0, 2.0, 0.05], position: [0, 0, -0.105], name: table}\n'
        f'objects:\n  - {{box: [0.06, 0.06, 0.3], position: [{radius * np.cos(turn)}, {radius * np.sin(turn)}, 0.0701],'
        f' mass: 0.3, friction: 0.8, name: block}}\n', 'world')
    physics = build_physics(ur5, obstacles=world['obstacles'], objects=world['objects'], home=home)
    model, data = physics.model, physics.data()
    assert physics.objects == ('block',)
    block = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, 'block')
    assert model.geom_friction[block, 0] == 0.8 and model.body_mass[model.geom_bodyid[block]] == pytest.approx(0.3)
    for _ in range(500):
        mujoco.mj_step(model, data)
    settled = physics.object_pose(data, 'block')
    assert settled[2, 3] == pytest.approx(-0.08 + 0.15, abs=1e-3) and settled[2, 2] > 0.999    # upright on the top
    data.ctrl[physics.actuated.index('shoulder_pan_joint')] = 0.8
    for _ in range(1500):
        mujoco.mj_step(model, data)
    assert np.linalg.norm(physics.object_pose(data, 'block')[:3, 3] - settled[:3, 3]) > 0.05


def test_objects_from_text_and_their_errors_in_one_line(tmp_path):
    path = tmp_path / 'world.yaml'
    path.write_text('objects:\n  - {cylinder: [0.03, 0.1], position: [0.5, 0, 0.05]}\n  - {sphere: 0.02}\n')
    can, ball = physics_model.parse_objects(str(path))
    assert (can.kind, can.size, can.mass, ball.kind, ball.name) == ('cylinder', (0.03, 0.1), 0.1, 'sphere',
                                                                     'object 1 (sphere)')
    for bad, says in (([{'cone': 1}], 'give one of box'), ([{'box': [1, 1]}], 'box must be 3 finite numbers'),
                      ([{'sphere': 0.1, 'mass': 0}], 'must be positive'), ([{'sphere': 0.1, 'colour': 1}],
                                                                           'unknown keys'),
                      ([{'sphere': 0.1, 'name': 'a'}, {'sphere': 0.1, 'name': 'a'}], "the name 'a' is taken"),
                      ({'sphere': 0.1}, 'must be a list')):
        with pytest.raises(PhysicsError, match=says) as e:
            build_physics(robot('kuka_lwr_arm.urdf'), objects=bad)
        assert '\n' not in str(e.value)
    with pytest.raises(PhysicsError, match="both named 'table'"):
        build_physics(robot('kuka_lwr_arm.urdf'), obstacles=TABLE, objects=[{'sphere': 0.1, 'name': 'table'}])


def test_each_kind_of_object_is_built_at_its_size_and_rests_on_the_table():
    """A box, a sphere and a cylinder (a sphere among them failed to build once: the cylinder's length was read of
    every object): MuJoCo's half sizes, and each settles on the table, its lowest point on the top."""
    physics = build_physics(robot('kuka_lwr_arm.urdf'), obstacles=TABLE, objects=[
        {'box': [0.04, 0.06, 0.08], 'position': [0.5, 0.2, 0.0], 'name': 'box'},
        {'sphere': 0.03, 'position': [0.5, -0.2, 0.0], 'name': 'ball'},
        {'cylinder': [0.025, 0.1], 'position': [0.6, 0.0, 0.0], 'name': 'can'}])
    model, data = physics.model, physics.data()
    size = {n: model.geom_size[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n)] for n in physics.objects}
    np.testing.assert_allclose(size['box'], [0.02, 0.03, 0.04])
    assert size['ball'][0] == 0.03 and tuple(size['can'][:2]) == (0.025, 0.05)
    for _ in range(500):
        mujoco.mj_step(model, data)
    top = TABLE[0]['position'][2] + TABLE[0]['box'][2] / 2
    for name, half in (('box', 0.04), ('ball', 0.03), ('can', 0.05)):
        assert physics.object_pose(data, name)[2, 3] == pytest.approx(top + half, abs=2e-3), name


def test_the_gripper_is_the_finger_joints_the_package_detects():
    """The Panda's hand: one servo (its second finger mimics the first, by the constraint); an arm without a hand
    has none."""
    panda = build_physics(robot('panda.urdf'))
    assert panda.gripper == ('panda_finger_joint1',) and panda.model.neq == 1
    assert build_physics(robot('ur5.urdf')).gripper == ()
    model, data = panda.model, panda.data()
    data.ctrl[panda.actuated.index('panda_finger_joint1')] = 0.035
    for _ in range(1000):
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(panda.joint_positions(data, ['panda_finger_joint1', 'panda_finger_joint2']), 0.035,
                               atol=1e-3)


def test_an_inertia_that_is_not_positive_definite_is_made_so_and_said():
    """The Fetch's fingers have a principal moment of 0 (MuJoCo refuses the model: 'inertia must have positive
    eigenvalues'): the nearest positive definite inertia, said in a note; a physical one is left as it is."""
    good = np.array([0.02, 0.03, 0.04, 0.001, 0.0, 0.0])
    assert physics_model._positive(good) is good
    flat = np.array([1e-4, 1e-4, 0.0, 0.0, 0.0, 0.0])
    fixed = physics_model._positive(flat)
    assert np.allclose(fixed[:2], 1e-4) and fixed[2] >= 1e-10 and np.all(np.linalg.eigvalsh(np.array(
        [[fixed[0], fixed[3], fixed[4]], [fixed[3], fixed[1], fixed[5]], [fixed[4], fixed[5], fixed[2]]])) > 0)
    urdf = ('<robot name="thin"><link name="base"/><link name="finger"><inertial><mass value="0.1"/>'
            '<inertia ixx="1e-4" iyy="1e-4" izz="0" ixy="0" ixz="0" iyz="0"/></inertial></link>'
            '<joint name="slide" type="prismatic"><parent link="base"/><child link="finger"/><axis xyz="0 1 0"/>'
            '<limit lower="0" upper="0.05" effort="60" velocity="0.05"/></joint></robot>')
    physics = build_physics(load_model(urdf=urdf))
    assert any('not positive definite made so' in n and 'finger' in n for n in physics.notes)
