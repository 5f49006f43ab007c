"""reach_controller: a reach policy drives an arm of the ROS graph toward points clicked in rviz, safely.

Every 1/~rate seconds of ROS time it reads the arm's joints (joint_states) and its tip from /tf (the frames
forward_kinematics or robot_state_publisher publishes) and acts as the reach env would from where the arm stands (the
same observation, the policy's action, the same damped least squares). Between the policy and the output sits a
safety layer no policy can pass (robot_ai.reach.safety): the joint position, velocity and acceleration limits (the
URDF's, narrowed by a MoveIt joint_limits.yaml, scaled by ~velocity_scale), and the arm's body (its URDF collision
geometry) against itself and the obstacles with a margin, checked over each command's whole motion and the stop
after it; a command that would pass a limit or touch is not sent, the arm stops on the path already checked, holds,
and the node says why. joint_states older than ~state_timeout, a NaN or infinite number anywhere (state, goal, the
policy's answer), ~enable false and ~stop: the arm stops within its limits and holds, and goes on when the cause is
gone (after ~stop: at ~enable true). Whatever fails in a step, the loop goes on; at Ctrl-C the arm stops.

The output is ~command: `position` (ros_control's JointGroupPositionController: std_msgs/Float64MultiArray on
<~controller>/command, the position the plan commands one step on) or `trajectory` (joint_trajectory_controller, the
controller real arms' drivers expose, ur_robot_driver's and franka_ros': trajectory_msgs/JointTrajectory on
<~controller>/command, each step's motion and the stop after it, with positions, velocities and times that respect
the limits; a command that comes late, or never, leaves the arm stopping on a checked path). arm_sim takes both.

Goals come from rviz's Publish Point tool (/clicked_point), ~goal, ~goal_pose or the interactive marker
~pose_marker (dragged and released in rviz), in any frame tf knows; the goal is drawn as a marker and its distance
published. ~goal pose: a goal is the tip's position and orientation (a point keeps the tip's orientation now).
With the arm's body, each goal is planned first (ReachSetup.planned_way: OMPL's RRT-Connect over the body and
the world, the layer's margin and a centimetre more kept; `planned in <ms> (straight in joint space | round the
contacts, RRTConnect, <k> steps)`, and `planning a way ...` while a plan takes over a second): the arm follows the
way, a step each period through the safety layer (checked as every command is), and the policy has it for the rest;
an arm a collision holds (on the way, or the policy's short of the goal) gets a way planned again from where it
stands (MAX_REPLANS tries a goal); with no way (`no plan (<why>)`) the policy drives.
It says `reached <goal> in <s> s (<d> m)` once the tip is within the policy's thresholds. When the distance stops
shrinking within the arm's reach (joints at their limits, a collision, a
configuration the policy cannot leave: a goal the arm must come at another way), it takes the arm home and tries
once more from there; then it says `not reached: closest <d> m ...` and why (beyond
the arm's reach, with the distance; stalled with the joints at their limits, named; blocked by a collision; or
neither), takes the arm back to the closest configuration it found and holds it until the next goal. ~home takes the
arm home and drops the goal.

ROS Parameters
    robot_description (str): the robot, searched up the namespaces and waited for.
    ~policy (str, ""): a reach policy file (.npz, python -m robot_ai.reach train) or an ONNX model (.onnx) exported
        from another library (examples/sb3_sac_her_reach_onnx.py; robot_ai.policies.onnx); empty: ARS trains on the
        robot description at start (seconds) and says so. A bad file, or one of another robot or tip, ends the node
        with one line.
    ~tip (str, ""): the tip link; empty: the policy's, or the arm's end (a tool frame such as tool0, not a finger).
    ~goal (str, ""): position | pose, the kind of goal (pose: the tip's position and orientation, within the
        policy's distance and angle thresholds); empty: the policy file's, or position when ARS learns at start.
    ~rate (float, 20): control steps per second of ROS time.
    ~command_joints (list of str, [] = the robot's active joints): the joints of the command, in its order (a real
        controller's joints); those the arm does not move hold the positions joint_states reports.
    ~stalled_after (float, 2.0): seconds without a millimetre of progress before a goal is called not reached, at
        full speed: divided by ~velocity_scale, as the arm's motions take that much longer (8 s at 0.25).
    ~command (str, "position"): position | trajectory, the output (above).
    ~controller (str, "" = joint_group_position_controller or joint_trajectory_controller, as ~command): the
        controller whose <controller>/command topic takes the commands (scaled_pos_joint_traj_controller on a UR,
        position_joint_trajectory_controller on a Panda).
    ~joint_limits (str, ""): a MoveIt joint_limits.yaml (joint_limits: {joint: {has_velocity_limits, max_velocity,
        has_acceleration_limits, max_acceleration, ...}}); it narrows the URDF's limits, never widens them. Joints with
        no acceleration limit: full speed in 0.25 s.
    ~velocity_scale (float, 0.25): the velocity limits' share used, in (0, 1].
    ~acceleration_scale (float, = ~velocity_scale): the acceleration limits' share used, in (0, 1].
    ~collision (bool, true): the arm's body (its URDF collision geometry) checked against itself and the obstacles on
        every command; where no geometry can be read, the limits only (said at start).
    ~collision_margin (float, 0.02): metres kept between the body and itself or an obstacle (where the arm stands
        within it already, only motions that would touch are refused, so that it can move out).
    ~state_timeout (float, 0.2): joint_states older than this (seconds of ROS time): the arm stops and holds.
    ~enabled (bool, true): whether commands go out at start (false: after ~enable true).
    ~nice (int, -10): the scheduling priority it asks for once trained, so that its commands reach the arm's
        controller within the layer's lead on a loaded machine (root or CAP_SYS_NICE; otherwise it runs as started,
        and says so); 0 leaves it (robot_ai.priority).
    ~home_position (list or dict, []): the arm's home, where ~home takes it and a stalled goal is tried again from:
        joint positions in the arm's order, or {joint: position} (the others mid-range); empty: the policy file's, or
        the middle of every joint's range. Outside the limits or in contact: the node does not start, saying which
        pair touches; within ~collision_margin: ~home is refused (said at start).
    ~obstacles (str or list, ""): obstacles in the arm's base frame, a YAML file (or a list parameter) of
        {box: [sx, sy, sz], position: [x, y, z], rpy: [r, p, y]} or {sphere: r, position: [x, y, z]}; empty: the
        world the policy file learned in, if any; rviz draws them (~obstacle_markers).

ROS Subscribers
    joint_states (sensor_msgs/JointState): the arm's joints.
    /clicked_point (geometry_msgs/PointStamped): a goal, from rviz's Publish Point tool.
    ~goal (geometry_msgs/PointStamped): a goal (pose goals: at the tip's orientation now).
    ~goal_pose (geometry_msgs/PoseStamped): a goal pose, in any frame tf knows (position goals: its position).
    ~pose_marker/feedback (visualization_msgs/InteractiveMarkerFeedback): the interactive marker server ~pose_marker
        (pose goals); a marker released in rviz is the next goal.
    ~stop (std_msgs/Empty): the arm stops at once, within its limits, and holds until ~enable true.

ROS Publishers
    <~controller>/command (std_msgs/Float64MultiArray or trajectory_msgs/JointTrajectory, as ~command): the
        commands, for ~command_joints.
    ~goal_marker (visualization_msgs/Marker, latched): the goal, a sphere of the threshold's size, in the base frame
        (pose goals: and an arrow along the goal's x axis).
    ~pose_marker/update, ~pose_marker/update_full: the interactive marker `goal` (pose goals only: position goals
        have rviz's Publish Point), for rviz's InteractiveMarkers display.
    ~distance (std_msgs/Float64): the tip's distance to the goal, every step.
    ~obstacle_markers (visualization_msgs/MarkerArray, latched): the obstacles, in the base frame.

ROS Services
    ~home (std_srvs/Trigger): the arm to its home (the middle of each joint's range, the policy's), goal dropped;
        refused, and nothing sent, when home is outside the limits or within ~collision_margin of the body or world.
    ~enable (std_srvs/SetBool): false: the arm stops within its limits and holds, no command goes out once it is
        at rest; true: it goes on.
    ~load_policy (robot_ai/LoadPolicy): drive with another reach policy file or ONNX model of this robot, tip and
        control; a bad file, or one of another robot or tip, changes nothing. No command goes out while it loads
        and predicts (the arm comes to rest along its last command's stop).

Parameters it sets: ~policy_info (str): the policy that drives, in one line; ~success_rate (float): its success rate
over fresh goals (held-out) as its file or its training says, -1 when unknown; ~predicted_success_rate (float): its
success rate through this node's safety layer, predicted in-process (Reach-v0 velocity_scale: PREDICTION_GOALS fresh
goals from home, PREDICTION_PLANNED with a body, each planned first as here), -1 when it could not be played.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PointStamped, PoseStamped
from interactive_markers.interactive_marker_server import InteractiveMarkerServer
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty, Float64, Float64MultiArray
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import (InteractiveMarker, InteractiveMarkerControl, InteractiveMarkerFeedback, Marker,
                                    MarkerArray)

from robot_ai import ars
from robot_ai import policies
from robot_ai.nodes.params import (bool_param, init_node, int_param, number_param, publish, quiet_on_shutdown,
                                   str_param)
from robot_ai.srv import LoadPolicy, LoadPolicyResponse
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.nodes.markers import obstacle_markers
from robot_ai.priority import NICE, raise_priority
from robot_ai.reach import learn, policy_files
from robot_ai.reach.arm import ReachError
from robot_ai.motion.body import BodyError, CollisionModel
from robot_ai.reach.env import MAX_REPLANS, RECOVERING, READY, PlannedWay, ReachSetup, Recovery
from robot_ai.reach.planning import PLAN_BUDGET
from robot_ai.reach.safety import (DEFAULT_MARGIN, DEFAULT_VELOCITY_SCALE, SAMPLE_STEP, Limits, Plan, SafetyLayer,
                                   StampClock, measure_lead)
from robot_ai.reach.task import GOALS, goal_angle, goal_distance_one, why_unreached
from robot_ai.text import percent

COMMANDS = {'position': 'joint_group_position_controller',       # ~command -> the default ~controller
            'trajectory': 'joint_trajectory_controller'}
PROGRESS = 0.001          # m: less than this over ~stalled_after seconds is no progress
AT_HOME = 0.01            # rad (or m): every joint this near home is home (a retry starts there)
HOME_REACHED = 1e-6       # rad (or m): ~home is over when every joint is this near home, at rest
MAX_GOAL = 1000.0         # m from the base: a goal farther out is a mistake (a 1e308 goal), not a place to reach


TRAIL_STEP = 0.02          # rad between the configurations kept of the way the arm came
MAX_TRAIL = 5000           # configurations kept (the oldest go first)
REROUTE = 25               # configurations of the way home passed before a straighter way is looked for again
PREDICTION_GOALS = 200     # fresh goals of the in-process prediction through the safety layer (a second or two)
PLANNING_SAID_AFTER = 1.0  # s a plan takes before the log says one is being made
PREDICTION_PLANNED = 50    # as many where the arm has a body: each goal is planned first, as here (UR5 among a table
                           # and two objects: 200 took 15 s, 50 take 3)


def _multiply(a, b) -> tuple[float, float, float, float]:
    """The product a b of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + bw * ax + ay * bz - az * by, aw * by + bw * ay + az * bx - ax * bz,
            aw * bz + bw * az + ax * by - ay * bx, aw * bw - ax * bx - ay * by - az * bz)


def _unit(q) -> list[float] | None:
    """q (x, y, z, w) as a unit quaternion with w >= 0, or None when it has no length or is not finite."""
    norm = math.sqrt(sum(v * v for v in q))
    if not math.isfinite(norm) or norm < 1e-6:
        return None
    sign = -1.0 if q[3] < 0 else 1.0
    return [sign * v / norm for v in q]


def _rotate(q, v) -> list[float]:
    """v rotated by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)]


class Starting:
    """Says every `every` seconds what the node is still doing at its start, until ready() (issue 55: 5,000
    obstacles kept it silent 79 to 203 s): the stage, and ARS's iterations while it learns."""

    def __init__(self, every: float = 30.0):
        self.stage = 'reading the robot description'
        self.iterations = 0                   # ARS's, while it learns at start
        self.t0 = time.monotonic()
        self.done = threading.Event()
        threading.Thread(target=self._say, args=(every,), daemon=True, name='starting').start()

    def _say(self, every: float) -> None:
        while not self.done.wait(every):
            stage = self.stage + (f' (iteration {self.iterations})' if self.stage.startswith('ARS') else '')
            rospy.loginfo(f'reach_controller: not ready yet, {time.monotonic() - self.t0:.0f} s after its start: '
                          f'{stage}')

    def ready(self) -> None:
        self.done.set()


class ReachController:

    def __init__(self, tree, xml: str, starting: Starting):
        self.rate = number_param('~rate', 20.0, 'a positive number of steps per second', lambda v: 0 < v <= 1000)
        self.stalled_after = number_param('~stalled_after', 2.0, 'a positive number of seconds',
                                          lambda v: 0 < v <= 3600)
        self.state_timeout = number_param('~state_timeout', 0.2, 'a positive number of seconds',
                                          lambda v: 0 < v <= 3600)
        self.command_kind = str_param('~command', 'position')
        if self.command_kind not in COMMANDS:
            raise ValueError(f'~command must be one of {", ".join(COMMANDS)}, got {self.command_kind!r}')
        controller = str_param('~controller', '') or COMMANDS[self.command_kind]
        world = rospy.get_param('~obstacles', '') or None
        goal_kind = str_param('~goal', '')
        if goal_kind not in ('', *GOALS):
            raise ValueError(f'~goal must be one of {", ".join(GOALS)} (or empty: the policy\'s), got {goal_kind!r}')
        home = rospy.get_param('~home_position', None)
        if home in (None, [], {}, ''):
            home = None
        elif not isinstance(home, (list, dict)):
            raise ValueError(f'~home_position must be a list of joint positions in the arm\'s order or a dict '
                             f'{{joint: position}}, got {home!r}')
        self.policy, self.setup, info, success = self._policy(xml, str_param('~policy', ''), str_param('~tip', ''),
                                                              starting, world, goal_kind, home)
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
        starting.stage = 'reading the joint limits and building the collision model of the arm\'s body'
        self.layer = self._safety_layer(tree, xml)
        starting.stage = 'timing plans to set the lead'
        lead = measure_lead(self.layer.limits, self.layer.period, self.layer.body, self.layer.margin,
                            self.setup.home)
        self.layer.lead = lead.lead
        rospy.loginfo(f'reach_controller: {lead.note}')
        self.moving = self.setup.through(self.layer.limits, self.layer.period, self.layer.margin)   # as it moves
        starting.stage = 'predicting the policy\'s success through the safety layer'
        self._predict(self.policy)
        # the arm moves at velocity_scale of its speed: a motion takes 1 / velocity_scale as long, a stall too (a
        # pose goal from a singular home turns first, its distance growing for seconds at 0.25)
        self.stall_window = self.stalled_after / self.layer.limits.velocity_scale
        self.epoch = rospy.Time.now()             # the safety layer's times count from here (a float of seconds since
                                                  # 1970 keeps only 0.2 us: it shows in an acceleration)
        self.lock = threading.Lock()
        self.output_lock = threading.Lock()
        self.sent: Plan | None = None             # the last trajectory sent (trajectory commands)
        self.step_lock = threading.Lock()         # one control step at a time
        self.joints: dict[str, float] = {}
        self.speeds: dict[str, float] = {}
        self.measured: dict[str, float] = {}     # the time each joint's last state describes (its stamp; the
                                                  # time it came when it has none or is on another clock)
        self.stamps = StampClock()                # whether they are on this node's clock: a late state is old
        self.no_action = ''                       # why the policy gave no action for the last state it was asked
        self.enabled = bool_param('~enabled', True)
        self.going_home = False                   # ~home: the arm on its way home, no goal
        self.version = 0                          # one more at every goal and ~home: a step of an older one changes
                                                  # no state of the new one
        self.said_hold = ''                       # the last reason to hold that was said (said again when it changes)
        self.hold_kind = ''                       # and its kind (a stale state, a NaN, ...), '' when not holding
        self.announced: dict[str, float] = {}     # when each kind was said last
        self.goal: list[float] | None = None
        self.goal_since = 0.0
        self.best = float('inf')
        self.best_parts = (float('inf'), float('inf'))    # the closest's distance (m) and angle (rad)
        self.progress_mark = float('inf')         # the distance at the last progress of PROGRESS or more
        self.best_q: list[float] | None = None    # the arm's joints when it was closest to the goal
        self.improved_at = 0.0
        self.said = False
        self.holding = False                      # a goal said not reached: the arm holds at its closest
        self.homing = False                       # stalled at joint limits: going home to try again from there
        self.retried = False                      # the goal's one retry from home was made
        self.recovery = Recovery()                # the goal's limit recovery (ReachSetup.recover), as the env's,
                                                  # or the goal's planned way (RECOVERING along its points)
        self.planning: int | None = None          # with a body: the goal version a plan is being made for (the arm
                                                  # holds meanwhile), None when none is
        self.replans = 0                          # the goal's plans made again (at most MAX_REPLANS)
        self.plan_lock = threading.Lock()         # one plan at a time (the setup's planner is one)
        self.homing_since = 0.0
        self.route_home = False                   # the way home chosen (_way_home) from where the arm is
        self.route_came = 0                       # the way home is chosen again when this much of it is left
        self.blocked = ''                         # the contacts that refused the last motion ('' when it was sent)
        self.trail: list[list[float]] = []        # with a body: the configurations the arm came by, clear of contacts
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(10))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        topic = f'{controller}/command'
        if self.command_kind == 'trajectory':
            # every plan starts where the one before leaves the arm: none may be dropped (queue_size 1 dropped one
            # under load, and the controller joined the next from where the arm was: a 7x acceleration)
            self.command_pub = rospy.Publisher(topic, JointTrajectory, queue_size=100, tcp_nodelay=True)
        else:
            self.command_pub = rospy.Publisher(topic, Float64MultiArray, queue_size=1, tcp_nodelay=True)
        self.marker_pub = rospy.Publisher('~goal_marker', Marker, queue_size=1, latch=True)
        self.distance_pub = rospy.Publisher('~distance', Float64, queue_size=1)
        self.obstacles_pub = rospy.Publisher('~obstacle_markers', MarkerArray, queue_size=1, latch=True)
        self._draw_obstacles()
        # pose goals: an interactive marker to drag (position goals have rviz's Publish Point)
        self.markers = InteractiveMarkerServer(rospy.resolve_name('~pose_marker')) if self.setup.pose else None
        self.marker_placed = not self.setup.pose  # at the tip once /tf has it (at home until then)
        self._offer_marker(self.setup.goals_of(self.setup.home[:, None])[:, 0].tolist())
        self.subs = [rospy.Subscriber('joint_states', JointState, self._on_joints, queue_size=1, tcp_nodelay=True),
                     rospy.Subscriber('/clicked_point', PointStamped, self._on_goal, queue_size=1),
                     rospy.Subscriber('~goal', PointStamped, self._on_goal, queue_size=1),
                     rospy.Subscriber('~goal_pose', PoseStamped, self._on_goal_pose, queue_size=1),
                     rospy.Subscriber('~stop', Empty, self._on_stop, queue_size=1, tcp_nodelay=True)]
        self.home_blocked = self.layer.clear_of(self.setup.home)
        if self.home_blocked:
            rospy.logwarn(f'reach_controller: home {np.round(self.setup.home, 3).tolist()} is {self.home_blocked}: '
                          f'~home is refused and a stalled goal is not tried again from there')
        self.services = [rospy.Service('~home', Trigger, self._on_home),
                         rospy.Service('~load_policy', LoadPolicy, self._on_load_policy),
                         rospy.Service('~enable', SetBool, self._on_enable)]
        rospy.on_shutdown(self._on_shutdown)
        # after the training at start, which must not take the processor from the rest of the machine
        nice = int_param('~nice', NICE, 'a whole number from -20 to 19', lambda v: -20 <= v <= 19)
        priority = raise_priority(nice) if nice < 0 else f'at its own priority (~nice {nice})'
        self.timer = rospy.Timer(rospy.Duration(1.0 / self.rate), self._step)
        rospy.loginfo(f'reach_controller ready: {arm.describe()}; {self.rate:g} steps/s; {self.command_kind} commands '
                      f'on {rospy.resolve_name(topic)}, {self.layer.limits.describe()}'
                      f'{"" if self.enabled else "; disabled until ~enable"}; {self.setup.task.goal} goals: click a '
                      f'point in rviz (Publish Point), '
                      + (f'drag and release the marker {rospy.resolve_name("~pose_marker")}, ' if self.setup.pose
                         else '')      # position goals have no marker
                      + f'or publish {rospy.resolve_name("~goal")} or {rospy.resolve_name("~goal_pose")}; {priority}')
        starting.ready()

    def _safety_layer(self, tree, xml: str) -> SafetyLayer:
        """~joint_limits, ~velocity_scale, ~acceleration_scale, ~collision and ~collision_margin as a SafetyLayer."""
        scale = number_param('~velocity_scale', DEFAULT_VELOCITY_SCALE, 'a number in (0, 1]', lambda v: 0 < v <= 1)
        acceleration = number_param('~acceleration_scale', scale, 'a number in (0, 1]', lambda v: 0 < v <= 1)
        margin = number_param('~collision_margin', DEFAULT_MARGIN, 'a number of metres from 0 to 1',
                              lambda v: 0 <= v <= 1)
        try:
            limits = Limits.of(self.setup.arm, rospy.get_param('~joint_limits', '') or None, scale, acceleration)
        except ReachError as e:
            raise ValueError(f'~joint_limits: {e}') from None
        for note in limits.notes:
            rospy.loginfo(f'reach_controller: {note}')
        body = self.setup.body
        if body is None and bool_param('~collision', True):
            try:
                body = CollisionModel(tree, xml, self.setup.arm, self.setup.obstacles)
            except BodyError as e:
                rospy.logwarn(f'reach_controller: no collision check of the arm\'s body: {e}')
        if body is not None and body.beyond:
            rospy.loginfo(f'reach_controller: {body.beyond} of the obstacles lie beyond the arm\'s reach '
                          f'({body.reach():.2f} m and a metre of margin): left out of its checks')
        if body is not None and not len(body.radii):
            rospy.logwarn(f'reach_controller: {tree.name} has no collision geometry: the commands are checked '
                          f'against the limits only')
            body = None
        elif body is not None and body.stand_ins:
            rospy.logwarn(f'reach_controller: collision meshes not found ({len(body.missing)}), links stood in for '
                          f'by capsules: ' + '; '.join(f'{link}: {how}' for link, how in
                                                       list(body.stand_ins.items())[:8]))
        return SafetyLayer(limits, 1.0 / self.rate, body, margin, follows_plans=self.command_kind == 'trajectory')

    # ------------------------------------------------------------------------------------------------ the policy
    def _prediction_goals(self) -> int:
        """Goals the prediction plays: fewer where each is planned first (the planning is its cost)."""
        return PREDICTION_PLANNED if self.moving.plans_first else PREDICTION_GOALS

    def _predict(self, policy) -> None:
        """The policy's success rate through this node's safety layer (its limits, one step a control period),
        played in-process from home (a second or two), logged and set as ~predicted_success_rate."""
        setup = self.moving
        try:
            rate = learn.evaluate(policy, setup, self._prediction_goals()).success_rate
        except (policies.PolicyError, ValueError) as e:       # a model that answers no action somewhere
            rospy.logwarn(f'reach_controller: no prediction through the safety layer: {e}')
            rate = -1.0
        else:
            rospy.loginfo(f'reach_controller: through its safety layer ({self.layer.limits.describe()}) the policy '
                          f'reaches {percent(rate)} of {self._prediction_goals()} fresh goals from home within '
                          f'{setup.episode_steps * setup.control_period:g} s (predicted in-process)')
        rospy.set_param('~predicted_success_rate', float(rate))

    @staticmethod
    def _announce(info: str, success: float | None) -> None:
        rospy.set_param('~policy_info', info)
        rospy.set_param('~success_rate', float(success) if isinstance(success, (int, float)) else -1.0)
        rospy.loginfo(f'reach_controller: driving with {info}')

    @staticmethod
    def _policy(xml: str, path: str, tip: str, starting: Starting, world=None, goal: str = '', home=None):
        """(an object with act_batch(flat observations), the reach setup it acts in, a line on it, its success rate)
        of ~policy, or of an ARS run on the robot description when it is empty; world: ~obstacles; goal: ~goal
        ('' : the policy file's, or position); home: ~home_position (None: the policy file's, or mid-range);
        starting: told each stage (main makes it, and readies it however the start ends)."""
        if path:
            starting.stage = f'loading ~policy {path}'
            try:
                policy, setup, note = policy_files.load(path, urdf=xml, tip=tip or None, obstacles=world,
                                                        goal=goal or None, home=home)
            except (policies.PolicyError, ReachError) as e:
                raise ValueError(f'~policy or ~home_position: {e}') from None
            if note:
                rospy.logwarn(note)
            return policy.actor, setup, policy.describe(), policy.metadata.get('success_rate')
        pose = dict(goal='pose') if goal == 'pose' else {}
        starting.stage = 'reading the arm and ~obstacles'
        if home is not None:
            pose['home'] = home
        try:
            setup = ReachSetup(urdf=xml, tip=tip or None, obstacles=world, **pose)
        except ReachError as e:
            raise ValueError(f'~tip, ~obstacles or ~home_position: {e}') from None
        for warning in setup.arm.warnings:
            rospy.logwarn(f'reach_controller: {warning}')
        rospy.loginfo(f'reach_controller: no ~policy: ARS learns to reach with {setup.arm.describe()} (seconds; '
                      f'python -m robot_ai.reach train writes a file to give as ~policy instead)')
        t = time.monotonic()
        # a Ctrl-C during the training ends it at the next iteration (it took ARS's seconds, and under load minutes,
        # before roslaunch's escalation to SIGTERM 15 s later)
        starting.stage = 'ARS learning to reach (seconds on a quiet machine; give ~policy to skip it)'

        def stop() -> bool:            # asked once an iteration
            starting.iterations += 1
            return rospy.core.is_shutdown_requested()
        kwargs = dict(urdf=xml, tip=setup.arm.tip, **pose)
        if world is not None:
            kwargs['obstacles'] = world
        training = learn.train(kwargs, seed=0, should_stop=stop, evaluate_episodes=1000)
        if rospy.core.is_shutdown_requested():
            raise rospy.ROSInterruptException('reach_controller: shut down during its training')
        rate = training.held_out.success_rate
        within = f'{setup.task.distance_threshold:g} m' + (f' and {setup.task.angle_threshold:g} rad' if pose else '')
        info = (f'ARS trained at start on {setup.model.tree.name}: {percent(rate)} of 1000 fresh {setup.task.goal} '
                f'goals within {within}, {time.monotonic() - t:.1f} s, {training.result.steps:,} steps')
        return training.policy, training.setup, info, rate

    # ------------------------------------------------------------------------------------------------ callbacks
    def _on_joints(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position):
            rospy.logwarn_throttle(5.0, 'joint_states without as many names as positions skipped')
            return
        now = self._now()
        stamp, note = self.stamps.time_of(None if msg.header.stamp.is_zero() else
                                          (msg.header.stamp - self.epoch).to_sec(), now)
        if note:
            rospy.logwarn(note)
        with self.lock:
            self.joints.update(zip(msg.name, msg.position))
            self.measured.update(dict.fromkeys(msg.name, stamp))
            if len(msg.velocity) == len(msg.name):
                self.speeds.update(zip(msg.name, msg.velocity))

    def _in_base(self, point: PointStamped) -> list[float] | None:
        p = self._to_base(point.header.frame_id, point.point)
        return None if p is None else p[0]

    def _to_base(self, frame: str, position) -> tuple[list[float], tuple] | None:
        """(position in the base frame, the rotation (x, y, z, w) from frame to the base) of a geometry_msgs Point in
        frame, by one tf lookup; None (said) when tf has no transform."""
        frame = frame.lstrip('/') or self.base
        p = [position.x, position.y, position.z]
        if frame == self.base:
            return p, (0.0, 0.0, 0.0, 1.0)
        try:
            t = self.tf_buffer.lookup_transform(self.base, frame, rospy.Time(0), rospy.Duration(1.0)).transform
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as e:
            rospy.logwarn(f'goal in {frame} ignored: no transform from {frame} to {self.base} ({e})')
            return None
        q = (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        r = _rotate(q, p)
        return [r[0] + t.translation.x, r[1] + t.translation.y, r[2] + t.translation.z], q

    def _on_goal(self, point: PointStamped) -> None:
        """A point: the goal's position; for pose goals the tip keeps the orientation it has."""
        goal = self._in_base(point)
        if goal is None:
            return
        if self.setup.pose:
            goal = goal + self._orientation_now()
        self._set_goal(goal)

    def _on_goal_pose(self, msg: PoseStamped) -> None:
        self._on_pose(msg.header.frame_id, msg.pose)

    def _on_pose(self, frame: str, pose) -> None:
        """A pose (~goal_pose, the released marker; any frame tf knows): the goal; for position goals its position
        only."""
        goal = self._pose_in_base(frame, pose)
        if goal is not None:
            self._set_goal(goal if self.setup.pose else goal[:3])

    def _pose_in_base(self, frame: str, pose) -> list[float] | None:
        """A geometry_msgs/Pose in frame as [x, y, z, qx, qy, qz, qw] in the base frame (unit, qw >= 0), or None
        (said) when the frame is unknown or the quaternion has no length."""
        o = pose.orientation
        q = _unit((o.x, o.y, o.z, o.w))
        if q is None:
            rospy.logwarn(f'goal pose ignored: its orientation ({o.x:g}, {o.y:g}, {o.z:g}, {o.w:g}) is not a '
                          f'quaternion (0, 0, 0, 1 is its frame\'s own orientation)')
            return None
        placed = self._to_base(frame, pose.position)
        if placed is None:
            return None
        p, r = placed
        return p + _unit(_multiply(r, q))

    def _orientation_now(self) -> list[float]:
        """The tip's orientation now (from /tf), or at home when /tf has none yet."""
        tip = self._tip()
        if tip is not None:
            return tip[3:]
        return self.setup.goals_of(self.setup.home[:, None])[3:, 0].tolist()

    def _set_goal(self, goal: list[float]) -> None:
        if not all(math.isfinite(v) for v in goal) or not all(abs(v) <= MAX_GOAL for v in goal[:3]):
            shown = ', '.join(f'{v:.4g}' for v in goal)
            rospy.logwarn(f'goal ({shown}) in {self.base} ignored: each coordinate must be a finite number of metres, '
                          f'at most {MAX_GOAL:g} from the base')
            return
        inside = self.setup.obstacle_holding(goal)
        if inside is not None:
            rospy.logwarn(f'goal ({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) in {self.base} ignored: it is inside '
                          f'{inside}')
            return
        with self.lock:
            self.goal, self.goal_since, self.best, self.said = goal, time.monotonic(), float('inf'), False
            self.blocked = ''
            self.best_q, self.holding, self.homing, self.retried = None, False, False, False
            self.recovery = Recovery()
            self.improved_at = self.goal_since
            self.going_home = False
            self.version += 1
            self.replans = 0
            version = self.version
        self._draw(goal)
        self.marker_placed = True
        self._offer_marker(goal)
        rospy.loginfo(f'goal {self._shown(goal)} in {self.base}')
        self._start_planning(goal, version)
        if hasattr(self, 'timer'):
            self._step(None)              # the first command at once, not at the next tick

    @staticmethod
    def _shown(goal: list[float]) -> str:
        text = f'({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) m'
        if len(goal) == 7:
            text += f', orientation ({goal[3]:+.3f}, {goal[4]:+.3f}, {goal[5]:+.3f}, {goal[6]:+.3f})'
        return text

    def _draw(self, goal: list[float] | None) -> None:
        """The goal as a sphere of the threshold's size; a pose goal also as an arrow along its x axis."""
        marker = Marker(type=Marker.SPHERE, ns='reach_goal', id=0,
                        action=Marker.ADD if goal is not None else Marker.DELETE)
        marker.header.frame_id = self.base
        marker.header.stamp = rospy.Time.now()
        arrow = Marker(type=Marker.ARROW, ns='reach_goal', id=1,
                       action=Marker.ADD if goal is not None and len(goal) == 7 else Marker.DELETE)
        arrow.header = marker.header
        if goal is not None:
            marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = goal[:3]
            marker.pose.orientation.w = 1.0
            size = 2 * self.setup.task.distance_threshold
            marker.scale.x = marker.scale.y = marker.scale.z = size
            marker.color.r, marker.color.g, marker.color.b, marker.color.a = 0.1, 0.9, 0.1, 0.6
            if len(goal) == 7:
                arrow.pose.position = marker.pose.position
                o = arrow.pose.orientation
                o.x, o.y, o.z, o.w = goal[3:]
                arrow.scale.x, arrow.scale.y, arrow.scale.z = 3 * size, 0.2 * size, 0.2 * size
                arrow.color.r, arrow.color.g, arrow.color.b, arrow.color.a = 0.9, 0.2, 0.1, 0.9
        publish(self.marker_pub, marker)
        publish(self.marker_pub, arrow)

    def _offer_marker(self, goal: list[float]) -> None:
        """The interactive marker (~pose_marker, pose goals only) at goal (at start: where the tip is): arrows and
        rings to drag; released, it is the next goal."""
        if self.markers is None or len(goal) != 7:
            return
        marker = InteractiveMarker(name='goal', description='pose goal: drag, then release')
        marker.header.frame_id = self.base
        marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = goal[:3]
        o = marker.pose.orientation
        o.x, o.y, o.z, o.w = goal[3:]
        marker.scale = max(0.15, 4 * self.setup.task.distance_threshold)
        for axis, (x, y, z) in (('x', (1, 0, 0)), ('y', (0, 1, 0)), ('z', (0, 0, 1))):
            for kind, mode in (('move', InteractiveMarkerControl.MOVE_AXIS),
                               ('rotate', InteractiveMarkerControl.ROTATE_AXIS)):
                control = InteractiveMarkerControl(name=f'{kind}_{axis}', interaction_mode=mode)
                # a control's axis is the x axis of its orientation: the interactive_markers tutorial's (1, 0, 0, 1)
                # for x, (0, 0, 1, 1) for y, (0, 1, 0, 1) for z
                q = _unit((x, z, y, 1.0))
                control.orientation.x, control.orientation.y, control.orientation.z, control.orientation.w = q
                marker.controls.append(control)
        # every feedback comes to _on_marker (the server's default callback): with only MOUSE_UP's given, each
        # POSE_UPDATE of a drag in rviz raised inside interactive_markers (its default callback None)
        self.markers.insert(marker, self._on_marker)
        self.markers.applyChanges()

    def _place_marker(self) -> None:
        """The marker to where the tip stands (a real arm starts anywhere), once /tf has the tip."""
        if not self.tf_buffer.can_transform(self.base, self.tip, rospy.Time(0)):
            return
        tip = self._tip()
        if tip is not None:
            self.marker_placed = True
            self._offer_marker(tip)

    def _on_marker(self, feedback) -> None:
        """The marker's feedback: released (MOUSE_UP), its pose is the goal; dragged, clicked or pressed, nothing
        (the arm does not chase the marker; the server moves it)."""
        if feedback.event_type == InteractiveMarkerFeedback.MOUSE_UP:
            self._on_pose(feedback.header.frame_id, feedback.pose)

    def _on_load_policy(self, req) -> LoadPolicyResponse:
        """Another policy, loaded and its prediction made between two control steps: no command goes out meanwhile,
        and the arm comes to rest along the stop its last command ends in. Loading and predicting take the processor
        for seconds, and a command made meanwhile would reach the controller late (one came 734 ms after its start
        under load, spliced in with a jolt)."""
        with self.step_lock:
            try:
                policy, _, note = policy_files.load(req.path, self.setup)
            except (policies.PolicyError, ReachError) as e:
                return LoadPolicyResponse(success=False, message=f'{e}; still driving with the policy it had')
            with self.lock:
                self.policy = policy.actor
                self._restart_stall_clock()       # the time it took is no stall
            self._announce(policy.describe(), policy.metadata.get('success_rate'))
        # answered now, the prediction made after (between two control steps: seconds, a minute in a large world,
        # the arm resting meanwhile): the caller waited 44 s for it, with no word of what went on
        threading.Thread(target=self._predict_between_steps, args=(policy.actor,), daemon=True).start()
        return LoadPolicyResponse(success=True, message=f'driving with {policy.describe()}' + (f' ({note})' if note
                                  else '') + f'; predicting its success through the safety layer over '
                                  f'{self._prediction_goals()} goals now (the arm rests until then; the log and '
                                  f'~predicted_success_rate say it)')

    def _predict_between_steps(self, policy) -> None:
        with self.step_lock:
            rospy.loginfo(f'reach_controller: predicting the new policy\'s success through the safety layer over '
                          f'{self._prediction_goals()} goals; the arm rests until then')
            self._predict(policy)
            with self.lock:
                self._restart_stall_clock()       # the time it took is no stall

    def _on_home(self, req) -> TriggerResponse:
        if self.home_blocked:      # the layer would refuse its every last step, the arm short of it for good
            return TriggerResponse(success=False, message=f'home {np.round(self.setup.home, 3).tolist()} is '
                                   f'{self.home_blocked}: the safety layer does not take the arm there; nothing sent')
        with self.lock:
            self.goal, self.going_home = None, True
            self.version += 1
        self._draw(None)
        return TriggerResponse(success=True, message=f'going home: {np.round(self.setup.home, 3).tolist()}')

    def _on_enable(self, req) -> SetBoolResponse:
        with self.lock:
            was, self.enabled = self.enabled, bool(req.data)
            self.improved_at = time.monotonic()          # the stall clock starts again
        if req.data:
            rospy.loginfo('enabled: commands go out again' if not was else 'enabled already')
            return SetBoolResponse(success=True, message='enabled' + (' already' if was else ''))
        rospy.logwarn('disabled (~enable false): the arm stops within its limits and holds')
        return SetBoolResponse(success=True, message='disabled: the arm stops and holds')

    def _on_stop(self, msg) -> None:
        with self.lock:
            was, self.enabled = self.enabled, False
        if was:
            rospy.logwarn('stop (~stop): the arm stops within its limits and holds until ~enable true')

    def _on_shutdown(self) -> None:
        """Ctrl-C: the arm stops where its plan's stop ends and holds there (a trajectory stops by itself)."""
        with self.lock:
            last = self.layer.last
            joints = dict(self.joints)
        if last is None or last.end <= self._now():
            return
        try:
            self._plan_and_send(None, None, None, joints, why_not='shut down', final=True)
        except Exception:             # the node is going: nothing more to do
            pass

    # ------------------------------------------------------------------------------------------------ the output
    def _now(self) -> float:
        """Seconds of ROS time since the node started."""
        return (rospy.Time.now() - self.epoch).to_sec()

    def _plan_and_send(self, target, measured, velocity, joints: dict, why_not: str = '',
                       final: bool = False, measured_at: float | None = None) -> Plan:
        """The safety layer's plan, sent: every plan made is sent (the next one starts where it leaves the arm),
        one at a time (the control step, a hold, the shutdown). The plan starts two periods from now, now taken
        here, after the policy's and the tf's time, so that the command reaches the arm before its start.
        measured: the arm's state at measured_at (None, a hold: the plans sent go on)."""
        with self.output_lock:
            now = self._now()
            plan = self.layer.plan(now, target, measured, velocity, why_not=why_not, measured_at=measured_at,
                                   clock=self._now)
            self._send(plan, joints, final)
            return plan

    def _send(self, plan: Plan, joints: dict, final: bool = False) -> None:
        """The plan as the controller's command: a trajectory of its points (the other ~command_joints held), or the
        position it commands one step on (final: where it comes to rest)."""
        if self.command_kind == 'trajectory':
            times, positions, velocities = plan.points(self.layer.period)
            if plan.held and self._on_controller(plan.start + times, positions, velocities):
                return        # the stop of the trajectory the controller has: sending it again changes nothing,
                              # and late it would be one more splice to count
            msg = JointTrajectory(joint_names=list(self.command_joints))
            msg.header.stamp = self.epoch + rospy.Duration.from_sec(plan.start)
            fixed = [joints.get(n, 0.0) for n in self.command_joints]
            for t, p, v in zip(times, positions, velocities):
                point = JointTrajectoryPoint(positions=list(fixed), velocities=[0.0] * len(fixed),
                                             time_from_start=rospy.Duration.from_sec(float(t)))
                for k, slot in enumerate(self.slot):
                    point.positions[slot], point.velocities[slot] = float(p[k]), float(v[k])
                msg.points.append(point)
            publish(self.command_pub, msg)
            self.sent = plan
            return
        at = plan.rest() if final else plan.state_at(plan.start)[0]
        positions = [joints.get(n, 0.0) for n in self.command_joints]
        for k, value in zip(self.slot, at):
            positions[k] = float(value)
        publish(self.command_pub, Float64MultiArray(data=positions))

    def _on_controller(self, times, positions, velocities) -> bool:
        """Whether the last trajectory sent goes through these points (positions and velocities at these times)."""
        if self.sent is None:
            return False
        for t, p, v in zip(times, positions, velocities):
            q, w = self.sent.state_at(float(t))
            if np.abs(q - p).max() > 1e-9 or np.abs(w - v).max() > 1e-9:
                return False
        return True

    def _draw_obstacles(self) -> None:
        publish(self.obstacles_pub, obstacle_markers(self.setup.obstacles, self.base))

    def _tip(self) -> list[float] | None:
        """The tip from /tf in the base frame: its position, and for pose goals its orientation after it (unit,
        w >= 0)."""
        try:
            transform = self.tf_buffer.lookup_transform(self.base, self.tip, rospy.Time(0)).transform
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as e:
            rospy.logwarn_throttle(5.0, f'no transform {self.base} -> {self.tip} yet ({e}): is forward_kinematics '
                                        f'(or robot_state_publisher) running?')
            return None
        t, r = transform.translation, transform.rotation
        if not self.setup.pose:
            return [t.x, t.y, t.z]
        q = _unit((r.x, r.y, r.z, r.w))
        return None if q is None else [t.x, t.y, t.z] + q

    def _step(self, event) -> None:
        """One control step (the timer's, or at once for a new goal); whatever goes wrong in it, the arm stops and
        the loop goes on."""
        try:
            with self.step_lock:
                self._control()
        except Exception as e:          # noqa: BLE001 (the loop must survive anything)
            rospy.logerr_throttle(5.0, f'the control step failed ({type(e).__name__}: {e}): the arm stops and '
                                       f'holds')
            try:
                self._hold(self._now(), 'the control step failed', dict(self.joints))
            except Exception:          # noqa: BLE001
                pass

    def _hold(self, now: float, why: str, joints: dict, kind: str = '') -> None:
        """The arm stops (the last plan's stop goes on) and holds, said once per kind of reason (kind, or why);
        nothing is sent once it is at rest (so that another controller may take it over)."""
        kind = kind or why
        if kind != self.hold_kind:               # a hold begins: said, unless this kind was said within 5 s
            said = time.monotonic() - self.announced.get(kind, -math.inf) > 5.0
            self.said_hold, self.hold_kind = (why if said else ''), kind
            if said:
                self.announced[kind] = time.monotonic()
                rospy.logwarn(f'holding: {why}')
        else:
            rospy.logwarn_throttle(5.0, f'holding: {why}')
        self.improved_at = time.monotonic()          # no stall while held from outside
        if self.layer.resting(now):
            return                                   # at rest: nothing more to send
        self._plan_and_send(None, None, None, joints, why_not=why)

    def _control(self) -> None:
        now = self._now()
        with self.lock:
            goal, joints, speeds, policy = self.goal, dict(self.joints), dict(self.speeds), self.policy
            holding, homing, enabled, going_home = self.holding, self.homing, self.enabled, self.going_home
            measured_at, version = dict(self.measured), self.version
            recovery, planning = self.recovery, self.planning == self.version
        arm = self.setup.arm
        if not self.marker_placed and goal is None:
            self._place_marker()
        if goal is None and not going_home and self.layer.resting(now):
            return                                   # idle, at rest
        if not all(n in joints for n in self.command_joints):      # the arm's, and the others the command holds
            missing = ', '.join(n for n in self.command_joints if n not in joints)
            rospy.logwarn_throttle(5.0, f'joint_states does not report {missing} (of ~command_joints) yet: nothing is '
                                        f'sent until it does (a joint not reported would be commanded blind)')
            return
        measured = [float(joints[n]) for n in arm.joints]
        age = now - min(measured_at[n] for n in arm.joints)     # from its stamp: a state delivered late is old
        if not all(math.isfinite(v) for v in measured):
            bad = ', '.join(n for n, v in zip(arm.joints, measured) if not math.isfinite(v))
            return self._hold(now, f'joint_states gives {bad} a NaN or infinite position', joints, kind='nan')
        if age > self.state_timeout:
            return self._hold(now, f'joint_states is {age:.2f} s old (more than ~state_timeout '
                                   f'{self.state_timeout:g} s)', joints, kind='stale')
        if not enabled:
            return self._hold(now, 'disabled (~enable true to go on)', joints)
        if self.said_hold:
            rospy.loginfo(f'going on: {self.said_hold} no more')
        self.said_hold = self.hold_kind = ''
        q = [min(max(v, lo), hi) for v, lo, hi in zip(measured, arm._lower, arm._upper)]
        velocity = [speeds.get(n, 0.0) for n in arm.joints]
        if going_home:
            target = self.setup.home.tolist()
            last = self.layer.last                # home, and at rest there: the plans arrive at it exactly
            if max(abs(a - b) for a, b in zip(q, target)) < HOME_REACHED and last is not None \
                    and not last.velocities.any():
                with self.lock:
                    self.going_home = False
        elif goal is None:
            target = None                  # a stop that is not over: it goes on
        else:
            tip = self._tip()
            if tip is None:
                return self._hold(now, f'no transform {self.base} -> {self.tip}', joints)
            publish(self.distance_pub, Float64(goal_distance_one(tip, goal)))
            if holding:
                target = self.best_q
            elif homing:
                target = self._home_target(goal, q)
            elif planning:
                target = None              # the plan is being made: the arm comes to rest along its last command
            else:
                target = self._policy_target(policy, q, tip, goal, recovery, version)
                if target is None:       # a verdict at once, said once: the arm holds where it is (no flapping log)
                    with self.lock:
                        if version == self.version and not self.said:
                            self.said, self.holding, self.best_q = True, True, q
                            rospy.loginfo(f'not reached: the policy answered no action for this goal '
                                          f'({self.no_action}); holding where the arm is')
                    return self._hold(now, 'the policy gave no action', joints)
        plan = self._plan_and_send(target, measured, velocity, joints,
                                   measured_at=min(measured_at[n] for n in arm.joints))
        if self.layer.resynced:
            rospy.logwarn_throttle(5.0, self.layer.resynced)
            with self.lock:              # held until now: the policy's stall clock starts from where the arm stands
                if version == self.version:
                    self._restart_stall_clock()
        blocked = ''
        if plan.held and target is not None:
            blocked = ', '.join(plan.contacts) or plan.held
            rospy.logwarn_throttle(2.0, f'holding: {plan.held}, so the motion was not sent')
            replan = False
            # held on its way, or the policy's arm short of the goal: planned again (the env's rule: replanning)
            stuck = bool(plan.contacts) and goal is not None and not homing and not holding and self.moving.replanning(
                [recovery.state == RECOVERING], np.array(self.setup.place_one(q)[0])[:, None],
                np.array(goal)[:, None])[0]
            with self.lock:           # a step a collision refuses, as in the env: a way round it was on is given up,
                if version == self.version:   # and it is a step without progress (the recovery goes round);
                    replan = bool(stuck and self.replans < MAX_REPLANS)
                    self.replans += replan
                    self.recovery = (self.recovery.give_up() if plan.contacts    # a step held for any other
                                     else dataclasses.replace(self.recovery, since=0))   # reason is no step
            if replan:                # held: a plan from where the arm stands, MAX_REPLANS times a goal at most
                rospy.loginfo(f'held by a collision ({blocked}) short of the goal: planning again from here')
                self._start_planning(goal, version)
        elif self.layer.body is not None and goal is not None and not homing and not holding and (
                not self.trail or max(abs(a - b) for a, b in zip(q, self.trail[-1])) > TRAIL_STEP):
            self.trail.append(q)          # where the arm is: clear of contacts, the way back home
            del self.trail[:-MAX_TRAIL]
        with self.lock:
            if version == self.version:
                self.blocked = blocked if plan.contacts else ''
        if goal is not None and not homing and not holding:
            # judged on the joints' own tip (the kinematics of q), not /tf's: the two can be a message apart under
            # load, and the configuration held after `not reached` must be the one whose distance was said
            self._judge(goal, self.setup.place_one(q)[0], q)

    def _policy_target(self, policy, q: list[float], tip: list[float], goal: list[float], recovery: Recovery,
                       version: int) -> list[float] | None:
        """The joints the policy's action asks for from q (the env's move and limit recovery: recovery is the
        goal's state, of goal version `version`), or None when it gives no action."""
        observation = self.setup.observation_one(q, tip, goal)
        try:
            action = policy.act_batch(ars.flatten_batch(self.setup.observation_space,
                                                        {k: v[None] for k, v in observation.items()}))[0]
            a = self.setup.check_action_one(np.asarray(action, dtype=np.float64))
        except (policies.PolicyError, ValueError) as e:      # a model that answers no action here (NaN): none
            self.no_action = str(e)
            return None
        own_tip, jac = self.setup.place_one(q)
        moved = self.moving.move_one(q, jac, a)       # through the layer: each joint's share weighted by its speed
        target, after = self.moving.recover_one(q, own_tip, moved, a, goal, recovery)   # its stall: the layer's steps
        with self.lock:
            if version != self.version:
                return target
            self.recovery = after
            if after.state == RECOVERING:    # on purpose away from the goal: no stall, the clock starts after it
                self._restart_stall_clock()
        if after.state == RECOVERING and recovery.state == READY:
            stuck = ', '.join(self.setup.arm.at_limits(moved))
            if stuck:
                why = (f'the goal lies beyond a joint limit the way the arm stands ({stuck} at '
                       f'{"its limit" if "," not in stuck else "their limits"})')
            else:
                error = self.setup.task.error(np.array(own_tip), np.array(goal))
                with self.lock:
                    blocked = self.blocked
                where = f'held by a collision ({blocked})' if blocked else 'with no joint at a limit (a local minimum)'
                why = (f'no progress for {self.moving.stall_steps * self.layer.period:.2f} s, {error:.3f} m from the '
                       f'goal, {where}')
            rospy.loginfo(f'{why}: going round in joint space, to a configuration that reaches it'
                          + (' clear of contacts' if self.moving.body is not None else ''))
        return target

    def _judge(self, goal: list[float], achieved: list[float], q: list[float]) -> None:
        """Says reached or not reached once per goal; after not reached, the arm holds at its closest configuration
        (at the edge of its workspace a policy would otherwise jitter); at joint limits or a collision, home first
        and once more from there. Pose goals: the distance judged is the task's dense error, the distance plus the
        angle x distance_threshold / angle_threshold."""
        now = time.monotonic()
        task = self.setup.task
        distance = goal_distance_one(achieved, goal)
        angle = float(goal_angle(np.array(achieved), np.array(goal))) if self.setup.pose else 0.0
        error = distance + angle * (task.distance_threshold / task.angle_threshold)
        with self.lock:
            if goal is not self.goal or self.said:
                return
            if self.best_q is None or error < self.progress_mark - PROGRESS:
                self.progress_mark, self.improved_at = error, now    # progress: the stall clock starts again
            if self.best_q is None or error < self.best:     # the closest configuration, however small the gain
                self.best, self.best_q, self.best_parts = error, q, (distance, angle)
            reached = distance < task.distance_threshold and angle < task.angle_threshold
            stalled = now - self.improved_at > self.stall_window
            if not (reached or stalled):
                return
            kind, why = why_unreached(self.setup.arm, goal[:3], q, distance) if not reached else ('', '')
            if not reached and distance < task.distance_threshold:
                stuck = self.setup.arm.at_limits(q)
                at = f', with {", ".join(stuck)} at {"its limit" if len(stuck) == 1 else "their limits"}'
                kind, why = 'turn', (f'at the goal\'s position, turned {angle:.3f} rad from its orientation (more than '
                                     f'{task.angle_threshold:g} rad){at if stuck else ""}')
            if not reached and self.blocked and kind != 'beyond':
                kind, why = 'collision', f'blocked {distance:.3f} m away by a collision ({self.blocked})'
            if not reached and kind != 'beyond' and not self.retried and not self.home_blocked:
                # stalled within reach: home, once more (unless home is where the layer cannot take the arm)
                self.homing, self.retried, self.homing_since, self.route_home = True, True, now, False
                rospy.loginfo(f'{why}: going home to try again from there')
                return
            self.said = True
            self.holding = not reached
            since, best, (best_distance, best_angle) = self.goal_since, self.best, self.best_parts
        where = f'({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f})'
        turned = f', {angle:.3f} rad' if self.setup.pose else ''
        if reached:
            rospy.loginfo(f'reached {where} in {now - since:.2f} s ({distance:.3f} m{turned})')
            return
        closest = f'{best:.3f} m'
        if self.setup.pose:          # a distance and an angle, each in its unit (the error weighing both is no metre)
            closest = f'{best_distance:.3f} m and {best_angle:.3f} rad'
        rospy.loginfo(f'not reached: closest {closest} to {where}: {why}; holding at the closest')

    def _restart_stall_clock(self) -> None:
        """The goal's stall clock starts afresh, from no progress mark, and so does the recovery's count of steps
        without progress (under self.lock)."""
        self.improved_at, self.progress_mark = time.monotonic(), float('inf')
        if self.recovery.since:
            self.recovery = dataclasses.replace(self.recovery, since=0)

    def _start_planning(self, goal: list[float], version: int, q: list[float] | None = None) -> None:
        """With a body: the goal (of goal version `version`) planned in a thread of its own from q (None: where the
        arm comes to rest), the arm holding meanwhile (_plan_goal)."""
        if self.moving.body is None:
            return
        with self.lock:
            if version != self.version:
                return
            self.planning = version
        threading.Thread(target=self._plan_goal, args=(goal, version, q), daemon=True, name='planning').start()
        timer = threading.Timer(PLANNING_SAID_AFTER, self._say_planning, args=(version,))
        timer.daemon = True
        timer.start()

    def _say_planning(self, version: int) -> None:
        """A plan that takes a while is said while it is made: the arm holds meanwhile, and a held arm with nothing
        said looks stuck."""
        with self.lock:
            still = self.planning == version and self.version == version
        if still:
            rospy.loginfo(f'planning a way round the arm\'s body and the world (the arm holds meanwhile, '
                          f'{PLAN_BUDGET} motion checks at most)')

    def _plan_goal(self, goal: list[float], version: int, q: list[float] | None) -> None:
        """A planned way to the goal (ReachSetup.planned_way through the layer: OMPL's RRT-Connect over the arm's
        body and the world, the layer's margin and a centimetre more kept, its points a control period's travel
        apart; the straight way in joint space where that is clear). The arm follows it, each step through the
        safety layer (checked as every command is), and the policy has it at its end for the rest of the way to the
        goal (a local controller, as MoveIt users pair a planner with one); with no way, the policy drives and the
        reason is said."""
        began = time.monotonic()
        way = PlannedWay(None, '', 'a newer goal came first')
        try:
            with self.plan_lock:
                if q is None:
                    q = self._planning_start()
                with self.lock:
                    current = version == self.version
                if current and q is not None:
                    way = self.moving.planned_way(np.asarray(goal, dtype=float), np.asarray(q, dtype=float),
                                                  PLAN_BUDGET)
                elif current:
                    way = PlannedWay(None, '', 'joint_states does not report every joint of the arm yet')
        except Exception as e:        # noqa: BLE001 (a plan that fails leaves the policy to drive)
            way = PlannedWay(None, '', f'the planner failed ({type(e).__name__}: {e})')
        finally:
            with self.lock:
                current = version == self.version
                if current:
                    self.planning = None
                    if way.found:
                        self.recovery = Recovery.along(way.points)
                    self._restart_stall_clock()       # the time it took is no stall
        if not current:
            return
        took = f'{1000 * (time.monotonic() - began):.0f} ms'
        if not way.found:
            rospy.loginfo(f'no plan ({way.reason}, {took}): the policy drives')
        else:
            how = 'straight in joint space' if way.how == 'straight' else f'round the contacts, {way.how}'
            rospy.loginfo(f'planned in {took} ({how}, {len(way.points)} steps): the arm follows it through the safety '
                          f'layer, then the policy')

    def _planning_start(self) -> list[float] | None:
        """Where a plan starts: where the arm comes to rest along the last command (it holds while the plan is
        made), or where joint_states has it at rest; None while a joint of the arm is not reported."""
        last = self.layer.last
        if last is not None and not self.layer.resting(self._now()):
            return last.rest().tolist()
        with self.lock:
            joints = dict(self.joints)
        arm = self.setup.arm
        if not all(n in joints for n in arm.joints):
            return None
        return [min(max(float(joints[n]), lo), hi) for n, lo, hi in zip(arm.joints, arm._lower, arm._upper)]

    def _home_target(self, goal: list[float], q: list[float]) -> list[float] | None:
        """On the way home for a retry: home (with a body, along _way_home: straight where that is clear of
        contacts, else back the way the arm came first) until every joint is there (or the stall window has passed
        twice without getting there); then q, and the policy drives again from there, its stall clock started
        afresh."""
        home = self.setup.home.tolist()
        there = max(abs(a - b) for a, b in zip(q, home)) < AT_HOME
        with self.lock:
            trail = None if self.route_home else list(self.trail)
        if trail is not None:           # the way home, shortened where a straight way is clear: at the start of
            way, came = self._way_home(q, trail)      # a retry, and again where it is back on the way it came
            with self.lock:      # chosen again once past the straight part and REROUTE more of the way on
                self.route_home, self.trail, self.route_came = True, way, min(came, len(way) - REROUTE)
        with self.lock:
            done = there or time.monotonic() - self.homing_since > 2 * self.stall_window + 30.0
            if done:
                self.homing = False
                self._restart_stall_clock()
                self.recovery = Recovery()            # the retry's own way, planned from here
                if there:
                    self.trail = [home]
            version = self.version
        if done:
            self._start_planning(goal, version, q)
            return q
        with self.lock:
            while self.trail and max(abs(a - b) for a, b in zip(q, self.trail[-1])) < 2 * TRAIL_STEP:
                self.trail.pop()          # passed: the next one back
            if 0 < len(self.trail) <= self.route_came:
                self.route_home = False   # back on the way it came: a straighter way from here, next step
            return self.trail[-1] if self.trail else home

    def _way_home(self, q: list[float], trail: list[list[float]]) -> tuple[list[list[float]], int]:
        """(the way home of a retry as a trail to follow back (oldest first, the last one next), how much of it is
        the way the arm came). The trail runs from where the arm was last at home (or its oldest kept) to q; the way
        is the shortest of: straight home in joint space, or straight to a configuration of the trail (two dozen
        tried, spread evenly) and back along the trail from there, counting steps of TRAIL_STEP, among those whose
        straight part is clear of contacts (the layer's margin kept); all of the trail when none is. A straight part
        is given as configurations TRAIL_STEP apart, as the arm's own trail is, so that the arm keeps to the line
        checked. Retracing all the way it came took 45 s at velocity_scale 0.25 after a way round, in silence: the
        trail holds every goal's way since the arm was last at home."""
        body = self.layer.body
        if body is None or not trail:
            return trail, len(trail)
        here = np.array(q)
        padding = self.layer.padding(here)
        best = None
        for k in dict.fromkeys([-1, *np.linspace(0, len(trail) - 1, min(len(trail), 24)).astype(int).tolist()]):
            end = self.setup.home if k < 0 else np.array(trail[k])
            steps = max(1, math.ceil(np.abs(end - here).max() / TRAIL_STEP))
            cost = steps + (k + 1 if k >= 0 else 0)
            if best is not None and cost >= best[0]:
                continue
            n = min(400, max(2, math.ceil(np.abs(end - here).max() / SAMPLE_STEP) + 1))
            line = here + np.linspace(0.0, 1.0, n)[:, None] * (end - here)
            if not body.in_collision(line, padding).any():
                best = cost, k, end, steps
        if best is None:
            return trail, len(trail)
        _, k, end, steps = best
        back = end + np.linspace(0.0, 1.0, steps + 1)[:-1, None] * (here - end)      # end first, q not
        return trail[:k + 1] + back.tolist(), k + 1


@quiet_on_shutdown
def main():
    init_node('reach_controller')
    tree, key = wait_for_tree()
    if tree is None:
        return
    starting = Starting()
    try:
        ReachController(tree, rospy.get_param(key), starting)
    except ValueError as e:
        rospy.logfatal(f'reach_controller: bad parameter: {e}')
        raise SystemExit(1)
    finally:
        starting.ready()
    rospy.spin()
