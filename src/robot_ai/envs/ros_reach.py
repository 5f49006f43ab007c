"""The reach task through a robot namespace of the ROS graph: RosReachEnv (robot_ai/RosReach-v0).

The env meets the arm as reach_controller does: it publishes ros_control's JointGroupPositionController command
(``<ns>/joint_group_position_controller/command``, every joint of the sim's ``~joints``), reads ``<ns>/joint_states``
(the arm's answer) and the tip from ``<ns>/tf`` and ``<ns>/tf_static`` (forward_kinematics' frames of that state,
matched by stamp), and resets through ``<ns>/arm_sim/set_state``. It computes each command as ReachEnv moves its
arm (the same damped least squares on the same Jacobian, from the joint positions the arm reported), and draws goals
and starts from the same np_random, so every observation equals ``robot_ai/Reach-v0``'s from the same seed and
actions to 1e-9 m (the tip comes through tf's quaternions), and successes (and sparse rewards) are identical.

The sim must be an arm_sim in lockstep (``roslaunch robot_ai reach_gym.launch``) and the env's own: it takes its
lease, in ``robot_ns`` or, without one, the first free one of the running ones (robot_ai.envs.link); a state counts
only from the sim's node, the next message this env receives from it. The model defaults to the namespace's
robot_description (read from the master when the env is made; no node is started then). No master, no sim, a sim
that dies, no frames from forward_kinematics: RosReachError naming the namespace within ``timeout``; after a failure
every call raises until the next reset().

    env = gymnasium.make('robot_ai/RosReach-v0', robot_ns='/arm_0')       # with reach_gym.launch running
"""
from __future__ import annotations

import hashlib
import re
import threading
import time
import warnings

import gymnasium
import numpy as np
import rosgraph
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage

from robot_ai.envs.link import (DEFAULT_TIMEOUT, RosEnvError, ensure_node, master_answers, new_token, release,
                                resolve, take)
from robot_ai.reach.env import LIMIT_AVOIDANCE, RENDER_FPS, ReachSetup, Recovery
from robot_ai.reach.task import goal_distance_one
from robot_ai.srv import SetJointPositions
from robot_ai.tf_wire import (JointStateDecoder, TFDecoder, WireError, decode_tf, encode_float64_array, header_of,
                               raw_message_class)

POLL = 0.05
SIM_NODE = 'arm_sim'
LAUNCH_HINT = 'roslaunch robot_ai reach_gym.launch sims:=N model:=...'
COMMAND_TOPIC = 'joint_group_position_controller/command'
KEEP_STAMPS = 16              # /tf messages kept while the matching joint_states is awaited
RawJointState = raw_message_class(JointState)
RawTFMessage = raw_message_class(TFMessage)
RawCommand = raw_message_class(Float64MultiArray)


class RosReachError(RosEnvError):
    """The ROS side of RosReachEnv failed: no master, no arm_sim, one another env holds, one not in lockstep, one that
    stopped answering, or no frames from forward_kinematics."""


def description_of(robot_ns: str, timeout: float, hint: str = LAUNCH_HINT, error=None, sim_param: str = '') -> str:
    """The robot_description of robot_ns (or, without one, of the first running arm_sim's namespace in natural order,
    among those that set sim_param if given: in a graph of several robots, give robot_ns or model), read from the
    master without starting a node; error (RosReachError) of one line, ending with hint, where there is none."""
    error = error or RosReachError
    problem = master_answers(timeout)
    if problem:
        raise error(problem)
    master = rosgraph.Master('/robot_ai_env')
    ns = robot_ns
    if not ns:
        sims = [name[:-len(f'/{SIM_NODE}/lease')] or '/' for name, _ in master.getSystemState()[2]
                if name.endswith(f'/{SIM_NODE}/lease')]
        if sim_param:
            sims = [n for n in sims if master.hasParam(rosgraph.names.ns_join(resolve(n, SIM_NODE), sim_param))]
        if not sims:
            raise error(f'no arm_sim{" with ~" + sim_param if sim_param else ""} runs, and no model= was given: '
                        f'start the sims first ({hint})')
        ns = min(sims, key=lambda n: [int(t) if t.isdigit() else t for t in re.split(r'(\d+)', n)])
    try:
        key = rosgraph.Master(rosgraph.names.ns_join(ns, 'robot_ai_env')).searchParam('robot_description')
        xml = master.getParam(key)
    except rosgraph.MasterException:
        raise error(f'{ns}: no robot_description there or above: give model= or start the sims ({hint})') from None
    if not isinstance(xml, str):
        raise error(f'{ns}: robot_description holds {type(xml).__name__}, not a URDF')
    return xml


def description_above(ns: str) -> str | None:
    """robot_description of ns or the nearest namespace above it (as the nodes in ns find it), or None."""
    parts = [p for p in ns.split('/') if p]
    for k in range(len(parts), -1, -1):
        key = '/' + '/'.join(parts[:k] + ['robot_description'])
        if rospy.has_param(key):
            return rospy.get_param(key)
    return None


def _rotate(q: tuple, v: tuple) -> tuple:
    """Vector v rotated by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


def _multiply(a: tuple, b: tuple) -> tuple:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


class ArmLink:
    """One arm_sim as an env holds it: its lease, the command publisher, the joint_states, tf and tf_static
    subscribers and the set_state service, connected once."""

    def __init__(self, robot_ns: str, timeout: float, setup: ReachSetup):
        self.timeout = float(timeout)
        self.setup = setup
        try:
            ensure_node(self.timeout)
        except RosEnvError as e:
            raise RosReachError(str(e)) from None
        self.token = new_token()
        self.ns = robot_ns or ''
        self.leased = False
        self.changed = threading.Condition()
        self.decoder = JointStateDecoder()
        self.tf_decoder = TFDecoder()
        self.ready = threading.Lock()      # released by a callback when the awaited state and its frames are here
        self.ready.acquire()
        self.awaited: int | None = None     # the number of the sim's message the env waits for
        self.seq = -1                     # the number of the sim's last state this env has taken
        self.last_seq = -1                # the number of its last message received, counted here from 0: rospy bumps
                                          # header.seq when it re-sends a latched message to a new subscriber
        self.last_state = None            # (stamp, its bytes) of the sim's last joint_states
        self.frames: dict[tuple, dict] = {}   # stamp -> {child: (parent, transform)} of /tf
        self.static: dict[str, tuple] = {}    # child -> (parent, transform) of /tf_static
        self.parts = []
        try:
            self._connect()
        except RosEnvError as e:
            self.close()
            raise RosReachError(str(e)) from None
        except BaseException:
            self.close()
            raise

    def _fail(self, what: str) -> RosReachError:
        return RosReachError(f'{self.ns}: {what}')

    def _unusable(self, ns: str) -> str:
        """Why the arm_sim in ns cannot serve this env ('' if it can): not in lockstep, or another robot."""
        param = f'{resolve(ns, SIM_NODE)}/lockstep'
        if rospy.get_param(param, False) is not True:
            return (f'is not in lockstep ({param} is not true): it moves on its own clock and an env needs one step '
                    f'per action; start it with lockstep true ({LAUNCH_HINT})')
        xml = description_above(ns)
        if xml is None:
            return 'has no robot_description in its namespace or above'
        if not isinstance(xml, str) or hashlib.sha256(xml.encode()).hexdigest() != self.setup.model.sha256:
            return f'holds another robot than this env\'s {self.setup.model.tree.name} ({self.setup.model.name})'
        return ''

    def _connect(self) -> None:
        self.ns = take(self.ns, SIM_NODE, self.token, self.timeout, LAUNCH_HINT, self._unusable, said='the arm_sim ')
        self.leased = True
        self.sim_node = resolve(self.ns, SIM_NODE)
        self.sim_joints = rospy.get_param(f'{self.sim_node}/joints', None)
        arm = self.setup.arm
        missing = [n for n in arm.joints if not self.sim_joints or n not in self.sim_joints]
        if missing:
            raise self._fail(f'the arm_sim does not move {", ".join(missing)} (its ~joints: {self.sim_joints}): '
                             f'not the robot this env reaches with')
        self.index = [self.sim_joints.index(n) for n in arm.joints]
        self.chain = [(arm.tree.joints[n].parent, arm.tree.joints[n].child, arm.tree.joints[n].moving)
                      for n in arm.chain]
        self.moving_children = {child for _, child, moving in self.chain if moving}
        self.state_topic = resolve(self.ns, 'joint_states')
        self.tf_topic, self.static_topic = resolve(self.ns, 'tf'), resolve(self.ns, 'tf_static')
        with warnings.catch_warnings():   # queue_size None: published in the caller's thread, the shortest way
            warnings.simplefilter('ignore')
            self.command_pub = rospy.Publisher(resolve(self.ns, COMMAND_TOPIC), RawCommand, queue_size=None,
                                               tcp_nodelay=True)
        self.parts = [self.command_pub,
                      rospy.Subscriber(self.state_topic, RawJointState, self._on_state, tcp_nodelay=True),
                      rospy.Subscriber(self.tf_topic, RawTFMessage, self._on_tf, tcp_nodelay=True, queue_size=100),
                      rospy.Subscriber(self.static_topic, RawTFMessage, self._on_static, tcp_nodelay=True)]
        self.set_state = rospy.ServiceProxy(f'{self.sim_node}/set_state', SetJointPositions, persistent=True)
        fixed = {child for _, child, moving in self.chain if not moving}
        tf_sub = self.parts[2]        # connected to forward_kinematics before the first reset: else its frames of
        #                               the start state can go out before this env listens (a 10 s wait, then a fail)
        self._wait(lambda: self.command_pub.get_num_connections() > 0 and self.last_seq >= 0
                   and fixed <= set(self.static) and tf_sub.get_num_connections() > 0,
                   f'the arm_sim and forward_kinematics did not connect within {self.timeout:g} s (commands on '
                   f'{self.command_pub.resolved_name}, states on {self.state_topic}, fixed frames on '
                   f'{self.static_topic}): start forward_kinematics in the namespace ({LAUNCH_HINT} does)')
        self.seq = self.last_seq

    # ------------------------------------------------------------------------------------------------ callbacks
    def _on_state(self, msg) -> None:
        sender = getattr(msg, '_connection_header', {}).get('callerid', '')
        if sender != self.sim_node:
            rospy.logwarn_throttle(5.0, f'{self.state_topic} from {sender} ignored: only {self.sim_node} answers '
                                        f'this env')
            return
        try:
            _, secs, nsecs = header_of(msg.buff)
        except WireError:
            return
        with self.changed:      # decoded by the env once answered: this thread hands over at once
            self.last_seq += 1
            self.last_state = ((secs, nsecs), msg.buff)
            self._hand_over()

    def _on_tf(self, msg) -> None:
        try:
            transforms = self.tf_decoder.decode(msg.buff)
        except WireError:
            return
        with self.changed:
            for secs, nsecs, parent, child, data in transforms:
                if child in self.moving_children:
                    self.frames.setdefault((secs, nsecs), {})[child] = (parent, data)
            while len(self.frames) > KEEP_STAMPS:
                del self.frames[next(iter(self.frames))]
            self._hand_over()
            self.changed.notify_all()

    def _hand_over(self) -> None:
        """With self.changed held: wake the env if what it awaits is here (one lock hand-off, no condition)."""
        if self.awaited is not None and self._answered(self.awaited):
            self.awaited = None
            self.ready.release()

    def _on_static(self, msg) -> None:
        try:
            transforms = decode_tf(msg.buff)
        except WireError:
            return
        with self.changed:
            for _, _, parent, child, data in transforms:
                self.static[child] = (parent, data)
            self.changed.notify_all()

    def _wait(self, done, failure: str) -> None:
        deadline = time.monotonic() + self.timeout
        with self.changed:
            while not done():
                left = deadline - time.monotonic()
                if left <= 0 or rospy.is_shutdown():
                    raise self._fail(failure if left <= 0 else 'rospy is shutting down')
                self.changed.wait(min(left, POLL))

    # ------------------------------------------------------------------------------------------------ answers
    def _answered(self, expected: int) -> bool:
        """Whether the sim's state expected (or a later one) and its frames are here (checked under the lock)."""
        if self.last_seq < expected:
            return False
        return self.last_seq > expected or self.moving_children <= set(self.frames.get(self.last_state[0], ()))

    def _answer(self, failure: str) -> tuple[list, list, list]:
        """(all the sim's positions, the arm's joints, the tip from tf) of the state that answers this env's last
        command or reset. One wait, woken by the frames (which come after the state)."""
        expected = self.seq + 1
        with self.changed:
            waiting = not self._answered(expected)
            if waiting:
                self.awaited = expected
        if waiting and not self.ready.acquire(timeout=self.timeout):
            with self.changed:
                self.awaited = None
                self.ready.acquire(blocking=False)    # a hand-over that came after the timeout: taken back
            if self.last_seq < expected:
                raise self._fail(failure)
            stamp = self.last_state[0]
            raise self._fail(f'no frames on {self.tf_topic} for the state of {stamp[0]}.{stamp[1]:09d} within '
                             f'{self.timeout:g} s: forward_kinematics is not running in {self.ns}, or drops states '
                             f'(give it ~ignore_timestamp true, as reach_gym.launch does)') from None
        if self.last_seq != expected:
            raise self._fail(f'the arm_sim published {self.last_seq - expected} state(s) this env did not ask for: '
                             f'another node commanded or reset it (an arm_sim refuses them while an env holds its '
                             f'lease)')
        self.seq = expected
        stamp, buff = self.last_state
        try:
            _, _, names, positions = self.decoder.decode(buff)
        except WireError as e:
            raise self._fail(f'the arm_sim\'s joint_states cannot be read: {e}') from None
        if list(names) != self.sim_joints:
            raise self._fail(f'joint_states names {names}, not the sim\'s ~joints {self.sim_joints}')
        positions = positions.tolist()
        with self.changed:
            frames = self.frames.get(stamp, {})
            tip = self._tip(frames)
        return positions, [positions[i] for i in self.index], tip

    def _tip(self, frames: dict) -> list[float]:
        """The tip's position in the arm's base frame, composed along the chain from tf's transforms."""
        p, q = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
        for parent, child, moving in self.chain:
            found = frames.get(child) if moving else self.static.get(child)
            if found is None or found[0] != parent:
                topic = self.tf_topic if moving else self.static_topic
                raise self._fail(f'no transform {parent} -> {child} on {topic}')
            t = found[1]
            r = _rotate(q, t[:3])
            p = (p[0] + r[0], p[1] + r[1], p[2] + r[2])
            q = _multiply(q, t[3:])
        return list(p)

    # ------------------------------------------------------------------------------------------------ operations
    def start(self, positions: list) -> tuple:
        try:
            answer = self.set_state(positions)
        except (rospy.ServiceException, OSError) as e:
            raise self._fail(f'arm_sim\'s set_state failed ({e}): the sim stopped or died') from None
        if not answer.success:
            raise self._fail(f'arm_sim refused the start: {answer.message}')
        return (*self._answer(f'the arm_sim did not publish the start on {self.state_topic} within '
                              f'{self.timeout:g} s'), None)

    def command(self, positions: list, meanwhile=None) -> tuple:
        """Send positions; meanwhile(): work to do while the arm answers (its result is returned last)."""
        try:
            self.command_pub.publish(RawCommand(encode_float64_array(positions)))
        except rospy.ROSException as e:
            raise self._fail(f'cannot publish the command: {e}') from None
        early = meanwhile() if meanwhile is not None else None
        return (*self._answer(f'no joint_states on {self.state_topic} within {self.timeout:g} s of the command: the '
                              f'arm_sim stopped answering (killed, or no longer in lockstep)'), early)

    def close(self) -> None:
        for part in self.parts:
            part.unregister()
        self.parts = []
        if getattr(self, 'set_state', None) is not None:
            self.set_state.close()
            self.set_state = None
        if self.leased:
            release(self.ns, SIM_NODE, self.token)
            self.leased = False


class RosReachEnv(gymnasium.Env):
    """The reach task of robot_ai/Reach-v0 through the arm in robot_ns (see the module's docstring).

    Args: robot_ns (default: a free arm_sim of the running ones), timeout (seconds any wait lasts), then
    ReachEnv's (model defaults to the namespace's robot_description)."""

    metadata = {'render_modes': ['rgb_array'], 'render_fps': RENDER_FPS}

    def __init__(self, robot_ns: str = '', timeout: float = DEFAULT_TIMEOUT, model: str | None = None,
                 xacro_args=None, tip: str | None = None, control: str = 'ee', start: str = 'home',
                 reward_type: str = 'sparse', distance_threshold: float = 0.05, ee_step: float | None = None,
                 damping: float | None = None, home=None, urdf: str | None = None, render_mode: str | None = None,
                 limit_avoidance: float = LIMIT_AVOIDANCE, limit_recovery: bool = True):
        if not (isinstance(timeout, (int, float)) and 0 < timeout <= 3600):
            raise ValueError(f'timeout must be a number of seconds in (0, 3600], got {timeout!r}')
        if model is None and urdf is None:
            urdf = description_of(robot_ns, float(timeout))
        self.setup = ReachSetup(model, xacro_args, tip, control, start, reward_type, distance_threshold, ee_step,
                                damping, home, urdf, limit_avoidance, limit_recovery=limit_recovery)
        self.arm, self.task = self.setup.arm, self.setup.task
        self.observation_space = self.setup.observation_space
        self.action_space = self.setup.action_space
        self.robot_ns, self.timeout, self.render_mode = robot_ns, float(timeout), render_mode
        self.link: ArmLink | None = None
        self._q = self._all = self._tip = self._goal = self._jac = self._own_tip = None
        self._recovery = Recovery()             # limit recovery's state in the episode (ReachSetup.recover)
        self._failure = ''
        self._renderer = None

    @property
    def sim_namespace(self) -> str | None:
        return self.link.ns if self.link is not None else None

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    def _broken(self, error: RosReachError) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None
        self._q = None
        self._failure = str(error)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        goal_q, start_q = self.setup.first_states([self.np_random], [self._q])    # chained: from where it stands
        self._goal = self.arm.forward_one(goal_q[:, 0].tolist())[0]
        self._failure, self._recovery = '', Recovery()
        try:
            if self.link is None:
                self.link = ArmLink(self.robot_ns, self.timeout, self.setup)
            positions = list(self._all if self._all is not None else self._sim_home())
            for k, value in zip(self.link.index, start_q[:, 0].tolist()):
                positions[k] = value
            self._all, q, tip, _ = self.link.start(positions)
        except RosReachError as e:
            self._broken(e)
            raise
        self._take(q, tip)
        if self._renderer is not None:
            self._renderer.new_episode()
        return self.setup.observation_one(self._q, self._tip, self._goal), self._info()

    def _sim_home(self) -> list:
        """The sim's positions as it stands (its last joint_states), to keep the joints this arm does not move."""
        return self.link.decoder.decode(self.link.last_state[1])[3].tolist()

    def _take(self, q: list, tip: list, q_early: list | None = None, placed_early=None) -> None:
        """The arm's answer: its joints (as the sim reported them) and the tip (from tf); the kinematics' tip and
        Jacobian of the next step from those joints, as ReachEnv computes them (those computed early, if they are
        of these very joints: a lockstep sim reports the command it was sent, already within the limits)."""
        self._q, self._tip = q, tip
        self._own_tip, self._jac = placed_early if q_early == self._q else self.setup.place_one(self._q)

    def step(self, action):
        if self._failure:
            raise RosReachError(f'{self._failure} [this env failed: call reset() to start again]')
        if self._q is None:
            raise gymnasium.error.ResetNeeded('Cannot call env.step() before calling env.reset()')
        a = self.setup.check_action_one(action)
        commanded = self.setup.move_one(self._q, self._jac, a)
        commanded, self._recovery = self.setup.recover_one(self._q, self._own_tip, commanded, a, self._goal,
                                                           self._recovery)
        positions = list(self._all)
        for k, value in zip(self.link.index, commanded):
            positions[k] = value
        try:   # the next step's kinematics, from the commanded positions, while the arm answers
            self._all, q_new, tip, (q_early, placed_early) = self.link.command(
                positions, lambda: (commanded, self.setup.place_one(commanded)))
        except RosReachError as e:
            self._broken(e)
            raise
        self._take(q_new, tip, q_early, placed_early)
        distance = goal_distance_one(self._tip, self._goal)
        return (self.setup.observation_one(self._q, self._tip, self._goal), self.task.reward_one(distance), False,
                False, {'is_success': distance < self.task.distance_threshold})

    def _info(self) -> dict:
        return {'is_success': goal_distance_one(self._tip, self._goal) < self.task.distance_threshold}

    def render(self):
        if self.render_mode != 'rgb_array':
            return None
        if self._renderer is None:
            from robot_ai.reach.render import ArmRenderer
            self._renderer = ArmRenderer(self.arm, self.task.distance_threshold)
        q = self.setup.home if self._q is None else np.array(self._q)
        return self._renderer.draw(q, None if self._goal is None else np.array(self._goal))

    def close(self):
        if self.link is not None:
            self.link.close()
            self.link = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
