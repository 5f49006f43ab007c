"""rviz_view: rviz on whatever robot robot_description holds, its root as the fixed frame, the camera framing it.

rviz takes its fixed frame and camera from a config file or `-f`, which a launch file cannot derive from a URDF
given by model:=. This node reads robot_description (searched up the namespaces, waited for), takes the tree's
root and the reach of its links at the zero pose, writes the config it is given with those filled in, and runs
rviz on that config.

    rosrun robot_ai rviz_view $(rospack find robot_ai)/rviz/robot_ai.rviz _fixed_frame:=world_link

Debian's rviz under software GL sometimes dies of SIGSEGV as it opens its window (about 1 launch in 3 with two rviz
starting at once on a loaded machine): rviz_view starts it again when it dies of a crash signal, up to
RVIZ_RESTARTS times, and passes a stop (SIGINT, SIGTERM, SIGHUP) on to it. `rviz_view --run COMMAND...` does only
that, for an rviz with a config of its own (launch-prefix="rosrun robot_ai rviz_view --run" in cartpole.launch).

ROS Parameters
    ~fixed_frame (str, ""): rviz's fixed frame; empty: the URDF's root link, or on a floating base the floating
        joint's child (nothing publishes the root then). The TF display's axes are scaled to the robot's size.
    ~beside_sliders (bool, false): a narrower window (WIDTH_BESIDE_SLIDERS), the sliders' window beside it.
"""
import ctypes
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import rospy

from robot_ai.kinematics import KinematicTree
from robot_ai.nodes.params import bool_param, init_node, quiet_on_shutdown, str_param
from robot_ai.nodes.robot_description import wait_for_tree

VIEW_ANGLE = 0.785        # rviz's vertical field of view (rad)
MIN_REACH = 0.3           # m: a tiny robot is still shown at a sensible distance
TF_SCALE = 0.6            # the TF display's marker scale in rviz/robot_ai.rviz, for robots of FULL_SIZE or more
FULL_SIZE = 0.8           # m: reach from the view frame at which the axes keep the config's scale
WIDTH_BESIDE_SLIDERS = 720   # px: rviz's window with ~beside_sliders, leaving room for the sliders (about 300 px)
NARROW_VIEW_FACTOR = 1.7      # its 3D view's height over its width: the camera steps back by as much
RVIZ_RESTARTS = 3             # times rviz is started again after a crash
CRASH_SIGNALS = (signal.SIGSEGV, signal.SIGABRT, signal.SIGBUS, signal.SIGILL, signal.SIGFPE)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
PR_SET_PDEATHSIG = 1


def view_frame(tree: KinematicTree) -> str:
    """The frame rviz shows the robot in: the root, or on a floating base (a humanoid's pelvis, a mobile base's
    body) the floating joint's child, the frame everything else is published in (nothing publishes the root)."""
    return tree.floating_base() or tree.root


def floating_base_notes(tree: KinematicTree, fixed_frame: str) -> list[str]:
    """What a user of a floating base sees in rviz and why: the RobotModel display's red status for the links above
    the floating joint, which nothing places (localisation does on a real robot, not joint_states)."""
    notes = []
    for name in tree.floating_joints:
        parent, child = tree.floating_links(name)
        notes.append(f'{child} hangs from {parent} by the floating joint {name}: joint_states cannot place it, so '
                     f'nothing publishes {parent} -> {child}. rviz shows the robot in {fixed_frame}, and its '
                     f'RobotModel display turns red with "No transform from [{parent}] to [{fixed_frame}]" for the '
                     f'links above it (they have no pose); the links below are drawn. On a real robot localisation '
                     f'publishes it; here, to silence it: rosrun tf2_ros static_transform_publisher 0 0 0 0 0 0 '
                     f'{parent} {child}')
    return notes


def marker_scale(tree: KinematicTree) -> float:
    """The TF display's axes, sized to the robot: the config's 0.6 for a robot of FULL_SIZE and more, smaller for
    a small one (on a 0.15 m gripper full-size axes hide it)."""
    size = max(float(np.linalg.norm(p[:3, 3])) for p in tree.link_poses(base=tree.floating_base()).values())
    return round(TF_SCALE * min(1.0, max(size, 0.01) / FULL_SIZE), 3)


def camera(tree: KinematicTree) -> tuple[tuple[float, float, float], float]:
    """(focal point, distance) that frame every link the robot can reach: the middle of its links' heights above
    the view frame, and a distance at which a sphere of its reach fills rviz's view."""
    points = np.array([pose[:3, 3] for pose in tree.link_poses(base=tree.floating_base()).values()])
    reach = max(MIN_REACH, float(np.linalg.norm(points, axis=1).max()))
    low, high = float(points[:, 2].min()), float(points[:, 2].max())
    focal = (0.0, 0.0, round((low + high) / 2.0, 3))
    radius = max(reach, (high - low) / 2.0) * 1.3     # margin: links near the camera look larger
    return focal, round(radius / math.sin(VIEW_ANGLE / 2.0), 2)


def configure(template: str, fixed_frame: str, focal: tuple, distance: float, scale: float | None = None,
              width: int | None = None) -> str:
    """The rviz config text of template with the fixed frame, the focal point, the distance, the TF display's
    marker scale and the window's width replaced."""
    text = re.sub(r'(\n\s*Fixed Frame: ).*', lambda m: m.group(1) + fixed_frame, template, count=1)
    if scale is not None:
        text = re.sub(r'(\n\s*Marker Scale: ).*', lambda m: m.group(1) + f'{scale}', text, count=1)
    if width is not None:   # Window Geometry's own Width, the last one in the file (displays have widths too)
        at = text.rfind('\nWindow Geometry:')
        if at >= 0:
            text = text[:at] + re.sub(r'(\n\s*Width: ).*', lambda m: m.group(1) + f'{width}', text[at:], count=1)
    text = re.sub(r'(\n\s*Focal Point: ).*', lambda m: m.group(1) + f'{{X: {focal[0]}, Y: {focal[1]}, Z: {focal[2]}}}',
                  text, count=1)
    return re.sub(r'(\n\s*Distance: ).*', lambda m: m.group(1) + f'{distance}', text, count=1)


def crashed(returncode: int) -> bool:
    """Whether a child's exit status (subprocess's: -N for a signal) is a crash rather than an exit or a stop."""
    return returncode < 0 and -returncode in CRASH_SIGNALS


def _die_with_parent():
    """In the child before exec: SIGTERM when rviz_view ends, even by SIGKILL (roslaunch's last resort)."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def run_rviz(command: list[str], restarts: int = RVIZ_RESTARTS) -> int:
    """Run command (rviz) until it ends; started again, up to restarts times, when it dies of a crash signal and no
    stop was passed on to it. Returns the exit status for this process (128 + N for a signal N)."""
    stopping = []
    child = None

    def pass_on(signum, _frame):
        stopping.append(signum)
        if child is not None and child.poll() is None:
            child.send_signal(signum)

    for signum in STOP_SIGNALS:
        signal.signal(signum, pass_on)
    for attempt in range(restarts + 1):
        started = time.monotonic()
        child = subprocess.Popen(command, preexec_fn=_die_with_parent)
        if stopping:                       # a stop that came while it was being started
            child.send_signal(stopping[0])
        returncode = child.wait()
        if stopping or not crashed(returncode) or attempt == restarts:
            break
        print(f'[rviz_view] rviz died of {signal.Signals(-returncode).name} {time.monotonic() - started:.1f} s '
              f'after it started: starting it again ({attempt + 1} of {restarts})', file=sys.stderr, flush=True)
    return 128 - returncode if returncode < 0 else returncode


def main():
    if sys.argv[1:2] == ['--run']:
        if len(sys.argv) < 3:
            print('rviz_view --run: give the command to run, e.g. rviz -d my.rviz', file=sys.stderr)
            raise SystemExit(2)
        raise SystemExit(run_rviz(sys.argv[2:]))
    view()


@quiet_on_shutdown
def view():
    argv = rospy.myargv()
    init_node('rviz_view', anonymous=True)
    if len(argv) < 2 or not os.path.isfile(argv[1]):
        rospy.logfatal('rviz_view: give the rviz config to start from, e.g. $(find robot_ai)/rviz/robot_ai.rviz')
        raise SystemExit(2)
    fixed_frame = str_param('~fixed_frame', '')
    beside_sliders = bool_param('~beside_sliders', False)
    tree, _ = wait_for_tree()
    if tree is None:
        return
    focal, distance = camera(tree)
    if beside_sliders:    # the narrower 3D view (about 370 x 630 px) is the narrow side: step back to frame it
        distance = round(distance * NARROW_VIEW_FACTOR, 2)
    fixed_frame = fixed_frame or view_frame(tree)
    with open(argv[1]) as f:
        text = configure(f.read(), fixed_frame, focal, distance, marker_scale(tree),
                         WIDTH_BESIDE_SLIDERS if beside_sliders else None)
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
    for note in floating_base_notes(tree, fixed_frame):
        rospy.loginfo(note)
    rospy.signal_shutdown('rviz takes over')
    # roslaunch's name and log arguments go to rviz, as if it were started directly
    ros_args = [a for a in sys.argv[1:] if ':=' in a and not a.startswith('_')]
    raise SystemExit(run_rviz(['rviz', '-d', path, '-f', fixed_frame] + ros_args))
