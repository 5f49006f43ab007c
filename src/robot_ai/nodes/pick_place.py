"""pick_place: a pick and place clicked in rviz. Click an object (rviz's Publish Point tool, on the object), then a
place (on the table): the arm goes to the task's ready configuration by a planned way (the motion planner over its
body and the world), then the scripted expert, or a learned PickAndPlace-v0 policy (~policy), carries the object
there, the gripper opens, the arm rises clear, and the node says `placed <object> at (x, y, z), <d> m from the
place` or `not placed: <why>` (no object near the click, a place outside the workspace, no way to the ready
configuration, the object short of the place when the policy's time ran out, the safety layer holding the arm)
on ~result and in its log (robot_ai.physics.pick). Every arm command goes through a safety layer (robot_ai.reach
.safety: the limits at ~velocity_scale, the arm's body against itself and ~obstacles, ~collision_margin kept on the
way to the task; while the policy has the arm, only motions that would touch are refused) as a joint_trajectory
_controller's trajectory; the gripper as ros_control's gripper_action_controller takes it. arm_sim with ~physics
mujoco is the arm (pick.launch), or any arm whose driver exposes those two controllers.

The task's layout (its table, the ready configuration, the workspace) is worked out from robot_description as the
envs do (robot_ai.physics.workspace): give arm_sim and this node the world `python -m robot_ai.physics world` writes
for the robot (rosparam load: ~obstacles, ~objects, ~home), or one with the same table.

ROS Parameters
    robot_description (str): the robot (an arm with a gripper), searched up the namespaces and waited for.
    ~tip (str, ""): the link the gripper hangs from; empty: the policy's, or the arm's end.
    ~policy (str, ""): a PickAndPlace-v0 policy file of this robot (.npz of python -m robot_ai.physics train, or its
        .onnx); empty: the scripted expert (robot_ai.physics.expert). A bad file ends the node with one line.
    ~obstacles (str or list, ""): the world's obstacles in the robot's root frame (arm_sim's: the table among them).
    ~objects (str or list, ""): the loose objects (arm_sim's), whose frames (their names, made frame-safe as arm_sim
        makes them) it reads from /tf.
    ~velocity_scale (float, 0.5): the share of the velocity and acceleration limits used, in (0, 1].
    ~joint_limits (str, ""): a MoveIt joint_limits.yaml narrowing the URDF's limits.
    ~collision_margin (float, 0.02): metres kept between the arm's body and itself or an obstacle on the way.
    ~controller (str, "joint_trajectory_controller"): the controller whose <controller>/command takes the arm's
        trajectories.
    ~state_timeout (float, 0.5): joint_states or an object's pose older than this (s of ROS time): the arm holds; a pick
        that waits INPUT_WAIT (5 s) for them ends, not placed. A pick with no gripper action server is refused.

ROS Subscribers
    joint_states (sensor_msgs/JointState): the arm's and the gripper's joints.
    /clicked_point (geometry_msgs/PointStamped): rviz's Publish Point: an object, then the place (any frame tf
        knows).

ROS Publishers
    <~controller>/command (trajectory_msgs/JointTrajectory): the arm's commands, each the safety layer's plan.
    ~result (std_msgs/String, latched): each pick's outcome, and a click refused (`not placed: ...`).
    ~place_marker (visualization_msgs/Marker, latched): the object chosen and the place.
    ~obstacle_markers (visualization_msgs/MarkerArray, latched): the obstacles, in the robot's root frame.

ROS Actions (client)
    gripper_controller/gripper_cmd (robot_ai/GripperCommand): the gripper, as ros_control's gripper_action_controller
        takes it.

ROS Services
    ~cancel (std_srvs/Trigger): the pick under way ends, the arm holds where it is.
"""
from __future__ import annotations

import threading

import actionlib
import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger, TriggerResponse
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from robot_ai.msg import GripperCommandAction, GripperCommandGoal
from robot_ai.nodes.arm_physics import GRIPPER_ACTION, object_frames
from robot_ai.nodes.markers import obstacle_markers
from robot_ai.nodes.params import number_param, publish, run_node, str_param
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.physics import PhysicsError, parse_objects
from robot_ai.physics.pick import PickError, PickPlace, PickStep

GRIPPER_STEP = 0.05         # the gripper's opening (0 to 1) moves this much before a new goal is sent
INPUT_WAIT = 5.0            # s of ROS time a pick waits for joint_states or its object's pose before it ends
GRIPPER_WAIT = 2.0          # s: how long a pick waits for the gripper's action server to be there


def _transform_matrix(t) -> np.ndarray:
    from tf.transformations import quaternion_matrix
    q = t.transform.rotation
    m = quaternion_matrix([q.x, q.y, q.z, q.w])
    m[:3, 3] = [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
    return m


class PickPlaceNode:
    def __init__(self, xml: str, tree):
        from robot_ai.physics.env import ManipulationSetup
        from robot_ai.physics import policy_files
        from robot_ai.policies import PolicyError
        tip = str_param('~tip', '') or None
        path = str_param('~policy', '')
        policy = None
        try:
            if path:
                loaded, setup = policy_files.load(path, model='', urdf=xml, tip=tip)
                if setup.task != 'pick_and_place':
                    raise ValueError(f'{path} acts in {setup.task}, not pick_and_place')
                policy, said = loaded.act_batch, f'the policy {path}'
            else:
                setup = ManipulationSetup('pick_and_place', urdf=xml, tip=tip)
                said = 'the scripted expert'
            objects = parse_objects(rospy.get_param('~objects', '') or ())
            self.picking = PickPlace(
                setup, obstacles=rospy.get_param('~obstacles', '') or (), policy=policy, objects=objects,
                velocity_scale=number_param('~velocity_scale', 0.5, 'a number in (0, 1]', lambda v: 0 < v <= 1),
                margin=number_param('~collision_margin', 0.02, 'metres, 0 to 1', lambda v: 0 <= v <= 1),
                joint_limits=str_param('~joint_limits', '') or None)
        except (PolicyError, PhysicsError, PickError) as e:
            raise ValueError(str(e)) from None
        self.setup, self.tree = setup, tree
        self.frames = object_frames([o.name for o in objects], set(tree.links))
        self.timeout = number_param('~state_timeout', 0.5, 'a positive number of seconds', lambda v: v > 0)
        controller = str_param('~controller', 'joint_trajectory_controller')
        self.lock = threading.Lock()
        self.joints: dict[str, float] = {}
        self.joints_at = None
        self.chosen: str | None = None
        self.missing_since: float | None = None
        self.opening: float | None = None
        self.epoch = rospy.Time.now()
        self.buffer = tf2_ros.Buffer()
        self.listener = tf2_ros.TransformListener(self.buffer)
        # every plan starts where the one before leaves the arm: none may be dropped (reach_controller's lesson: a
        # queue of 1 dropped one under load and the controller joined the next from where the arm was)
        self.command_pub = rospy.Publisher(f'{controller}/command', JointTrajectory, queue_size=100,
                                           tcp_nodelay=True)
        self.result_pub = rospy.Publisher('~result', String, queue_size=10, latch=True)
        self.marker_pub = rospy.Publisher('~place_marker', Marker, queue_size=1, latch=True)
        self.obstacles_pub = rospy.Publisher('~obstacle_markers', MarkerArray, queue_size=1, latch=True)
        publish(self.obstacles_pub, obstacle_markers(self.picking.reach.obstacles, tree.root))
        self.gripper = actionlib.SimpleActionClient(GRIPPER_ACTION, GripperCommandAction)
        rospy.Subscriber('joint_states', JointState, self._on_joints, queue_size=1, tcp_nodelay=True)
        rospy.Subscriber('/clicked_point', PointStamped, self._on_click, queue_size=10)
        rospy.Service('~cancel', Trigger, self._on_cancel)
        self.timer = rospy.Timer(rospy.Duration(self.picking.period), self._tick)
        rospy.loginfo(f'pick_place: ready: {tree.name} (tip {setup.arm.tip}, gripper '
                      f'{", ".join(setup.gripper)}), {said}, {len(self.frames)} objects '
                      f'({", ".join(self.frames.values()) or "none: give ~objects"}); click an object in rviz '
                      f'(Publish Point), then the place')
        if self.picking.ready_note:
            rospy.loginfo(f'pick_place: {self.picking.ready_note}')
        for note in setup.notes:
            rospy.logwarn(f'pick_place: {note}')

    # ---------------------------------------------------------------------------------------------- inputs
    def _on_joints(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position):
            return
        with self.lock:
            self.joints.update(zip(msg.name, msg.position))
            self.joints_at = rospy.Time.now()

    def _now(self) -> float:
        return (rospy.Time.now() - self.epoch).to_sec()

    def _say(self, line: str, error: bool = False) -> None:
        (rospy.logwarn if error else rospy.loginfo)(f'pick_place: {line}')
        if line.startswith(('placed', 'not placed')):
            publish(self.result_pub, String(data=line))

    def _object_positions(self) -> dict[str, np.ndarray]:
        out = {}
        for name, frame in self.frames.items():
            try:
                t = self.buffer.lookup_transform(self.tree.root, frame, rospy.Time(0), rospy.Duration(0.1))
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
                continue
            out[name] = _transform_matrix(t)[:3, 3]
        return out

    def _on_click(self, msg: PointStamped) -> None:
        try:
            t = self.buffer.lookup_transform(self.tree.root, msg.header.frame_id or self.tree.root, rospy.Time(0),
                                             rospy.Duration(0.5))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as e:
            self._say(f'not placed: the click\'s frame {msg.header.frame_id!r} is not on /tf ({e})', error=True)
            return
        point = (_transform_matrix(t) @ [msg.point.x, msg.point.y, msg.point.z, 1.0])[:3]
        if not np.isfinite(point).all():
            self._say('not placed: the click is not a finite point', error=True)
            return
        with self.lock:
            if self.picking.phase:
                rospy.logwarn(f'pick_place: picking {self.picking.name} still: the click is ignored (~cancel ends '
                              f'the pick)')
                return
            objects = self._object_positions()
            try:
                if self.chosen is None:
                    self.chosen = self.picking.choose(point, objects)
                    self._marker(objects[self.chosen], None)
                    self._say(f'{self.chosen} chosen: now click where to place it')
                    return
                name, self.chosen = self.chosen, None
                if name not in objects:
                    raise PickError(f'{name}\'s frame {self.frames[name]} is not on /tf')
                place = self.picking.place_of(point, {k: v for k, v in objects.items() if k != name}, name)
                if not self.gripper.wait_for_server(rospy.Duration(GRIPPER_WAIT)):
                    raise PickError(f'no gripper action server on {rospy.resolve_name(GRIPPER_ACTION)} (arm_sim with '
                                    f'~physics mujoco serves one, a real arm\'s gripper_action_controller does)')
                self._say(self.picking.start(name, objects[name], place, self._now()))
                self.missing_since = None
                self._marker(objects[name], place)
            except PickError as e:
                self._say(f'not placed: {e}', error=True)

    def _on_cancel(self, _request) -> TriggerResponse:
        with self.lock:
            if not self.picking.phase:
                return TriggerResponse(success=False, message='no pick under way')
            name = self.picking.name
            self.picking.stop()
            self.chosen = None
        self._say(f'not placed: the pick of {name} was cancelled (the arm holds)')
        return TriggerResponse(success=True, message=f'the pick of {name} ends; the arm holds')

    # ----------------------------------------------------------------------------------------------- output
    def _marker(self, at, place) -> None:
        m = Marker(type=Marker.SPHERE_LIST, action=Marker.ADD, ns='pick_place', id=0)
        m.header.frame_id, m.header.stamp = self.tree.root, rospy.Time.now()
        m.pose.orientation.w = 1.0
        size = self.setup.object_size * 1.5
        m.scale.x = m.scale.y = m.scale.z = size
        from geometry_msgs.msg import Point
        from std_msgs.msg import ColorRGBA
        for p, colour in ((at, (1.0, 0.6, 0.0, 0.6)), (place, (0.1, 0.9, 0.2, 0.6))):
            if p is not None:
                m.points.append(Point(*map(float, p)))
                m.colors.append(ColorRGBA(*colour))
        publish(self.marker_pub, m)

    def _send(self, plan) -> None:
        times, positions, velocities = plan.points(self.picking.period)
        msg = JointTrajectory(joint_names=list(self.setup.arm.joints))
        msg.header.stamp = self.epoch + rospy.Duration.from_sec(plan.start)
        for t, p, v in zip(times, positions, velocities):
            msg.points.append(JointTrajectoryPoint(positions=p.tolist(), velocities=v.tolist(),
                                                   time_from_start=rospy.Duration.from_sec(float(t))))
        publish(self.command_pub, msg)

    def _grip(self, opening: float) -> None:
        if self.opening is not None and abs(opening - self.opening) < GRIPPER_STEP:
            return
        self.opening = opening
        goal = GripperCommandGoal()
        goal.command.position = self.setup.grip_position(opening)
        goal.command.max_effort = 0.0
        self.gripper.send_goal(goal)

    def _tick(self, _event) -> None:
        with self.lock:
            if not self.picking.phase:
                return
            now = self._now()
            name = self.picking.name
            missing = ''
            try:
                arm = [self.joints[n] for n in self.setup.arm.joints]
                finger = self.joints[self.setup.gripper[0]]
                t = self.buffer.lookup_transform(self.tree.root, self.frames[name], rospy.Time(0))
                pose = _transform_matrix(t)
                if self.joints_at is None or (rospy.Time.now() - self.joints_at).to_sec() > self.timeout:
                    missing = f'joint_states older than {self.timeout:g} s'
                elif (rospy.Time.now() - t.header.stamp).to_sec() > self.timeout:
                    missing = f'{name}\'s pose on /tf older than {self.timeout:g} s'
            except KeyError as e:
                missing = f'joint_states without {e}'
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
                missing = f'no pose of {name} on /tf'
            if missing:             # the arm holds; a pick that waits INPUT_WAIT for its inputs ends
                if self.missing_since is None:
                    self.missing_since = now
                rospy.logwarn_throttle(5, f'pick_place: {missing}: the arm holds')
                if self.picking.layer.last is not None:
                    self._send(self.picking.layer.plan(now, None, None, why_not=missing))
                if now - self.missing_since < INPUT_WAIT:
                    return
                self.picking.stop()
                step = PickStep(said=f'not placed: {missing} for {INPUT_WAIT:g} s: the pick of {name} ends, the arm '
                                     f'holds', outcome='not placed')
            else:
                self.missing_since = None
                step = self.picking.step(now, np.array(arm), float(finger), pose)
            if step.plan is not None:
                self._send(step.plan)
            if step.opening is not None:
                self._grip(float(step.opening))
        if step.said:
            self._say(step.said, error=step.outcome.startswith('not placed'))


def main():
    def build():
        tree, key = wait_for_tree()
        if tree is None:
            return None
        return PickPlaceNode(rospy.get_param(key), tree)
    run_node('pick_place', build)
