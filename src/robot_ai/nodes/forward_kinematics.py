"""forward_kinematics: a drop-in robot_state_publisher in Python.

Reads the URDF from ``robot_description``, listens to ``joint_states`` and publishes one parent -> child
transform per URDF joint: moving joints on ``/tf`` stamped with the JointState's ``header.stamp``, fixed
joints once on the latched ``/tf_static``.

ROS Parameters
    robot_description (str): the URDF, searched up the namespaces. Waited for if missing or invalid.
    ~publish_frequency (float, 50.0): a JointState is published only if its stamp is at least
        1/frequency newer than the last published one of the same joints. A value that is not a positive number
        (and a ~use_tf_static or ~ignore_timestamp that is not true or false) falls back to the default with a
        warning that says what is allowed.
    ~use_tf_static (bool, true): fixed joints latched on /tf_static; false: on /tf at publish_frequency.
    ~ignore_timestamp (bool, false): publish every JointState whatever its stamp.
    ~tf_prefix (str, ""): searched up the namespaces; put before frame names as robot_state_publisher does.

ROS Subscribers
    joint_states (sensor_msgs/JointState): queue of 1, so that under overload old messages are dropped.

ROS Publishers
    /tf (tf2_msgs/TFMessage): moving joints, one message per accepted JointState.
    /tf_static (tf2_msgs/TFMessage, latched): fixed joints.

ROS Services
    ~reload (std_srvs/Trigger): re-read robot_description; on failure the current robot is kept. One reload
        runs at a time: requests that come during one are answered together by the next.
"""
import ctypes
import gc
import threading

import warnings

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger, TriggerResponse
from tf2_msgs.msg import TFMessage

from robot_ai.nodes.params import bool_param, init_node, number_param, publish, quiet_on_shutdown
from robot_ai.nodes.robot_description import load_tree, wait_for_tree
from robot_ai.tf_wire import JointStateDecoder, TFMessageEncoder, WireError, raw_message_class

THROTTLE = 10.0  # seconds between repeats of one input warning or error


def release_memory() -> None:
    """Give what a parse freed back to the system: Python's cycles collected, then glibc's free memory of every
    thread's arena trimmed (a 20,000-joint reload otherwise keeps hundreds of MB)."""
    gc.collect()
    try:
        ctypes.CDLL('libc.so.6').malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


RawJointState = raw_message_class(JointState)   # decoded by JointStateDecoder in the callback
RawTFMessage = raw_message_class(TFMessage)     # written by TFMessageEncoder


class Robot:
    """Everything derived from one robot_description, swapped as a whole on reload."""

    def __init__(self, tree, tf_prefix):
        self.tree = tree
        self.plan = tree.transform_plan(tf_prefix)
        self.encoder = TFMessageEncoder(self.plan.parent_frames, self.plan.child_frames)
        self.static_encoder = TFMessageEncoder(self.plan.static_parent_frames, self.plan.static_child_frames)
        self.layouts = {}

    def layout(self, names):
        """The plan's MessageLayout of a tuple of names, cached (a publisher rarely changes its names)."""
        found = self.layouts.get(names)
        if found is None:
            if len(self.layouts) > 64:
                self.layouts.clear()
            found = self.layouts[names] = self.plan.message_layout(names)
        return found


class ForwardKinematicsNode:

    def __init__(self):
        self.publish_frequency = number_param('~publish_frequency', 50.0, 'a positive number (Hz)',
                                              lambda v: v > 0)
        self.use_tf_static = bool_param('~use_tf_static', True)
        self.ignore_timestamp = bool_param('~ignore_timestamp', False)
        self.tf_prefix = self._tf_prefix()
        self.interval_ns = int(round(1e9 / max(self.publish_frequency, 1.0)))

        # with ~ignore_timestamp (an env's lockstep sim: every state's frames, awaited) /tf is published in the
        # callback's thread, with no hand-off to rospy's queue thread; otherwise queued, so that a slow subscriber
        # (rviz across a network) never holds the node
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            self.tf_pub = rospy.Publisher('/tf', RawTFMessage, queue_size=None if self.ignore_timestamp else 100,
                                          tcp_nodelay=self.ignore_timestamp)
        self.static_pub = rospy.Publisher('/tf_static', RawTFMessage, queue_size=100, latch=True)
        self.decoder = JointStateDecoder()
        self.tf_msg = RawTFMessage()
        # robot_state_publisher's gate: per joint name, the stamp (ns) of its last published JointState
        self.slot_of = {}                # name -> index in last_publish
        self.slots = {}                  # tuple of names -> their indices
        self.last_publish = np.zeros(0, np.int64)
        self.last_callback_ns = 0
        self.lock = threading.Lock()     # the callback against a reload
        self.reload_done = threading.Condition()  # one reload at a time (see _on_reload)
        self.reloading = False
        self.reload_requests = 0         # ~reload requests so far
        self.reload_covered = 0          # requests answered by a finished reload that started after them
        self.reload_answer = None

        self.robot = self._wait_for_robot()
        if self.robot is None:
            return
        self._publish_static()
        if not self.use_tf_static:
            rospy.Timer(rospy.Duration(self.interval_ns * 1e-9), lambda _: self._publish_static())
        self.reload_srv = rospy.Service('~reload', Trigger, self._on_reload)
        self.sub = rospy.Subscriber('joint_states', RawJointState, self._on_joint_state, queue_size=1,
                                    tcp_nodelay=True)

    # ----------------------------------------------------------------------------- robot_description
    @staticmethod
    def _tf_prefix():
        if rospy.has_param('~tf_prefix'):
            return str(rospy.get_param('~tf_prefix'))
        key = rospy.search_param('tf_prefix')
        return str(rospy.get_param(key, '')) if key else ''

    def _load(self):
        """Robot from robot_description, or raise URDFError/MissingDescription with a message."""
        tree, key = load_tree(warn_meshes=True)
        return self._robot(tree), key

    def _robot(self, tree):
        for warning in tree.warnings:
            rospy.logwarn(warning)
        return Robot(tree, self.tf_prefix)

    def _wait_for_robot(self):
        tree, key = wait_for_tree(warn_meshes=True)
        if tree is None:
            return None
        robot = self._robot(tree)
        self._log_loaded(robot, key)
        return robot

    @staticmethod
    def _log_loaded(robot, key):
        t = robot.tree
        rospy.loginfo(f'robot {t.name!r} from {key}: root {t.root}, {len(t.links)} links, {len(t.moving_joints)} '
                      f'moving joints ({len(t.mimic_joints)} mimic), {len(t.static_joints)} fixed, '
                      f'{len(t.floating_joints)} floating skipped')

    def _on_reload(self, _req) -> TriggerResponse:
        """One reload at a time: requests that arrive during a reload wait, and the next reload (which reads
        robot_description after they came) answers all of them; memory goes back to the system after each."""
        with self.reload_done:
            ticket = self.reload_requests = self.reload_requests + 1
            while self.reload_covered < ticket:
                if not self.reloading:
                    break
                self.reload_done.wait()
            else:
                return self.reload_answer     # a reload that started after this request has answered it
            self.reloading, covers = True, self.reload_requests
        answer = None
        try:
            answer = self._reload()
        finally:
            release_memory()
            with self.reload_done:
                self.reloading = False
                if answer is not None:  # else a waiting request reloads
                    self.reload_covered, self.reload_answer = covers, answer
                self.reload_done.notify_all()
        return answer

    def _reload(self) -> TriggerResponse:
        try:
            robot, key = self._load()
        except Exception as e:  # a URDF the parser or the kinematics cannot take: say why, keep the robot
            rospy.logerr(f'reload failed, keeping the current robot: {e}')
            return TriggerResponse(success=False, message=f'reload failed, kept the current robot: {e}')
        with self.lock:
            self.robot = robot
            self.last_publish[:] = 0
        self._log_loaded(robot, key)
        self._publish_static()
        return TriggerResponse(success=True, message=f'loaded {robot.tree.name!r}: {len(robot.tree.links)} links, '
                                                     f'{len(robot.tree.moving_joints)} moving joints')

    def _publish_static(self):
        robot = self.robot
        plan = robot.plan
        stamp = rospy.Time.now()
        if not self.use_tf_static:
            stamp += rospy.Duration(0.5)  # as robot_state_publisher: valid until the next timer tick
        idx = np.arange(len(plan.static_names))
        buff = robot.static_encoder.encode(idx, stamp.secs, stamp.nsecs, plan.static_xyz, plan.static_quat)
        (self.static_pub if self.use_tf_static else self.tf_pub).publish(RawTFMessage(buff))

    # ---------------------------------------------------------------------------------- joint_states
    def _on_joint_state(self, msg):
        try:
            secs, nsecs, names, positions = self.decoder.decode(msg.buff)
        except WireError as e:
            rospy.logerr_throttle(THROTTLE, f'dropped a JointState: {e}')
            return
        if len(names) != len(positions):
            rospy.logerr_throttle(THROTTLE, f'dropped a JointState with {len(names)} names and {len(positions)} '
                                            'positions; they must be as many')
            return
        if not np.isfinite(positions).all():
            bad = [n for n, p in zip(names, positions) if not np.isfinite(p)]
            rospy.logerr_throttle(THROTTLE, f'dropped a JointState with non-finite positions for {bad}')
            return
        with self.lock:
            self._publish(names, positions, secs, nsecs)

    def _slots(self, names):
        """Gate slots of the message's joints that the URDF has: names it does not have get none, so that
        ever-new names cannot grow what the node keeps (memory stays bounded by the URDF)."""
        slots = self.slots.get(names)
        if slots is None:
            joints = self.robot.tree.joints
            known = [n for n in names if n in joints]
            for n in known:
                self.slot_of.setdefault(n, len(self.slot_of))
            if len(self.slot_of) > len(self.last_publish):
                grown = np.zeros(2 * len(self.slot_of), np.int64)
                grown[:len(self.last_publish)] = self.last_publish
                self.last_publish = grown
            if len(self.slots) > 64:
                self.slots.clear()
            slots = self.slots[names] = np.array([self.slot_of[n] for n in known], np.intp)
        return slots

    def _publish(self, names, positions, secs, nsecs):
        robot = self.robot
        layout = robot.layout(names)
        if layout.unknown:
            shown = ', '.join(n[:80] for n in layout.unknown[:10])
            more = len(layout.unknown) - 10
            rospy.logwarn_throttle(THROTTLE, f'joint_states names {len(layout.unknown)} '
                                             f'joint{"s" if len(layout.unknown) > 1 else ""} that are not in the URDF, '
                                             f'ignored: {shown}{f" and {more} more" if more > 0 else ""}')
        now_ns = rospy.Time.now().to_nsec()
        stamp_ns = secs * 1000000000 + nsecs
        if now_ns < self.last_callback_ns:
            rospy.logwarn('time moved backwards (a bag looped or the clock was reset): re-publishing')
            self.last_publish[:] = 0
        self.last_callback_ns = now_ns
        if stamp_ns + 30000000000 < now_ns:
            rospy.logwarn_throttle(THROTTLE, f'received a JointState {(now_ns - stamp_ns) * 1e-9:.1f} s old')
        slots = self._slots(names)
        if not self.ignore_timestamp:
            oldest = min(now_ns, int(self.last_publish[slots].min())) if len(slots) else now_ns
            if stamp_ns < oldest + self.interval_ns:
                return
        data = robot.plan.message_transforms(layout, positions)
        self.tf_msg.buff = robot.encoder.encode_data(layout.out_idx, secs, nsecs, data)
        publish(self.tf_pub, self.tf_msg)
        self.last_publish[slots] = stamp_ns


@quiet_on_shutdown
def main():
    init_node('forward_kinematics')
    node = ForwardKinematicsNode()
    if node.robot is not None:
        rospy.spin()
