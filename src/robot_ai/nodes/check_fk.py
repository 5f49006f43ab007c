"""check_fk: grade a forward-kinematics node (a student's, say) against robot_ai's kinematics.

    rosrun robot_ai check_fk --model my_robot.urdf --candidate my_pkg/my_fk_node [--configurations 50]
                             [--seed 0] [--tolerance 1e-6] [--timeout 5]

It starts a roscore of its own when none runs, then the candidate with its /tf and /tf_static remapped into a
namespace of its own, reading the URDF from robot_description in that namespace (and from /robot_description,
set while the check runs if nothing else set it), and drives it with joint_states: the zero pose, then seeded
random configurations within the joints' limits. The reference poses are computed in this process from the URDF
(robot_ai.kinematics, what forward_kinematics publishes, equal to robot_state_publisher), so nothing the candidate
does can stop, spoof or reconfigure them. A configuration counts once the candidate's poses have settled for it
(see grade()), whatever its stamps and however slow its callback. The candidate's output is drained into a log
file, and its last lines are quoted when it dies or publishes nothing. It prints a table per link and a verdict,
and exits 0 on PASS, 1 on FAIL, 2 on bad arguments.
"""
import argparse
import collections
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from robot_ai import candidates, sandbox
from robot_ai.child_process import PR_SET_CHILD_SUBREAPER, descendants, prctl, reap
from robot_ai.fk_grading import Grade, comparison_frame, configurations
from robot_ai.kinematics import KinematicTree, URDFError, prefix_frame

RESEND = 0.2            # seconds without a tf message after which the configuration is sent again
STABLE = 3              # fresh tf messages in a row with the same poses: the candidate's answer
QUIET = 0.03            # seconds without a tf message after an answer before the next send: a node that publishes
                        # a message per link answers one send with a burst, which must not bring a send per message
SAME_AS_BEFORE = 15     # fresh messages with the previous configuration's poses after which they are the answer
MAX_MESSAGES = 400      # fresh messages for one configuration whose poses never settle: the last ones count
STARTUP = 120.0         # seconds a candidate may take to register with the master (a loaded machine is slow)
SUBSCRIBE = 10.0        # seconds from then to its joint_states subscription (it reads the URDF first)
MAX_CONFIGURATIONS = 10000
MAX_TIMEOUT = 600.0     # seconds
MAX_FRAMES = 10000      # frame names a candidate's tree may introduce before the rest are only counted
MAX_NAME = 120          # characters of a frame name kept for the report
TAIL_LINES = 20         # lines of the candidate's output quoted in a verdict
TAIL_CHARS = 300        # characters kept of each of them
LOG_BYTES = 10 * 1024 * 1024   # the candidate's log file stops growing here (its output is still drained)
CHUNK = 64 * 1024              # bytes of the candidate's output read at a time
BUDGET_BASE = 120.0            # seconds: the default --budget is this plus BUDGET_PER_CONFIGURATION per configuration
BUDGET_PER_CONFIGURATION = 3.0
RESULT_BYTES = 64 * 1024       # a judge's result (JSON) is at most this
REPORT_TAIL = 64 * 1024        # bytes of a judge's report a class run keeps in memory


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def start_master():
    """The roscore process this starts, or None when a master already runs (ROS_MASTER_URI)."""
    import rosgraph
    if rosgraph.is_master_online():
        return None
    port = free_port()
    os.environ['ROS_MASTER_URI'] = f'http://127.0.0.1:{port}'
    return subprocess.Popen(['roscore', '-p', str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=os.setsid)


def wait_for_master(core) -> None:
    import rosgraph
    deadline = time.time() + 30
    while core is not None and not rosgraph.is_master_online():
        if time.time() > deadline or core.poll() is not None:
            raise RuntimeError(f'could not start a roscore at {os.environ["ROS_MASTER_URI"]}')
        time.sleep(0.2)


def stop(proc, timeout: float = 10) -> None:
    """SIGINT to the process's group (it was started in a session of its own), then SIGKILL to what is left of the
    group: a child that ignores SIGINT, or outlives its parent, does not survive."""
    if proc is None:
        return
    if proc.poll() is None:
        _signal_group(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
    _signal_group(proc.pid, signal.SIGKILL)
    proc.wait()


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Output:
    """A process's stdout and stderr, drained by a thread into a log file (bounded), its last lines kept."""

    def __init__(self, stream, path: str):
        self.path = path
        self.tail = collections.deque(maxlen=TAIL_LINES)
        self.thread = threading.Thread(target=self._drain, args=(stream,), daemon=True)
        self.thread.start()

    def _drain(self, stream):
        """Read the output in pieces of at most CHUNK bytes, whatever it writes (1 GiB without a newline
        included): the log is cut at LOG_BYTES, a line kept for the tail at TAIL_CHARS."""
        written, line = 0, b''
        try:
            log = open(self.path, 'wb')
        except OSError:
            log, self.path = None, ''
        fd = stream.fileno()
        while True:
            try:
                chunk = os.read(fd, CHUNK)
            except OSError:
                break
            if not chunk:
                break
            if log is not None and written < LOG_BYTES:
                log.write(chunk[:LOG_BYTES - written])
                written += len(chunk)
            *complete, rest = chunk.split(b'\n')
            for piece in complete:
                self._keep((line + piece)[:4 * TAIL_CHARS])
                line = b''
            line = (line + rest)[:4 * TAIL_CHARS]
        if line:
            self._keep(line)
        if log is not None:
            log.close()

    def _keep(self, line: bytes) -> None:
        text = line.decode(errors='replace').rstrip()
        if text:    # escaped: a carriage return or an escape sequence in it cannot rewrite a line of the report
            self.tail.append(sandbox.printable(text, TAIL_CHARS))

    def lines(self) -> list[str]:
        """The last lines of its output, indented, and where the whole output is; [] if there was none."""
        self.thread.join(1.0)
        if not self.tail:
            return []
        where = [f'  (its whole output: {self.path})'] if self.path else []
        return ['its last output:'] + ['  | ' + l for l in self.tail] + where


class TfTree:
    """The candidate's tf tree, from its remapped /tf and /tf_static: statics kept, the rest per configuration."""

    def __init__(self, ns: str):
        import rospy
        import tf2_ros
        from tf2_msgs.msg import TFMessage
        self._tf2 = tf2_ros
        self.statics, self.frames, self.children, self.received, self.non_finite = [], set(), set(), 0, []
        self.buffer = tf2_ros.Buffer(cache_time=rospy.Duration(60))
        self.subs = [rospy.Subscriber(f'{ns}/candidate/tf', TFMessage, self._on_tf, queue_size=1000),
                     rospy.Subscriber(f'{ns}/candidate/tf_static', TFMessage, self._on_static, queue_size=100)]

    @staticmethod
    def _name(frame: str) -> str:
        """A frame's name as the report shows it: escaped (a name holding a newline or a carriage return stays on
        its line), so a frame with such characters is never one of the URDF's links."""
        return sandbox.printable(frame[1:] if frame.startswith('/') else frame, MAX_NAME)

    def _check(self, msg) -> None:
        for t in msg.transforms:
            child = self._name(t.child_frame_id)
            if len(self.frames) < MAX_FRAMES:   # a flood of ever-new names is counted, not kept
                self.frames.update((self._name(t.header.frame_id), child))
                self.children.add(child)
            r, p = t.transform.rotation, t.transform.translation
            if not all(math.isfinite(v) for v in (r.x, r.y, r.z, r.w, p.x, p.y, p.z)):
                self.non_finite.append(child)

    def parentless(self) -> set:
        """Frames that are some transform's parent and no transform's child."""
        return self.frames - self.children

    def _on_tf(self, msg) -> None:
        self._check(msg)
        self.received += 1
        buf = self.buffer
        for t in msg.transforms:
            buf.set_transform(t, 'check_fk')

    def _on_static(self, msg) -> None:
        self._check(msg)
        self.statics.extend(msg.transforms)
        for t in msg.transforms:
            self.buffer.set_transform_static(t, 'check_fk')

    def next_configuration(self) -> None:
        """Forget the moving transforms of the last configuration; keep the static ones."""
        import rospy
        buf = self._tf2.Buffer(cache_time=rospy.Duration(60))
        for t in self.statics:
            buf.set_transform_static(t, 'check_fk')
        self.buffer = buf

    def poses(self, frame: str, links: dict) -> dict:
        """{link: 4x4 pose in frame} for the links ({URDF link: tf frame}) this tree can give now."""
        import rospy
        from tf import transformations as tft
        out = {}
        for link, name in links.items():
            try:
                t = self.buffer.lookup_transform(frame, name, rospy.Time(0))
            except (self._tf2.LookupException, self._tf2.ConnectivityException, self._tf2.ExtrapolationException):
                continue
            r, p = t.transform.rotation, t.transform.translation
            m = tft.quaternion_matrix([r.x, r.y, r.z, r.w])
            m[:3, 3] = [p.x, p.y, p.z]
            out[link] = m
        return out


def parse_args(argv):
    p = argparse.ArgumentParser(prog='rosrun robot_ai check_fk', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                                description='Grade a forward-kinematics node against robot_ai\'s kinematics '
                                '(equal to robot_state_publisher): exit status 0 on PASS, 1 on FAIL.')
    p.add_argument('--model', required=True, help='the URDF or xacro file')
    p.add_argument('--xacro-args', default='', help='the xacro file\'s arguments: "name:=value name2:=value2"')
    p.add_argument('--candidate', help='the node to grade: PACKAGE/TYPE (what rosrun takes) or a file (a student\'s '
                   'solution.py); a Python file runs with this Python whatever its #! line says')
    p.add_argument('--candidates', metavar='DIR', help='grade a class: the node in each folder of DIR (one folder per '
                   'student), each in a sandbox of its own (see --no-sandbox), one line per student and a CSV')
    p.add_argument('--csv', default='', help='with --candidates: where the CSV goes (default: check_fk_<DIR>.csv '
                   'in the current folder); each student\'s report goes to a folder beside it')
    p.add_argument('--jobs', type=int, default=0, help='with --candidates: students graded at once (0: one per core)')
    p.add_argument('--expect', choices=('pass', 'fail'), default='pass',
                   help='the verdict that makes the exit status 0 (fail: a course\'s test that a wrong node is caught)')
    p.add_argument('--configurations', type=int, default=50, help='joint configurations: the zero pose, then random')
    p.add_argument('--seed', type=int, default=0, help='seed of the random configurations')
    p.add_argument('--tolerance', type=float, default=1e-6, help='largest error allowed, in m and rad')
    p.add_argument('--timeout', type=float, default=5.0, help='seconds a configuration may take to appear on tf')
    p.add_argument('--budget', type=float, default=0.0,
                   help=f'wall-clock seconds one check may take, the candidate\'s start included, before it ends with '
                   f'a verdict that says so; 0: {BUDGET_BASE:g} + {BUDGET_PER_CONFIGURATION:g} per configuration '
                   f'(270 s for 50)')
    p.add_argument('--sandbox', action='store_true', help='with --candidate: run it in a sandbox, as --candidates '
                   'runs every student (root; bubblewrap and util-linux)')
    p.add_argument('--no-sandbox', action='store_true', help='with --candidates: run the students as yourself, with '
                   'your files and network (only for code you trust)')
    p.add_argument('--gtest_output', default='', help=argparse.SUPPRESS)  # rostest's: xml:<results file>
    # a class run's judge: the check of one student, in a network namespace of its own, the student sandboxed
    p.add_argument('--judge-uid', type=int, default=-1, help=argparse.SUPPRESS)
    p.add_argument('--judge-folder', default='', help=argparse.SUPPRESS)
    p.add_argument('--judge-hide', action='append', default=[], help=argparse.SUPPRESS)
    p.add_argument('--result-fd', type=int, default=-1, help=argparse.SUPPRESS)
    p.add_argument('--judge-shown', default='', help=argparse.SUPPRESS)   # the candidate as the user named it
    a = p.parse_args(argv)
    if (a.candidate is None) == (a.candidates is None):
        p.error('give one of --candidate (a node) and --candidates (a folder of student folders)')
    if a.candidates is not None and not os.path.isdir(a.candidates):
        p.error(f'--candidates must be a folder of student folders, got {a.candidates!r}')
    if a.candidate is not None and not os.path.isfile(a.candidate) and (
            a.candidate.count('/') != 1 or not all(a.candidate.split('/'))):
        p.error(f'--candidate must be PACKAGE/TYPE, as rosrun takes it, or a file, got {a.candidate!r}')
    if not 0 <= a.jobs <= 64:
        p.error(f'--jobs must be 0 to 64, got {a.jobs}')
    if not 1 <= a.configurations <= MAX_CONFIGURATIONS:
        p.error(f'--configurations must be 1 to {MAX_CONFIGURATIONS}, got {a.configurations}')
    if not (0 < a.tolerance < math.inf and 0 < a.timeout <= MAX_TIMEOUT):   # NaN fails too
        p.error(f'--tolerance must be a positive number and --timeout one of at most {MAX_TIMEOUT:g} s, got '
                f'{a.tolerance:g} and {a.timeout:g}')
    if not 0 <= a.budget <= 24 * 3600:
        p.error(f'--budget must be 0 (the default) to {24 * 3600} seconds, got {a.budget:g}')
    if a.sandbox and a.candidates is not None:
        p.error('--sandbox is for --candidate; --candidates sandboxes every student unless --no-sandbox')
    if (a.sandbox or (a.candidates is not None and not a.no_sandbox)) and a.judge_uid < 0:
        problem = sandbox.unavailable()
        if problem:
            p.error(problem)
    return a


def read_model(path: str, xacro_args: str = '') -> tuple[str, KinematicTree]:
    """(the URDF text, its tree); a xacro file expanded first (robot_ai.urdf_source, with xacro_args); ValueError
    with one line for anything that is not a URDF this can grade."""
    from robot_ai.urdf_source import XacroError, expand, parse_mappings
    try:
        xml = expand(path, parse_mappings(xacro_args.split()))
    except XacroError as e:
        message = str(e)
        raise ValueError('cannot read the model ' + message[len('cannot read '):] if message.startswith('cannot read ')
                         else message)
    xacro = (f'{path} looks like unexpanded xacro without the xacro namespace: expand it first (rosrun robot_ai '
             f'xacro {path} > robot.urdf) and grade the URDF')
    try:
        tree = KinematicTree.from_xml_string(xml)
    except URDFError as e:
        if '${' in xml or '<xacro:' in xml:     # ${half_pi} in an rpy, a macro call where a link should be
            raise ValueError(f'{xacro} ({e})')
        raise ValueError(f'cannot read the model {path}: {e}')
    except (Exception, RecursionError) as e:    # whatever a hostile file does to the parser: one line
        raise ValueError(f'cannot read the model {path}: {type(e).__name__}: {" ".join(str(e).split())[:300]}')
    # an expanded URDF may keep xacro calls and ${...} in blocks nobody reads (the PR2's, the course's KUKA), but
    # no definitions: with them, links inside macros would load as a robot of one link
    if any(d in xml for d in ('<xacro:macro', '<xacro:property', '<xacro:include', '<xacro:arg')):
        raise ValueError(f'{xacro}: it defines xacro macros or properties')
    return xml, tree


def log_path(candidate: str) -> str:
    """Where the candidate's output goes: $ROS_HOME/log/check_fk_<candidate>_<pid>.log."""
    folder = os.path.join(os.environ.get('ROS_HOME') or os.path.expanduser('~/.ros'), 'log')
    os.makedirs(folder, exist_ok=True)
    return os.path.join(folder, f'check_fk_{candidate.replace("/", "_")}_{os.getpid()}.log')


def candidate_command(candidate: str) -> tuple[list[str], str | None]:
    """(the command that starts the candidate, its file or None): a file as it is, PACKAGE/TYPE found as rosrun
    finds it; a Python file runs with this Python (a course node's `#!/usr/bin/env python` names no command on
    Debian 12, or pyenv's Python without ROS's modules). Not found: rosrun, which says what is missing."""
    if os.path.isfile(candidate):
        path = os.path.abspath(candidate)
    else:
        pkg, node_type = candidate.split('/')
        try:
            import roslib.packages
            found = roslib.packages.find_resource(pkg, node_type)
        except Exception:     # an unknown package: rosrun's own words
            found = []
        if len(found) != 1:   # none, or several (rosrun asks which): rosrun's own words
            return ['rosrun', pkg, node_type], None
        path = found[0]
    return candidates.command(path, sys.executable), path


def exit_status(verdict: str, expect: str) -> int:
    """0 when the verdict is the one expected (--expect pass: PASS; --expect fail: a FAIL), else 1."""
    return 0 if verdict.startswith('PASS') == (expect == 'pass') else 1


def result_of(lines: list[str], tree, status: int, seconds: float) -> dict:
    """What a judge hands its class run (JSON on --result-fd): the verdict line, the score, the first wrong link,
    the exit status; from this process's own report, never from text the candidate wrote."""
    r = candidates.Result.of('', '\n'.join(lines), seconds, tree.links)
    return dict(verdict=r.verdict, score=r.score, first_wrong_link=r.first_wrong_link, status=status,
                seconds=round(seconds, 3))


def finish(a, tree, lines: list[str], seconds: float) -> int:
    """Print the report (every line escaped: one line each, whatever the candidate's names and output held), write
    rostest's results file and a judge's result; the exit status."""
    lines = [sandbox.printable(line, 2000, backslashes=False) for line in lines]
    print('\n'.join(lines), flush=True)
    status = exit_status(lines[-1], a.expect)
    if a.gtest_output.startswith('xml:'):
        write_junit(a.gtest_output[4:], a.judge_shown or a.candidate, lines, seconds, a.expect)
    if a.result_fd >= 0:
        import json
        data = json.dumps(result_of(lines, tree, status, seconds)).encode()[:RESULT_BYTES]
        try:
            os.write(a.result_fd, data)
            os.close(a.result_fd)
        except OSError:
            pass
    return status


def sandboxed(a) -> bool:
    return a.judge_uid >= 0


def reexec_in_namespaces(a, argv) -> int:
    """--candidate with --sandbox: this check again as a judge in a network, PID and mount namespace of its own
    (its own master, the candidate as a user of its own, a copy of its folder); its exit status."""
    uid = sandbox.uid_for(os.getpid(), 0)
    work = tempfile.mkdtemp(prefix='check_fk_sandbox_')
    candidate, folder = a.candidate, ''
    try:
        if os.path.isfile(a.candidate):
            source = os.path.abspath(a.candidate)
            folder = os.path.join(work, 'student')
            try:
                sandbox.copy_folder(os.path.dirname(source), folder, uid)
            except (sandbox.SandboxError, OSError) as e:   # ~/solution.py: its folder is a home, not a submission
                shutil.rmtree(folder, ignore_errors=True)
                alone = os.path.join(work, 'alone')
                os.mkdir(alone)
                shutil.copy2(source, alone)
                sandbox.copy_folder(alone, folder, uid)
                print(f'check_fk: the sandbox holds {sandbox.printable(os.path.basename(source))} alone: its folder '
                      f'cannot be copied ({sandbox.printable(str(e))})', flush=True)
            candidate = os.path.join(folder, os.path.basename(source))
        words = argv + ['--candidate', candidate]   # the last --candidate is argparse's: the copy
        cmd = sandbox.judge_prefix() + [sys.executable, '-c', JUDGE] + words + [
            '--judge-uid', str(uid), '--judge-folder', folder, '--judge-hide', work, '--judge-shown', a.candidate]
        proc = subprocess.Popen(cmd, env=judge_env())
        try:
            return proc.wait()
        except BaseException:
            proc.kill()
            proc.wait()
            raise
    finally:
        shutil.rmtree(work, ignore_errors=True)


JUDGE = 'import sys; from robot_ai.nodes.check_fk import main; sys.exit(main(sys.argv[1:]))'


def judge_env() -> dict:
    """A judge's environment: ROS on loopback (its network namespace has nothing else)."""
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_IP', 'ROS_HOSTNAME', 'ROS_MASTER_URI')}
    env.update(ROS_HOSTNAME='127.0.0.1', ROS_MASTER_URI='http://127.0.0.1:11311')
    return env


def main(argv=None) -> int:
    import rospy
    # ROS's special arguments (rostest's __name:=, __log:=) are not check_fk's; rospy.myargv would also drop every
    # word with := in it, xacro's name:=value arguments included
    argv = [w for w in sys.argv[1:] if not w.startswith('__')] if argv is None else argv
    a = parse_args(argv)
    try:
        xml, tree = read_model(a.model, a.xacro_args)
    except ValueError as e:
        print(f'check_fk: {e}', file=sys.stderr)
        return 2
    if a.sandbox and not sandboxed(a):
        return reexec_in_namespaces(a, argv)
    command, source = candidate_command(a.candidate) if a.candidate is not None else ([], None)
    if source is not None:
        verdict = None
        if candidates.is_python(source):
            verdict = candidates.syntax_verdict(source)        # a Python 2 file: a verdict, not the node's traceback
        elif not os.access(source, os.X_OK):
            verdict = (f'FAIL: {sandbox.printable(os.path.basename(source))} is neither a Python file (.py, or a #! '
                       f'line naming python) nor executable: the node cannot start')
        if verdict is not None:
            print(f'check_fk: {sandbox.printable(a.judge_shown or a.candidate)} on {a.model}')
            return finish(a, tree, [verdict], 0.0)
    # Ctrl-C, SIGTERM (what `timeout` sends) and SIGHUP (the terminal closed) end the grade and clean up; a second
    # signal while it cleans up is ignored, so that the clean-up always finishes. As a child subreaper, check_fk
    # inherits every process the candidate leaves behind (a double fork into a session of its own included).
    stopping = []

    def on_signal(signum, frame):
        if stopping:
            return
        stopping.append(signum)
        raise SystemExit(128 + signum)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, on_signal)
    if a.candidates is not None:
        try:
            return grade_class(a, tree, argv)
        finally:
            stopping.append('clean-up')
    prctl(PR_SET_CHILD_SUBREAPER, 1)
    core = proc = None
    own_global = False
    env = None
    budget_end = time.monotonic() + budget_of(a)
    try:
        if sandboxed(a):
            sandbox.loopback_up()          # this judge's own network namespace: loopback, and its master on it
        core = start_master()
        wait_for_master(core)
        from sensor_msgs.msg import JointState
        rospy.init_node('check_fk', anonymous=True, disable_signals=True,
                        argv=[sys.argv[0]] + [w for w in sys.argv[1:] if w.startswith('__') and ':=' in w])
        ns = f'/check_fk_{os.getpid()}'
        rospy.set_param(ns + '/robot_description', xml)
        if not rospy.has_param('/robot_description'):  # for nodes that read the absolute name
            rospy.set_param('/robot_description', xml)
            own_global = True
        candidate = TfTree(ns)
        remaps = ['__name:=candidate', f'__ns:={ns}', f'/joint_states:={ns}/joint_states',
                  f'/tf:={ns}/candidate/tf', f'/tf_static:={ns}/candidate/tf_static']
        if sandboxed(a):
            folder = a.judge_folder or tempfile.mkdtemp(prefix='check_fk_empty_')
            inside = [('/student' + w[len(folder):]) if folder and w.startswith(folder.rstrip('/') + '/') else w
                      for w in command]
            command, env = sandbox.candidate_command(inside, a.judge_uid, folder, sandbox.Limits(
                cpu_seconds=int(budget_of(a)) + 60), a.judge_hide)
            env['ROS_MASTER_URI'] = os.environ['ROS_MASTER_URI']
            env['ROS_HOSTNAME'] = '127.0.0.1'
        proc = subprocess.Popen(command + remaps, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, preexec_fn=os.setsid, env=env)
        output = Output(proc.stdout, log_path((a.judge_shown or a.candidate).strip('/').replace(os.sep, '_')))
        pub = rospy.Publisher(ns + '/joint_states', JointState, queue_size=10)
        t0 = time.time()
        print(f'check_fk: {sandbox.printable(a.judge_shown or a.candidate)} on {a.model} ({len(tree.links)} links, '
              f'{len(tree.active_joints)} driven joints), {a.configurations} configurations', flush=True)
        lines, _ = grade(tree, a, candidate, proc, output, pub, JointState, budget_end)
        return finish(a, tree, lines[:-1] + [f'(graded in {time.time() - t0:.1f} s)', lines[-1]], time.time() - t0)
    finally:
        stopping.append('clean-up')
        stop(proc)
        end_descendants(keep=core)
        try:
            if rospy.core.is_initialized():
                rospy.delete_param(f'/check_fk_{os.getpid()}')
                if own_global:
                    rospy.delete_param('/robot_description')
        except Exception:
            pass
        if rospy.core.is_initialized():
            rospy.signal_shutdown('check_fk done')
        stop(core)
        end_descendants()


class Reader:
    """A judge's stdout, drained by a thread: its last REPORT_TAIL bytes kept, the whole (up to LOG_BYTES) written to
    a report file."""

    def __init__(self, stream, path: str):
        self.tail = b''
        self.path = path
        self.thread = threading.Thread(target=self._drain, args=(stream,), daemon=True)
        self.thread.start()

    def _drain(self, stream) -> None:
        written = 0
        try:
            report = open(self.path, 'wb')
        except OSError:
            report, self.path = None, ''
        while True:
            try:
                chunk = os.read(stream.fileno(), CHUNK)
            except OSError:
                break
            if not chunk:
                break
            self.tail = (self.tail + chunk)[-REPORT_TAIL:]
            if report is not None and written < LOG_BYTES:
                report.write(chunk[:LOG_BYTES - written])
                written += len(chunk)
        if report is not None:
            report.close()

    def last_lines(self, n: int = 3) -> str:
        self.thread.join(5.0)
        lines = self.tail.decode(errors='replace').strip().splitlines()[-n:]
        return ' | '.join(sandbox.printable(line, 200) for line in lines)


def read_result(fd: int) -> dict | None:
    """A judge's result from the read end of its pipe (at most RESULT_BYTES), None when there is none or it is not
    the JSON a judge writes."""
    import json
    data = b''
    try:
        while len(data) <= RESULT_BYTES:
            chunk = os.read(fd, RESULT_BYTES)
            if not chunk:
                break
            data += chunk
    except OSError:
        return None
    finally:
        os.close(fd)
    try:
        result = json.loads(data.decode())
    except ValueError:
        return None
    if not isinstance(result, dict) or not all(isinstance(result.get(k), str) for k in
                                               ('verdict', 'score', 'first_wrong_link')):
        return None
    return result


def grade_class(a, tree, argv) -> int:
    """--candidates DIR: the node in each student folder of DIR graded by a judge of its own (a check_fk in a network,
    PID and mount namespace of its own, its own roscore; the student's node in a sandbox: see robot_ai.sandbox),
    --jobs at a time; one line per student as each ends, then the CSV. A student's verdict is the judge's result and
    exit status, which the student's code cannot write; a crash, a hang or an escape attempt is that student's
    verdict and the others go on. A signal stops the run: the CSV holds the students graded, and the rest are named.
    0 once every student has a line."""
    import concurrent.futures
    import csv
    import shutil
    folder = os.path.abspath(a.candidates)
    students = sorted(d for d in os.listdir(folder) if os.path.isdir(os.path.join(folder, d)) and d[0] != '.')
    if not students:
        print(f'check_fk: {folder} has no student folders', file=sys.stderr)
        return 2
    jobs = a.jobs or os.cpu_count() or 1
    budget = budget_of(a)
    limit = budget + 60.0             # a judge that has not ended by then is killed with its namespaces
    path = a.csv or f'check_fk_{os.path.basename(folder)}.csv'
    reports = os.path.splitext(os.path.abspath(path))[0] + '_reports'
    os.makedirs(reports, exist_ok=True)
    for old in os.listdir(reports):        # an earlier run's reports: this run's numbering may differ
        if old[:3].isdigit() and old[3:4] == '_' and old.endswith('.txt'):
            os.remove(os.path.join(reports, old))
    work = tempfile.mkdtemp(prefix='check_fk_class_')
    os.chmod(work, 0o711)
    running, lock = {}, threading.Lock()
    on_model = f'{a.model}' + (f' with xacro arguments "{a.xacro_args}"' if a.xacro_args else '')
    limits = sandbox.Limits(cpu_seconds=int(budget) + 60)
    print(f'check_fk: {len(students)} students in {sandbox.printable(folder)} on {on_model} ({len(tree.links)} '
          f'links), {a.configurations} configurations (seed {a.seed}, tolerance {a.tolerance:g}, timeout '
          f'{a.timeout:g} s), at most {budget:g} s each, {jobs} at a time')
    if a.no_sandbox:
        print('check_fk: NOT sandboxed (--no-sandbox): every student runs as you, with your files and network')
    else:
        print(f'check_fk: each student in a sandbox: a user of its own, a copy of its folder, a network of its own, '
              f'{limits.describe()}')
    print(f'check_fk: reports in {reports}', flush=True)
    options = ['--model', a.model, '--xacro-args', a.xacro_args, '--configurations', str(a.configurations),
               '--seed', str(a.seed), '--tolerance', repr(a.tolerance), '--timeout', repr(a.timeout),
               '--budget', repr(budget), '--expect', 'pass']
    stopping_class = []

    def one(index: int, student: str) -> candidates.Result:
        shown = sandbox.printable(student)
        original = os.path.join(folder, student)
        node = candidates.find_node(original)
        if node is None:
            return candidates.Result(shown, 'FAIL: no node found (no Python file that calls rospy.init_node)',
                                     '', '', 0.0)
        t = time.time()
        cmd, env, copy = [sys.executable, '-c', JUDGE] + options, None, ''
        if a.no_sandbox:
            env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{free_port()}')   # none runs there: its own
            cmd += ['--candidate', node]
        else:
            uid = sandbox.uid_for(os.getpid(), index)
            copy = os.path.join(work, str(index))
            try:
                sandbox.copy_folder(original, copy, uid)
            except (sandbox.SandboxError, OSError) as e:
                return candidates.Result(shown, f'FAIL: its folder cannot be graded: {sandbox.printable(str(e))}',
                                         '', '', 0.0)
            cmd = sandbox.judge_prefix() + cmd + [
                '--candidate', os.path.join(copy, os.path.relpath(node, original)), '--judge-uid', str(uid),
                '--judge-folder', copy, '--judge-hide', folder, '--judge-hide', reports, '--judge-hide', work]
            env = judge_env()
        read_end, write_end = os.pipe()
        try:
            with lock:
                if stopping_class:
                    return None
                proc = subprocess.Popen(cmd + ['--result-fd', str(write_end)], env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                        pass_fds=(write_end,))
                running[student] = proc
        finally:
            os.close(write_end)
        reader = Reader(proc.stdout, os.path.join(reports, f'{index:03d}_{_file_name(student)}.txt'))
        try:
            proc.wait(timeout=limit)
            timed_out = False
        except subprocess.TimeoutExpired:
            _signal_group(proc.pid, signal.SIGKILL)       # unshare, and with it the judge's namespaces
            proc.wait()
            timed_out = True
        finally:
            with lock:
                running.pop(student, None)
        result = read_result(read_end)
        if copy:
            shutil.rmtree(copy, ignore_errors=True)
        seconds = time.time() - t
        if stopping_class and (result is None or proc.returncode < 0):
            return None
        if timed_out:
            verdict = f'FAIL: grading did not end within {limit:.0f} s (its budget and a minute): ended'
            return candidates.Result(shown, verdict, '', '', seconds)
        if result is None:
            return candidates.Result(shown, f'FAIL: check_fk ended with status {proc.returncode} and no result: '
                                     f'{reader.last_lines()}', '', '', seconds)
        verdict = sandbox.printable(result['verdict'], 600, backslashes=False)
        if verdict.startswith('PASS') != (proc.returncode == 0):
            verdict = f'FAIL: check_fk said {verdict[:200]} but ended with status {proc.returncode}'
        return candidates.Result(shown, verdict, sandbox.printable(result['score'], 100, backslashes=False),
                                 sandbox.printable(result['first_wrong_link'], MAX_NAME, backslashes=False), seconds)

    results = {}
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=jobs)
    stopped = None
    try:
        futures = {pool.submit(one, i, student): student for i, student in enumerate(students)}
        for future in concurrent.futures.as_completed(futures):
            result = future.result()
            if result is not None:
                results[futures[future]] = result
                print(result.line(), flush=True)
    except BaseException as e:   # a signal: the students being graded are stopped, none starts, the CSV is written
        stopped = e
    finally:
        with lock:
            stopping_class.append(True)
            left = list(running.values())
        for proc in left:
            _signal_group(proc.pid, signal.SIGKILL)
        pool.shutdown(wait=True, cancel_futures=True)
        shutil.rmtree(work, ignore_errors=True)
        with open(path, 'w', newline='') as f:
            w = csv.writer(f)
            w.writerow(['student', 'verdict', 'score', 'first_wrong_link', 'seconds'])
            for student in students:
                r = results.get(student)
                if r is None:
                    w.writerow([sandbox.printable(student), 'not graded (check_fk was stopped)', '', '', ''])
                else:
                    w.writerow([r.student, r.verdict, r.score, r.first_wrong_link, f'{r.seconds:.1f}'])
    passed = sum(r.verdict.startswith('PASS') for r in results.values())
    if stopped is not None:
        rest = [sandbox.printable(s) for s in students if s not in results]
        print(f'check_fk: stopped: {len(results)} of {len(students)} graded ({passed} PASS); CSV: '
              f'{os.path.abspath(path)}; not graded: {", ".join(rest)}', flush=True)
        if isinstance(stopped, SystemExit):
            return stopped.code if isinstance(stopped.code, int) else 1
        raise stopped
    print(f'{passed} of {len(students)} PASS; CSV: {os.path.abspath(path)}')
    return 0


def _file_name(student: str) -> str:
    """A report file's name for a student folder's name: letters, digits, '.', '-' and '_' kept."""
    return ''.join(c if c.isalnum() or c in '.-_' else '_' for c in student)[:80] or 'student'


def end_descendants(keep=None) -> None:
    """SIGKILL every process left below this one but keep (a Popen) and its own, and reap them: check_fk is a child
    subreaper, so whatever the candidate started and left behind has become its descendant."""
    for _ in range(100):
        spared = set() if keep is None else {keep.pid, *descendants(keep.pid)}
        left = [pid for pid in descendants(os.getpid()) if pid not in spared]
        if not left:
            return
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.01)
        reap()


def write_junit(path: str, candidate: str, lines: list, seconds: float, expect: str = 'pass') -> None:
    """The results file rostest asks a <test> node for: one test case, failed unless the verdict is the one
    expected (--expect: PASS, or with fail a FAIL)."""
    from xml.sax.saxutils import escape, quoteattr
    failed = exit_status(lines[-1], expect) != 0
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    message = lines[-1] if expect == 'pass' else f'expected a FAIL, got {lines[-1]}'
    failure = (f'    <failure message={quoteattr(message)}>{escape(chr(10).join(lines))}</failure>\n'
               if failed else '')
    with open(path, 'w') as f:
        f.write(f'<?xml version="1.0" encoding="utf-8"?>\n<testsuite name="check_fk" tests="1" errors="0" '
                f'failures="{int(failed)}" time="{seconds:.3f}">\n  <testcase classname="check_fk" '
                f'name={quoteattr(candidate)} time="{seconds:.3f}">\n{failure}  </testcase>\n</testsuite>\n')


def send(pub, JointState, q: dict) -> None:
    import rospy
    msg = JointState(name=list(q), position=list(q.values()))
    msg.header.stamp = rospy.Time.now()
    pub.publish(msg)


def tf_name(link: str) -> str:
    """The frame tf2 keeps for a link: robot_state_publisher drops a leading slash, and tf2 one more."""
    frame = prefix_frame('', link)
    return frame[1:] if frame.startswith('/') else frame


def same(a: dict, b: dict, tolerance: float = 1e-9) -> bool:
    return a.keys() == b.keys() and all(np.allclose(a[k], b[k], atol=tolerance, rtol=0) for k in a)


def settle(candidate: TfTree, frame: str, links: dict, q: dict, previous: dict | None, changes: bool, pub,
           JointState, timeout: float, dead, moving: bool = True) -> dict:
    """The candidate's poses of links in frame, in answer to configuration q.

    Paced by the candidate's own messages, not the clock, so that a loaded machine gives the verdict a quiet one
    does: q is sent, and sent again only once a tf message has come since and QUIET seconds passed after it (one
    send in flight: a slow node never queues a backlog of old configurations) or RESEND seconds passed without one. The poses count once STABLE
    fresh messages in a row left them the same, and they differ from the previous configuration's (a slow node may
    still answer a copy of it first) unless the reference's do not change (`changes` false) or SAME_AS_BEFORE
    messages gave them (a node that ignores the joints). Only `timeout` seconds without any tf message, or
    MAX_MESSAGES without settling, end the wait: then the poses it has."""
    sent = -math.inf
    answered = True                   # a tf message came after the last send
    last, stable, same_as_before, messages = {}, 0, 0, 0
    received = candidate.received
    heard = time.monotonic()
    while not dead():
        now_t = time.monotonic()
        if (answered and now_t - heard >= QUIET and now_t - sent >= QUIET) or now_t - sent >= RESEND:
            send(pub, JointState, q)
            sent, answered = now_t, False
        time.sleep(0.01)
        fresh = candidate.received > received or not moving
        if not fresh:
            if time.monotonic() - heard > timeout:
                return last           # the candidate stopped answering: what it gave
            continue
        received, heard, answered = candidate.received, time.monotonic(), True
        messages += 1
        now = candidate.poses(frame, links)
        if not now or not same(now, last):
            last, stable = now, 1
        else:
            stable += 1
        if messages >= MAX_MESSAGES:
            return last
        if stable < STABLE:
            continue
        if previous is not None and changes and same(now, previous):
            same_as_before += 1
            if same_as_before < SAME_AS_BEFORE:
                continue
        return now
    return last


def registered(node: str) -> bool:
    """Whether a node of that name has registered with the master (rospy.init_node or ros::init has run)."""
    import rosnode
    try:
        return node in rosnode.get_node_names()
    except rosnode.ROSNodeIOException:
        return False


def budget_of(a) -> float:
    """--budget, or its default for the run's configurations (0 given)."""
    return a.budget or BUDGET_BASE + BUDGET_PER_CONFIGURATION * a.configurations


def grade(tree, a, candidate: TfTree, proc, output: Output, pub, JointState, budget_end: float = math.inf):
    """Drive the candidate through the configurations until budget_end (time.monotonic()); (report lines, exit
    status)."""
    names = {link: tf_name(link) for link in tree.links}     # URDF link -> the frame tf2 keeps
    link_of = {f: link for link, f in names.items()}
    done = [0]       # configurations graded

    def over():
        return time.monotonic() > budget_end

    def dead():
        return proc.poll() is not None or over()

    def died():
        """The lines that end a grade stopped early: the candidate's output, then the verdict."""
        if over():
            return output.lines() + [f'FAIL: grading did not end within its budget of {budget_of(a):g} s (--budget): '
                                     f'{done[0]} of {a.configurations} configurations graded']
        return output.lines() + [f'FAIL: the candidate node exited with status {proc.returncode}']

    if len(tree.links) == 1:
        return [f'{tree.root} is a single link with no joint: there is no transform to publish or to grade',
                'PASS'], 0
    # a node's start on a loaded machine (its imports can take many seconds) is waited for, up to STARTUP, until it
    # has registered with the master; then it has SUBSCRIBE seconds (or --timeout, if longer) to subscribe
    node = pub.resolved_name.rsplit('/', 1)[0] + '/candidate'
    deadline = time.monotonic() + STARTUP
    while not registered(node) and time.monotonic() < deadline and not dead():
        time.sleep(0.1)
    deadline = time.monotonic() + max(a.timeout, SUBSCRIBE)
    while pub.get_num_connections() < 1 and time.monotonic() < deadline and not dead():
        time.sleep(0.05)
    configs = configurations(tree, a.configurations, a.seed)
    result, graded, previous, reference = None, None, None, None
    for k, q in enumerate(configs):
        before = reference                                   # one configuration's poses at a time
        candidate.next_configuration()
        if result is None:       # the first configuration: wait for the candidate's frames, then choose the frame
            # until its set of frames stays the same over STABLE fresh messages (a node that publishes a message
            # per link sends them over a while), at least 1 s; nothing at all within the timeout is a verdict
            start = time.monotonic()
            known, unchanged, received = set(), 0, candidate.received
            while time.monotonic() < start + a.timeout or candidate.frames:
                if dead():
                    break
                send(pub, JointState, q)
                time.sleep(0.1)
                fresh = candidate.received > received or not tree.active_joints
                received = candidate.received
                if candidate.frames and time.monotonic() > start + 3 * a.timeout:
                    break                # statics only, a node gone quiet, frames that never settle: what it has
                if not candidate.frames or not fresh:
                    continue
                unchanged = unchanged + 1 if candidate.frames == known else 0
                known = set(candidate.frames)
                if unchanged >= STABLE and time.monotonic() > start + 1.0:
                    break
            if dead():
                return died(), 1
            if not candidate.frames:
                return output.lines() + [f'FAIL: the candidate published nothing on /tf or /tf_static within '
                                         f'{a.timeout:g} s of the first joint_states'], 1
            ours = {link_of[f] for f in candidate.frames if f in link_of}
            if not ours and len(candidate.frames) > 1:
                others = sorted(candidate.frames)
                return output.lines() + [
                    f'FAIL: the candidate publishes frames the URDF does not have ({", ".join(others[:5])}'
                    f'{", ..." if len(others) > 5 else ""}) and none of its {len(tree.links)} links: is it written for '
                    f'another robot? This one\'s root is {tree.root}'], 1
            frame, note = comparison_frame(tree, {link_of.get(f, f) for f in candidate.frames},
                                           candidate.parentless())
            result = Grade(tree, None if frame is None else link_of.get(frame, frame), a.tolerance, note)
            result.extra = {f for f in candidate.frames if f not in link_of} - {frame}
            if frame is None:
                return result.report(), 1
            frame_name = names.get(frame, frame)
            graded = {link: names[link] for link in result.links}
        reference = result.reference_poses(q)       # from the root, or from a floating joint's child
        changes = before is None or not same(reference, before)
        got = settle(candidate, frame_name, graded, q, previous, changes, pub, JointState, a.timeout, dead,
                     moving=bool(tree.active_joints))
        if dead():
            return result.report()[:-1] + died(), 1
        if candidate.non_finite:
            result.problems.append(f'the candidate published a non-finite (NaN or inf) transform for '
                                   f'{candidate.non_finite[0]}')
            return result.report(), 1
        previous = got
        result.add(k, q, reference, got)
        done[0] = k + 1
    return result.report(), 0 if result.verdict() == 'PASS' else 1
