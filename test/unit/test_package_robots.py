"""The package's own robots (urdf/) against the reference robots in ../shared/robots: the same frames for
every shared link at random configurations, and the zero poses of SOURCES.md."""
import math
import os

import numpy as np
import pytest

from fk_helpers import robot_path
from robot_ai.kinematics import KinematicTree

HERE = os.path.dirname(os.path.realpath(__file__))
URDF_DIR = os.path.join(HERE, '..', '..', 'urdf')


@pytest.mark.parametrize('ours, reference, root, tip, zero', [
    ('ur5_arm.urdf', 'ur5.urdf', 'base_link', 'tool0', (0.81725, 0.19145, -0.00549)),
    ('kuka_lwr_arm.urdf', 'kuka_lwr_arm.urdf', 'world_link', 'lwr_arm_7_link', (0.0, 0.0, 1.3785)),
])
def test_package_robot_matches_reference(ours, reference, root, tip, zero):
    mine = KinematicTree.from_file(os.path.join(URDF_DIR, ours))
    ref = KinematicTree.from_file(robot_path(reference))
    assert mine.root == root and mine.active_joints == ref.active_joints
    np.testing.assert_allclose(mine.link_poses()[tip][:3, 3], zero, atol=1e-5)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = {n: float(rng.uniform(-3, 3)) for n in mine.active_joints}
        a, b = mine.link_poses(q), ref.link_poses(q)
        shared = set(a) & set(b)
        assert tip in shared and len(shared) >= len(mine.active_joints) + 2
        for link in shared:
            np.testing.assert_allclose(a[link], b[link], atol=1e-9, err_msg=link)
    for n in mine.active_joints:
        assert (mine.joints[n].lower, mine.joints[n].upper) == (ref.joints[n].lower, ref.joints[n].upper)


@pytest.mark.parametrize('urdf, tip', [
    (os.path.join(URDF_DIR, 'ur5_arm.urdf'), 'tool0'),
    (os.path.join(URDF_DIR, 'kuka_lwr_arm.urdf'), 'lwr_arm_7_link'),
    (robot_path('ur5.urdf'), 'tool0'),                  # ROS-Industrial's tool frame, not flange or wrist_3_link
    (robot_path('kuka_lwr_arm.urdf'), 'lwr_arm_7_link'),   # no tool frame: the last link
    (robot_path('panda.urdf'), 'panda_hand'),           # 7 arm joints; the fingers' slides are not the arm's
    (robot_path('pr2.urdf'), 'r_gripper_tool_frame'),   # two arms: the first one's tool frame, not a finger tip
    (os.path.join(HERE, '..', 'urdf', 'mimic_gripper.urdf'), 'wrist'),
])
def test_the_default_tip_is_the_arms_end_not_a_finger(urdf, tip):
    """Issue 38: the default tip (demo_client's tip_frame, reach's tip) was a finger on nearly every real robot.
    Whatever the robot, it lies below the most arm joints (moving, not mimic, not a hand's), never below a finger
    joint."""
    tree = KinematicTree.from_file(urdf)
    found = tree.end_effector()
    assert found == tip
    fingers = tree.finger_joints()
    parent_joint = {j.child: n for n, j in tree.joints.items()}

    def arm_joints(link):
        n = 0
        while link in parent_joint:
            name = parent_joint[link]
            if name in fingers:
                return -1                    # below a finger
            n += name in tree.active_joints
            link = tree.joints[name].parent
        return n
    assert arm_joints(found) == max(arm_joints(link) for link in tree.links)
    assert not any(tree.joints[n].type == 'prismatic' and 'finger' in n for n in tree.active_joints
                   if n not in fingers)


def test_every_arm_of_a_two_armed_robot_is_listed_and_reach_says_so():
    tree = KinematicTree.from_file(robot_path('pr2.urdf'))
    assert tree.end_effectors() == ['r_gripper_tool_frame', 'l_gripper_tool_frame']
    assert {'r_gripper_joint', 'l_gripper_joint', 'r_gripper_l_finger_joint'} <= tree.finger_joints()
    from robot_ai.reach import Arm
    arm = Arm(tree)
    assert arm.tip == 'r_gripper_tool_frame' and arm.n == 8
    assert any('the right arm' in w and 'l_gripper_tool_frame (left arm)' in w for w in arm.warnings), arm.warnings
    assert Arm(tree, tip='l_gripper_tool_frame').warnings == []     # a tip given: nothing to say


def two_arms(sides, extra):
    """A torso with two 5-joint arms, Pepper's shape: sides are the joints' prefixes ('L', 'R' or 'left_', ...),
    each arm's last link {s}_wrist ({s}: the prefix's first letter, lower case); extra: {link: (joint type, parent)}
    below each arm, formatted with S (the prefix) and s."""
    body = '<link name="torso"/>'
    for side in sides:
        s, parent = side[0].lower(), 'torso'
        for k, joint in enumerate(('ShoulderPitch', 'ShoulderRoll', 'ElbowYaw', 'ElbowRoll', 'WristYaw')):
            child = f'{side}{joint}_link' if k < 4 else f'{s}_wrist'
            body += (f'<link name="{child}"/><joint name="{side}{joint}" type="revolute"><parent link="{parent}"/>'
                     f'<child link="{child}"/><origin xyz="0.1 {0.15 if s == "l" else -0.15} 0"/>'
                     f'<axis xyz="{"0 1 0" if k % 2 == 0 else "0 0 1"}"/>'
                     f'<limit lower="-2" upper="2" effort="1" velocity="1"/></joint>')
            parent = child
        for link, (kind, above) in extra.items():
            link, above = link.format(S=side, s=s), above.format(S=side, s=s)
            body += (f'<link name="{link}"/><joint name="{link}_joint" type="{kind}"><parent link="{above}"/>'
                     f'<child link="{link}"/><origin xyz="0.03 0 0"/><axis xyz="1 0 0"/>'
                     f'<limit lower="0" upper="1" effort="1" velocity="1"/></joint>')
    return KinematicTree.from_xml_string(f'<robot name="two_arms">{body}</robot>')


def test_a_touch_sensors_frame_on_the_wrist_is_not_the_tip():
    """Issue 57: on Pepper the default tip was LHandTouchBack_frame, a touch sensor's frame fixed to the wrist
    (pepper_description), not the hand: a sensor's frame is a tip only where nothing else is left."""
    from robot_ai.reach import Arm
    tree = two_arms(['L', 'R'], {'{S}HandTouchBack_frame': ('fixed', '{s}_wrist'),
                                 '{S}HandTouchLeft_frame': ('fixed', '{s}_wrist'),
                                 '{s}_gripper': ('revolute', '{s}_wrist')})       # Pepper's LHand: the hand opens
    assert tree.end_effectors() == ['l_wrist', 'r_wrist']
    arm = Arm(tree)
    assert arm.tip == 'l_wrist' and arm.n == 5
    # a grasp frame, when the file has one (pepper_moveit_config's l_grasp_link), is the tip
    tree = two_arms(['L', 'R'], {'{S}HandTouchBack_frame': ('fixed', '{s}_wrist'),
                                 '{s}_grasp_link': ('fixed', '{s}_wrist')})
    assert tree.end_effectors() == ['l_grasp_link', 'r_grasp_link']


def test_the_warning_of_a_two_armed_robot_says_which_arm_the_default_is():
    """Issue 57: on Baxter the default tip is the right arm; the line that names the other arm says so."""
    from robot_ai.reach import Arm
    for sides, tip, other in ((['right_', 'left_'], 'right_gripper', 'left_gripper'),
                              (['L', 'R'], 'Lgripper', 'Rgripper')):
        arm = Arm(two_arms(sides, {'{S}gripper': ('fixed', '{s}_wrist')}))
        assert arm.tip == tip, arm.tip
        side, other_side = ('right', 'left') if tip[0] in 'rR' else ('left', 'right')
        (warning,) = arm.warnings
        assert f'no tip given: {tip}, the end of the {side} arm' in warning, warning
        assert f'the other arm ends at {other} ({other_side} arm)' in warning, warning
        assert '--tip' in warning and 'tip:=' in warning


def test_the_default_tip_below_a_floating_base_is_the_arms_end_in_the_bases_frame():
    """Issue 38: on a floating-base file the default tip was the world link, refused with no candidates."""
    with open(robot_path('ur5.urdf')) as f:
        text = f.read()
    root = KinematicTree.from_xml_string(text).root
    floating = text.replace('</robot>', f'<link name="odom"/><joint name="odom_to_{root}" type="floating">'
                                        f'<parent link="odom"/><child link="{root}"/></joint></robot>')
    tree = KinematicTree.from_xml_string(floating)
    assert tree.root == 'odom' and tree.end_effector() == 'tool0'
    assert tree.frame_above('tool0') == root and tree.frame_above('odom') == 'odom'
    from robot_ai.reach import Arm
    arm = Arm(tree)
    assert (arm.base, arm.tip, arm.n) == (root, 'tool0', 6)
    assert 'tool0' in Arm.candidate_tips(tree)


def test_fingers_are_told_from_arm_joints_by_name_and_by_place():
    """Named fingers (a hand's joints), and unnamed prismatic or mimic joints with no arm joint below them; a
    prismatic joint with an arm below it (a torso lift, a linear axis) is the arm's."""
    def urdf(joints):
        links = {'base'} | {c for _, _, _, c in joints}
        body = ''.join(f'<link name="{n}"/>' for n in sorted(links))
        for name, kind, parent, child in joints:
            body += (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                     f'<origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" '
                     f'velocity="1"/></joint>')
        return KinematicTree.from_xml_string(f'<robot name="t">{body}</robot>')
    tree = urdf([('lift', 'prismatic', 'base', 'a'), ('shoulder', 'revolute', 'a', 'b'),
                 ('elbow', 'revolute', 'b', 'c'), ('RHand', 'revolute', 'c', 'h'), ('slide', 'prismatic', 'c', 's'),
                 ('index_proximal', 'revolute', 'c', 'i1'), ('index_distal', 'revolute', 'i1', 'i2'),
                 ('index_tip', 'revolute', 'i2', 'i3')])
    assert tree.finger_joints() == {'RHand', 'slide', 'index_proximal', 'index_distal', 'index_tip'}
    assert tree.end_effector() == 'c'


def test_cartpole_urdf_has_gymnasiums_frames_and_signs():
    tree = KinematicTree.from_file(os.path.join(URDF_DIR, 'cartpole.urdf'))
    assert tree.root == 'rail' and sorted(tree.active_joints) == ['cart_slider', 'pole_hinge']
    slider = tree.joints['cart_slider']
    assert (slider.lower, slider.upper) == (-2.4, 2.4)       # gymnasium's x_threshold
    for x, theta in ((0.0, 0.0), (1.3, 0.2), (-2.0, -0.15)):
        poses = tree.link_poses({'cart_slider': x, 'pole_hinge': theta})
        tip = poses['pole'].dot([0, 0, 1.0, 1])                 # the pole's top, 1 m along its z axis
        hinge = poses['pole'][:3, 3]
        assert poses['cart'][0, 3] == x
        np.testing.assert_allclose(tip[:3] - hinge, [math.sin(theta), 0, math.cos(theta)], atol=1e-12)


@pytest.mark.parametrize('urdf, config', [('ur5_arm.urdf', 'ur5_sweep.yaml'), ('kuka_lwr_arm.urdf', None)])
def test_the_launch_files_sweep_keeps_every_link_above_the_base(urdf, config):
    """forward_kinematics.launch's sweep of the package's arms never takes a link below the base's plane (the UR5's
    default sweep took its wrist 0.76 m below it)."""
    import yaml
    from robot_ai.nodes.joint_sweep import positions, sweep_ranges
    tree = KinematicTree.from_file(os.path.join(URDF_DIR, urdf))
    settings = {}
    if config:
        with open(os.path.join(URDF_DIR, '..', 'config', config)) as f:
            settings = yaml.safe_load(f)
    ranges = sweep_ranges(tree, 0.8, settings.get('home'), settings.get('scale'))
    lowest = min(pose[2, 3] for t in np.linspace(0, 8, 400)
                 for link, pose in tree.link_poses(dict(zip(tree.active_joints, positions(ranges, t, 8)))).items())
    assert lowest >= -1e-9, lowest
    moving = [a for _, _, a in ranges]
    assert min(moving) > 0.5                       # every joint still moves visibly
