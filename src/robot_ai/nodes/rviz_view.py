"""rviz_view: rviz on whatever robot robot_description holds, its root as the fixed frame, the camera framing it.

rviz takes its fixed frame and camera from a config file or `-f`, which a launch file cannot derive from a URDF
given by model:=. This node reads robot_description (searched up the namespaces, waited for), takes the tree's
root and the reach of its links at the zero pose, writes the config it is given with those filled in, and
replaces itself with rviz on that config.

    rosrun robot_ai rviz_view $(rospack find robot_ai)/rviz/robot_ai.rviz _fixed_frame:=world_link

ROS Parameters
    ~fixed_frame (str, ""): rviz's fixed frame; empty: the URDF's root link.
"""
import math
import os
import re
import sys
import tempfile

import numpy as np
import rospy

from robot_ai.kinematics import KinematicTree
from robot_ai.nodes.params import quiet_on_shutdown, str_param
from robot_ai.nodes.robot_description import wait_for_tree

VIEW_ANGLE = 0.785        # rviz's vertical field of view (rad)
MIN_REACH = 0.3           # m: a tiny robot is still shown at a sensible distance


def camera(tree: KinematicTree) -> tuple[tuple[float, float, float], float]:
    """(focal point, distance) that frame every link the robot can reach: the middle of its links' heights above
    the root, and a distance at which a sphere of its reach fills rviz's view."""
    points = np.array([pose[:3, 3] for pose in tree.link_poses().values()])
    reach = max(MIN_REACH, float(np.linalg.norm(points, axis=1).max()))
    low, high = float(points[:, 2].min()), float(points[:, 2].max())
    focal = (0.0, 0.0, round((low + high) / 2.0, 3))
    radius = max(reach, (high - low) / 2.0) * 1.3     # margin: links near the camera look larger
    return focal, round(radius / math.sin(VIEW_ANGLE / 2.0), 2)


def configure(template: str, fixed_frame: str, focal: tuple, distance: float) -> str:
    """The rviz config text of template with the fixed frame, the focal point and the distance replaced."""
    text = re.sub(r'(\n\s*Fixed Frame: ).*', lambda m: m.group(1) + fixed_frame, template, count=1)
    text = re.sub(r'(\n\s*Focal Point: ).*', lambda m: m.group(1) + f'{{X: {focal[0]}, Y: {focal[1]}, Z: {focal[2]}}}',
                  text, count=1)
    return re.sub(r'(\n\s*Distance: ).*', lambda m: m.group(1) + f'{distance}', text, count=1)


@quiet_on_shutdown
def main():
    argv = rospy.myargv()
    rospy.init_node('rviz_view', anonymous=True)
    if len(argv) < 2 or not os.path.isfile(argv[1]):
        rospy.logfatal('rviz_view: give the rviz config to start from, e.g. $(find robot_ai)/rviz/robot_ai.rviz')
        raise SystemExit(2)
    fixed_frame = str_param('~fixed_frame', '')
    tree, _ = wait_for_tree()
    if tree is None:
        return
    focal, distance = camera(tree)
    fixed_frame = fixed_frame or tree.root
    with open(argv[1]) as f:
        text = configure(f.read(), fixed_frame, focal, distance)
    # one config per robot and config in $ROS_HOME/robot_ai_rviz, replaced whole: rviz may be reading an older one
    folder = os.path.join(os.environ.get('ROS_HOME') or os.path.expanduser('~/.ros'), 'robot_ai_rviz')
    os.makedirs(folder, exist_ok=True)
    name = re.sub(r'[^A-Za-z0-9_.-]', '_', f'{tree.root}_{os.path.basename(argv[1])}')
    fd, tmp = tempfile.mkstemp(prefix='.tmp_', suffix='.rviz', dir=folder)
    with os.fdopen(fd, 'w') as f:
        f.write(text)
    path = os.path.join(folder, name)
    os.replace(tmp, path)
    rospy.loginfo(f'rviz: fixed frame {fixed_frame}, camera {distance} m from {focal} ({path})')
    rospy.signal_shutdown('rviz takes over')
    # rviz replaces this process: roslaunch's name and log arguments go to it, as if it were started directly
    ros_args = [a for a in sys.argv[1:] if ':=' in a and not a.startswith('_')]
    os.execvp('rviz', ['rviz', '-d', path, '-f', fixed_frame] + ros_args)
