"""Helpers for rostest tests: run robot_state_publisher and forward_kinematics side by side."""
import math
import os
import signal
import subprocess
import time

import numpy as np
import rospy
import tf2_ros
import yaml
from sensor_msgs.msg import JointState
from tf import transformations as tft
from tf2_msgs.msg import TFMessage

NODES = {
    'rsp': ['rosrun', 'robot_state_publisher', 'robot_state_publisher'],
    'fk': ['rosrun', 'robot_ai', 'forward_kinematics'],
}


def tf2_name(frame):
    """tf2 strips one leading slash from frame ids it is given."""
    return frame[1:] if frame.startswith('/') else frame


def to_matrix(transform):
    t, r = transform.transform.translation, transform.transform.rotation
    m = tft.quaternion_matrix([r.x, r.y, r.z, r.w])
    m[:3, 3] = [t.x, t.y, t.z]
    return m


def rotation_angle(m1, m2):
    d = m1[:3, :3].T.dot(m2[:3, :3])
    s = np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2.0
    return abs(math.atan2(s, (np.trace(d) - 1.0) / 2.0))


class TfRecorder(object):
    """A tf2 buffer fed from one node's remapped tf topics, and the stamps of every /tf message."""

    def __init__(self, ns, who):
        self.buffer = tf2_ros.Buffer(cache_time=rospy.Duration(3600))
        self.stamps = []
        self.subs = [rospy.Subscriber('%s/%s/tf' % (ns, who), TFMessage, self._on_tf, queue_size=1000),
                     rospy.Subscriber('%s/%s/tf_static' % (ns, who), TFMessage, self._on_static,
                                      queue_size=100)]

    def _on_tf(self, msg):
        if msg.transforms:
            self.stamps.append(msg.transforms[0].header.stamp)
        for t in msg.transforms:
            self.buffer.set_transform(t, 'test')

    def _on_static(self, msg):
        for t in msg.transforms:
            self.buffer.set_transform_static(t, 'test')

    def frames(self):
        return set(yaml.safe_load(self.buffer.all_frames_as_yaml()) or {})

    def close(self):
        for s in self.subs:
            s.unregister()


class NodePair(object):
    """robot_state_publisher ('rsp') and forward_kinematics ('fk') in namespace ns on the same URDF.

    Each publishes on ns/<who>/tf and ns/<who>/tf_static; both listen to ns/joint_states."""

    def __init__(self, ns, xml, params=None, who=('rsp', 'fk')):
        self.ns = ns
        if rospy.has_param(ns):
            rospy.delete_param(ns)  # start from a clean namespace: nothing left from an earlier case
        rospy.set_param(ns + '/robot_description', xml)
        node_args = []
        for key, value in (params or {}).items():
            if key == 'tf_prefix':
                rospy.set_param(ns + '/tf_prefix', value)  # searched up the namespaces by both
            else:
                node_args.append('_%s:=%s' % (key, value))
        self.recorders, self.procs = {}, {}
        for name in who:
            self.recorders[name] = TfRecorder(ns, name)
            self.procs[name] = subprocess.Popen(
                NODES[name] + ['__ns:=' + ns, '__name:=' + name, '/tf:=%s/%s/tf' % (ns, name),
                               '/tf_static:=%s/%s/tf_static' % (ns, name)] + node_args,
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=os.setsid)
        self.pub = rospy.Publisher(ns + '/joint_states', JointState, queue_size=100)

    def wait_connected(self, timeout=30.0):
        deadline = time.time() + timeout
        def connected():
            return (self.pub.get_num_connections() >= len(self.procs)
                    and all(s.get_num_connections() > 0 for r in self.recorders.values() for s in r.subs))
        while not connected():
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise AssertionError('%s exited early: %s' % (name, p.stderr.read().decode()[-2000:]))
            if time.time() > deadline:
                raise AssertionError('nodes did not subscribe to %s/joint_states' % self.ns)
            time.sleep(0.05)

    def send(self, positions, stamp=None):
        stamp = stamp or rospy.Time.now()
        msg = JointState(name=list(positions), position=[float(v) for v in positions.values()])
        msg.header.stamp = stamp
        self.pub.publish(msg)
        return stamp

    def alive(self, name):
        return self.procs[name].poll() is None

    def close(self):
        for p in self.procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in self.procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        for r in self.recorders.values():
            r.close()
        self.pub.unregister()


def wait_for(predicate, timeout=10.0, step=0.02):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


def action_client(name, action, timeout=30.0):
    """A SimpleActionClient of name whose server is up and whose feedback and result subscriptions are connected:
    wait_for_server checks only the goal, cancel and status topics, and under load the server's first feedback (seen:
    episode 1 of 120) went out before the client's feedback subscription had its connection. None after timeout."""
    import actionlib
    client = actionlib.SimpleActionClient(name, action)
    deadline = time.monotonic() + timeout
    if not client.wait_for_server(rospy.Duration(timeout)):
        return None
    inner = client.action_client
    while time.monotonic() < deadline:
        if inner.feedback_sub.get_num_connections() and inner.result_sub.get_num_connections():
            return client
        time.sleep(0.02)
    return None


def said_by(log, node, words, since, timeout=30.0):
    """The first line node said in log ([(name, text)], from index since) that holds every word of one of words (a
    list of word lists), waiting up to timeout seconds; None when none came (the caller fails with the lines)."""
    deadline = time.monotonic() + timeout
    while True:
        said = [m for n, m in log[since:] if n == node and any(all(w in m for w in ws) for ws in words)]
        if said:
            return said[0]
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.05)


def wait_file(path, timeout=20.0):
    """True once path is a non-empty file (a plot appears after its response), False after timeout seconds."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if os.path.isfile(path) and os.path.getsize(path) > 0:
            return True
        time.sleep(0.1)
    return False


def on_this_master(pid) -> bool:
    """Whether process pid is a node of this test's master (its ROS_MASTER_URI, roslaunch's with a trailing '/'): make
    test runs rostests side by side, and another test's node may have the same name (the demo's cartpole_search)."""
    mine = os.environ.get('ROS_MASTER_URI', '').rstrip('/').encode()
    try:
        with open(f'/proc/{pid}/environ', 'rb') as f:
            return any(v.rstrip(b'/') == b'ROS_MASTER_URI=' + mine for v in f.read().split(b'\0'))
    except OSError:
        return False


def cases_of(test_class, names, chosen: bool, name: str):
    """test_class with only the cases in names (chosen) or only the others: one script, two rostest files that make
    test runs side by side."""
    cases = [n for n in dir(test_class) if n.startswith('test_')]
    assert set(names) <= set(cases), f'{name}: a case {test_class.__name__} does not have'
    return type(name, (test_class,), dict.fromkeys(n for n in cases if (n in names) != chosen))
