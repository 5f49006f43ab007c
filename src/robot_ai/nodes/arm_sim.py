"""arm_sim: any robot_description as a kinematic arm that takes ros_control's JointGroupPositionController command.

Each joint of ~joints moves toward its commanded position at most at its URDF velocity limit (DEFAULT_VELOCITY
where the URDF gives none), ~rate times per second of ROS time times ~real_time_factor, and joint_states is
published after every tick; forward_kinematics turns them into /tf as on a real robot. In ~lockstep an env
(robot_ai.envs: RosReach-v0) drives it: one step per command, the command clipped to the limits and reached at once,
joint_states published then (latched). A command is ros_control's: std_msgs/Float64MultiArray, one position per
joint of ~joints, in that order, so that reach_controller drives a real arm's JointGroupPositionController the same
way. NaN, infinite values or a wrong length: the command is ignored with a throttled warning, the arm holds.

An env takes the sim's ~lease: while it holds it, commands and ~set_state from any other node are ignored or refused
(robot_ai.nodes.lease).

ROS Parameters
    robot_description (str): the robot, searched up the namespaces and waited for.
    ~joints (list of str, [] = the robot's active joints): the joints the sim moves and publishes, in command order.
    ~home (list of float or dict name -> float, [] or {} = the middle of each joint's range): where the arm starts.
    ~rate (float, 100): ticks per second of ROS time (free-running).
    ~real_time_factor (float, 1.0): simulated seconds per second of ROS time.
    ~lockstep (bool, false): true = one step per command, reached at once (no clock, no velocity limit).

ROS Subscribers
    joint_group_position_controller/command (std_msgs/Float64MultiArray): target positions, in ~joints order.

ROS Publishers
    joint_states (sensor_msgs/JointState): names ~joints, positions, velocities (of the last tick).

ROS Services
    ~set_state (robot_ai/SetJointPositions): the arm at these positions at once (the command too), published then;
        refused unless one finite number per joint within its limits.
    ~lease (robot_ai/Lease): an env takes the sim (or gives it back).
"""
from __future__ import annotations

import threading
import warnings

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from robot_ai.lease import Lease, caller_of
from robot_ai.nodes.params import bool_param, init_node, number_param, numpy_service, publish, quiet_on_shutdown
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.reach.arm import joint_limits, joint_velocity
from robot_ai.srv import Lease as LeaseService
from robot_ai.srv import SetJointPositions, SetJointPositionsResponse
from robot_ai.tf_wire import JointStateEncoder, WireError, decode_float64_array, raw_message_class

COMMAND_TOPIC = 'joint_group_position_controller/command'
RawJointState = raw_message_class(JointState)         # written and read at wire level, as forward_kinematics does
RawCommand = raw_message_class(Float64MultiArray)


class ArmSim:

    def __init__(self, tree):
        self.joints = self._joints_param(tree)
        limits = [joint_limits(tree.joints[n]) for n in self.joints]
        self.lower = np.array([lo for lo, _, _ in limits])
        self.upper = np.array([hi for _, hi, _ in limits])
        self.velocity = np.array([joint_velocity(tree.joints[n]) for n in self.joints])
        self.rate = number_param('~rate', 100.0, 'a positive number of ticks per second', lambda v: 0 < v <= 10000)
        self.real_time_factor = number_param('~real_time_factor', 1.0, 'a positive number', lambda v: 0 < v <= 1000)
        self.lockstep = bool_param('~lockstep', False)
        self.positions = self._home_param(tree)
        self.command = self.positions.copy()
        self.speeds = np.zeros(len(self.joints))
        self.lock = threading.Lock()
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
        self.services = [rospy.Service('~set_state', numpy_service(SetJointPositions), self._on_set_state),
                         rospy.Service('~lease', LeaseService, self.lease.handle)]
        mode = ('lockstep: one step per command, reached at once' if self.lockstep else
                f'{self.rate * self.real_time_factor:g} ticks per second of ROS time, at the URDF velocity limits')
        rospy.loginfo(f'arm_sim ready: {len(self.joints)} joints ({", ".join(self.joints)}), {mode}; commands on '
                      f'{rospy.resolve_name(COMMAND_TOPIC)}')

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
    def _publish(self) -> None:
        stamp = rospy.Time.now()
        self.published += 1
        publish(self.state_pub, RawJointState(self.encoder.encode(self.published, stamp.secs, stamp.nsecs,
                                                                  self.positions, self.speeds)))

    def _tick(self, dt: float) -> None:
        """One tick of dt simulated seconds: each joint toward its command at most its velocity limit."""
        step = np.clip(self.command - self.positions, -self.velocity * dt, self.velocity * dt)
        self.positions = self.positions + step
        self.speeds = step / dt
        self._publish()

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
            self.command = command
            if self.lockstep:
                self.speeds = np.zeros(len(self.joints))
                self.positions = command
                self._publish()

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
            self.positions, self.command = positions.copy(), positions.copy()
            self.speeds = np.zeros(len(self.joints))
            self._publish()
        return SetJointPositionsResponse(success=True, message=f'the arm at {positions.tolist()}')


@quiet_on_shutdown
def main():
    init_node('arm_sim')
    tree, _ = wait_for_tree()
    if tree is None:
        return
    if not tree.active_joints:
        rospy.logfatal(f'arm_sim: {tree.name} has no moving joint: nothing to simulate')
        raise SystemExit(1)
    try:
        sim = ArmSim(tree)
    except ValueError as e:
        rospy.logfatal(f'arm_sim: bad parameter: {e}')
        raise SystemExit(1)
    sim.run()
