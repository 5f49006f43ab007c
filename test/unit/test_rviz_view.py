"""rviz_view's choices from the URDF alone (issue 25): the fixed frame on a floating base, the camera on the whole
robot, axes sized to the robot, a narrower window beside the sliders; and the mesh packages a URDF needs."""
import os
import signal
import subprocess
import sys
import time

from fk_helpers import robot_path
from robot_ai.kinematics import KinematicTree
from robot_ai.nodes.rviz_view import TF_SCALE, camera, configure, crashed, marker_scale, run_rviz, view_frame
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


# rviz started again after a crash (Debian's rviz under software GL dies of SIGSEGV at start now and then): a stand-in
# for rviz that crashes a given number of times, counted in a file, then exits with a status of its own.
CRASHING = '''
count=$(cat "$1" 2>/dev/null || echo 0); echo $((count + 1)) > "$1"
if [ "$count" -lt "$2" ]; then kill -SEGV $$; fi
exit 7
'''


def crashing_rviz(tmp_path, crashes):
    counter = tmp_path / 'starts'
    return ['bash', '-c', CRASHING, 'rviz', str(counter), str(crashes)], counter


def test_rviz_that_crashes_at_start_is_started_again_and_its_own_exit_status_is_kept(tmp_path, capfd):
    command, counter = crashing_rviz(tmp_path, 2)
    assert run_rviz(command, restarts=3) == 7
    assert counter.read_text().strip() == '3'
    err = capfd.readouterr().err
    assert err.count('rviz died of SIGSEGV') == 2 and '(2 of 3)' in err


def test_rviz_that_keeps_crashing_is_given_up_with_the_signal_as_the_status(tmp_path, capfd):
    command, counter = crashing_rviz(tmp_path, 10)
    assert run_rviz(command, restarts=2) == 128 + signal.SIGSEGV
    assert counter.read_text().strip() == '3'      # the first start and 2 more


def test_an_exit_or_a_stop_is_not_a_crash():
    assert not crashed(0) and not crashed(1) and not crashed(-signal.SIGINT) and not crashed(-signal.SIGTERM)
    assert crashed(-signal.SIGSEGV) and crashed(-signal.SIGABRT)


def test_a_stop_is_passed_on_to_rviz_and_rviz_is_not_started_again(tmp_path):
    """rviz_view --run in a process of its own, sent SIGINT as roslaunch's Ctrl-C: the stand-in rviz gets it (it
    records it and ends by it), and nothing is started again."""
    seen, starts = tmp_path / 'seen', tmp_path / 'starts'
    rviz = (f'echo x >> {starts}; trap "echo INT > {seen}; trap - INT; kill -INT \\$\\$" INT; '
            'while :; do sleep 0.1; done')
    proc = subprocess.Popen([sys.executable, '-c', 'import sys; from robot_ai.nodes.rviz_view import main; '
                             'sys.argv = ["rviz_view", "--run", "bash", "-c", sys.argv[1]]; main()', rviz],
                            start_new_session=True)      # only the wrapper is signalled, not its group
    deadline = time.monotonic() + 30
    while not starts.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=30) == 128 + signal.SIGINT
    assert seen.read_text().strip() == 'INT'
    assert starts.read_text().count('x') == 1


def test_rviz_ends_with_rviz_view_even_when_that_is_killed(tmp_path):
    """roslaunch's last resort is SIGKILL: rviz must not outlive rviz_view."""
    pid_file = tmp_path / 'pid'
    proc = subprocess.Popen([sys.executable, '-c', 'import sys; from robot_ai.nodes.rviz_view import run_rviz; '
                             'run_rviz(["bash", "-c", f"echo $$ > {sys.argv[1]}; exec sleep 60"])', str(pid_file)])
    deadline = time.monotonic() + 30
    while not pid_file.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    child = int(pid_file.read_text())
    proc.kill()
    proc.wait(timeout=10)
    deadline = time.monotonic() + 10
    while os.path.exists(f'/proc/{child}') and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not os.path.exists(f'/proc/{child}')
