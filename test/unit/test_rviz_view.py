"""rviz_view's choices from the URDF alone (issue 25): the fixed frame on a floating base, the camera on the whole
robot, axes sized to the robot, a narrower window beside the sliders; and the mesh packages a URDF needs."""
import os

from fk_helpers import robot_path
from robot_ai.kinematics import KinematicTree
from robot_ai.nodes.rviz_view import TF_SCALE, camera, configure, marker_scale, view_frame
from robot_ai.urdf_source import mesh_packages, missing_packages

HERE = os.path.dirname(os.path.realpath(__file__))
TEMPLATE = os.path.join(HERE, '..', '..', 'rviz', 'robot_ai.rviz')


def test_a_floating_base_is_the_fixed_frame_and_the_camera_frames_what_hangs_below_it():
    floating = KinematicTree.from_file(os.path.join(HERE, '..', 'urdf', 'floating_base_arm.urdf'))
    assert view_frame(floating) == 'body'
    focal, distance = camera(floating)
    assert focal[2] > 0 and distance > 0.5       # the arm 0.5 m above body, not the root alone
    kuka = KinematicTree.from_file(robot_path('kuka_lwr_arm.urdf'))
    assert view_frame(kuka) == kuka.root


def test_axes_scale_with_the_robot():
    gripper = KinematicTree.from_file(os.path.join(HERE, '..', 'urdf', 'mimic_gripper.urdf'))   # 0.1 m tall
    kuka = KinematicTree.from_file(robot_path('kuka_lwr_arm.urdf'))
    assert marker_scale(kuka) == TF_SCALE
    assert 0 < marker_scale(gripper) < TF_SCALE / 5


def test_configure_fills_in_frame_camera_scale_and_width():
    with open(TEMPLATE) as f:
        template = f.read()
    text = configure(template, 'pelvis', (0.0, 0.0, 0.5), 3.2, 0.07, 720)
    assert '\n    Fixed Frame: pelvis' in text and 'Distance: 3.2' in text and 'Marker Scale: 0.07' in text
    window = text[text.rfind('\nWindow Geometry:'):]
    assert '\n  Width: 720' in window
    assert 'Line Width: 0.03' in text                       # the grid's own width is left alone
    assert '\n  Width: 1024' in configure(template, 'base', (0, 0, 0), 1.0)


def test_the_mesh_packages_a_urdf_needs():
    with open(robot_path('panda.urdf')) as f:
        xml = f.read()
    assert mesh_packages(xml) == ['moveit_resources_panda_description']
    assert missing_packages(['robot_ai_no_such_package', 'rospy']) == ['robot_ai_no_such_package']
    assert mesh_packages('<mesh filename="package://a/m.dae"/><mesh filename="package://b/x.stl"/>'
                         '<mesh filename="package://a/n.dae"/>') == ['a', 'b']
