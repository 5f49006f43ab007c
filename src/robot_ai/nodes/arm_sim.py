"""arm_sim: any robot_description as a kinematic arm that takes ros_control's position or trajectory commands.

Each joint of ~joints moves toward its commanded position at most at its URDF velocity limit (DEFAULT_VELOCITY
where the URDF gives none), ~rate times per second of ROS time times ~real_time_factor, and joint_states is
published after every tick; forward_kinematics turns them into /tf as on a real robot. In ~lockstep an env
(robot_ai.envs: RosReach-v0) drives it: one step per command, the command clipped to the limits and reached at once,
joint_states published then (latched). A command is ros_control's: std_msgs/Float64MultiArray, one position per
joint of ~joints, in that order, so that reach_controller drives a real arm's JointGroupPositionController the same
way. It takes joint_trajectory_controller's command too (trajectory_msgs/JointTrajectory, the topic a real arm's
driver exposes: ur_robot_driver, franka_ros) and follows it as that controller does (robot_ai.reach.trajectory: from
the trajectory's start, through its points, cubic where they give velocities; joints it does not name hold), each
joint still at most at its URDF velocity limit; trajectories run on ROS time. Unlike that controller, it joins a
trajectory that comes after its start (a busy machine) as a real arm's drives allow: further on, where the joining
curve keeps within the share of the velocity and acceleration limits (the URDF's, ~joint_limits') that the
trajectory itself uses, not at once with a jolt (robot_ai.reach.trajectory.ArmBounds). Each joint_states message is
stamped with the time it describes. NaN, infinite values or a wrong length: the command is ignored with a throttled
warning, the arm holds.

With ~physics mujoco the arm has mass, gravity and effort limits (robot_ai.physics: a MuJoCo model built from
robot_description, its inertias from the URDF or estimated, its real meshes where ROS_PACKAGE_PATH has them): the
command, or the trajectory's position, is each joint's servo target, moving at most at the joint's velocity limit
as the kinematic sim moves the joint; the servos track it within the URDF's effort limits, joint_states carries
their efforts, and the arm meets ~obstacles and pushes ~objects. In ~lockstep each command is one tick of physics.
The objects' poses go on /tf after every tick (each object's frame, its name with _ for what a frame cannot hold,
a child of the robot's root), drawn by ~object_markers in those frames. The gripper (the hand's actuated finger
joints) takes ros_control's gripper_action_controller goal (robot_ai/GripperCommand: control_msgs' fields and
md5sums): its servos toward the position at the joints' velocity limits with at most the effort asked for, the goal
succeeded when the gripper is there or stalled on what it grips (reached_goal, stalled), over the sim's ticks (in
~lockstep, over the following commands); from the first goal on, the arm's commands no longer move those joints.

With ~task push or pick_and_place the world is that manipulation task's (robot_ai.physics.env.ManipulationSetup of
~task and ~task_args: its table and its cube, named object, the arm at the task's ready configuration), built as
robot_ai/Push-v0 builds it; with ~lockstep and ~rate 25 (the task's 0.04 s step) the envs over ROS
(robot_ai.envs.ros_manipulation: robot_ai/RosPush-v0, robot_ai/RosPickAndPlace-v0) drive it and equal the envs over
MuJoCo. The objects' poses and velocities go on ~object_states after every tick, stamped as the joint_states of that
tick; ~set_object_pose puts one at rest.

An env takes the sim's ~lease: while it holds it, commands and ~set_state from any other node are ignored or refused
(robot_ai.nodes.lease).

ROS Parameters
    robot_description (str): the robot, searched up the namespaces and waited for.
    ~joints (list of str, [] = the robot's active joints): the joints the sim moves and publishes, in command order.
    ~home (list of float or dict name -> float, [] or {} = the middle of each joint's range): where the arm starts.
    ~rate (float, 100): ticks per second of ROS time (free-running).
    ~real_time_factor (float, 1.0): simulated seconds per second of ROS time.
    ~lockstep (bool, false): true = one step per command, reached at once (no clock, no velocity limit).
    ~joint_limits (str, ""): a MoveIt joint_limits.yaml (reach_controller's): its acceleration limits are the arm's
        (a joint without one: full speed in 0.25 s), within which a late trajectory is joined.
    ~physics (str, ""): "" (kinematic: each joint goes where it is commanded) or mujoco (physics: see above).
    ~obstacles (str, ""): with ~physics mujoco, a world of boxes and spheres (a YAML file or text, as
        reach_controller's ~obstacles), static, in the robot's root frame.
    ~objects (str, ""): with ~physics mujoco, loose objects (the same file's objects key: boxes, spheres and
        cylinders with a mass and a friction) the arm can push.
    ~task (str, ""): with ~physics mujoco, push or pick_and_place: the world is that task's (see above); "" = the
        world of ~obstacles and ~objects.
    ~task_args (dict, {}): with ~task, ManipulationSetup's arguments (tip, object_size, object_mass, obj_range,
        goal_range, step_time, ...), as the env is made with them.
    ~nice (int, -10): the scheduling priority the sim asks for, as a real arm's controller runs real-time (root or
        CAP_SYS_NICE; otherwise it runs as started, and says so); 0 leaves it (robot_ai.priority).

ROS Subscribers
    joint_group_position_controller/command (std_msgs/Float64MultiArray): target positions, in ~joints order.
    joint_trajectory_controller/command (trajectory_msgs/JointTrajectory): a trajectory of named joints.

ROS Publishers
    joint_states (sensor_msgs/JointState): names ~joints, positions, velocities (and efforts with ~physics),
        stamped with the time they describe.
    tf (tf2_msgs/TFMessage): with ~physics, the objects' poses in the robot's root frame, after every tick.
    ~object_markers (visualization_msgs/MarkerArray, latched): with ~physics, the objects, each in its frame.
    ~object_states (robot_ai/ObjectStates): with ~physics, the objects' poses and velocities (linear and angular) in
        the robot's root frame, after every tick, stamped as that tick's joint_states (latched in ~lockstep).

ROS Actions
    gripper_controller/gripper_cmd (robot_ai/GripperCommand): with ~physics and a gripper, the gripper's command.

ROS Services
    ~set_state (robot_ai/SetJointPositions): the arm at these positions at once (the command too), published then;
        refused unless one finite number per joint within its limits.
    ~lease (robot_ai/Lease): an env takes the sim (or gives it back).
    ~set_object_pose (robot_ai/SetObjectPose): with ~physics, an object at a pose in the root frame, at rest; the
        state published then; refused for an unknown object or a pose that is not one.

Parameters it sets
    ~joints: the joints it moves, in command order.
    ~world_digest (str): with ~physics, sha256 of the MuJoCo model's binary form (an env over ROS checks it is its
        world).
"""
from __future__ import annotations

import threading
import warnings

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

from robot_ai.lease import Lease, caller_of
from robot_ai.nodes.params import (bool_param, init_node, int_param, number_param, numpy_service, publish,
                                   quiet_on_shutdown)
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.priority import NICE, raise_priority
from robot_ai.reach.arm import ReachError, joint_limits, joint_velocity
from robot_ai.reach.safety import DEFAULT_ACCELERATION_TIME, acceleration_limits, joint_names, read_joint_limits
from robot_ai.reach.trajectory import ArmBounds, Follower, TrajectoryError
from robot_ai.srv import Lease as LeaseService
from robot_ai.srv import SetJointPositions, SetJointPositionsResponse, SetObjectPose, SetObjectPoseResponse
from robot_ai.tf_wire import JointStateEncoder, WireError, decode_float64_array, raw_message_class

COMMAND_TOPIC = 'joint_group_position_controller/command'
TRAJECTORY_TOPIC = 'joint_trajectory_controller/command'
MAX_POINTS = 100_000          # points in one trajectory at most
RawJointState = raw_message_class(JointState)         # written and read at wire level, as forward_kinematics does
RawCommand = raw_message_class(Float64MultiArray)


class ArmSim:

    def __init__(self, tree, xml: str = ''):
        self.joints = self._joints_param(tree)
        limits = [joint_limits(tree.joints[n]) for n in self.joints]
        self.lower = np.array([lo for lo, _, _ in limits])
        self.upper = np.array([hi for _, hi, _ in limits])
        self.velocity = np.array([joint_velocity(tree.joints[n]) for n in self.joints])
        self.bounds, self.notes = self._bounds(tree)
        self.rate = number_param('~rate', 100.0, 'a positive number of ticks per second', lambda v: 0 < v <= 10000)
        self.real_time_factor = number_param('~real_time_factor', 1.0, 'a positive number', lambda v: 0 < v <= 1000)
        self.lockstep = bool_param('~lockstep', False)
        self.nice = int_param('~nice', NICE, 'a whole number from -20 to 19', lambda v: -20 <= v <= 19)
        self.positions = self._home_param(tree)
        self.command = self.positions.copy()
        self.speeds = np.zeros(len(self.joints))
        self.lock = threading.Lock()
        self.arm, self.world = self._physics(xml, tree)   # an ArmPhysics and its PhysicsWorld with ~physics mujoco
        self.efforts = self.arm.efforts if self.arm is not None else None
        self.target = self.positions.copy()       # with physics: the servos' target, moving within the velocities
        self.follower: Follower | None = None     # a trajectory being followed
        self.ticked = None                        # ROS time of the last tick
        self.epoch = rospy.Time.now()             # trajectories' times count from here (a float of seconds since
                                                  # 1970 keeps only 0.2 us, which shows in a velocity's difference)
        self.lease = Lease(rospy.get_name())
        rospy.set_param('~joints', list(self.joints))
        self.encoder = JointStateEncoder(self.joints)
        self.published = 0                    # joint_states published: each one's header.seq
        with warnings.catch_warnings():   # lockstep: published in the command's thread (queue_size None), no hand-off
            warnings.simplefilter('ignore')
            self.state_pub = rospy.Publisher('joint_states', RawJointState, queue_size=None if self.lockstep else 10,
                                             tcp_nodelay=True, latch=self.lockstep)
        self.command_sub = rospy.Subscriber(COMMAND_TOPIC, RawCommand, self._on_command, queue_size=10,
                                            tcp_nodelay=True)
        self.trajectory_sub = rospy.Subscriber(TRAJECTORY_TOPIC, JointTrajectory, self._on_trajectory,
                                               queue_size=100, tcp_nodelay=True)   # none dropped, late ones said
        self.services = [rospy.Service('~set_state', numpy_service(SetJointPositions), self._on_set_state),
                         rospy.Service('~lease', LeaseService, self.lease.handle)]
        if self.arm is not None:
            self.services.append(rospy.Service('~set_object_pose', SetObjectPose, self._on_set_object))
        priority = raise_priority(self.nice) if self.nice < 0 else f'at its own priority (~nice {self.nice})'
        mode = ('lockstep: one step per command, reached at once' if self.lockstep else
                f'{self.rate * self.real_time_factor:g} ticks per second of ROS time, at the URDF velocity limits')
        if self.arm is not None:
            mode += (f'; physics: MuJoCo, {self.world.describe()}' +
                     (' (lockstep: a tick of physics per command)' if self.lockstep else ''))
        for note in self.notes:
            rospy.loginfo(f'arm_sim: {note}')
        rospy.loginfo(f'arm_sim ready: {len(self.joints)} joints ({", ".join(self.joints)}), {mode}; commands on '
                      f'{rospy.resolve_name(COMMAND_TOPIC)} and {rospy.resolve_name(TRAJECTORY_TOPIC)}; {priority}')

    # --------------------------------------------------------------------------------------------- parameters
    @staticmethod
    def _joints_param(tree) -> list[str]:
        value = rospy.get_param('~joints', None)
        if value is None or value == []:
            return list(tree.active_joints)
        if not isinstance(value, list) or not value or not all(isinstance(n, str) for n in value):
            raise ValueError(f'~joints must be a list of joint names, got {value!r}')
        bad = [n for n in value if n not in tree.joints or not tree.joints[n].moving
               or tree.joints[n].mimic is not None]
        if bad:
            raise ValueError(f'~joints: {", ".join(bad)} are not moving joints of {tree.name} that follow no other '
                             f'(its active joints: {", ".join(tree.active_joints)})')
        if len(set(value)) != len(value):
            raise ValueError(f'~joints names a joint twice: {value}')
        return value

    def _physics(self, xml: str, tree):
        """~physics' ArmPhysics at home and its PhysicsWorld ((None, None) without physics); ValueError of one line
        for what cannot be built."""
        kind = rospy.get_param('~physics', '') or ''
        if kind not in ('', 'mujoco'):
            raise ValueError(f'~physics must be "" (kinematic) or mujoco, got {kind!r}')
        task = rospy.get_param('~task', '') or ''
        if task not in ('', 'push', 'pick_and_place'):
            raise ValueError(f'~task must be "", push or pick_and_place, got {task!r}')
        if not kind:
            if task:
                raise ValueError(f'~task {task} is a world of physics: give ~physics mujoco too')
            return None, None
        from robot_ai.nodes.arm_physics import PhysicsWorld
        from robot_ai.physics import PhysicsError, build_physics, parse_objects
        from robot_ai.physics.model import model_digest
        from robot_ai.physics.sim import ArmPhysics
        from robot_ai.reach.model import load_model
        try:
            if task:
                physics, objects = self._task_world(task, xml)
            else:
                objects = parse_objects(rospy.get_param('~objects', '') or ())
                physics = build_physics(load_model(urdf=xml), obstacles=rospy.get_param('~obstacles', '') or (),
                                        objects=objects, home=dict(zip(self.joints, self.positions.tolist())))
            arm = ArmPhysics(physics, self.joints)
            world = PhysicsWorld(arm, objects, tree.root, tree.links, self.lock, self.lockstep)
        except (PhysicsError, ReachError, ValueError, TypeError) as e:
            raise ValueError(f'~physics mujoco: {e}') from None
        for note in physics.notes:
            rospy.loginfo(f'arm_sim: physics: {note}')
        if task:                                  # it starts where the task's episodes do
            self.positions, self.command = arm.positions, arm.positions
        rospy.set_param('~world_digest', model_digest(physics.model))
        return arm, world

    def _task_world(self, task: str, xml: str):
        """(physics, objects) of the manipulation task's world (robot_ai.physics.env.ManipulationSetup of task and
        ~task_args on this robot: the table, the cube, the ready configuration), as Push-v0 or PickAndPlace-v0 build
        it."""
        from robot_ai.physics import parse_objects
        from robot_ai.physics.env import OBJECT, ManipulationSetup
        args = rospy.get_param('~task_args', {}) or {}
        if not isinstance(args, dict):
            raise ValueError(f'~task_args must be a dict of ManipulationSetup\'s arguments, got {args!r}')
        if rospy.get_param('~obstacles', '') or rospy.get_param('~objects', ''):
            raise ValueError('~task builds the task\'s world (its table and cube): leave ~obstacles and ~objects '
                             'empty')
        setup = ManipulationSetup(task, urdf=xml, **args)
        missing = [n for n in (*setup.arm.joints, *setup.gripper) if n not in self.joints]
        if missing:
            raise ValueError(f'~task {task}: the sim must move the arm\'s and the gripper\'s joints; ~joints lacks '
                             f'{", ".join(missing)}')
        return setup.physics, parse_objects([setup.cube(setup.space.centre, OBJECT)])

    def _bounds(self, tree) -> tuple[ArmBounds, tuple[str, ...]]:
        """What the arm can do: the URDF's positions and velocities, ~joint_limits' accelerations."""
        try:
            given, notes = joint_names(read_joint_limits(rospy.get_param('~joint_limits', '') or None),
                                       list(tree.joints))
        except ReachError as e:
            raise ValueError(f'~joint_limits: {e}') from None
        acceleration, missing = acceleration_limits(given, self.joints, self.velocity)
        if missing:
            notes += (f'accelerations: full speed in {DEFAULT_ACCELERATION_TIME:g} s for {len(missing)} of '
                      f'{len(self.joints)} joints (no ~joint_limits entry)',)
        return ArmBounds(self.lower, self.upper, self.velocity, acceleration), notes

    def _home_param(self, tree) -> np.ndarray:
        home = (self.lower + self.upper) / 2.0
        value = rospy.get_param('~home', None)
        if value is None or value == [] or value == {}:
            return home
        if isinstance(value, dict):
            unknown = sorted(set(value) - set(self.joints))
            if unknown:
                raise ValueError(f'~home names joints the sim does not move: {", ".join(unknown)}')
            for name, v in value.items():
                home[self.joints.index(name)] = float(v)
        else:
            values = np.asarray(value, dtype=float).reshape(-1)
            if values.shape != home.shape:
                raise ValueError(f'~home must be {len(home)} positions (one per joint of ~joints), got {values.size}')
            home = values
        if not (np.isfinite(home).all() and (home >= self.lower).all() and (home <= self.upper).all()):
            raise ValueError(f'~home must be finite and within the joint limits, got {home.tolist()}')
        return home

    # ------------------------------------------------------------------------------------------------ stepping
    def _publish(self, stamp: rospy.Time | None = None) -> None:
        stamp = rospy.Time.now() if stamp is None else stamp
        self.published += 1
        publish(self.state_pub, RawJointState(self.encoder.encode(self.published, stamp.secs, stamp.nsecs,
                                                                  self.positions, self.speeds, self.efforts)))
        if self.world is not None:
            self.world.ticked(stamp)

    def _tick(self, dt: float) -> None:
        """One tick of dt simulated seconds: each joint toward its command at most its velocity limit; along the
        trajectory it follows, at the tick's ROS time."""
        now = rospy.Time.now()
        t, last = (now - self.epoch).to_sec(), self.ticked
        self.ticked = t
        if self.arm is not None:
            self._tick_physics(t, dt)
            self._publish(now)
            return
        if self.follower is not None:
            p, v = self._followed(t)
            elapsed = t - last if last is not None and t > last else dt
            step = np.clip(p - self.positions, -self.velocity * elapsed, self.velocity * elapsed)
            exact = np.array_equal(step, p - self.positions)
            self.positions = self.positions + step
            self.speeds = v if exact else step / elapsed
            self._publish(now)
            return
        step = np.clip(self.command - self.positions, -self.velocity * dt, self.velocity * dt)
        self.positions = self.positions + step
        self.speeds = step / dt
        self._publish(now)

    def _followed(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(positions within the limits, velocities) along the trajectory followed, at t; at its end the command is
        its last point and it is followed no more."""
        p, v = self.follower.state_at(t)
        if t >= self.follower.end:
            self.command, self.follower = self.follower.final, None
        return np.minimum(np.maximum(p, self.lower), self.upper), v

    def _tick_physics(self, t: float, dt: float) -> None:
        """One tick with physics: the servos' target toward the command (or the trajectory's position at t) at most
        at the velocity limits, dt seconds of MuJoCo toward it; the state is the physics'."""
        wanted = self._followed(t)[0] if self.follower is not None else self.command
        self.target = self.target + np.clip(wanted - self.target, -self.velocity * dt, self.velocity * dt)
        self._physics_step(self.target, dt)

    def _physics_step(self, target: np.ndarray, dt: float) -> None:
        """dt seconds of physics toward target; the sim's state (positions, velocities, efforts) is the physics'."""
        self.arm.step(target, dt)
        self.positions, self.speeds, self.efforts = self.arm.positions, self.arm.velocities, self.arm.efforts

    def _physics_at(self, positions: np.ndarray) -> None:
        """The physics' arm at positions at once, at rest, its servos holding there."""
        self.arm.set_state(positions)
        self.target, self.efforts = positions.copy(), self.arm.efforts

    def run(self) -> None:
        with self.lock:
            self._publish()
        if self.lockstep:
            rospy.spin()
            return
        period = rospy.Duration(1.0 / (self.rate * self.real_time_factor))
        dt = 1.0 / self.rate
        while not rospy.is_shutdown():
            try:
                rospy.sleep(period)
            except rospy.ROSTimeMovedBackwardsException:
                continue
            except rospy.ROSInterruptException:
                break
            with self.lock:
                self._tick(dt)

    # ----------------------------------------------------------------------------------------------- callbacks
    def _check(self, values, what: str) -> np.ndarray | str:
        """values as positions of the sim's joints, or why not (a count first: a message may hold millions)."""
        if len(values) != len(self.joints):
            return f'{what} of {len(values)} positions ignored: the sim moves {len(self.joints)} joints ' \
                   f'({", ".join(self.joints)})'
        array = np.array(values, dtype=float)     # a copy: a numpy request is a read-only view of its bytes
        if not np.isfinite(array).all():
            return f'{what} {array.tolist()} ignored: positions must be finite numbers'
        return array

    def _on_command(self, msg) -> None:
        caller = caller_of(msg)
        if not self.lease.allows(caller):
            rospy.logwarn_throttle(5.0, f'command from {caller} ignored: {self.lease.refusal(caller)}')
            return
        try:
            data = decode_float64_array(msg.buff)
        except WireError as e:
            rospy.logwarn_throttle(5.0, f'command ignored: {e}')
            return
        command = self._check(data, 'command')
        if isinstance(command, str):
            rospy.logwarn_throttle(5.0, command)
            return
        command = np.minimum(np.maximum(command, self.lower), self.upper)
        with self.lock:
            self.command, self.follower = command, None
            if self.lockstep and self.arm is not None:     # one tick of physics toward it
                self.target = command
                self._physics_step(command, 1.0 / self.rate)
                self._publish()
            elif self.lockstep:
                self.speeds = np.zeros(len(self.joints))
                self.positions = command
                self._publish()

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        caller = caller_of(msg)
        if not self.lease.allows(caller):
            rospy.logwarn_throttle(5.0, f'trajectory from {caller} ignored: {self.lease.refusal(caller)}')
            return
        try:
            columns, times, positions, velocities = self._trajectory(msg)
            with self.lock:
                follower = self.follower if self.follower is not None else Follower(self.positions, self.bounds)
                now = (rospy.Time.now() - self.epoch).to_sec()
                start = (msg.header.stamp - self.epoch).to_sec() if not msg.header.stamp.is_zero() else now
                full = np.tile(follower.state_at(max(now, start))[0], (len(times), 1))
                full[:, columns] = positions
                full_v = None
                if velocities is not None:
                    full_v = np.zeros_like(full)
                    full_v[:, columns] = velocities
                full = np.minimum(np.maximum(full, self.lower), self.upper)
                if self.lockstep:
                    self.positions, self.command = full[-1].copy(), full[-1].copy()
                    self.speeds = np.zeros(len(self.joints))
                    if self.arm is not None:
                        self._physics_at(self.positions)
                    self._publish()
                    return
                follower.take(now, start, times, full, full_v)
                self.follower = follower
                if start < now - 1e-3:
                    rospy.logwarn_throttle(1.0, f'a trajectory came {1000 * (now - start):.0f} ms after its start: '
                                                f'joined from where the arm is {1000 * (follower.joined - now):.0f} '
                                                f'ms on, {follower.joined_how}')
        except TrajectoryError as e:
            rospy.logwarn_throttle(5.0, f'trajectory ignored: {e}')

    def _trajectory(self, msg: JointTrajectory):
        """(the columns of the sim's joints it names, times, positions, velocities or None) of a trajectory, or
        TrajectoryError."""
        names = list(msg.joint_names)
        unknown = [n for n in names if n not in self.joints]
        if unknown or len(set(names)) != len(names) or not names:
            raise TrajectoryError(f'joint_names must name joints of the sim once each ({", ".join(self.joints)}), '
                                  f'got {names}')
        points = msg.points
        if not 0 < len(points) <= MAX_POINTS:
            raise TrajectoryError(f'{len(points)} points: from 1 to {MAX_POINTS} are followed')
        if any(len(p.positions) != len(names) for p in points):
            raise TrajectoryError(f'every point needs one position per joint named ({len(names)})')
        given = [len(p.velocities) for p in points]
        if any(g not in (0, len(names)) for g in given) or len(set(given)) > 1:
            raise TrajectoryError('velocities must be given for every joint at every point, or at none')
        times = np.array([p.time_from_start.to_sec() for p in points])
        positions = np.array([p.positions for p in points], dtype=float)
        velocities = np.array([p.velocities for p in points], dtype=float) if given[0] else None
        return [self.joints.index(n) for n in names], times, positions, velocities

    def _on_set_object(self, req) -> SetObjectPoseResponse:
        from robot_ai.physics.model import PhysicsError
        caller = caller_of(req)
        if not self.lease.allows(caller):
            return SetObjectPoseResponse(success=False, message=self.lease.refusal(caller))
        p, q = req.pose.position, req.pose.orientation
        with self.lock:
            try:
                self.arm.set_object(req.name, [p.x, p.y, p.z], [q.w, q.x, q.y, q.z])
            except PhysicsError as e:
                return SetObjectPoseResponse(success=False, message=str(e))
            self._publish()
        return SetObjectPoseResponse(success=True, message=f'{req.name} at rest at ({p.x:g}, {p.y:g}, {p.z:g})')

    def _on_set_state(self, req) -> SetJointPositionsResponse:
        caller = caller_of(req)
        if not self.lease.allows(caller):
            return SetJointPositionsResponse(success=False, message=self.lease.refusal(caller))
        positions = self._check(req.positions, 'set_state')
        if isinstance(positions, str):
            return SetJointPositionsResponse(success=False, message=positions)
        outside = [f'{n} {v:g} not in [{lo:g}, {hi:g}]' for n, v, lo, hi in
                   zip(self.joints, positions, self.lower, self.upper) if not lo <= v <= hi]
        if outside:
            return SetJointPositionsResponse(success=False, message='outside the joint limits: ' + '; '.join(outside))
        with self.lock:
            self.positions, self.command, self.follower = positions.copy(), positions.copy(), None
            self.speeds = np.zeros(len(self.joints))
            if self.arm is not None:                  # at rest there, the servos holding it
                self._physics_at(positions)
            self._publish()
        return SetJointPositionsResponse(success=True, message=f'the arm at {positions.tolist()}')


@quiet_on_shutdown
def main():
    init_node('arm_sim')
    tree, key = wait_for_tree()
    if tree is None:
        return
    if not tree.active_joints:
        rospy.logfatal(f'arm_sim: {tree.name} has no moving joint: nothing to simulate')
        raise SystemExit(1)
    try:
        sim = ArmSim(tree, rospy.get_param(key))
    except ValueError as e:
        rospy.logfatal(f'arm_sim: bad parameter: {e}')
        raise SystemExit(1)
    sim.run()
