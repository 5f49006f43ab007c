"""robot_ai.physics.sim: an arm in MuJoCo driven by position targets as ros_control drives one: it tracks a
trajectory with a tracking error a kinematic sim never has, within the effort limits, reports efforts that hold the
arm's weight, a payload sags it, and set_state places it at once. No rospy."""
from __future__ import annotations

import copy
import os

import numpy as np
import pytest

from robot_ai.physics import PhysicsError, build_physics
from robot_ai.physics.sim import ArmPhysics
from robot_ai.reach.model import load_model

from exact_meshes import MESHES, ROBOTS

PANDA = os.path.join(ROBOTS, 'panda.urdf')
HOME = {'shoulder_lift_joint': -1.57, 'elbow_joint': 1.57, 'wrist_1_joint': -1.57, 'wrist_2_joint': 1.57}


@pytest.fixture(autouse=True)
def meshes(monkeypatch):
    monkeypatch.setenv('ROS_PACKAGE_PATH', os.pathsep.join((MESHES, os.environ.get('ROS_PACKAGE_PATH', ''))))


def ur5(**kwargs):
    return build_physics(load_model(os.path.join(ROBOTS, 'ur5.urdf')), home=HOME, **kwargs)


def test_a_trajectory_is_tracked_with_an_error_that_ends_within_the_effort_limits():
    """A quintic move of the shoulder and the elbow by 0.5 rad in 1 s, a target every 10 ms: during it the arm lags
    (a real servo's tracking error, some milliradians), at its end it settles on the target; each step's effort
    within the URDF's."""
    physics = ur5()
    joints = list(physics.actuated)
    arm = ArmPhysics(physics, joints)
    start = arm.positions
    end = start + np.array([0, 0.5, -0.5, 0, 0, 0])
    lags, limit = [], physics.model.jnt_actfrcrange[physics.model.actuator_trnid[:, 0], 1]
    for k in range(1, 151):
        s = min(k / 100, 1.0)
        target = start + (end - start) * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
        assert arm.step(target, 0.01) == 5
        lags.append(np.abs(arm.positions - target).max())
        assert (np.abs(arm.efforts) <= limit + 1e-9).all()
    assert 1e-3 < max(lags[:100]) < 0.1 and lags[-1] < 1e-3
    np.testing.assert_allclose(arm.positions, end, atol=1e-3)
    assert arm.time == pytest.approx(1.5)


def test_efforts_hold_the_weight_and_a_payload_sags_the_arm():
    """Stretched out, the shoulder's effort is the arm's weight times its reach (tens of N m; none for the pan); a
    2 kg block laid on the wrist sags it by the payload over the servo's stiffness."""
    home = {'shoulder_lift_joint': 0.0, 'elbow_joint': 0.0, 'wrist_1_joint': 0.0}
    bare = ArmPhysics(build_physics(load_model(os.path.join(ROBOTS, 'ur5.urdf')), home=home),
                      ['shoulder_pan_joint', 'shoulder_lift_joint'])
    bare.step(bare.targets, 0.5)
    pan, lift = bare.efforts
    assert abs(pan) < 0.1 and 20 < abs(lift) < 150
    tip = load_model(os.path.join(ROBOTS, 'ur5.urdf')).tree.link_poses(home)['wrist_1_link'][:3, 3]
    loaded = ArmPhysics(build_physics(load_model(os.path.join(ROBOTS, 'ur5.urdf')), home=home, objects=[
        {'box': [0.05, 0.05, 0.05], 'position': (tip + [0, 0, 0.1]).tolist(), 'mass': 2.0, 'name': 'payload'}]),
        ['shoulder_pan_joint', 'shoulder_lift_joint'])
    loaded.step(loaded.targets, 1.0)
    assert loaded.object_poses()['payload'][2, 3] > tip[2]              # it lies on the arm, not through it
    assert abs(loaded.efforts[1]) > abs(lift) + 5.0                     # the payload's weight at its reach
    assert abs(loaded.positions[1] - bare.positions[1]) > 1e-4          # and the shoulder gives under it


def test_set_state_places_the_arm_at_rest_and_bad_input_is_one_line():
    physics = build_physics(load_model(os.path.join(ROBOTS, 'panda.urdf')))
    joints = [n for n in physics.actuated if n != 'panda_finger_joint1'] + ['panda_finger_joint1']
    arm = ArmPhysics(physics, joints)
    state = arm.positions + np.array([0.1] * 7 + [0.01])                # the fingers from 0.02 to 0.03 m
    arm.set_state(state)
    np.testing.assert_allclose(arm.positions, state)
    assert not arm.velocities.any()
    arm.step(state, 0.5)
    np.testing.assert_allclose(arm.positions, state, atol=1e-3)          # held there, the second finger too
    assert physics.joint_positions(arm.data, ['panda_finger_joint2'])[0] == pytest.approx(state[-1], abs=1e-3)
    with pytest.raises(PhysicsError, match='a target is 8 finite positions'):
        arm.step([0.0] * 7, 0.01)
    with pytest.raises(PhysicsError, match='a state is 8 finite positions'):
        arm.set_state([float('nan')] * 8)
    with pytest.raises(PhysicsError, match="panda_finger_joint2: not joints the model's servos drive"):
        ArmPhysics(physics, ['panda_finger_joint2'])


PANDA_HOME = {'panda_joint4': -2.3, 'panda_joint6': 2.3, 'panda_joint7': 0.785, 'panda_finger_joint1': 0.04}
TABLE = [{'box': [0.4, 0.4, 0.02], 'position': [0.512, 0, 0.215], 'name': 'table'}]     # its top at 0.225


def cube_in_the_hand(edge: float):
    """The Panda's hand open over a table, a cube of edge on the table between its fingers (its real meshes)."""
    physics = build_physics(load_model(os.path.join(ROBOTS, 'panda.urdf')), home=PANDA_HOME, obstacles=TABLE,
                            objects=[{'box': [edge] * 3, 'position': [0.512, 0, 0.226 + edge / 2], 'name': 'cube'}])
    arm = ArmPhysics(physics, [n for n in physics.actuated if n not in physics.gripper])
    arm.step(arm.targets, 0.2)
    return arm


@pytest.mark.parametrize('edge', [0.02, 0.04])
def test_the_gripper_closes_on_a_cube_squeezes_it_with_the_effort_asked_and_the_arm_lifts_it(edge):
    """grip(0, 10 N): the fingers close at their velocity limit and stall on the cube (the wider cube further open),
    the finger's effort the 10 N asked for; the forearm raised, the cube rises with the hand; grip(open) lets it go:
    reached, and it falls back to the table."""
    arm = cube_in_the_hand(edge)
    rest = arm.object_poses()['cube'][:3, 3]
    assert arm.gripper == ('panda_finger_joint1',) and arm.gripper_outcome() is None
    assert arm.grip(0.0, 10.0) == 0.0
    positions = []
    for _ in range(100):
        arm.step(arm.targets, 0.01)
        positions.append(arm.gripper_state()[0])
        if arm.gripper_outcome() is not None:
            break
    assert arm.gripper_outcome() == (False, True)                # stalled: held short of closed
    position, _, effort = arm.gripper_state()
    assert edge / 2 - 0.01 < position < edge / 2 + 0.005 and effort == pytest.approx(-10.0, abs=0.1)
    speeds = np.abs(np.diff(positions)) / 0.01
    assert speeds.max() <= 0.2 * 1.2                             # the finger's URDF velocity limit, and a little
    up = arm.targets
    up[arm.joints.index('panda_joint4')] += 0.3
    for k in range(1, 101):
        arm.step(arm.targets + (up - arm.targets) * k / 100, 0.01)
    arm.step(up, 0.5)
    assert arm.object_poses()['cube'][2, 3] > rest[2] + 0.1       # lifted with the hand
    assert arm.grip(1.0) == pytest.approx(0.04)                   # clipped to the finger's range
    for _ in range(100):
        arm.step(up, 0.01)
        if arm.gripper_outcome() is not None:
            break
    assert arm.gripper_outcome() == (True, False)
    arm.step(up, 1.0)
    assert arm.object_poses()['cube'][2, 3] < rest[2] + 0.005     # let go: on the table again


def test_a_gripper_command_overrides_the_arm_targets_until_set_state_and_bad_ones_are_one_line():
    physics = build_physics(load_model(os.path.join(ROBOTS, 'panda.urdf')), home=PANDA_HOME)
    arm = ArmPhysics(physics, list(physics.actuated))              # the finger among the joints commanded
    arm.grip(0.01)
    arm.step(arm.targets, 0.5)                                     # the targets say 0.04 for the finger: not taken
    assert arm.gripper_state()[0] == pytest.approx(0.01, abs=1e-3)
    arm.set_state(arm.positions[:-1].tolist() + [0.03])           # placed: the gripper command ends
    arm.step(arm.targets, 0.5)
    assert arm.gripper_state()[0] == pytest.approx(0.03, abs=1e-3) and arm.gripper_outcome() is None
    with pytest.raises(PhysicsError, match='a gripper command is a finite position and effort'):
        arm.grip(float('nan'))
    ur5 = ArmPhysics(build_physics(load_model(os.path.join(ROBOTS, 'ur5.urdf')), home=HOME), ['shoulder_pan_joint'])
    with pytest.raises(PhysicsError, match='the arm has no gripper'):
        ur5.grip(0.0)


def test_a_gripper_command_takes_every_finger_joint_to_the_same_share_of_its_own_range():
    """A hand of independent finger joints with different ranges (a Kinova JACO2: its fingers close to 1.51 rad,
    their tips to 2): the command is the first joint's position, and every other joint goes to the same share of its
    own range (each clipped to its range, the tips closed only to 1.51 with the fingers, where the envs, which command
    each joint, close them to 2: a grasp the policy never learned)."""
    link = ('<link name="{0}"><inertial><origin xyz="0 0 0.03"/><mass value="0.05"/><inertia ixx="2e-5" iyy="2e-5" '
            'izz="2e-6" ixy="0" ixz="0" iyz="0"/></inertial><collision><origin xyz="0 0 0.03"/><geometry><box '
            'size="0.01 0.01 0.06"/></geometry></collision></link>')
    joint = ('<joint name="{0}" type="revolute"><parent link="{1}"/><child link="{2}"/><origin xyz="0 0 {3}"/>'
             '<axis xyz="0 1 0"/><limit lower="0" upper="{4}" effort="5" velocity="2"/></joint>')
    xml = ('<robot name="hand"><link name="palm"/>' + link.format('finger') + link.format('tip') +
           joint.format('finger_joint', 'palm', 'finger', 0.0, 1.51) +
           joint.format('finger_tip_joint', 'finger', 'tip', 0.06, 2.0) + '</robot>')
    physics = build_physics(load_model(urdf=xml))
    assert physics.gripper == ('finger_joint', 'finger_tip_joint')
    arm = ArmPhysics(physics, [])
    for position, tip in ((1.51, 2.0), (0.755, 1.0), (0.0, 0.0), (5.0, 2.0)):
        assert arm.grip(position) == pytest.approx(min(position, 1.51))
        arm.step([], 1.5)
        k = [physics.actuated.index(n) for n in physics.gripper]
        np.testing.assert_allclose(arm.data.ctrl[k], [min(position, 1.51), tip], atol=1e-9)

def test_a_joint_the_urdf_damps_heavily_still_follows_its_target():
    """The Fetch's wrist roll: damping 5 N m s/rad on a link of grams. Its servo, tuned for the inertia alone, lagged
    its target by seconds; with the damping counted it goes at what its effort limit can drive through the damping
    (7.36 / 5 rad/s) and is there within 0.3 s."""
    xml = ('<robot name="wrist"><link name="base"/><link name="roll"><inertial><mass value="0.1"/>'
           '<inertia ixx="0.0001" ixy="0" ixz="0" iyy="0.0001" iyz="0" izz="0.0001"/></inertial>'
           '<collision><geometry><box size="0.02 0.02 0.02"/></geometry></collision></link>'
           '<joint name="roll" type="continuous"><parent link="base"/><child link="roll"/><axis xyz="1 0 0"/>'
           '<limit effort="7.36" velocity="2.268"/><dynamics damping="5.0"/></joint></robot>')
    arm = ArmPhysics(build_physics(load_model(urdf=xml)), ['roll'])
    arm.step([0.3], 0.3)
    assert abs(arm.positions[0] - 0.3) < 0.3 * 0.02


def test_an_object_is_set_at_rest_and_its_state_is_the_envs():
    """set_object puts a loose object at a pose at rest; object_states gives its pose and its velocity in the world
    frame (MuJoCo's mj_objectVelocity) after a step; an unknown object or a pose that is not one is one line."""
    import mujoco
    physics = build_physics(load_model(PANDA), objects=[{'box': [0.04] * 3, 'position': [0.5, 0.0, 0.5],
                                                         'mass': 0.1, 'name': 'cube'}])
    arm = ArmPhysics(physics, ['panda_joint1'])
    half = np.sqrt(0.5)
    arm.set_object('cube', [0.4, 0.1, 0.6], [half, 0.0, 0.0, half])
    position, q, velocity = arm.object_states()['cube']
    np.testing.assert_array_equal(position, [0.4, 0.1, 0.6])
    np.testing.assert_allclose(q, [half, 0.0, 0.0, half])
    np.testing.assert_array_equal(velocity, np.zeros(6))
    arm.data.qvel[-3:] = [0.0, 2.0, 0.0]           # a spin about its own y, which is the world's -x
    arm.step(arm.positions, 0.01)
    position, q, velocity = arm.object_states()['cube']
    body = mujoco.mj_name2id(arm.model, mujoco.mjtObj.mjOBJ_BODY, 'cube')
    np.testing.assert_array_equal(position, arm.data.xpos[body])   # the bodies of the joints as they now stand
    res, now = np.zeros(6), copy.copy(arm.data)
    mujoco.mj_forward(arm.model, now)              # mj_step leaves its velocities a step behind
    mujoco.mj_objectVelocity(arm.model, now, mujoco.mjtObj.mjOBJ_BODY, body, res, 0)
    np.testing.assert_allclose(velocity, [*res[3:], *res[:3]], atol=1e-12)
    assert velocity[3] < -1.0                      # about the world's -x
    with pytest.raises(PhysicsError, match="no object 'ball'"):
        arm.set_object('ball', [0, 0, 0], [1, 0, 0, 0])
    with pytest.raises(PhysicsError, match='unit quaternion'):
        arm.set_object('cube', [0, 0, 0], [0, 0, 0, 0])
