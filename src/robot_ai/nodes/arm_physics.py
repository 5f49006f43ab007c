"""arm_sim's ROS side of physics (~physics mujoco): the loose objects' poses on /tf, their poses and velocities on
~object_states (robot_ai/ObjectStates: gazebo_msgs/ModelStates' fields and a stamp), drawn as rviz markers, and the
gripper's command as ros_control's gripper_action_controller takes it (robot_ai/GripperCommand: the fields, and so
the md5sums, of control_msgs/GripperCommand, which Debian does not ship).

    world = PhysicsWorld(arm, base, links, lock)   # arm: physics.sim.ArmPhysics; lock: the sim's
    world.ticked(stamp)                             # after each tick of physics: /tf, and the gripper's goal checked
"""
from __future__ import annotations

import re
import threading
import warnings

import actionlib
import rospy
from geometry_msgs.msg import Pose, TransformStamped, Twist
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from robot_ai.msg import GripperCommandAction, GripperCommandFeedback, GripperCommandResult, ObjectStates
from robot_ai.nodes.params import publish
from robot_ai.physics import PhysicsError
from robot_ai.physics.model import Object
from robot_ai.physics.sim import ArmPhysics

GRIPPER_ACTION = 'gripper_controller/gripper_cmd'
OBJECT_COLOUR = (0.2, 0.5, 0.8, 1.0)     # as the physics model draws them


def object_frames(names, taken) -> dict[str, str]:
    """{object: its /tf frame}: the name with each run of characters other than letters, digits and _ made one _
    ('object 0 (box)' -> object_0_box); ValueError of one line where two objects, or an object and a link of taken,
    would share a frame."""
    frames: dict[str, str] = {}
    for name in names:
        frame = re.sub(r'[^A-Za-z0-9_]+', '_', name).strip('_') or 'object'
        if frame in taken or frame in frames.values():
            raise ValueError(f'the object {name!r} would be the frame {frame!r}, which a link or another object '
                             f'has: name it otherwise')
        frames[name] = frame
    return frames


class PhysicsWorld:
    """The objects of arm (an ArmPhysics; objects: what its model was built with) on tf (each in its own frame, a
    child of base) and as markers drawn in those frames (~object_markers, latched); the gripper's action server,
    its goals carried out over the sim's ticks (lock: the sim's, held while the physics is read or commanded)."""

    def __init__(self, arm: ArmPhysics, objects: tuple[Object, ...], base: str, links, lock: threading.Lock,
                 lockstep: bool = False):
        self.arm, self.base, self.lock = arm, base, lock
        self.frames = object_frames([o.name for o in objects], set(links))
        self.tick = threading.Condition()
        self.tf_pub = rospy.Publisher('tf', TFMessage, queue_size=10) if self.frames else None
        with warnings.catch_warnings():   # lockstep: published in the command's thread, as joint_states is
            warnings.simplefilter('ignore')
            self.states_pub = rospy.Publisher('~object_states', ObjectStates, queue_size=None if lockstep else 10,
                                              tcp_nodelay=True, latch=lockstep)
        self.markers_pub = rospy.Publisher('~object_markers', MarkerArray, queue_size=1, latch=True)
        publish(self.markers_pub, self._markers(objects))
        self.server = None
        if arm.gripper:
            self.server = actionlib.SimpleActionServer(GRIPPER_ACTION, GripperCommandAction, self._on_goal,
                                                       auto_start=False)
            self.server.start()

    def describe(self) -> str:
        """What it serves, for the sim's ready line."""
        count = f'{len(self.frames)} object{"s" if len(self.frames) > 1 else ""}'
        objects = f'{count} on /tf ({", ".join(self.frames.values())})' if self.frames else 'no objects'
        gripper = (f'the gripper ({", ".join(self.arm.gripper)}) on {rospy.resolve_name(GRIPPER_ACTION)}'
                   if self.server else 'no gripper')
        return f'{objects}; {gripper}'

    def ticked(self, stamp: rospy.Time) -> None:
        """After a tick of physics (the sim's lock held): the objects' poses on tf at stamp; a gripper goal waiting
        on the tick is woken."""
        states = self.arm.object_states()
        if self.tf_pub is not None:
            message = TFMessage()
            for name, (position, q, _) in states.items():
                t = TransformStamped()
                t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, self.base, self.frames[name]
                t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = position
                r = t.transform.rotation
                r.w, r.x, r.y, r.z = q
                message.transforms.append(t)
            publish(self.tf_pub, message)
        message = ObjectStates(name=list(states))
        message.header.stamp, message.header.frame_id = stamp, self.base
        for position, q, velocity in states.values():
            pose, twist = Pose(), Twist()
            pose.position.x, pose.position.y, pose.position.z = position
            pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = q
            twist.linear.x, twist.linear.y, twist.linear.z = velocity[:3]
            twist.angular.x, twist.angular.y, twist.angular.z = velocity[3:]
            message.pose.append(pose)
            message.twist.append(twist)
        publish(self.states_pub, message)
        with self.tick:
            self.tick.notify_all()

    def _markers(self, objects: tuple[Object, ...]) -> MarkerArray:
        markers = MarkerArray()
        for k, o in enumerate(objects):
            m = Marker(type={'box': Marker.CUBE, 'sphere': Marker.SPHERE, 'cylinder': Marker.CYLINDER}[o.kind],
                       ns='objects', id=k, action=Marker.ADD, frame_locked=True)
            m.header.frame_id = self.frames[o.name]
            if o.kind == 'box':
                m.scale.x, m.scale.y, m.scale.z = o.size
            else:                       # a sphere's diameter, or a cylinder's and its length
                m.scale.x = m.scale.y = 2 * o.size[0]
                m.scale.z = o.size[1] if o.kind == 'cylinder' else 2 * o.size[0]
            m.pose.orientation.w = 1.0
            m.color.r, m.color.g, m.color.b, m.color.a = OBJECT_COLOUR
            label = Marker(type=Marker.TEXT_VIEW_FACING, ns='object_names', id=k, action=Marker.ADD,
                           frame_locked=True, text=o.name)
            label.header.frame_id = m.header.frame_id
            label.pose.position.z = max(m.scale.z, 0.02) / 2 + 0.03     # above the object
            label.pose.orientation.w = label.color.r = label.color.g = label.color.b = label.color.a = 1.0
            label.scale.z = 0.03
            markers.markers += [m, label]
        return markers

    def _on_goal(self, goal) -> None:
        """A gripper goal, carried out over the sim's ticks (free-running, or one per command in lockstep) until
        the gripper reaches it or stalls on what it grips (succeeded, stalled said), a new goal preempts it or the
        node stops."""
        with self.lock:
            try:
                target = self.arm.grip(goal.command.position, goal.command.max_effort)
            except PhysicsError as e:
                self.server.set_aborted(self._result(GripperCommandResult), text=str(e))
                return
        effort = f'at most {goal.command.max_effort:g}' if goal.command.max_effort > 0 else 'the URDF\'s effort limit'
        rospy.loginfo(f'arm_sim: the gripper toward {target:g}, with {effort}')
        while not rospy.is_shutdown():
            with self.tick:
                self.tick.wait(0.5)
            if self.server.is_preempt_requested():
                self.server.set_preempted(self._result(GripperCommandResult), text='a new goal came')
                return
            with self.lock:
                outcome = self.arm.gripper_outcome()
                feedback = self._result(GripperCommandFeedback)
            self.server.publish_feedback(feedback)
            if outcome is not None:
                result = self._result(GripperCommandResult)
                result.reached_goal, result.stalled = outcome
                text = 'reached' if outcome[0] else f'stalled at {result.position:g}, gripping with {result.effort:g}'
                self.server.set_succeeded(result, text=text)
                return

    def _result(self, kind):
        """A result or feedback of the gripper as it stands (the sim's lock held or not needed)."""
        position, _, effort = self.arm.gripper_state()
        outcome = self.arm.gripper_outcome() or (False, False)
        return kind(position=position, effort=effort, reached_goal=outcome[0], stalled=outcome[1])
