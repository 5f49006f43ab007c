"""check_fk: grade a forward-kinematics node (a student's, say) against robot_ai's forward_kinematics.

    rosrun robot_ai check_fk --model my_robot.urdf --candidate my_pkg/my_fk_node [--configurations 50]
                             [--seed 0] [--tolerance 1e-6] [--timeout 5]

It starts a roscore of its own when none runs, then the candidate with its /tf and /tf_static remapped into a
namespace of its own and forward_kinematics beside it, both reading the URDF from robot_description in that
namespace (and from /robot_description, set while the check runs if nothing else set it) and the same
joint_states (the zero pose, then seeded random configurations within the joints' limits). For every
configuration it compares the pose of every link as each node's tf tree gives it (tf2 lookups, so a node that
hangs every link under a 'world' frame is graded as fairly as one that publishes parent -> child per joint),
prints a table per link and a verdict, and exits 0 on PASS, 1 on FAIL, 2 on bad arguments.
"""
import argparse
import os
import signal
import socket
import subprocess
import sys
import time

from robot_ai.fk_grading import Grade, comparison_frame, configurations
from robot_ai.kinematics import KinematicTree, URDFError, prefix_frame


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def ensure_master():
    """The roscore process this started, or None when a master already runs (ROS_MASTER_URI)."""
    import rosgraph
    if rosgraph.is_master_online():
        return None
    port = free_port()
    os.environ['ROS_MASTER_URI'] = 'http://127.0.0.1:%d' % port
    core = subprocess.Popen(['roscore', '-p', str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=os.setsid)
    deadline = time.time() + 30
    while not rosgraph.is_master_online():
        if time.time() > deadline or core.poll() is not None:
            raise RuntimeError('could not start a roscore on port %d' % port)
        time.sleep(0.2)
    return core


def stop(proc, timeout=10):
    if proc is not None and proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class TfTree(object):
    """One node's tf tree, from its remapped /tf and /tf_static: statics kept, the rest per configuration."""

    def __init__(self, ns, who):
        import rospy
        import tf2_ros
        from tf2_msgs.msg import TFMessage
        self._tf2 = tf2_ros
        self.statics, self.frames, self.received, self.non_finite = [], set(), 0, []
        self.buffer = tf2_ros.Buffer(cache_time=rospy.Duration(60))
        self.subs = [rospy.Subscriber('%s/%s/tf' % (ns, who), TFMessage, self._on_tf, queue_size=1000),
                     rospy.Subscriber('%s/%s/tf_static' % (ns, who), TFMessage, self._on_static, queue_size=100)]

    @staticmethod
    def _name(frame):
        return frame[1:] if frame.startswith('/') else frame

    def _check(self, msg):
        import math
        for t in msg.transforms:
            self.frames.update((self._name(t.header.frame_id), self._name(t.child_frame_id)))
            r, p = t.transform.rotation, t.transform.translation
            if not all(math.isfinite(v) for v in (r.x, r.y, r.z, r.w, p.x, p.y, p.z)):
                self.non_finite.append(self._name(t.child_frame_id))

    def _on_tf(self, msg):
        self._check(msg)
        self.received += 1
        buf = self.buffer
        for t in msg.transforms:
            buf.set_transform(t, 'check_fk')

    def _on_static(self, msg):
        self._check(msg)
        self.statics.extend(msg.transforms)
        for t in msg.transforms:
            self.buffer.set_transform_static(t, 'check_fk')

    def next_configuration(self):
        """Forget the moving transforms of the last configuration; keep the static ones."""
        import rospy
        buf = self._tf2.Buffer(cache_time=rospy.Duration(60))
        for t in self.statics:
            buf.set_transform_static(t, 'check_fk')
        self.buffer = buf

    def poses(self, frame, links):
        """{link: 4x4 pose in frame} for the links this tree can give now."""
        import rospy
        from tf import transformations as tft
        out = {}
        for link in links:
            try:
                t = self.buffer.lookup_transform(frame, link, rospy.Time(0))
            except (self._tf2.LookupException, self._tf2.ConnectivityException, self._tf2.ExtrapolationException):
                continue
            r, p = t.transform.rotation, t.transform.translation
            m = tft.quaternion_matrix([r.x, r.y, r.z, r.w])
            m[:3, 3] = [p.x, p.y, p.z]
            out[link] = m
        return out

    def has_all(self, frame, links):
        import rospy
        return all(self.buffer.can_transform(frame, l, rospy.Time(0)) for l in links)


def parse_args(argv):
    p = argparse.ArgumentParser(prog='rosrun robot_ai check_fk', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                                description='Grade a forward-kinematics node against robot_ai\'s forward_kinematics '
                                '(equal to robot_state_publisher): exit status 0 on PASS, 1 on FAIL.')
    p.add_argument('--model', required=True, help='the URDF file')
    p.add_argument('--candidate', required=True, help='the node to grade, as PACKAGE/TYPE (what rosrun takes)')
    p.add_argument('--configurations', type=int, default=50, help='joint configurations: the zero pose, then random')
    p.add_argument('--seed', type=int, default=0, help='seed of the random configurations')
    p.add_argument('--tolerance', type=float, default=1e-6, help='largest error allowed, in m and rad')
    p.add_argument('--timeout', type=float, default=5.0, help='seconds a configuration may take to appear on tf')
    p.add_argument('--gtest_output', default='', help=argparse.SUPPRESS)  # rostest's: xml:<results file>
    a = p.parse_args(argv)
    if a.candidate.count('/') != 1 or not all(a.candidate.split('/')):
        p.error('--candidate must be PACKAGE/TYPE, as rosrun takes it, got %r' % a.candidate)
    if a.configurations < 1 or not a.tolerance > 0 or not a.timeout > 0:
        p.error('--configurations must be at least 1, --tolerance and --timeout positive')
    return a


def main(argv=None):
    import rospy
    a = parse_args(rospy.myargv(sys.argv)[1:] if argv is None else argv)
    try:
        with open(a.model) as f:
            xml = f.read()
        tree = KinematicTree.from_xml_string(xml)
    except (OSError, URDFError) as e:
        print('check_fk: cannot read the model %s: %s' % (a.model, e), file=sys.stderr)
        return 2
    core = ensure_master()
    procs = {}
    own_global = False
    try:
        from sensor_msgs.msg import JointState
        rospy.init_node('check_fk', anonymous=True, disable_signals=True)
        ns = '/check_fk_%d' % os.getpid()
        rospy.set_param(ns + '/robot_description', xml)
        if not rospy.has_param('/robot_description'):  # for nodes that read the absolute name
            rospy.set_param('/robot_description', xml)
            own_global = True
        trees = {who: TfTree(ns, who) for who in ('reference', 'candidate')}
        pkg, node_type = a.candidate.split('/')
        common = ['__ns:=' + ns, '/joint_states:=%s/joint_states' % ns]
        procs['reference'] = subprocess.Popen(
            ['rosrun', 'robot_ai', 'forward_kinematics', '__name:=reference', '/tf:=%s/reference/tf' % ns,
             '/tf_static:=%s/reference/tf_static' % ns, '_publish_frequency:=1000.0'] + common,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=os.setsid)
        procs['candidate'] = subprocess.Popen(
            ['rosrun', pkg, node_type, '__name:=candidate', '/tf:=%s/candidate/tf' % ns,
             '/tf_static:=%s/candidate/tf_static' % ns] + common,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=os.setsid)
        pub = rospy.Publisher(ns + '/joint_states', JointState, queue_size=10)
        t0 = time.time()
        print('check_fk: %s on %s (%d links, %d driven joints), %d configurations' % (
            a.candidate, a.model, len(tree.links), len(tree.active_joints), a.configurations))
        lines, status = grade(tree, a, trees, procs, pub, JointState)
        print('\n'.join(lines[:-1] + ['(graded in %.1f s)' % (time.time() - t0), lines[-1]]))
        if a.gtest_output.startswith('xml:'):
            write_junit(a.gtest_output[4:], a.candidate, lines, time.time() - t0)
        return status
    finally:
        for p in procs.values():
            stop(p)
        if own_global:
            try:
                rospy.delete_param('/robot_description')
            except Exception:
                pass
        rospy.signal_shutdown('check_fk done')
        stop(core)


def write_junit(path, candidate, lines, seconds):
    """The results file rostest asks a <test> node for: one test case, failed unless the verdict is PASS."""
    from xml.sax.saxutils import escape, quoteattr
    failed = lines[-1] != 'PASS'
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, 'w') as f:
        f.write('<?xml version="1.0" encoding="utf-8"?>\n<testsuite name="check_fk" tests="1" errors="0" '
                'failures="%d" time="%.3f">\n  <testcase classname="check_fk" name=%s time="%.3f">\n%s  </testcase>\n'
                '</testsuite>\n' % (failed, seconds, quoteattr(candidate), seconds,
                                     '    <failure message=%s>%s</failure>\n' % (quoteattr(lines[-1]),
                                                                               escape('\n'.join(lines)))
                                     if failed else ''))


def crashed(procs):
    """A verdict line if the candidate or the reference has exited, else None."""
    for who, p in procs.items():
        if p.poll() is not None:
            err = p.stderr.read().decode(errors='replace').strip().splitlines()[-5:]
            return 'FAIL: the %s node exited with status %s%s' % (
                who, p.returncode, (': ' + ' | '.join(err)) if err else '')
    return None


def send(pub, JointState, q):
    import rospy
    msg = JointState(name=list(q), position=list(q.values()))
    msg.header.stamp = rospy.Time.now()
    pub.publish(msg)


def tf_name(link):
    """The frame tf2 keeps for a link: robot_state_publisher drops a leading slash, and tf2 one more."""
    frame = prefix_frame('', link)
    return frame[1:] if frame.startswith('/') else frame


def grade(tree, a, trees, procs, pub, JointState):
    """Drive both nodes through the configurations; (report lines, exit status)."""
    names = {l: tf_name(l) for l in tree.links}     # URDF link -> the frame tf2 keeps
    link_of = {f: l for l, f in names.items()}
    all_frames = [names[l] for l in tree.links]
    if len(tree.links) == 1:
        return ['%s is a single link with no joint: there is no transform to publish or to grade' % tree.root,
                'PASS'], 0
    deadline = time.time() + a.timeout
    while pub.get_num_connections() < 2 and time.time() < deadline:  # both nodes subscribed (or a silent one)
        verdict = crashed(procs)
        if verdict:
            return [verdict], 1
        time.sleep(0.05)
    result, known = None, set()
    for k, q in enumerate(configurations(tree, a.configurations, a.seed)):
        for t in trees.values():
            t.next_configuration()
        # the first configuration may take the whole time limit; later ones, until the links seen so far are there
        limit = time.time() + (a.timeout if k == 0 else min(a.timeout, 2.0))
        while time.time() < limit:
            verdict = crashed(procs)
            if verdict:
                return (result.report()[:-1] if result else []) + [verdict], 1
            send(pub, JointState, q)
            time.sleep(0.05)
            root = names[tree.root]
            if not trees['reference'].has_all(root, all_frames):
                continue
            candidate = trees['candidate']
            if k == 0 and candidate.has_all(root, all_frames):
                break
            if k > 0 and candidate.has_all(names[result.frame], [names[l] for l in known]):
                break
        candidate = trees['candidate']
        if candidate.non_finite:
            result = result or Grade(tree, tree.root, a.tolerance)
            result.problems.append('the candidate published a non-finite (NaN or inf) transform for %s' %
                                   candidate.non_finite[0])
            return result.report(), 1
        if result is None:
            if not candidate.frames:
                return ['FAIL: the candidate published nothing on /tf or /tf_static within %g s of the first '
                        'joint_states' % a.timeout], 1
            frame, note = comparison_frame(tree, {link_of[f] for f in candidate.frames if f in link_of})
            result = Grade(tree, frame, a.tolerance, note)
            result.extra = {f for f in candidate.frames if f not in link_of}
            if frame is None:
                return result.report(), 1
            graded = [names[l] for l in result.links]
        # {tf frame: pose} -> {URDF link: pose}
        reference = {link_of[f]: m for f, m in trees['reference'].poses(names[result.frame], graded).items()}
        got = {link_of[f]: m for f, m in candidate.poses(names[result.frame], graded).items()}
        known.update(got)
        result.add(k, reference, got)
    return result.report(), 0 if result.verdict() == 'PASS' else 1

