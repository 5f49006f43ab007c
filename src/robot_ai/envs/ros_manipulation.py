"""Push-v0 and PickAndPlace-v0 through a robot namespace of the ROS graph: robot_ai/RosPush-v0 and
robot_ai/RosPickAndPlace-v0 (RosManipulationEnv).

The env meets the arm as a ROS controller does: it publishes ros_control's JointGroupPositionController command
(``<ns>/joint_group_position_controller/command``: every joint of the sim's ``~joints``, the gripper's among them),
reads ``<ns>/joint_states`` and the objects' poses and velocities on ``<ns>/arm_sim/object_states``, and resets
through ``<ns>/arm_sim/set_object_pose`` and ``<ns>/arm_sim/set_state``. The sim must be an arm_sim with physics in
lockstep whose world is this env's (``~task``: the task's table, cube and ready configuration; its
``~world_digest`` is checked against the env's own model) and whose tick is the task's step (``~rate`` 25 for
0.04 s): ``roslaunch robot_ai manipulation_gym.launch``. It computes each command as Push-v0 moves its arm (the same
damped least squares from the joints the arm reported, the same gripper ramp) and observes with the same
expressions (the tip's pose from MuJoCo's kinematics of those joints, the cube's from the sim's message), so that
with the same seed and actions every observation, reward and success equals robot_ai/Push-v0's (or
PickAndPlace-v0's) bit for bit. (An arm with a continuous joint: arm_sim holds its commands within [-pi, pi], MuJoCo
does not; the envs part there.)

No master, no sim, a sim in another world or not in lockstep, a sim that dies: RosManipulationError naming the
namespace within ``timeout``; after a failure every call raises until the next reset().

    env = gymnasium.make('robot_ai/RosPush-v0', robot_ns='/arm_0')     # with manipulation_gym.launch running
    envs = gymnasium.make_vec('robot_ai/RosPickAndPlace-v0', num_envs=2, vectorization_mode='async')
"""
from __future__ import annotations

import threading
import time
import warnings

import gymnasium
import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from robot_ai.envs.link import DEFAULT_TIMEOUT, RosEnvError, ensure_node, new_token, release, resolve, take
from robot_ai.envs.ros_reach import description_of
from robot_ai.msg import ObjectStates
from robot_ai.physics.env import OBJECT, ManipulationSetup
from robot_ai.physics.model import model_digest
from robot_ai.srv import SetJointPositions, SetObjectPose
from robot_ai.tf_wire import JointStateDecoder, WireError, encode_float64_array, header_of, raw_message_class

SIM_NODE = 'arm_sim'
LAUNCH_HINT = 'roslaunch robot_ai manipulation_gym.launch sims:=N model:=... task_args:=...'
COMMAND_TOPIC = 'joint_group_position_controller/command'
KEEP_STAMPS = 16              # object states kept while the matching joint_states is awaited
RawJointState = raw_message_class(JointState)
RawCommand = raw_message_class(Float64MultiArray)


class RosManipulationError(RosEnvError):
    """The ROS side of RosManipulationEnv failed: no master, no arm_sim, one another env holds, one in another world
    or not in lockstep, or one that stopped answering."""


class WorldLink:
    """One arm_sim with the task's world as an env holds it: its lease, the command publisher, the joint_states and
    object_states subscribers, the set_object_pose and set_state services, connected once."""

    def __init__(self, robot_ns: str, timeout: float, setup: ManipulationSetup):
        self.timeout, self.setup = float(timeout), setup
        try:
            ensure_node(self.timeout)
        except RosEnvError as e:
            raise RosManipulationError(str(e)) from None
        self.digest = model_digest(setup.physics.model)
        self.token, self.ns, self.leased = new_token(), robot_ns or '', False
        self.changed = threading.Condition()
        self.decoder = JointStateDecoder()
        self.last_seq = -1                # the sim's joint_states received, counted here from 0
        self.seq = -1                     # the last one this env has taken
        self.last_state = None            # (stamp, bytes) of the last joint_states
        self.objects: dict[tuple, ObjectStates] = {}     # stamp -> the object states of that tick
        self.parts, self.services = [], []
        try:
            self._connect()
        except RosEnvError as e:
            self.close()
            raise RosManipulationError(str(e)) from None
        except BaseException:
            self.close()
            raise

    def _fail(self, what: str) -> RosManipulationError:
        return RosManipulationError(f'{self.ns}: {what}')

    def _unusable(self, ns: str) -> str:
        """Why the arm_sim in ns cannot serve this env ('' if it can)."""
        node = resolve(ns, SIM_NODE)
        if rospy.get_param(f'{node}/lockstep', False) is not True:
            return (f'is not in lockstep ({node}/lockstep is not true): an env needs one step per action '
                    f'({LAUNCH_HINT})')
        digest = rospy.get_param(f'{node}/world_digest', '')
        if digest != self.digest:
            task, args = rospy.get_param(f'{node}/task', ''), rospy.get_param(f'{node}/task_args', {})
            return (f'has another world than this env\'s ({"no ~task" if not task else f"~task {task}, ~task_args "}'
                    f'{args if task else ""}): give the env the sim\'s robot, task_args and meshes (the same '
                    f'ROS_PACKAGE_PATH), or start the sim with this env\'s ({LAUNCH_HINT})')
        rate = rospy.get_param(f'{node}/rate', 100.0)
        steps = max(1, int(round(1.0 / float(rate) / self.setup.physics.model.opt.timestep)))
        if steps != self.setup.substeps:
            return (f'ticks {1.0 / float(rate):g} s of physics ({node}/rate {rate}), this env steps '
                    f'{self.setup.step_time:g} s: give it ~rate {1.0 / self.setup.step_time:g}')
        return ''

    def _connect(self) -> None:
        self.ns = take(self.ns, SIM_NODE, self.token, self.timeout, LAUNCH_HINT, self._unusable, said='the arm_sim ')
        self.leased = True
        self.sim_node = resolve(self.ns, SIM_NODE)
        self.sim_joints = rospy.get_param(f'{self.sim_node}/joints', None) or []
        wanted = [*self.setup.arm.joints, *self.setup.gripper]
        missing = [n for n in wanted if n not in self.sim_joints]
        if missing:
            raise self._fail(f'the arm_sim does not move {", ".join(missing)} (its ~joints: {self.sim_joints})')
        self.arm_index = [self.sim_joints.index(n) for n in self.setup.arm.joints]
        self.grip_index = [self.sim_joints.index(n) for n in self.setup.gripper]
        self.state_topic = resolve(self.ns, 'joint_states')
        self.objects_topic = f'{self.sim_node}/object_states'
        with warnings.catch_warnings():   # queue_size None: published in the caller's thread, the shortest way
            warnings.simplefilter('ignore')
            self.command_pub = rospy.Publisher(resolve(self.ns, COMMAND_TOPIC), RawCommand, queue_size=None,
                                               tcp_nodelay=True)
        self.parts = [self.command_pub,
                      rospy.Subscriber(self.state_topic, RawJointState, self._on_state, tcp_nodelay=True),
                      rospy.Subscriber(self.objects_topic, ObjectStates, self._on_objects, tcp_nodelay=True,
                                       queue_size=100)]
        self.set_object = rospy.ServiceProxy(f'{self.sim_node}/set_object_pose', SetObjectPose, persistent=True)
        self.set_state = rospy.ServiceProxy(f'{self.sim_node}/set_state', SetJointPositions, persistent=True)
        self.services = [self.set_object, self.set_state]
        deadline = time.monotonic() + self.timeout
        with self.changed:
            while not (self.command_pub.get_num_connections() > 0 and self.last_seq >= 0 and self.objects):
                left = deadline - time.monotonic()
                if left <= 0 or rospy.is_shutdown():
                    raise self._fail(f'the arm_sim did not connect within {self.timeout:g} s (commands on '
                                     f'{self.command_pub.resolved_name}, states on {self.state_topic} and '
                                     f'{self.objects_topic})')
                self.changed.wait(min(left, 0.05))
        self.seq = self.last_seq

    # ------------------------------------------------------------------------------------------------ callbacks
    def _from_sim(self, msg, topic: str) -> bool:
        sender = getattr(msg, '_connection_header', {}).get('callerid', '')
        if sender != self.sim_node:
            rospy.logwarn_throttle(5.0, f'{topic} from {sender} ignored: only {self.sim_node} answers this env')
        return sender == self.sim_node

    def _on_state(self, msg) -> None:
        if not self._from_sim(msg, self.state_topic):
            return
        try:
            _, secs, nsecs = header_of(msg.buff)
        except WireError:
            return
        with self.changed:
            self.last_seq += 1
            self.last_state = ((secs, nsecs), msg.buff)
            self.changed.notify_all()

    def _on_objects(self, msg: ObjectStates) -> None:
        if not self._from_sim(msg, self.objects_topic):
            return
        with self.changed:
            self.objects[(msg.header.stamp.secs, msg.header.stamp.nsecs)] = msg
            while len(self.objects) > KEEP_STAMPS:
                del self.objects[next(iter(self.objects))]
            self.changed.notify_all()

    # ------------------------------------------------------------------------------------------------ answers
    def _answer(self, expected: int, failure: str) -> tuple[list, ObjectStates]:
        """(all the sim's positions, the object states of that tick) of the sim's state number expected."""
        deadline = time.monotonic() + self.timeout
        with self.changed:
            while self.last_seq < expected or self.last_state[0] not in self.objects:
                left = deadline - time.monotonic()
                if left <= 0 or rospy.is_shutdown():
                    if self.last_seq >= expected:
                        failure = (f'no object states on {self.objects_topic} for the state of '
                                   f'{self.last_state[0][0]}.{self.last_state[0][1]:09d} within {self.timeout:g} s')
                    raise self._fail(failure if left <= 0 else 'rospy is shutting down')
                self.changed.wait(min(left, 0.05))
            if self.last_seq != expected:
                raise self._fail(f'the arm_sim published {self.last_seq - expected} state(s) this env did not ask '
                                 f'for: another node commanded or reset it')
            stamp, buff = self.last_state
            objects = self.objects[stamp]
        self.seq = expected
        try:
            _, _, names, positions = self.decoder.decode(buff)
        except WireError as e:
            raise self._fail(f'the arm_sim\'s joint_states cannot be read: {e}') from None
        if list(names) != self.sim_joints:
            raise self._fail(f'joint_states names {names}, not the sim\'s ~joints {self.sim_joints}')
        return positions.tolist(), objects

    # ------------------------------------------------------------------------------------------------ operations
    def start(self, cube, positions: list) -> tuple[list, ObjectStates]:
        """The cube at rest at cube (upright), then the sim's joints at positions, at rest: the answer."""
        from geometry_msgs.msg import Pose
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = (float(x) for x in cube)
        pose.orientation.w = 1.0
        for call, args, what in ((self.set_object, (OBJECT, pose), 'set_object_pose'),
                                 (self.set_state, (positions,), 'set_state')):
            try:
                answer = call(*args)
            except (rospy.ServiceException, OSError) as e:
                raise self._fail(f'arm_sim\'s {what} failed ({e}): the sim stopped or died') from None
            if not answer.success:
                raise self._fail(f'arm_sim refused the start ({what}): {answer.message}')
        return self._answer(self.seq + 2, f'the arm_sim did not publish the start on {self.state_topic} within '
                                          f'{self.timeout:g} s')

    def command(self, positions: list) -> tuple[list, ObjectStates]:
        try:
            self.command_pub.publish(RawCommand(encode_float64_array(positions)))
        except rospy.ROSException as e:
            raise self._fail(f'cannot publish the command: {e}') from None
        return self._answer(self.seq + 1, f'no joint_states on {self.state_topic} within {self.timeout:g} s of the '
                                          f'command: the arm_sim stopped answering (killed, or no longer in '
                                          f'lockstep)')

    def close(self) -> None:
        for part in self.parts:
            part.unregister()
        for service in self.services:
            service.close()
        self.parts, self.services = [], []
        if self.leased:
            release(self.ns, SIM_NODE, self.token)
            self.leased = False


class RosManipulationEnv(gymnasium.Env):
    """Push-v0 or PickAndPlace-v0 (task) through the arm_sim in robot_ns (see the module's text).

    Args: task, robot_ns (default: a free arm_sim of the running ones in this env's world), timeout (seconds any
    wait lasts), then ManipulationSetup's (model defaults to the namespace's robot_description)."""

    metadata = {'render_modes': []}

    def __init__(self, task: str = 'push', robot_ns: str = '', timeout: float = DEFAULT_TIMEOUT,
                 model: str | None = None, urdf: str | None = None, **kwargs):
        if not (isinstance(timeout, (int, float)) and 0 < timeout <= 3600):
            raise ValueError(f'timeout must be a number of seconds in (0, 3600], got {timeout!r}')
        if model is None and urdf is None:
            urdf = description_of(robot_ns, float(timeout), LAUNCH_HINT, RosManipulationError, 'world_digest')
        self.setup = ManipulationSetup(task, model=model, urdf=urdf, **kwargs)
        self.observation_space, self.action_space = self.setup.observation_space, self.setup.action_space
        self.robot_ns, self.timeout = robot_ns, float(timeout)
        self.kinematics = self.setup.new_data()       # the tip's pose from the reported joints, as MuJoCo has it
        self.link: WorldLink | None = None
        self._positions: list | None = None   # the sim's joints' positions, as last reported
        self._command: list | None = None     # what each joint's servo was last sent
        self._goal = self._grip = None
        self._finger = 0.0
        self._failure = ''

    @property
    def sim_namespace(self) -> str | None:
        return self.link.ns if self.link is not None else None

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        return self.setup.compute_reward(achieved_goal, desired_goal, info)

    def _broken(self, error: RosManipulationError) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None
        self._positions, self._failure = None, str(error)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        s = self.setup
        cube, self._goal = s.sample(self.np_random)
        s.place(self.kinematics, cube)          # the start, as Push-v0 places it: what the sim is set to
        self._failure = ''
        try:
            if self.link is None:
                self.link = WorldLink(self.robot_ns, self.timeout, s)
            start = [float(self.kinematics.qpos[s.physics.qpos_address(n)]) for n in self.link.sim_joints]
            positions, objects = self.link.start(cube, start)
        except RosManipulationError as e:
            self._broken(e)
            raise
        self._command = start
        self._grip, self._finger = s.ready_grip.copy(), float(self.kinematics.qpos[s.finger_q])
        obs = self._observe(positions, objects)
        return obs, {'is_success': self._success(obs)}

    def step(self, action):
        if self._failure:
            raise RosManipulationError(f'{self._failure} [this env failed: call reset() to start again]')
        if self._positions is None:
            raise gymnasium.error.ResetNeeded('Cannot call env.step() before calling env.reset()')
        s, link = self.setup, self.link
        a = s.check_actions(np.reshape(action, (1, -1)))
        q = np.array([self._positions[k] for k in link.arm_index])[:, None]
        grip_now = np.array([self._command[k] for k in link.grip_index])[None]
        joints, grip = s.commands(q, self._grip[None], a, grip_now)
        command = list(self._command)
        for k, value in zip(link.arm_index, joints[:, 0].tolist()):
            command[k] = value
        for k, value in zip(link.grip_index, grip[0].tolist()):
            command[k] = value
        try:
            positions, objects = link.command(command)
        except RosManipulationError as e:
            self._broken(e)
            raise
        self._command = command
        obs = self._observe(positions, objects)
        info = {'is_success': self._success(obs)}
        return obs, float(self.compute_reward(obs['achieved_goal'], obs['desired_goal'], info)), False, False, info

    def _observe(self, positions: list, objects: ObjectStates) -> dict[str, np.ndarray]:
        """The observation of the sim's answer: the tip by MuJoCo's kinematics of the reported arm joints, the cube
        as the sim's message gives it."""
        import mujoco
        s, link, data = self.setup, self.link, self.kinematics
        if OBJECT not in objects.name:
            raise self._fail_now(f'{link.objects_topic} has no {OBJECT!r} (it lists {list(objects.name)})')
        self._positions = positions
        data.qpos[s.q_address] = [positions[k] for k in link.arm_index]
        mujoco.mj_kinematics(s.physics.model, data)
        k = list(objects.name).index(OBJECT)
        p, o, v, w = (objects.pose[k].position, objects.pose[k].orientation, objects.twist[k].linear,
                      objects.twist[k].angular)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.array([o.w, o.x, o.y, o.z]))
        finger = positions[link.grip_index[0]]
        observation, self._grip = s.observation(
            data.xpos[s.tip_body], data.xmat[s.tip_body].reshape(3, 3), np.array([p.x, p.y, p.z]),
            rotation.reshape(3, 3), finger, np.array([v.x, v.y, v.z, w.x, w.y, w.z]), self._grip, self._finger)
        self._finger = finger
        return {'achieved_goal': observation[3:6].copy(), 'desired_goal': self._goal.copy(),
                'observation': observation}

    def _fail_now(self, what: str) -> RosManipulationError:
        error = RosManipulationError(f'{self.link.ns}: {what}')
        self._broken(error)
        return error

    def _success(self, obs) -> bool:
        return bool(np.linalg.norm(obs['achieved_goal'] - obs['desired_goal']) <= self.setup.distance_threshold)

    def close(self):
        if self.link is not None:
            self.link.close()
            self.link = None
        super().close()
