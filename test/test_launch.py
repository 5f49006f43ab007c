#!/usr/bin/env python3
"""demo.launch as users run it: headless it ends by itself with status 0 and the summary; with rviz:=true
under Xvfb, a screenshot of rviz's 3D view shows the robot and its frames, not only the grid.

Each launch gets its own master on a free port, so it does not disturb rostest's."""
import functools
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import unittest

import rospkg
import rostest
import numpy as np
from PIL import Image

from robot_ai.child_process import process_stat
from ros_helpers import cases_of

ARTIFACTS = os.path.join(rospkg.RosPack().get_path('robot_ai'), '..', '..', 'build', 'test_artifacts')


def free_port():
    """A free port for a launch's master, below the kernel's ephemeral range: a port taken from that range is
    released before roslaunch binds it, and a node's XML-RPC server could get it meanwhile ('Address already in
    use', seen once in six fresh runs)."""
    try:
        with open('/proc/sys/net/ipv4/ip_local_port_range') as f:
            low = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768
    for port in random.sample(range(20000, max(20001, low)), min(500, max(1, low - 20000))):
        with socket.socket() as s:
            try:
                s.bind(('127.0.0.1', port))
                return port
            except OSError:
                continue
    with socket.socket() as s:   # none free down there: the ephemeral range, as before
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def free_display():
    for n in range(90, 200):
        if not os.path.exists('/tmp/.X%d-lock' % n) and not os.path.exists('/tmp/.X11-unix/X%d' % n):
            return n
    raise RuntimeError('no free X display number')


def launch(args, env=None, launch_file='demo.launch'):
    port = free_port()
    # unbuffered: the cases read roslaunch's lines as they come; into a pipe Python holds them back in 8 KB blocks,
    # and a case that waited for 'started with pid' waited its full 120 s (600 s of the suite where CI's clean
    # environment has no PYTHONUNBUFFERED)
    env = dict(env or os.environ, ROS_MASTER_URI='http://127.0.0.1:%d' % port, PYTHONUNBUFFERED='1')
    proc = subprocess.Popen(['roslaunch', '-p', str(port), 'robot_ai', launch_file] + args, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=os.setsid)
    proc.env = env
    return proc


def descendants(pid):
    """pid and every process below it, as strings (roslaunch starts each node in a session of its own)."""
    children = {}
    for line in subprocess.run(['ps', '-eo', 'pid=,ppid='], capture_output=True, text=True).stdout.splitlines():
        child, parent = line.split()
        children.setdefault(parent, []).append(child)
    out, todo = set(), [str(pid)]
    while todo:
        p = todo.pop()
        out.add(p)
        todo.extend(children.get(p, []))
    return out


def without_interpreter_startup(text):
    """text less CPython's own report of a Ctrl-C that came while a node's interpreter was still starting (importing
    site, before any code of the node's, the package's or ROS's ran): 'Fatal Python error: init_import_site' up to
    its KeyboardInterrupt line. No program can catch that one; a loaded machine can take half a second to get there."""
    out, skipping = [], False
    for line in text.splitlines():
        if line.startswith('Fatal Python error: init_import_site'):
            skipping = True
        if not skipping:
            out.append(line)
        elif line.startswith('KeyboardInterrupt'):
            skipping = False
    return '\n'.join(out)


def without_tracebacks(text, dropped):
    """text less each traceback (its frame lines and its exception line) for which dropped(frames, exception line)
    is true."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].startswith('Traceback (most recent call last):'):
            j = i + 1
            while j < len(lines) and lines[j].startswith(' '):
                j += 1
            if dropped(lines[i + 1:j], lines[j] if j < len(lines) else ''):
                i = j + 1                    # its frames and its exception line
                continue
        out.append(lines[i])
        i += 1
    return '\n'.join(out)


def without_debians_tracebacks(text):
    """text less the tracebacks none of whose frames is the package's (no '/robot_ai/' in them), each with its
    exception line: Debian's rosmaster, interrupted while it still imported numpy at a load of 28, printed its own
    KeyboardInterrupt. A node of the package's shows its script among the frames, whatever raised."""
    return without_tracebacks(text, lambda frames, _: not any('/robot_ai/' in line for line in frames))


def without_catkin_relay(text):
    """text less a Ctrl-C's traceback whose only frames of the package are catkin's relay in the devel space
    (devel/lib/robot_ai/<node>: it reads the node's script and execs it), with its KeyboardInterrupt line: a Ctrl-C
    0.5 s after roslaunch started cartpole_search, on a loaded machine, came while the relay still read the script,
    before any line of the node's ran, and no code of the package's can catch that one."""
    def relay_only(frames, exception):
        ours = [line for line in frames if line.lstrip().startswith('File "') and '/robot_ai/' in line]
        return bool(ours) and all('/devel/lib/robot_ai/' in line for line in ours) and \
            exception.startswith('KeyboardInterrupt')
    return without_tracebacks(text, relay_only)


def tracebacks(text):
    """The tracebacks in a launch's output, each as its frame lines (up to the first line that is not indented)."""
    found, lines = [], text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith('Traceback (most recent call last):'):
            frames = []
            for frame in lines[i + 1:]:
                if not frame.startswith(' '):
                    break
                frames.append(frame)
            found.append(frames)
    return found


def start_xvfb(size='1024x768'):
    """(display name, Xvfb process) of a new virtual screen, once it takes connections (its socket is there): a fixed
    second was too short on a loaded machine, and a GUI started before it could not open the display."""
    n = free_display()
    xvfb = subprocess.Popen(['Xvfb', f':{n}', '-screen', '0', f'{size}x24', '-nolisten', 'tcp'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not os.path.exists(f'/tmp/.X11-unix/X{n}') and time.monotonic() < deadline and xvfb.poll() is None:
        time.sleep(0.1)
    time.sleep(0.2)
    return f':{n}', xvfb


def run_to_end(args, env=None, launch_file='demo.launch', timeout=400):
    """(exit status, output) of a launch that ends by itself (the timeout only catches a hang: on a loaded machine
    the demo takes longer, and must still end with its verdict)."""
    proc = launch(args, env, launch_file)
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        stop(proc)
    return proc.returncode, out.decode(errors='replace')


@functools.lru_cache(maxsize=None)
def default_demo():
    """(exit status, output, ROS_HOME) of one run of the demo as `make demo` runs it but with ROS_HOME of its own and
    no output_dir, shared by the cases that read it (each asserts its own part of the same run)."""
    ros_home = os.path.abspath(os.path.join(ARTIFACTS, 'ros_home'))
    shutil.rmtree(ros_home, ignore_errors=True)
    t0 = time.time()
    status, text = run_to_end([], dict(os.environ, ROS_HOME=ros_home))
    print(f'the demo took {time.time() - t0:.0f} s')
    return status, text, ros_home


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def ended_output(proc, timeout=60):
    """The whole output of a launch that was sent SIGINT, once roslaunch itself has ended (within timeout).
    Debian's roslaunch, interrupted while it starts rosout, can end and leave its master running (seen once in 80
    Ctrl-Cs under load: 'cannot add process ... after process monitor has been shut down'); that orphan holds the
    output pipe, so the output is read up to roslaunch's end and any process left on the launch's master is ended."""
    chunks = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: proc.stdout.read1(65536), b'')), daemon=True)
    reader.start()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:   # Debian's roslaunch can hang in that same race: its bug, not the package's
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)
    port = proc.env['ROS_MASTER_URI'].encode().rstrip(b'/').rsplit(b':', 1)[1]
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            # roslaunch -p gives its nodes http://localhost:<port>/, not the launch's own 127.0.0.1: match the port
            # (an orphaned cartpole_search per interrupted start outlived the suite when only the URI was matched)
            with open(f'/proc/{pid}/environ', 'rb') as f:
                mine = any(v.startswith(b'ROS_MASTER_URI=') and v.rstrip(b'/').endswith(b':' + port)
                           for v in f.read().split(b'\0'))
            with open(f'/proc/{pid}/cmdline', 'rb') as f:
                mine = mine or b'-p\0' + port + b'\0' in f.read()
            if mine and int(pid) != os.getpid():
                os.kill(int(pid), signal.SIGKILL)
        except (OSError, ValueError):
            continue
    reader.join(10)
    return b''.join(chunks).decode(errors='replace')


def colour_counts(path):
    """Pixels of the robot's materials and of the TF axes inside rviz's 3D view (found as the bounding box of its
    background colour, so that the panel's blue labels and the toolbar's icons do not count), and the rows where
    the orange and the blue pixels start and end (in screen rows)."""
    img = np.asarray(Image.open(path).convert('RGB')).astype(int)
    background = (img == (48, 48, 48)).all(axis=2)
    y0 = 0
    if background.any():   # the rows and columns where the background is dense: the view, not stray pixels
        ys = np.nonzero(background.sum(axis=1) > 0.3 * background.sum(axis=1).max())[0]
        xs = np.nonzero(background.sum(axis=0) > 0.3 * background.sum(axis=0).max())[0]
        y0 = ys.min()
        img = img[y0:ys.max() + 1, xs.min():xs.max() + 1]
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    masks = dict(orange=(r > 190) & (g > 70) & (g < 160) & (b < 70),
                 blue=(r < 70) & (g > 50) & (g < 130) & (b > 150))
    masks['tf_red'] = (r > 180) & (g < 50) & (b < 50) & ~masks['orange']
    masks['tf_green'] = (g > 150) & (r < 80) & (b < 80)
    counts = {name: int(m.sum()) for name, m in masks.items()}
    for name in ('orange', 'blue'):
        rows = np.nonzero(masks[name])[0]
        counts[f'{name}_top'] = int(rows.min()) + y0 if len(rows) else -1
        counts[f'{name}_bottom'] = int(rows.max()) + y0 if len(rows) else -1
    counts['pole_rows'] = len(set(np.nonzero(masks['orange'])[0]))
    counts['view'] = (int(y0), int(y0 + img.shape[0]))
    return counts


class TestLaunch(unittest.TestCase):

    def test_demo_ends_cleanly_with_a_summary(self):
        status, text, ros_home = default_demo()
        self.assertEqual(status, 0, text[-3000:])
        self.assertIn('verdict: OK', text, text[-3000:])
        self.assertIn('the end effector moves', text)
        self.assertIn('best average', text)
        # the closed loop: the Q-learning agent's saved policy drives the cart-pole, and recovers from a push
        self.assertRegex(text, r'cartpole: the pole stayed up [0-9.]+ s of [0-9.]+ s')
        self.assertIn('recovered', text)
        video = [l.split()[-1] for l in text.splitlines() if l.strip().startswith('video ')][0]
        self.assertTrue(os.path.isfile(video) and video.startswith(os.path.join(ros_home, 'robot_ai')), video)

    def test_a_stale_parameter_on_a_master_that_stays_up_is_not_used(self):
        """Issue 27: after `rosrun robot_ai cartpole_search _policy:=<a file since deleted>` on a roscore that stays
        up, demo.launch picked up the stale /cartpole_search/policy, the search node died and the summary said only
        `timeout exceeded while waiting for service`. The launch files set every parameter their nodes read."""
        port = free_port()
        env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
        core = subprocess.Popen(['roscore', '-p', str(port)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            deadline = time.time() + 60
            while subprocess.run(['rosparam', 'set', '/cartpole_search/policy', '/nonexistent/deleted.npz'], env=env,
                                 capture_output=True).returncode != 0 and time.time() < deadline:
                time.sleep(0.3)
            subprocess.run(['rosparam', 'set', '/cartpole_q_learning/policy', '/nonexistent/deleted.npz'], env=env,
                           check=True, capture_output=True)
            proc = subprocess.Popen(['roslaunch', '-p', str(port), 'robot_ai', 'demo.launch', 'q_learners:=1',
                                     'record_video:=false', 'output_dir:=' + os.path.join(ARTIFACTS, 'stale')],
                                    env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=os.setsid)
            try:
                out, _ = proc.communicate(timeout=400)
            finally:
                stop(proc)
            text = out.decode(errors='replace')
            self.assertIn('verdict: OK', text, text[-3000:])
        finally:
            os.killpg(core.pid, signal.SIGINT)
            core.wait(30)

    def test_ctrl_c_of_the_sliders_leaves_no_node_on_a_master_that_stays_up(self):
        """Issue 27: after Ctrl-C of forward_kinematics.launch gui:=true on a roscore that stays up, the sliders node
        stayed in `rosnode list` (3 runs of 3): the default SIGINT killed it before it unregistered."""
        port = free_port()
        env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
        core = subprocess.Popen(['roscore', '-p', str(port)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        display, xvfb = start_xvfb()
        try:
            # the master up first: a roslaunch that does not find it starts one of its own, and then the roscore's
            # run_id does not match its own ('RLException: run_id on parameter server does not match')
            deadline = time.time() + 60
            while subprocess.run(['rosnode', 'list'], env=env, capture_output=True).returncode != 0:
                self.assertLess(time.time(), deadline, 'roscore did not start within 60 s')
                time.sleep(0.3)
            for _ in range(2):
                proc = subprocess.Popen(['roslaunch', '-p', str(port), 'robot_ai', 'forward_kinematics.launch',
                                         'gui:=true'], env=dict(env, DISPLAY=display), stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT)
                deadline = time.time() + 180      # a GUI's start (Python, Tk, rospy) takes long beside the suite
                nodes = ''
                while '/joint_state_publisher_gui' not in nodes and time.time() < deadline and proc.poll() is None:
                    time.sleep(0.5)
                    nodes = subprocess.run(['rosnode', 'list'], env=env, capture_output=True, text=True).stdout
                if '/joint_state_publisher_gui' not in nodes:
                    proc.send_signal(signal.SIGINT)
                    out, _ = proc.communicate(timeout=60)
                    self.fail(f'the sliders never registered: {nodes.split()}\n{out.decode(errors="replace")[-3000:]}')
                proc.send_signal(signal.SIGINT)     # a terminal's Ctrl-C reaches roslaunch
                out, _ = proc.communicate(timeout=60)
                nodes = subprocess.run(['rosnode', 'list'], env=env, capture_output=True, text=True).stdout
                self.assertEqual(nodes.split(), ['/rosout'], out.decode(errors='replace')[-2000:])
        finally:
            xvfb.terminate()
            os.killpg(core.pid, signal.SIGINT)
            core.wait(30)

    def test_ros_home_moves_every_artifact(self):
        _, text, ros_home = default_demo()
        self.assertIn('verdict: OK', text, text[-3000:])
        # the search's and the Q-learning agent's plot and video, all under $ROS_HOME/robot_ai
        files = sorted(os.listdir(os.path.join(ros_home, 'robot_ai')))
        self.assertEqual([f.split('_')[0] + os.path.splitext(f)[1] for f in files],
                         [f'{kind}.{ext}' for kind in ('qlearning', 'search') for ext in ('csv', 'mp4', 'npz', 'png')],
                         files)
        self.assertNotIn('Traceback', text)

    def test_ctrl_c_prints_no_traceback(self):
        """A terminal's Ctrl-C: SIGINT to roslaunch and every node, while they serve and while they work. The waits
        count from the moment roslaunch has started the nodes: on a loaded machine roslaunch itself can take more
        than 1.5 s to import its modules (and then prints its own KeyboardInterrupt, not the package's), and a node's
        interpreter can still be importing site half a second after its start (CPython's own fatal error, which no
        program catches: without_interpreter_startup)."""
        for launch_file, wait in (('cartpole_search.launch', 6), ('forward_kinematics.launch', 6),
                                  ('cartpole_search.launch', 0.5), ('cartpole_q_learning.launch', 1.0),
                                  ('demo.launch', 2), ('demo.launch', 4)):
            fk_only = launch_file == 'forward_kinematics.launch'
            args = [] if fk_only else ['output_dir:=' + os.path.join(ARTIFACTS, 'ctrl_c')]
            proc = launch(args, launch_file=launch_file)
            t0 = time.time()
            os.set_blocking(proc.stdout.fileno(), False)
            early, deadline = b'', time.time() + 120
            while b'started with pid' not in early.split(b'started core service')[-1] and time.time() < deadline:
                time.sleep(0.05)
                early += proc.stdout.read() or b''
            started = time.time()
            time.sleep(wait)
            os.killpg(proc.pid, signal.SIGINT)
            os.set_blocking(proc.stdout.fileno(), True)
            text = early.decode(errors='replace') + ended_output(proc)
            print(f'{launch_file} {wait} s: nodes started {started - t0:.1f} s after the launch, ended '
                  f'{time.time() - started - wait:.1f} s after the Ctrl-C', flush=True)
            ours = without_catkin_relay(without_debians_tracebacks(without_interpreter_startup(text)))
            self.assertEqual(tracebacks(ours), [], f'{launch_file} {wait} s after its nodes started:\n{text[-3000:]}')
            self.assertNotIn('KeyboardInterrupt', ours, launch_file)

    def test_ctrl_c_at_any_moment_of_the_start_prints_no_traceback_of_the_package(self):
        """Issue 23: a Ctrl-C while a node was still importing (or inside init_node) printed a KeyboardInterrupt or
        ROSInitException traceback. Ten random moments of the first 2 s of cartpole_search.launch: none from the
        package's processes. (Debian's roslaunch can print its own while it imports, in its first half second.)"""
        moments = sorted(random.uniform(0.0, 2.0) for _ in range(10))
        for wait in moments:
            proc = launch(['output_dir:=' + os.path.join(ARTIFACTS, 'ctrl_c')], launch_file='cartpole_search.launch')
            time.sleep(wait)
            os.killpg(proc.pid, signal.SIGINT)
            text = ended_output(proc)
            ours = [tb for tb in tracebacks(text) if any('/robot_ai/' in line for line in tb)]
            self.assertEqual(ours, [], f'Ctrl-C after {wait:.2f} s:\n{text[-3000:]}')

    def test_sigkill_of_roslaunch_under_the_guard_leaves_nothing_behind(self):
        """Issue 18: SIGKILL of roslaunch orphaned every node (the master, rosout, the nodes), and `make demo`'s
        tee, fed by their output, waited forever. make demo runs roslaunch under robot_ai.launch_guard."""
        port = free_port()
        env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
        log = os.path.join(ARTIFACTS, 'guard.log')
        shell = subprocess.Popen(['bash', '-o', 'pipefail', '-c', f'python -m robot_ai.launch_guard roslaunch -p '
                                  f'{port} robot_ai forward_kinematics.launch 2>&1 | tee {log}'], env=env,
                                 stdout=subprocess.DEVNULL, preexec_fn=os.setsid)
        try:
            deadline = time.time() + 60
            while time.time() < deadline and len(descendants(shell.pid)) < 8:  # bash, guard, tee, roslaunch, nodes
                time.sleep(0.5)
            time.sleep(2.0)
            started = descendants(shell.pid)
            roslaunch = [p for p in started if b'roslaunch' in open(f'/proc/{p}/cmdline', 'rb').read()
                         and b'launch_guard' not in open(f'/proc/{p}/cmdline', 'rb').read()]
            self.assertEqual(len(roslaunch), 1, started)
            os.kill(int(roslaunch[0]), signal.SIGKILL)
            shell.wait(30)   # tee saw the end of its input: nothing holds roslaunch's output any more
            self.assertEqual(shell.returncode, 128 + signal.SIGKILL)
            left = [p for p in started if (stat := process_stat(int(p))) is not None and stat.state != 'Z']
            self.assertEqual(left, [])
        finally:
            if shell.poll() is None:
                os.killpg(shell.pid, signal.SIGKILL)
                for p in descendants(shell.pid):
                    try:
                        os.kill(int(p), signal.SIGKILL)
                    except ProcessLookupError:
                        pass
        with open(log) as f:
            self.assertIn('launch_guard: roslaunch ended (killed by SIGKILL) and left', f.read())

    def test_ctrl_c_during_a_training_ends_it_at_once(self):
        """The learners run in worker processes: a Ctrl-C ends them and the node, the caller is told."""
        proc = launch(['output_dir:=' + os.path.join(ARTIFACTS, 'ctrl_c')], launch_file='cartpole_q_learning.launch')
        call = None
        try:
            deadline = time.time() + 60
            while subprocess.run(['rosservice', 'info', '/cartpole_q_learning/train'], env=proc.env,
                                 capture_output=True).returncode != 0 and time.time() < deadline:
                time.sleep(0.5)
            call = subprocess.Popen(['rosservice', 'call', '/cartpole_q_learning/train',
                                     '{learners: 8, episodes: 4000}'], env=proc.env, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT)
            time.sleep(4.0)
            self.assertIsNone(call.poll(), 'the training ended before the Ctrl-C')
            t = time.time()
            os.killpg(proc.pid, signal.SIGINT)
            out, _ = proc.communicate(timeout=30)
            self.assertLess(time.time() - t, 10.0, 'roslaunch had to escalate to SIGTERM/SIGKILL')
            answer, _ = call.communicate(timeout=10)
        finally:
            stop(proc)
            if call is not None and call.poll() is None:
                call.kill()
        text = out.decode(errors='replace')
        self.assertNotIn('Traceback', text, text[-3000:])
        self.assertNotIn('ERROR', text, text[-3000:])
        self.assertIn('cancelled: the node is shutting down', answer.decode(errors='replace'))

    def test_every_package_robot_and_one_never_seen(self):
        """robot:=kuka_lwr, and the Panda (not a package robot) by model:=: the client finds the root and the
        end effector from the URDF, the frames move, rviz gets a fixed frame that exists."""
        panda = os.path.join(rospkg.RosPack().get_path('robot_ai'), '..', '..', '..', '..', 'shared', 'robots',
                             'panda.urdf')
        for args, frames in ((['robot:=kuka_lwr'], 'world_link -> lwr_arm_7_link'),
                             (['model:=' + os.path.realpath(panda)], 'panda_link0 -> panda_hand')):   # the arm's end
            _, text = run_to_end(args + ['q_learners:=1', 'record_video:=false',
                                         'output_dir:=' + os.path.join(ARTIFACTS, 'robots')])
            self.assertIn('verdict: OK', text, text[-3000:])
            self.assertIn('forward_kinematics: %s from /tf' % frames, text)
            self.assertIn('the end effector moves', text)
            # issue 25: the Panda's meshes come from a package Debian does not ship: one line says so, once for each
            # robot_description that holds it (the demo's arm, and the reach part's arm in /reach)
            meshes = [l for l in text.splitlines() if 'is not found: rviz draws those links in red' in l]
            described = [l.split(': its meshes')[0].rsplit(' ', 1)[-1] for l in meshes]
            self.assertEqual(len(described), len(set(described)), meshes)
            self.assertEqual(sorted(described), ['/reach/robot_description', '/robot_description']
                             if 'panda' in args[0] else [], meshes)
            for line in meshes:
                self.assertIn('put moveit_resources_panda_description on ROS_PACKAGE_PATH', line)
        # a package-relative model, as docs/launch.md says, loads; a robot that does not exist says so
        bad = subprocess.run(['roslaunch', '--args', 'forward_kinematics', 'robot_ai', 'forward_kinematics.launch',
                              'model:=urdf/kuka_lwr_arm.urdf'], capture_output=True, text=True, timeout=60)
        self.assertEqual(bad.returncode, 0, bad.stdout + bad.stderr)
        status, text = run_to_end(['robot:=ur6'], launch_file='forward_kinematics.launch', timeout=60)
        self.assertNotEqual(status, 0)
        said = [l for l in text.splitlines() if 'ur6' in l or 'Exception' in l or 'rror' in l]
        self.assertEqual(said, ['robot:=ur6 is not one of the package robots (ur5, kuka_lwr); for any other URDF give '
                                'model:=/path/to/robot.urdf'], text)
        # issue 27: a wrong or relative model:= was four lines from roslaunch; now one, naming the path it tried
        for model, tried in (('urdf/nothere.urdf', '/urdf/nothere.urdf'), ('/nonexistent/robot.urdf', None)):
            status, text = run_to_end([f'model:={model}'], launch_file='forward_kinematics.launch', timeout=60)
            self.assertNotEqual(status, 0)
            said = [l for l in text.splitlines() if 'nothere' in l or 'nonexistent' in l or 'rror' in l
                    or 'Exception' in l]
            self.assertEqual(len(said), 1, text)
            self.assertIn(f'model:={model}: no such file', said[0])
            if tried:
                self.assertIn('a relative model:= is taken inside the robot_ai package', said[0])

    def test_a_xacro_model_with_find_and_its_arguments(self):
        """Issue 25: model:= a xacro file with $(find pkg) and xacro_args (name=value on roslaunch's command line,
        which refuses a second :=): robot_description is the expanded URDF and the frames reach /tf; a xacro error
        is our one line, naming the file and the cause, before roslaunch's."""
        import tempfile
        from fk_helpers import write_xacro_package
        folder = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, folder, True)
        arm = write_xacro_package(folder)
        env = dict(os.environ, ROS_PACKAGE_PATH=folder + os.pathsep + os.environ.get('ROS_PACKAGE_PATH', ''))
        proc = launch([f'model:={arm}', 'xacro_args:=hand=true'], env=env, launch_file='forward_kinematics.launch')
        try:
            deadline, echo = time.time() + 90, ''
            while time.time() < deadline and 'child_frame_id: "hand"' not in echo:
                echo = subprocess.run(['rostopic', 'echo', '-n', '1', '/tf'], env=proc.env, capture_output=True,
                                      text=True, timeout=60).stdout
            self.assertIn('child_frame_id: "hand"', echo)
            xml = subprocess.run(['rosparam', 'get', '/robot_description'], env=proc.env, capture_output=True,
                                 text=True, timeout=30).stdout
            self.assertIn('my_arm', xml)
            self.assertNotIn('xacro:', xml)
        finally:
            stop(proc)
        status, text = run_to_end([f'model:={arm}'], launch_file='forward_kinematics.launch', timeout=60)
        self.assertNotEqual(status, 0)      # the package is not on this ROS_PACKAGE_PATH
        ours = [l for l in text.splitlines() if l.startswith('xacro: ')]
        self.assertEqual(ours, [f'xacro: {arm}: xacro: package my_arm_description not found: put it on '
                                f'ROS_PACKAGE_PATH'], text)

    def test_a_model_path_with_quotes_and_sims_out_of_range(self):
        """Issue 34: a model:= path holding an apostrophe (or a double quote) loads; cartpole_gym.launch's sims:= out
        of range is one line."""
        import shutil
        import tempfile
        top = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, top, True)
        folder = os.path.join(top, "it's \"here\"")
        os.makedirs(folder)
        here = os.path.dirname(os.path.realpath(__file__))
        for name in ('reach_arm7.urdf.xacro', 'reach_segment.xacro'):
            shutil.copy(os.path.join(here, 'urdf', name), folder)
        arm = os.path.join(folder, "o'brien's arm.urdf.xacro")
        os.rename(os.path.join(folder, 'reach_arm7.urdf.xacro'), arm)
        proc = launch([f'model:={arm}', 'xacro_args:=scale=2 tool=true'], launch_file='forward_kinematics.launch')
        try:
            deadline, xml = time.time() + 90, ''
            while time.time() < deadline and 'reach_arm7' not in xml:
                time.sleep(1.0)
                xml = subprocess.run(['rosparam', 'get', '/robot_description'], env=proc.env, capture_output=True,
                                     text=True, timeout=30).stdout
            self.assertIn('reach_arm7', xml)
            self.assertIn('name=\\"tool\\"', xml)
        finally:
            stop(proc)
        for sims in ('0', '-3', '300', 'two'):
            status, text = run_to_end([f'sims:={sims}'], launch_file='cartpole_gym.launch', timeout=60)
            self.assertNotEqual(status, 0)
            said = [l for l in text.splitlines() if 'sims:=' in l or 'rror' in l or 'Exception' in l]
            self.assertEqual(said, [f'sims:={sims} must be a whole number from 1 to 64 (each sim is a process of '
                                    f'about 40 MiB)'], text)

    def test_sliders_under_xvfb(self):
        """gui:=true: the sliders' window opens (Debian 12's joint_state_publisher_gui crashed) and joint_states
        flows from it."""
        display, xvfb = start_xvfb()
        proc = None
        try:
            proc = launch(['gui:=true'], dict(os.environ, DISPLAY=display), launch_file='forward_kinematics.launch')
            deadline, windows = time.time() + 60, ''
            while 'Joint State Publisher' not in windows and time.time() < deadline:
                time.sleep(1.0)
                self.assertIsNone(proc.poll(), proc.stdout.read().decode(errors='replace')[-3000:] if proc.poll()
                                  is not None else '')
                windows = subprocess.run(['xwininfo', '-display', display, '-root', '-tree'], capture_output=True,
                                         text=True, timeout=30).stdout
            self.assertIn('Joint State Publisher', windows)
            echo = subprocess.run(['rostopic', 'echo', '-n', '1', '/joint_states'], env=proc.env, capture_output=True,
                                  text=True, timeout=30).stdout
            self.assertIn('shoulder_pan_joint', echo)
            self.assertIn('position: [', echo)
        finally:
            if proc is not None:
                stop(proc)
                text = proc.stdout.read().decode(errors='replace')
                self.assertNotIn('TypeError', text)
            xvfb.terminate()
            xvfb.wait(10)

    def test_sliders_stay_visible_beside_rviz(self):
        """Issue 25: gui:=true rviz:=true under Xvfb (no window manager: the window mapped last, rviz's, is on
        top): the sliders' window sits at the screen's right edge and rviz's window is narrower, so a screenshot
        shows the sliders (Qt's light grey) beside rviz."""
        display, xvfb = start_xvfb()
        proc = None
        try:
            proc = launch(['gui:=true', 'rviz:=true'], dict(os.environ, DISPLAY=display),
                          launch_file='forward_kinematics.launch')
            deadline, windows = time.time() + 120, ''
            while not ('Joint State Publisher' in windows and 'RViz' in windows) and time.time() < deadline:
                time.sleep(1.0)
                windows = subprocess.run(['xwininfo', '-display', display, '-root', '-tree'], capture_output=True,
                                         text=True, timeout=30).stdout
            self.assertIn('RViz', windows)
            time.sleep(3.0)
            windows = subprocess.run(['xwininfo', '-display', display, '-root', '-tree'], capture_output=True,
                                     text=True, timeout=30).stdout
            # the sliders' top-level window (Qt also maps a 1x1 leader window of the application's name)
            found = re.findall(r'"Node: [^"]*Joint State Publisher": \("sliders" "sliders"\)\s+(\d+)x(\d+)\+(-?\d+)'
                               r'\+(-?\d+)', windows)
            self.assertEqual(len(found), 1, windows)
            w, h, x, y = (int(v) for v in found[0])
            shot = os.path.join(ARTIFACTS, 'sliders_beside_rviz.png')
            subprocess.run(['import', '-display', display, '-window', 'root', shot], check=True, timeout=30)
            img = np.asarray(Image.open(shot).convert('RGB')).astype(int)
            region = img[y:y + h, x:x + w]
            geometry = f'{w}x{h}+{x}+{y}'
            self.assertGreater(x + w, img.shape[1] - 5, f'the sliders are at the right edge: {geometry}')
            light = (region > 200).all(axis=2).mean()
            self.assertGreater(light, 0.3, f'the sliders window is hidden: {light:.0%} light pixels in {geometry}')
        finally:
            if proc is not None:
                stop(proc)
            xvfb.terminate()
            xvfb.wait(10)

    def test_everything_listens_on_loopback_only(self):
        """ROS 1 has no authentication: make demo and make test (ROS_HOSTNAME=localhost) bind to loopback."""
        self.assertEqual(os.environ.get('ROS_HOSTNAME'), 'localhost', 'the Makefile sets ROS_HOSTNAME=localhost')
        proc = launch(['output_dir:=' + os.path.join(ARTIFACTS, 'loopback')], launch_file='cartpole_search.launch')
        try:
            deadline = time.time() + 60
            while subprocess.run(['rosservice', 'info', '/cartpole_search/random_search'], env=proc.env,
                                 capture_output=True).returncode != 0 and time.time() < deadline:
                time.sleep(0.5)
            pids = descendants(proc.pid)
            listening = [l for l in subprocess.run(['ss', '-ltnpH'], capture_output=True, text=True).stdout.splitlines()
                         if any('pid=%s,' % p in l for p in pids)]
        finally:
            stop(proc)
        self.assertGreaterEqual(len(listening), 4, listening)  # the master, rosout, the node (XML-RPC and TCPROS)
        for line in listening:
            local = line.split()[3]
            if '"rosout"' in line:
                # roscpp listens on every interface whatever ROS_HOSTNAME says, and its XML-RPC answers other
                # hosts: across_machines.test shows it, and the README's firewall that closes it
                continue
            self.assertTrue(local.startswith(('127.0.0.1:', '[::1]:')), line)
        self.assertTrue(any('"cartpole_search"' in l or 'python' in l for l in listening), listening)

    def rviz_screenshot(self, launch_args, name, drawn, launch_file='demo.launch', keep_running=True,
                        size='1024x768', crop=None):
        """Counts of colour_counts in a screenshot of rviz under Xvfb, taken once drawn(counts) says yes or after
        120 s (rviz takes a while to start under software GL, and rviz_view may start it again); the screenshot is
        kept as ARTIFACTS/name. crop: {name: (left, top, right, bottom)}: the counts of those parts of the screen
        instead, by name."""
        display, xvfb = start_xvfb(size)
        proc = None
        try:
            # rviz writes ~/.rviz and Mesa ~/.cache: keep them in the build folder, ROS's logs where they are
            home = os.path.abspath(os.path.join(ARTIFACTS, 'home'))
            os.makedirs(home, exist_ok=True)
            env = dict(os.environ, DISPLAY=display, HOME=home, ROS_HOME=rospkg.get_ros_home())
            proc = launch(launch_args, env, launch_file)
            shot = os.path.abspath(os.path.join(ARTIFACTS, name))
            counts, output = {}, b''
            os.set_blocking(proc.stdout.fileno(), False)
            deadline = time.time() + 120
            while time.time() < deadline:
                time.sleep(3.0)
                self.assertIsNone(proc.poll(), f'{launch_file} rviz:=true ended by itself')
                subprocess.run(['import', '-display', display, '-window', 'root', shot], check=True, timeout=30)
                if crop:
                    counts = {}
                    for part, box in crop.items():
                        Image.open(shot).crop(box).save(shot + f'.{part}.png')
                        counts[part] = colour_counts(shot + f'.{part}.png')
                else:
                    counts = colour_counts(shot)
                if drawn(counts):
                    break
                output += proc.stdout.read() or b''
            print(f'rviz screenshot: {shot} {counts}')
            if not drawn(counts):     # what the launch said, rviz_view's restarts among it, for the failure below
                output += proc.stdout.read() or b''
                print(output.decode(errors='replace')[-4000:])
            if keep_running:
                self.assertIsNone(proc.poll(), 'with rviz:=true the launch keeps running until stopped')
            return counts
        finally:
            if proc is not None:
                stop(proc)
            xvfb.terminate()
            xvfb.wait(10)

    def test_rviz_screenshot_shows_robot_and_frames(self):
        counts = self.rviz_screenshot(['rviz:=true', 'record_video:=false',
                                       'output_dir:=' + os.path.join(ARTIFACTS, 'rviz')], 'rviz_screenshot.png',
                                      lambda c: c['orange'] > 3000 and c['blue'] > 500 and c['tf_red'] > 30)
        self.assertGreater(counts['orange'], 3000, 'the arm is not drawn: %s' % counts)
        self.assertGreater(counts['blue'], 500, 'the arm is not drawn: %s' % counts)
        self.assertGreater(counts['tf_red'], 30, 'the TF axes are not drawn: %s' % counts)
        self.assertGreater(counts['tf_green'], 10, 'the TF axes are not drawn: %s' % counts)

    def test_rviz_finds_the_root_and_frames_any_robot(self):
        """forward_kinematics.launch rviz:=true on the KUKA LWR (the whole arm in view, its top was cut off) and on
        robots the package has never seen, the Panda and the PR2 (their meshes are not installed here, so rviz
        draws their frames): the fixed frame is found from the URDF, so the TF axes are drawn."""
        robots = os.path.realpath(os.path.join(rospkg.RosPack().get_path('robot_ai'), '..', '..', '..', '..',
                                               'shared', 'robots'))
        for name, args in (('kuka_lwr', ['robot:=kuka_lwr']), ('panda', [f'model:={robots}/panda.urdf']),
                           ('pr2', [f'model:={robots}/pr2.urdf'])):
            counts = self.rviz_screenshot(args + ['rviz:=true'], f'rviz_{name}.png',
                                          lambda c: c['tf_red'] > 20 and c['tf_green'] > 10 and (
                                              name != 'kuka_lwr' or c['orange'] > 800),
                                          'forward_kinematics.launch')
            self.assertGreater(counts['tf_red'], 20, f'{name}: no frames drawn: {counts}')
            self.assertGreater(counts['tf_green'], 10, f'{name}: no frames drawn: {counts}')
            if name == 'kuka_lwr':     # the whole arm inside the 3D view, clear of its top and bottom edges
                self.assertGreater(counts['orange'], 800, counts)
                top, bottom = counts['view']
                self.assertGreater(counts['orange_top'], top + 20, counts)
                self.assertLess(counts['orange_bottom'], bottom - 20, counts)

    def test_cartpole_rviz_screenshot_shows_the_pole_balancing(self):
        """cartpole.launch rviz:=true: the rail (its red end stops), the blue cart and the orange pole, upright."""
        def drawn(c):
            return c['orange'] > 150 and c['blue'] > 800 and c['tf_red'] > 20 and c['pole_rows'] > 60
        counts = self.rviz_screenshot(['rviz:=true'], 'cartpole_rviz_screenshot.png', drawn, 'cartpole.launch')
        self.assertGreater(counts['blue'], 800, f'the cart is not drawn: {counts}')
        self.assertGreater(counts['orange'], 150, f'the pole is not drawn: {counts}')
        self.assertGreater(counts['tf_red'], 20, f'the rail\'s end stops are not drawn: {counts}')
        # upright: the pole spans many rows, and its top stands well above the cart
        self.assertGreater(counts['pole_rows'], 60, f'the pole is not upright: {counts}')
        self.assertLess(counts['orange_top'], counts['blue_top'] - 50, f'the pole is not above the cart: {counts}')

    def test_reach_in_rviz_a_clicked_point_is_reached(self):
        """Issue 31: reach.launch with rviz under Xvfb; a user picks rviz's Publish Point tool and clicks on the arm
        (rviz picks a point on what it draws): the point goes out on /clicked_point, reach_controller (ARS trained at
        its start) drives the arm to it, and rviz draws the arm with the goal's green sphere at its tip."""
        display, xvfb = start_xvfb('1280x1024')
        proc = None
        env = dict(os.environ, DISPLAY=display)
        try:
            proc = launch(['rviz:=true'], env, launch_file='reach.launch')
            deadline = time.time() + 240      # ARS learns at the controller's start
            while time.time() < deadline:
                listed = subprocess.run(['rosservice', 'list'], env=proc.env, capture_output=True, text=True,
                                        timeout=30).stdout
                if '/reach_controller/home' in listed:
                    break
                self.assertIsNone(proc.poll())
                time.sleep(1.0)
            self.assertIn('/reach_controller/home', listed)
            time.sleep(8.0)                   # rviz's window and the arm's model
            clicked = subprocess.Popen(['rostopic', 'echo', '-n', '1', '/clicked_point'], env=proc.env,
                                       stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            xdo = ['xdotool']
            # the view (x 364-1007, y 63-690 on this screen): points around its middle until rviz finds the arm
            spots = [(686 + dx, 400 + dy) for r in range(0, 200, 25) for dx, dy in
                     ((-r, 0), (r, 0), (0, -r), (0, r), (-r, -r), (r, r), (-r, r), (r, -r))]
            for x, y in spots:
                subprocess.run(xdo + ['mousemove', '356', '42', 'click', '1'], env=env, timeout=10)   # Publish Point
                subprocess.run(xdo + ['mousemove', str(x - 3), str(y)], env=env, timeout=10)
                time.sleep(0.3)
                subprocess.run(xdo + ['mousemove', str(x), str(y), 'click', '1'], env=env, timeout=10)
                try:
                    out, _ = clicked.communicate(timeout=1.5)
                    break
                except subprocess.TimeoutExpired:
                    continue
            else:
                clicked.kill()
                self.fail('no click on the arm published a point')
            self.assertIn('frame_id: "base_link"', out)
            # the goal on the surface rviz picked, facing the view: drawn before the arm's own links can hide it
            os.makedirs(ARTIFACTS, exist_ok=True)
            # the goal's marker as clicked: the green pixels drawn with rviz's Goal display on and not with it off
            # (the TF display's y axes are green too; counted around the click, they made 72 pixels of a marker
            # the arm's links hid, and the test failed on what it could not see)
            marker_clicked = self.marker_pixels(display, env, 'reach_rviz_clicked')
            deadline, distance = time.time() + 60, float('inf')
            while time.time() < deadline and distance >= 0.05:
                echo = subprocess.run(['rostopic', 'echo', '-n', '1', '/reach_controller/distance'], env=proc.env,
                                      capture_output=True, text=True, timeout=30).stdout
                if 'data:' in echo:
                    distance = float(echo.split('data:')[1].split()[0])
            self.assertLess(distance, 0.05, out)
            time.sleep(2.0)
            marker_reached = self.marker_pixels(display, env, 'reach_rviz')
            img = np.asarray(Image.open(os.path.join(ARTIFACTS, 'reach_rviz.png')).convert('RGB')).astype(int)
            img = img[63:690, 364:1007]
            r, g, b = img[..., 0], img[..., 1], img[..., 2]
            orange = int(((r > 190) & (g > 70) & (g < 160) & (b < 70)).sum())
            self.assertGreater(orange, 1500, 'the arm is not drawn')
            # a sphere of 0.05 m is some 300 pixels here unhidden; clicked on a link's surface that faces the view,
            # its front half shows at least; reached, the tip is inside it and the wrist may hide most of it
            self.assertGreater(max(marker_clicked, marker_reached), 40,
                               f'the goal\'s marker is not drawn: {marker_clicked} pixels of it as clicked, '
                               f'{marker_reached} as reached')
        finally:
            if proc is not None:
                stop(proc)
            xvfb.kill()
            xvfb.wait()

    @staticmethod
    def marker_pixels(display: str, env: dict, name: str, timeout: float = 30.0) -> int:
        """The pixels of rviz's view (x 364-1007, y 63-690 on a 1280 x 1024 screen) that are green with its Goal
        display on and not with it off: screenshots name_on.png and name.png (the Goal display's checkbox, at
        (180, 170), clicked off, then on again). A loaded machine's rviz draws seconds late: the screenshot with it
        off is taken again until it differs and settles, or timeout."""
        def green(path):
            subprocess.run(['import', '-window', 'root', '-display', display, path], check=True, timeout=60)
            img = np.asarray(Image.open(path).convert('RGB')).astype(int)[63:690, 364:1007]
            r, g, b = img[..., 0], img[..., 1], img[..., 2]
            return (g > 90) & (g - r > 40) & (g - b > 40)

        def toggle():
            subprocess.run(['xdotool', 'mousemove', '180', '170', 'click', '1'], env=env, timeout=10)

        on = green(os.path.join(ARTIFACTS, f'{name}_on.png'))
        toggle()
        try:
            deadline, last = time.time() + timeout, None
            while True:
                time.sleep(1.0)
                shown = int((on & ~green(os.path.join(ARTIFACTS, f'{name}.png'))).sum())
                if (shown and shown == last) or time.time() > deadline:
                    return shown
                last = shown
        finally:
            toggle()

    def test_demo_rviz_shows_the_arm_and_the_cart_pole(self):
        """Issue 27: demo.launch rviz:=true showed the arm only, not the cart-pole the demo also drives: a second
        rviz window, to the right of the arm's (x 1030 on a screen wide enough), shows the cart-pole."""
        def drawn(c):      # the arm moves: folded, it shows about 900 orange pixels, stretched out 4000
            return (c['arm']['orange'] > 600 and c['arm']['blue'] > 500 and c['cartpole']['blue'] > 200
                    and c['cartpole']['orange'] > 40)
        counts = self.rviz_screenshot(['rviz:=true', 'record_video:=false',
                                       'output_dir:=' + os.path.join(ARTIFACTS, 'rviz_both')], 'rviz_demo_both.png',
                                      drawn, size='1700x768',
                                      crop={'arm': (0, 0, 1024, 768), 'cartpole': (1030, 0, 1700, 768)})
        self.assertGreater(counts['arm']['orange'], 600, f'the arm is not drawn: {counts}')
        self.assertGreater(counts['arm']['blue'], 500, f'the arm is not drawn: {counts}')
        self.assertGreater(counts['cartpole']['blue'], 200, f'the cart is not drawn: {counts}')
        self.assertGreater(counts['cartpole']['orange'], 40, f'the pole is not drawn: {counts}')


# The cases under Xvfb (rviz and the sliders) run as launch_rviz.test, the others as launch.test: make test runs the
# two side by side (each case alone in either).
RVIZ_CASES = ('test_sliders_under_xvfb', 'test_sliders_stay_visible_beside_rviz',
              'test_rviz_screenshot_shows_robot_and_frames', 'test_rviz_finds_the_root_and_frames_any_robot',
              'test_cartpole_rviz_screenshot_shows_the_pole_balancing', 'test_reach_in_rviz_a_clicked_point_is_reached',
              'test_demo_rviz_shows_the_arm_and_the_cart_pole')


if __name__ == '__main__':
    rviz = 'rviz' in sys.argv[1:]
    rostest.rosrun('robot_ai', 'test_launch_rviz' if rviz else 'test_launch',
                   cases_of(TestLaunch, RVIZ_CASES, rviz, 'TestLaunchRviz' if rviz else 'TestLaunchFiles'))
