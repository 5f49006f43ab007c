"""reach_controller: a reach policy drives an arm of the ROS graph toward points clicked in rviz.

Every 1/~rate seconds of ROS time it reads the arm's joints (joint_states) and its tip from /tf (the frames
forward_kinematics or robot_state_publisher publishes), acts as the reach env would from where the arm stands (the
same observation, the policy's action, the same damped least squares) and publishes ros_control's
JointGroupPositionController command; arm_sim takes it, and so does a real arm's controller (remap the command
topic to it, and give ~command_joints its joints). Goals come from rviz's Publish Point tool (/clicked_point) or
~goal, in any frame tf knows; the goal is drawn as a marker and its distance published. It says `reached <goal> in
<s> s (<d> m)` once the tip is within the policy's threshold. When the distance stops shrinking with joints at their
limits (a goal the arm must come at another way), it takes the arm home and tries once more from there; then it says
`not reached: closest <d> m ...` and why (beyond the arm's reach, with the distance; stalled with the joints at their
limits, named; or neither), takes the arm back to the closest configuration it found and holds it until the next
goal. ~home takes the arm home and drops the goal.

ROS Parameters
    robot_description (str): the robot, searched up the namespaces and waited for.
    ~policy (str, ""): a reach policy file (.npz, python -m robot_ai.reach train) or an ONNX model (.onnx) exported
        from another library (examples/sb3_sac_her_reach_onnx.py; robot_ai.policies.onnx); empty: ARS trains on the
        robot description at start (seconds) and says so. A bad file, or one of another robot or tip, ends the node
        with one line.
    ~tip (str, ""): the tip link; empty: the policy's, or the arm's end (a tool frame such as tool0, not a finger).
    ~rate (float, 20): control steps per second of ROS time.
    ~command_joints (list of str, [] = the robot's active joints): the joints of the command, in its order (a real
        controller's joints); those the arm does not move hold the positions joint_states reports.
    ~stalled_after (float, 2.0): seconds without a millimetre of progress before a goal is called not reached.
    ~obstacles (str or list, ""): obstacles in the arm's base frame, a YAML file (or a list parameter) of
        {box: [sx, sy, sz], position: [x, y, z], rpy: [r, p, y]} or {sphere: r, position: [x, y, z]}; empty: the
        world the policy file learned in, if any. With a world, the arm's body (its URDF collision geometry) is
        checked on every command: a command whose motion would touch the arm itself or an obstacle is not sent, the
        arm holds and the node says which links would touch.

ROS Subscribers
    joint_states (sensor_msgs/JointState): the arm's joints.
    /clicked_point (geometry_msgs/PointStamped): a goal, from rviz's Publish Point tool.
    ~goal (geometry_msgs/PointStamped): a goal.

ROS Publishers
    joint_group_position_controller/command (std_msgs/Float64MultiArray): positions of ~command_joints.
    ~goal_marker (visualization_msgs/Marker, latched): the goal, a sphere of the threshold's size, in the base frame.
    ~distance (std_msgs/Float64): the tip's distance to the goal, every step.
    ~obstacle_markers (visualization_msgs/MarkerArray, latched): the obstacles, in the base frame.

ROS Services
    ~home (std_srvs/Trigger): the arm to its home (the middle of each joint's range, the policy's), goal dropped.
    ~load_policy (robot_ai/LoadPolicy): drive with another reach policy file or ONNX model of this robot, tip and
        control; a bad file, or one of another robot or tip, changes nothing.

Parameters it sets: ~policy_info (str): the policy that drives, in one line; ~success_rate (float): its success rate
over fresh goals (held-out) as its file or its training says, -1 when unknown.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger, TriggerResponse
from visualization_msgs.msg import Marker, MarkerArray

from robot_ai import ars
from robot_ai import policies
from robot_ai.nodes.params import init_node, number_param, publish, quiet_on_shutdown, str_param
from robot_ai.srv import LoadPolicy, LoadPolicyResponse
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.reach import learn, policy_files
from robot_ai.reach.arm import ReachError
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.task import goal_distance_one, why_unreached
from robot_ai.text import percent

COMMAND_TOPIC = 'joint_group_position_controller/command'
PROGRESS = 0.001          # m: less than this over ~stalled_after seconds is no progress
AT_HOME = 0.01            # rad (or m): every joint this near home is home (a retry starts there)
MAX_GOAL = 1000.0         # m from the base: a goal farther out is a mistake (a 1e308 goal), not a place to reach


TRAIL_STEP = 0.02          # rad between the configurations kept of the way the arm came
MAX_TRAIL = 5000           # configurations kept (the oldest go first)


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix."""
    from tf import transformations as tft
    m = np.identity(4)
    m[:3, :3] = rotation
    return tuple(float(v) for v in tft.quaternion_from_matrix(m))


def _rotate(q, v) -> list[float]:
    """v rotated by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)]


class ReachController:

    def __init__(self, tree, xml: str):
        self.rate = number_param('~rate', 20.0, 'a positive number of steps per second', lambda v: 0 < v <= 1000)
        self.stalled_after = number_param('~stalled_after', 2.0, 'a positive number of seconds',
                                          lambda v: 0 < v <= 3600)
        world = rospy.get_param('~obstacles', '') or None
        self.policy, self.setup, info, success = self._policy(xml, str_param('~policy', ''), str_param('~tip', ''),
                                                              world)
        self._announce(info, success)
        arm = self.setup.arm
        self.base, self.tip = arm.base, arm.tip
        self.command_joints = rospy.get_param('~command_joints', []) or list(tree.active_joints)
        if not isinstance(self.command_joints, list) or not all(isinstance(n, str) for n in self.command_joints):
            raise ValueError(f'~command_joints must be a list of joint names, got {self.command_joints!r}')
        missing = [n for n in arm.joints if n not in self.command_joints]
        if missing:
            raise ValueError(f'~command_joints lacks {", ".join(missing)}, which the arm moves to reach')
        self.slot = [self.command_joints.index(n) for n in arm.joints]
        self.lock = threading.Lock()
        self.joints: dict[str, float] = {}
        self.goal: list[float] | None = None
        self.goal_since = 0.0
        self.best = float('inf')
        self.progress_mark = float('inf')         # the distance at the last progress of PROGRESS or more
        self.best_q: list[float] | None = None    # the arm's joints when it was closest to the goal
        self.improved_at = 0.0
        self.said = False
        self.holding = False                      # a goal said not reached: the arm holds at its closest
        self.homing = False                       # stalled at joint limits: going home to try again from there
        self.retried = False                      # the goal's one retry from home was made
        self.homing_since = 0.0
        self.blocked = ''                         # the contacts that refused the last motion ('' when it was sent)
        self.trail: list[list[float]] = []        # with a body: the configurations the arm came by, clear of contacts
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(10))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.command_pub = rospy.Publisher(COMMAND_TOPIC, Float64MultiArray, queue_size=1, tcp_nodelay=True)
        self.marker_pub = rospy.Publisher('~goal_marker', Marker, queue_size=1, latch=True)
        self.distance_pub = rospy.Publisher('~distance', Float64, queue_size=1)
        self.obstacles_pub = rospy.Publisher('~obstacle_markers', MarkerArray, queue_size=1, latch=True)
        self._draw_obstacles()
        self.subs = [rospy.Subscriber('joint_states', JointState, self._on_joints, queue_size=1, tcp_nodelay=True),
                     rospy.Subscriber('/clicked_point', PointStamped, self._on_goal, queue_size=1),
                     rospy.Subscriber('~goal', PointStamped, self._on_goal, queue_size=1)]
        self.services = [rospy.Service('~home', Trigger, self._on_home),
                         rospy.Service('~load_policy', LoadPolicy, self._on_load_policy)]
        self.timer = rospy.Timer(rospy.Duration(1.0 / self.rate), self._step)
        rospy.loginfo(f'reach_controller ready: {arm.describe()}; {self.rate:g} steps/s; click a point in rviz '
                      f'(Publish Point) or publish {rospy.resolve_name("~goal")}')

    # ------------------------------------------------------------------------------------------------ the policy
    @staticmethod
    def _announce(info: str, success: float | None) -> None:
        rospy.set_param('~policy_info', info)
        rospy.set_param('~success_rate', float(success) if isinstance(success, (int, float)) else -1.0)
        rospy.loginfo(f'reach_controller: driving with {info}')

    @staticmethod
    def _policy(xml: str, path: str, tip: str, world=None):
        """(an object with act_batch(flat observations), the reach setup it acts in, a line on it, its success rate)
        of ~policy, or of an ARS run on the robot description when it is empty; world: ~obstacles."""
        if path:
            try:
                policy, setup, note = policy_files.load(path, urdf=xml, tip=tip or None, obstacles=world)
            except (policies.PolicyError, ReachError) as e:
                raise ValueError(f'~policy: {e}') from None
            if note:
                rospy.logwarn(note)
            return policy.actor, setup, policy.describe(), policy.metadata.get('success_rate')
        try:
            setup = ReachSetup(urdf=xml, tip=tip or None, obstacles=world)
        except ReachError as e:
            raise ValueError(f'~tip or ~obstacles: {e}') from None
        for warning in setup.arm.warnings:
            rospy.logwarn(f'reach_controller: {warning}')
        rospy.loginfo(f'reach_controller: no ~policy: ARS learns to reach with {setup.arm.describe()} (seconds; '
                      f'python -m robot_ai.reach train writes a file to give as ~policy instead)')
        t = time.monotonic()
        # a Ctrl-C during the training ends it at the next iteration (it took ARS's seconds, and under load minutes,
        # before roslaunch's escalation to SIGTERM 15 s later)
        stop = rospy.core.is_shutdown_requested
        kwargs = dict(urdf=xml, tip=setup.arm.tip) if world is None else dict(urdf=xml, tip=setup.arm.tip,
                                                                                obstacles=world)
        training = learn.train(kwargs, seed=0, should_stop=stop, evaluate_episodes=1000)
        if stop():
            raise rospy.ROSInterruptException('reach_controller: shut down during its training')
        rate = training.held_out.success_rate
        info = (f'ARS trained at start on {setup.model.tree.name}: {percent(rate)} of 1000 fresh goals within '
                f'{setup.task.distance_threshold:g} m, {time.monotonic() - t:.1f} s, {training.result.steps:,} steps')
        return training.policy, training.setup, info, rate

    # ------------------------------------------------------------------------------------------------ callbacks
    def _on_joints(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position):
            rospy.logwarn_throttle(5.0, 'joint_states with as many names as positions skipped')
            return
        with self.lock:
            self.joints.update(zip(msg.name, msg.position))

    def _in_base(self, point: PointStamped) -> list[float] | None:
        frame = point.header.frame_id.lstrip('/') or self.base
        p = [point.point.x, point.point.y, point.point.z]
        if frame == self.base:
            return p
        try:
            t = self.tf_buffer.lookup_transform(self.base, frame, rospy.Time(0), rospy.Duration(1.0)).transform
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as e:
            rospy.logwarn(f'goal in {frame} ignored: no transform from {frame} to {self.base} ({e})')
            return None
        r = _rotate((t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w), p)
        return [r[0] + t.translation.x, r[1] + t.translation.y, r[2] + t.translation.z]

    def _on_goal(self, point: PointStamped) -> None:
        goal = self._in_base(point)
        if goal is None:
            return
        if not all(math.isfinite(v) and abs(v) <= MAX_GOAL for v in goal):
            shown = ', '.join(f'{v:.4g}' for v in goal)
            rospy.logwarn(f'goal ({shown}) in {self.base} ignored: each coordinate must be a finite number of metres, '
                          f'at most {MAX_GOAL:g} from the base')
            return
        inside = next((o.name for o in self.setup.obstacles if o.contains(goal)), None)
        if inside is not None:
            rospy.logwarn(f'goal ({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) in {self.base} ignored: it is inside '
                          f'{inside}')
            return
        with self.lock:
            self.goal, self.goal_since, self.best, self.said = goal, time.monotonic(), float('inf'), False
            self.blocked = ''
            self.best_q, self.holding, self.homing, self.retried = None, False, False, False
            self.improved_at = self.goal_since
        self._draw(goal)
        rospy.loginfo(f'goal ({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) m in {self.base}')

    def _draw(self, goal: list[float] | None) -> None:
        marker = Marker(type=Marker.SPHERE, ns='reach_goal', id=0,
                        action=Marker.ADD if goal is not None else Marker.DELETE)
        marker.header.frame_id = self.base
        marker.header.stamp = rospy.Time.now()
        if goal is not None:
            marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = goal
            marker.pose.orientation.w = 1.0
            size = 2 * self.setup.task.distance_threshold
            marker.scale.x = marker.scale.y = marker.scale.z = size
            marker.color.r, marker.color.g, marker.color.b, marker.color.a = 0.1, 0.9, 0.1, 0.6
        publish(self.marker_pub, marker)

    def _on_load_policy(self, req) -> LoadPolicyResponse:
        try:
            policy, _, note = policy_files.load(req.path, self.setup)
        except (policies.PolicyError, ReachError) as e:
            return LoadPolicyResponse(success=False, message=f'{e}; still driving with the policy it had')
        with self.lock:
            self.policy = policy.actor
        self._announce(policy.describe(), policy.metadata.get('success_rate'))
        return LoadPolicyResponse(success=True, message=f'driving with {policy.describe()}' + (f' ({note})' if note
                                                                                                  else ''))

    def _on_home(self, req) -> TriggerResponse:
        with self.lock:
            self.goal = None
            self._command(dict(self.joints), self.setup.home.tolist())
        self._draw(None)
        return TriggerResponse(success=True, message=f'going home: {np.round(self.setup.home, 3).tolist()}')

    # ------------------------------------------------------------------------------------------------ the loop
    def _command(self, joints: dict, arm_positions: list[float]) -> None:
        positions = [joints.get(n, 0.0) for n in self.command_joints]
        for k, value in zip(self.slot, arm_positions):
            positions[k] = value
        publish(self.command_pub, Float64MultiArray(data=positions))

    def _draw_obstacles(self) -> None:
        markers = MarkerArray()
        for k, o in enumerate(self.setup.obstacles):
            m = Marker()
            m.header.frame_id = self.base
            m.ns, m.id, m.action = 'obstacles', k, Marker.ADD
            m.type = Marker.CUBE if o.kind == 'box' else Marker.SPHERE
            size = o.size if o.kind == 'box' else (2 * o.size[0],) * 3
            m.scale.x, m.scale.y, m.scale.z = size
            m.pose.position.x, m.pose.position.y, m.pose.position.z = o.pose[:3, 3]
            x, y, z, w = _quaternion(o.pose[:3, :3])
            m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = x, y, z, w
            m.color.r, m.color.g, m.color.b, m.color.a = 0.55, 0.45, 0.35, 0.8
            markers.markers.append(m)
        publish(self.obstacles_pub, markers)

    def _tip(self) -> list[float] | None:
        try:
            t = self.tf_buffer.lookup_transform(self.base, self.tip, rospy.Time(0)).transform.translation
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as e:
            rospy.logwarn_throttle(5.0, f'no transform {self.base} -> {self.tip} yet ({e}): is forward_kinematics '
                                        f'(or robot_state_publisher) running?')
            return None
        return [t.x, t.y, t.z]

    def _step(self, event) -> None:
        with self.lock:
            goal, joints, policy = self.goal, dict(self.joints), self.policy
            holding, homing = self.holding, self.homing
        if goal is None:
            return
        arm = self.setup.arm
        if not all(n in joints for n in arm.joints):
            missing = ', '.join(n for n in arm.joints if n not in joints)
            rospy.logwarn_throttle(5.0, f'joint_states does not report {missing} yet')
            return
        tip = self._tip()
        if tip is None:
            return
        q = [min(max(float(joints[n]), lo), hi) for n, lo, hi in zip(arm.joints, arm._lower, arm._upper)]
        distance = goal_distance_one(tip, goal)
        publish(self.distance_pub, Float64(distance))
        if holding:
            return
        if homing:
            self._home_step(goal, joints, q)
            return
        observation = self.setup.observation_one(q, tip, goal)
        try:
            action = policy.act_batch(ars.flatten_batch(self.setup.observation_space,
                                                            {k: v[None] for k, v in observation.items()}))[0]
            a = self.setup.check_action_one(np.asarray(action, dtype=np.float64))
        except (policies.PolicyError, ValueError) as e:      # a model that answers no action here: no command
            rospy.logerr_throttle(10.0, f'the policy gave no action for this state, so no command was sent: {e}')
            return
        target = self.setup.move_one(q, self.setup.place_one(q)[1], a)
        body = self.setup.body
        blocked = ''
        held, hit = self.setup.guard_one(q, target)       # a motion that would touch: the arm holds where it is
        if hit:
            blocked = ', '.join(body.contacts(target)) or 'a contact'
            rospy.logwarn_throttle(2.0, f'holding: the next motion would touch ({blocked}), so it was not sent')
            target = held
        elif body is not None and (not self.trail or max(abs(a - b) for a, b in zip(q, self.trail[-1])) > TRAIL_STEP):
            self.trail.append(q)          # where the arm is: clear of contacts, the way back home
            del self.trail[:-MAX_TRAIL]
        self.blocked = blocked
        with self.lock:                  # a ~home or a new goal that came meanwhile wins: no stale command after it
            if goal is not self.goal:
                return
            self._command(joints, target)
        # judged on the joints' own tip (the kinematics of q), not /tf's: the two can be a message apart under load,
        # and the configuration held after `not reached` must be the one whose distance was said
        hold = self._judge(goal, goal_distance_one(self.setup.place_one(q)[0], goal), q)   # after the command
        if hold is not None:
            with self.lock:
                if goal is self.goal:
                    self._command(joints, hold)

    def _judge(self, goal: list[float], distance: float, q: list[float]) -> list[float] | None:
        """Says reached or not reached once per goal; after not reached, the joints to hold (the arm's closest
        configuration: at the edge of its workspace a policy would otherwise jitter), else None."""
        now = time.monotonic()
        with self.lock:
            if goal is not self.goal or self.said:
                return None
            if self.best_q is None or distance < self.progress_mark - PROGRESS:
                self.progress_mark, self.improved_at = distance, now    # progress: the stall clock starts again
            if self.best_q is None or distance < self.best:     # the closest configuration, however small the gain
                self.best, self.best_q = distance, q
            reached = distance < self.setup.task.distance_threshold
            stalled = now - self.improved_at > self.stalled_after
            if not (reached or stalled):
                return None
            kind, why = why_unreached(self.setup.arm, goal, q, distance) if not reached else ('', '')
            if not reached and self.blocked and kind != 'beyond':
                kind, why = 'collision', f'blocked {distance:.3f} m away by a collision ({self.blocked})'
            if kind in ('limits', 'collision') and not self.retried:       # home, and once more from there
                self.homing, self.retried, self.homing_since = True, True, now
                rospy.loginfo(f'{why}: going home to try again from there')
                return self.setup.home.tolist()
            self.said = True
            self.holding = not reached
            since, hold, best = self.goal_since, self.best_q, self.best
        where = f'({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f})'
        if reached:
            rospy.loginfo(f'reached {where} in {now - since:.2f} s ({distance:.3f} m)')
            return None
        rospy.loginfo(f'not reached: closest {best:.3f} m to {where}: {why}; holding at the closest')
        return hold

    def _home_step(self, goal: list[float], joints: dict, q: list[float]) -> None:
        """On the way home for a retry: home commanded until every joint is there (or ~stalled_after has passed
        twice without getting there), then the policy drives again from home, its stall clock started afresh. With
        a body, the arm goes back the way it came (the configurations it passed, each clear of contacts), then
        home, and a step home that would touch is not sent."""
        home = self.setup.home.tolist()
        there = max(abs(a - b) for a, b in zip(q, home)) < AT_HOME
        with self.lock:
            if goal is not self.goal:
                return
            if there or time.monotonic() - self.homing_since > 2 * self.stalled_after + 30.0:
                self.homing, self.improved_at, self.progress_mark = False, time.monotonic(), float('inf')
                if there:
                    self.trail = [home]
                return
            while self.trail and max(abs(a - b) for a, b in zip(q, self.trail[-1])) < 2 * TRAIL_STEP:
                self.trail.pop()          # passed: the next one back
            target = self.trail[-1] if self.trail else home
            body = self.setup.body
            if body is not None and not self.trail and body.in_collision(np.array([home]))[0]:
                rospy.logwarn_throttle(2.0, f'holding: home is in contact ({", ".join(body.contacts(home))})')
                return
            self._command(joints, target)


@quiet_on_shutdown
def main():
    init_node('reach_controller')
    tree, key = wait_for_tree()
    if tree is None:
        return
    try:
        ReachController(tree, rospy.get_param(key))
    except ValueError as e:
        rospy.logfatal(f'reach_controller: bad parameter: {e}')
        raise SystemExit(1)
    rospy.spin()
