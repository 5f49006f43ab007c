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
import math
import os
import signal
import subprocess
import sys
import tempfile
import time

from robot_ai.child_process import PR_SET_CHILD_SUBREAPER, prctl
from robot_ai.grading import candidates, sandbox
from robot_ai.grading.cgroups import BudgetClock
from robot_ai.grading.class_run import grade_class, reexec_in_namespaces, sandboxed
from robot_ai.grading.fk import Grade, comparison_frame, configurations
from robot_ai.grading.gradebook import FORMATS, ID_FROM, grade_line
from robot_ai.grading.master import read_refused
from robot_ai.grading.pacing import STABLE, Answer, Pacer, same
from robot_ai.grading.processes import Output, end_descendants, log_path, start_master, stop, wait_for_master
from robot_ai.grading.report import (BUDGET_BASE, BUDGET_PER_CONFIGURATION, MAX_NAME, RESULT_BYTES, budget_of,
                                     exit_status, graded_links, nothing_graded, read_model, result_of, write_junit)
from robot_ai.kinematics import prefix_frame

STARTUP = 120.0         # seconds a candidate may take to register with the master (a loaded machine is slow)
SUBSCRIBE = 10.0        # seconds from then to its joint_states subscription (it reads the URDF first)
MAX_CONFIGURATIONS = 10000
MAX_TIMEOUT = 600.0     # seconds
MAX_FRAMES = 10000      # frame names a candidate's tree may introduce before the rest are only counted
MAX_NAMED = 100         # frames with non-finite transforms kept for the report
CACHE_SECONDS = 10      # of moving transforms the judge's tf buffer keeps (it reads the latest)


class TfTree:
    """The candidate's tf tree, from its remapped /tf and /tf_static: statics kept, the rest per configuration."""

    def __init__(self, ns: str, keep: int):
        """keep: the frames whose transforms the buffer holds (the URDF's links and a few parents, the first that
        come); a flood of new frames is counted, never kept, so the judge's memory stays bounded (issue 40: a
        student's tf grew its judge to 1.2 GB)."""
        import rospy
        import tf2_ros
        from tf2_msgs.msg import TFMessage
        self._tf2 = tf2_ros
        self.statics, self.frames, self.children, self.received, self.non_finite = {}, set(), set(), 0, []
        self.keep, self.kept = keep, set()
        self.buffer = tf2_ros.Buffer(cache_time=rospy.Duration(CACHE_SECONDS))
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
            if not all(math.isfinite(v) for v in (r.x, r.y, r.z, r.w, p.x, p.y, p.z)) and \
                    len(self.non_finite) < MAX_NAMED:
                self.non_finite.append(child)

    def _keeps(self, t) -> bool:
        """Whether t's child frame is one the buffer holds (the first `keep` frames that come)."""
        child = t.child_frame_id
        if child not in self.kept:
            if len(self.kept) >= self.keep:
                return False
            self.kept.add(child)
        return True

    def parentless(self) -> set:
        """Frames that are some transform's parent and no transform's child."""
        return self.frames - self.children

    def _on_tf(self, msg) -> None:
        self._check(msg)
        self.received += 1
        buf = self.buffer
        for t in msg.transforms:
            if self._keeps(t):
                buf.set_transform(t, 'check_fk')

    def _on_static(self, msg) -> None:
        self._check(msg)
        for t in msg.transforms:
            if self._keeps(t):
                self.statics[t.child_frame_id] = t      # the latest of each frame: a flood of them costs nothing
                self.buffer.set_transform_static(t, 'check_fk')

    def next_configuration(self) -> None:
        """Forget the moving transforms of the last configuration; keep the static ones."""
        import rospy
        buf = self._tf2.Buffer(cache_time=rospy.Duration(CACHE_SECONDS))
        for t in self.statics.values():
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
    p.add_argument('--csv-format', choices=FORMATS, default='robot_ai',
                   help='with --candidates: the CSV\'s columns: robot_ai (student, id, grade, verdict, score, '
                   'first_wrong_link, seconds), moodle (an assignment\'s grading worksheet, for "Upload grading '
                   'worksheet") or canvas (the gradebook\'s import)')
    p.add_argument('--id-from', choices=ID_FROM, default='folder',
                   help='with --candidates: where a student\'s LMS id comes from: its folder\'s name (Moodle\'s '
                   '"Full Name_N_assignsubmission_file_") or its node file\'s name (Canvas\'s '
                   '"lastfirst_N_M_name.py")')
    p.add_argument('--assignment', default='check_fk',
                   help='with --csv-format canvas: the grade column\'s name, the assignment as Canvas\'s export '
                   'names it ("FK node (1234)")')
    p.add_argument('--jobs', type=int, default=0, help='with --candidates: students graded at once (0: one per core)')
    p.add_argument('--ray', default='', metavar='ADDRESS',
                   help='with --candidates: grade the class on a Ray cluster (HOST:PORT of its head, ray://HOST:PORT, '
                   'or auto: the cluster this machine joined), each student a task on whichever node it lands, in a '
                   'sandbox there; --jobs then says students per node (0: one per CPU). Ray is an optional extra: '
                   'docs/fleet.md')
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
    p.add_argument('--judge-pressure', default='', help=argparse.SUPPRESS)   # its group's cpu.pressure: the budget's
                                                                            # clock (robot_ai.grading.cgroups)
    p.add_argument('--judge-hide', action='append', default=[], help=argparse.SUPPRESS)
    p.add_argument('--result-fd', type=int, default=-1, help=argparse.SUPPRESS)
    p.add_argument('--judge-shown', default='', help=argparse.SUPPRESS)   # the candidate as the user named it
    p.add_argument('--judge-model', default='', help=argparse.SUPPRESS)   # the model as the user named it (a Ray
                                                                         # node grades the URDF it was sent)
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
    if a.ray and a.candidates is None:
        p.error('--ray grades a class: give it with --candidates')
    if a.ray:
        from robot_ai import fleet
        problem = fleet.available()
        if problem:
            p.error(f'--ray: {problem}')
    if a.sandbox and a.candidates is not None:
        p.error('--sandbox is for --candidate; --candidates sandboxes every student unless --no-sandbox')
    # a class on Ray is sandboxed on its nodes, which say so when they cannot; this machine only sends the folders
    if (a.sandbox or (a.candidates is not None and not a.no_sandbox and not a.ray)) and a.judge_uid < 0:
        problem = sandbox.unavailable()
        if problem:
            p.error(problem)
    return a


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


def finish(a, tree, lines: list[str], seconds: float) -> int:
    """Print the report (every line escaped: one line each, whatever the candidate's names and output held), write
    rostest's results file and a judge's result; the exit status."""
    lines = [sandbox.printable(line, 2000, backslashes=False) for line in lines]
    if not any(line.startswith('score: ') for line in lines):   # ended before any configuration was graded
        lines.insert(len(lines) - 1, nothing_graded(tree, a.configurations))
    if not any(line.startswith('grade: ') for line in lines):
        lines.insert(len(lines) - 1, 'grade: 100.0 (nothing to compare)' if lines[-1].startswith('PASS') else
                     grade_line(0, graded_links(tree), a.configurations))
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
            print(f'check_fk: {sandbox.printable(a.judge_shown or a.candidate)} on {a.judge_model or a.model}')
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
            if a.ray:
                from robot_ai.grading.on_ray import grade_class_on_ray
                return grade_class_on_ray(a, tree, xml)
            return grade_class(a, tree, argv)
        finally:
            stopping.append('clean-up')
    prctl(PR_SET_CHILD_SUBREAPER, 1)
    core = proc = None
    own_global = False
    ros_home = ''
    env = None
    clock = BudgetClock(budget_of(a), a.judge_pressure)
    try:
        if sandboxed(a):
            sandbox.loopback_up()          # this judge's own network namespace: loopback, and its master on it
            ros_home = sandbox.private_ros_home()   # its logs: bounded, in its own mount namespace, removed after
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
        candidate = TfTree(ns, keep=2 * len(tree.links) + 100)
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
        # a sandboxed judge's logs are on a tmpfs gone with its namespace: its report holds the output's last lines,
        # and names no file that will not be there
        output = Output(proc.stdout, '' if sandboxed(a) else
                        log_path((a.judge_shown or a.candidate).strip('/').replace(os.sep, '_')))
        pub = rospy.Publisher(ns + '/joint_states', JointState, queue_size=10)
        t0 = time.time()
        print(f'check_fk: {sandbox.printable(a.judge_shown or a.candidate)} on {a.judge_model or a.model} '
              f'({len(tree.links)} links, '
              f'{len(tree.active_joints)} driven joints), {a.configurations} configurations', flush=True)
        lines, _ = grade(tree, a, candidate, proc, output, pub, JointState, clock)
        refused = read_refused(core.refused_file) if core is not None else None
        if refused is not None:     # the candidate's, whatever else went wrong: the grader's own few are far below
            lines = lines[:-1] + [f'FAIL: the candidate asked its master to hold more than '
                                  f'{refused["limit"] // 1024 ** 2} MiB of parameters ({refused["what"]}): refused, '
                                  f'a bound of check_fk\'s']
        seconds = time.time() - t0        # one duration: the report's, the result's (the class's CSV) and rostest's
        return finish(a, tree, lines[:-1] + [f'(graded in {seconds:.1f} s)', lines[-1]], seconds)
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
        if core is not None:
            try:
                os.remove(core.refused_file)
            except OSError:
                pass
        if ros_home:
            sandbox.end_private_ros_home(ros_home)


def send(pub, JointState, q: dict) -> None:
    import rospy
    msg = JointState(name=list(q), position=list(q.values()))
    msg.header.stamp = rospy.Time.now()
    pub.publish(msg)


def tf_name(link: str) -> str:
    """The frame tf2 keeps for a link: robot_state_publisher drops a leading slash, and tf2 one more."""
    frame = prefix_frame('', link)
    return frame[1:] if frame.startswith('/') else frame


def settle(candidate: TfTree, frame: str, links: dict, q: dict, pacer: Pacer, previous: dict | None,
           changes: bool, pub, JointState, dead, moving: bool = True) -> Answer:
    """The candidate's answer to configuration q: the poses of links in frame, once they are its own answer to q
    (robot_ai.grading.pacing: paced by the candidate's own messages, not the clock, so that a slow node or a loaded
    machine gives the verdict a quiet one does, and a slow node's old answers are never taken for a new one)."""
    received = candidate.received
    pacer.begin(time.monotonic(), previous, changes)
    while not dead():
        now = time.monotonic()
        if pacer.want_send(now):
            send(pub, JointState, q)
            pacer.sent_at(now)
        time.sleep(0.01)
        now = time.monotonic()
        if candidate.received > received or not moving:
            received = candidate.received
            pacer.message(now, candidate.poses(frame, links))
        pacer.tick(now)
        if pacer.answer is not None:
            return pacer.answer
    return Answer(pacer.last, 'ended')


def registered(node: str) -> bool:
    """Whether a node of that name has registered with the master (rospy.init_node or ros::init has run)."""
    import rosnode
    try:
        return node in rosnode.get_node_names()
    except rosnode.ROSNodeIOException:
        return False


def grade(tree, a, candidate: TfTree, proc, output: Output, pub, JointState, clock: BudgetClock | None = None):
    """Drive the candidate through the configurations until the clock says the budget is spent (the time the
    candidate was given a CPU: robot_ai.grading.cgroups); (report lines, exit status)."""
    names = {link: tf_name(link) for link in tree.links}     # URDF link -> the frame tf2 keeps
    link_of = {f: link for link, f in names.items()}
    done = [0]       # configurations graded

    def over():
        return clock is not None and clock.over()

    def dead():
        return proc.poll() is not None or over()

    def died():
        """The lines that end a grade stopped early: the candidate's output, then the verdict."""
        if over():
            return output.lines() + [f'FAIL: too slow ({done[0]} of {a.configurations} configurations answered within '
                                     f'the budget of {budget_of(a):g} s, --budget)']
        exception = output.exception()
        return output.lines() + [f'FAIL: the candidate node exited with status {proc.returncode}'
                                 + (f': {exception}' if exception else '')]

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
    pacer = Pacer(a.timeout)
    result, graded, previous, reference = None, None, None, None
    for k, q in enumerate(configs):
        before = reference                                   # one configuration's poses at a time
        candidate.next_configuration()
        if result is None:       # the first configuration: wait for the candidate's frames, then choose the frame
            # until its set of frames stays the same over STABLE fresh messages (a node that publishes a message
            # per link sends them over a while), at least 1 s; nothing at all within the timeout is a verdict
            start = check = time.monotonic()
            known, unchanged, received, heard = set(), 0, candidate.received, candidate.received
            pacer.begin(start, None, True)
            while time.monotonic() < start + a.timeout or candidate.frames:
                if dead():
                    break
                now = time.monotonic()
                if pacer.want_send(now):      # paced as every configuration is: a slow node gets no backlog
                    send(pub, JointState, q)
                    pacer.sent_at(now)
                time.sleep(0.01)
                if candidate.received > heard:
                    heard = candidate.received
                    pacer.message(time.monotonic(), {})
                if time.monotonic() - check < 0.1:
                    continue
                check = time.monotonic()
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
            result.asked = a.configurations
            result.extra = {f for f in candidate.frames if f not in link_of} - {frame}
            if frame is None:
                return result.report(), 1
            frame_name = names.get(frame, frame)
            graded = {link: names[link] for link in result.links}
        reference = result.reference_poses(q)       # from the root, or from a floating joint's child
        changes = before is None or not same(reference, before)
        answer = settle(candidate, frame_name, graded, q, pacer, previous, changes, pub, JointState, dead,
                        moving=bool(tree.active_joints))
        if dead():
            return result.report()[:-1] + died(), 1
        if candidate.non_finite:
            result.problems.append(f'the candidate published a non-finite (NaN or inf) transform for '
                                   f'{candidate.non_finite[0]}')
            return result.report(), 1
        if pacer.unanswered():      # a node that reads the joints went silent on an old answer: never a wrong joint
            return result.report()[:-1] + [
                f'FAIL: too slow ({k} of {a.configurations} configurations answered): no answer to configuration {k} '
                f'and no tf message for {a.timeout:g} s (--timeout)'], 1
        previous = answer.poses
        result.add(k, q, reference, answer.poses)
        done[0] = k + 1
    return result.report(), 0 if result.verdict() == 'PASS' else 1
