"""The package's own robots (urdf/) against the reference robots in ../shared/robots: the same frames for
every shared link at random configurations, and the zero poses of SOURCES.md."""
import math
import os

import numpy as np
import pytest

from fk_helpers import robot_path
from robot_ai.kinematics import KinematicTree

URDF_DIR = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', 'urdf')


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
    (robot_path('ur5.urdf'), 'tool0'),
    (robot_path('panda.urdf'), 'panda_leftfinger'),     # 7 arm joints + a finger; the mimic finger is not counted
    (robot_path('pr2.urdf'), None),
    (robot_path('fixtures/one_link.urdf'), None),
])
def test_end_effector_found_from_the_urdf(urdf, tip):
    """What demo_client shows when no tip_frame is given: the link below the most driven joints."""
    tree = KinematicTree.from_file(urdf)
    found = tree.end_effector()
    if tip is not None:
        assert found == tip
    # whatever the robot, the tip is a link whose path from the root crosses the most driven joints
    poses = tree.link_poses()
    assert found in poses
    def driven(link):
        n = 0
        while link != tree.root:
            j = next(j for j in tree.joints.values() if j.child == link)
            n += j.name in tree.active_joints
            link = j.parent
        return n
    assert driven(found) == max(driven(l) for l in poses)


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
