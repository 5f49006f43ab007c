"""gymnasium's CartPole, stepped by a cartpole_sim of the ROS graph: RosCartPoleEnv and RosCartPoleVectorEnv.

The env talks to the robot as its controller does: it publishes ``<ns>/cart_force`` (+-force_mag, the action),
reads ``<ns>/joint_states`` (the state the sim published after that step) and resets through
``<ns>/cartpole_sim/set_state`` with a start state it draws as gymnasium's ``CartPoleEnv.reset`` does. The sim
steps float64 states with gymnasium's equations and the observation is their float32, so every observation,
reward, terminated and truncated equals ``gymnasium.make('CartPole-v1')``'s from the same seed under the same
actions, bit for bit.

The sim must be in lockstep (one step per cart_force: ``roslaunch robot_ai cartpole_gym.launch``) and the env's
own: it takes the sim's lease (robot_ai.envs.link), in ``robot_ns`` or, without one, the first free sim of the
running ones, so that ``gymnasium.make('robot_ai/RosCartPole-v1')`` copies made by any vectoriser each find a sim
of their own. A state counts only if it comes from the sim's node and answers the env's own command. Every wait (the
master, the sim's service, its first connection, each state) lasts at most ``timeout`` seconds and then raises
RosCartPoleError naming the namespace: an env never hangs; after a failure every call raises until the next
reset(). The env connects at its first reset(), not when it is made, so gymnasium's AsyncVectorEnv can make one in
its parent process before it starts its workers.

This is rospy client code, not a node: the first env of a process without a node starts one
(``robot_ai_env_<pid>_<time>``, anonymous, rospy's signal handlers left out).
"""
from __future__ import annotations

import threading
import time
import warnings
from typing import Any

import gymnasium
import numpy as np
import rospy
from gymnasium.envs.classic_control import utils
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.spaces import Discrete
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from robot_ai.envs.link import DEFAULT_TIMEOUT, RosEnvError, ensure_node, new_token, release, resolve, take
from robot_ai.lease import node_alive
from robot_ai.reach.env import vector_reset_args
from robot_ai.srv import SetCartPoleState

POLL = 0.05                  # s: how often a wait looks at what no message announces (connections)
SIM_NODE = 'cartpole_sim'    # the sim's node name in a robot namespace (cartpole_gym.launch, cartpole.launch)
LAUNCH_HINT = 'roslaunch robot_ai cartpole_gym.launch sims:=N'


class RosCartPoleError(RosEnvError):
    """The ROS side failed: no master, no sim, a sim another env holds, a sim not in lockstep, a sim that stopped
    answering."""


class SimLink:
    """One cartpole_sim as an env holds it: its lease, its cart_force publisher, joint_states subscriber and set_state
    service, connected once; a step is one message out and one back, which counts only if it comes from the sim's
    node and is the next one this env receives from it. Messages are counted here, not by header.seq: rospy bumps a
    publisher's seq when it re-sends a latched message to a new subscriber (a `rostopic echo`, rviz), which must not
    look like a step to this env."""

    def __init__(self, robot_ns: str, timeout: float):
        self.timeout = float(timeout)
        try:
            ensure_node(self.timeout)
        except RosEnvError as e:
            raise RosCartPoleError(str(e)) from None
        self.token = new_token()
        self.ns = robot_ns or ''
        self.leased = False
        self.changed = threading.Condition()
        self.seq = -1                # the number of the sim's last state this env has taken
        self.latest: tuple | None = None
        self.last_seq = -1           # the number of the sim's last message this env received (counted from 0)
        self.intruders: dict[str, int] = {}     # other nodes' joint_states on the sim's topic, by sender
        self.force_pub = self.state_sub = self.set_state = None
        try:
            self._connect()
        except RosEnvError as e:
            self.close()
            raise RosCartPoleError(str(e)) from None
        except BaseException:
            self.close()
            raise

    def _fail(self, what: str) -> RosCartPoleError:
        return RosCartPoleError(f'{self.ns}: {what}')

    def _connect(self) -> None:
        self.ns = take(self.ns, SIM_NODE, self.token, self.timeout, LAUNCH_HINT, self._unusable)
        self.leased = True
        self.force_topic = resolve(self.ns, 'cart_force')
        self.state_topic = resolve(self.ns, 'joint_states')
        self.sim_node = resolve(self.ns, SIM_NODE)
        self.service = f'{self.sim_node}/set_state'
        with warnings.catch_warnings():   # queue_size None: published in the caller's thread, the shortest way
            warnings.simplefilter('ignore')
            self.force_pub = rospy.Publisher(self.force_topic, Float64, queue_size=None, tcp_nodelay=True)
        self.state_sub = rospy.Subscriber(self.state_topic, JointState, self._on_state, tcp_nodelay=True)
        self.set_state = rospy.ServiceProxy(self.service, SetCartPoleState, persistent=True)
        self._wait(lambda: self.force_pub.get_num_connections() > 0 and self.state_sub.get_num_connections() > 0
                   and self.last_seq >= 0,
                   f'the cartpole_sim did not connect to {self.force_topic} and {self.state_topic} within '
                   f'{self.timeout:g} s')
        self.seq = self.last_seq     # the latched state: where the sim stands

    @staticmethod
    def _unusable(ns: str) -> str:
        """Why the sim in ns cannot serve an env ('' if it can): not in lockstep, or a controller drives it."""
        param = f'{resolve(ns, SIM_NODE)}/lockstep'
        if rospy.get_param(param, False) is not True:
            return (f'is not in lockstep ({param} is not true): it steps on its own clock and an env needs one step '
                    f'per action; start it with lockstep true ({LAUNCH_HINT}, or cartpole.launch lockstep:=true '
                    f'controller:=false)')
        drivers = SimLink._other_publishers(resolve(ns, 'cart_force'))
        if drivers:
            return (f'is driven already: {", ".join(drivers)} publishes {resolve(ns, "cart_force")}; an env needs a '
                    f'sim of its own (cartpole_gym.launch starts no controller)')
        return ''

    @staticmethod
    def _other_publishers(topic: str) -> list[str]:
        """The running nodes other than this one that publish topic (a controller); a node killed without
        unregistering stays at the master, so each is asked whether it still runs."""
        try:
            state = rospy.get_master().getSystemState()[2][0]
        except Exception:   # the master's answer is only a courtesy check here
            return []
        me = rospy.get_name()
        return [node for t, nodes in state for node in nodes if t == topic and node != me and node_alive(node)]

    def _on_state(self, msg: JointState) -> None:
        sender = getattr(msg, '_connection_header', {}).get('callerid', '')
        if sender != self.sim_node:
            with self.changed:
                self.intruders[sender] = self.intruders.get(sender, 0) + 1
            rospy.logwarn_throttle(5.0, f'{self.state_topic} from {sender} ignored: only {self.sim_node} answers '
                                        f'this env')
            return
        state = (msg.position[0], msg.velocity[0], msg.position[1], msg.velocity[1])
        with self.changed:
            self.latest = state
            self.last_seq += 1
            self.changed.notify_all()

    def _wait(self, done, failure: str) -> None:
        """Wait until done() (checked under the lock, at every message and every POLL s), at most timeout seconds."""
        deadline = time.monotonic() + self.timeout
        with self.changed:
            while not done():
                left = deadline - time.monotonic()
                if left <= 0 or rospy.is_shutdown():
                    raise self._fail(failure if left <= 0 else 'rospy is shutting down')
                self.changed.wait(min(left, POLL))

    def _answer(self, failure: str) -> tuple:
        """The sim's state that answers this env's last command or reset: the next message from the sim's node; a
        second one means the sim published a state nobody asked this env for."""
        expected = self.seq + 1
        self._wait(lambda: self.last_seq >= expected, failure)
        if self.last_seq != expected:
            raise self._fail(f'the cartpole_sim published {self.last_seq - expected} state(s) this env did not ask '
                             f'for: another node reset, pushed or stepped it (a sim of this robot_ai refuses them '
                             f'while an env holds its lease)')
        self.seq = expected
        return self.latest

    # ------------------------------------------------------------------------------------- the two operations
    def begin_start(self, state: np.ndarray) -> None:
        """Ask the sim to start a new episode at state (finish_start waits for it)."""
        try:
            answer = self.set_state(list(map(float, state)))
        except (rospy.ServiceException, OSError) as e:
            raise self._fail(f'cartpole_sim\'s set_state failed ({e}): the sim stopped or died') from None
        if not answer.success:
            raise self._fail(f'cartpole_sim refused the start state: {answer.message}')

    def finish_start(self, state: np.ndarray) -> None:
        got = self._answer(f'the cartpole_sim did not publish the start state on {self.state_topic} within '
                           f'{self.timeout:g} s')
        if got != tuple(map(float, state)):
            raise self._fail(f'the cartpole_sim published {got} where this env set {tuple(state)}')

    def begin_step(self, force: float) -> None:
        try:
            self.force_pub.publish(Float64(force))
        except rospy.ROSException as e:
            raise self._fail(f'cannot publish {self.force_topic}: {e}') from None

    def finish_step(self) -> tuple:
        return self._answer(f'no joint_states on {self.state_topic} within {self.timeout:g} s of the cart_force: '
                            f'the cartpole_sim stopped answering (killed, or no longer in lockstep)')

    def close(self) -> None:
        for part in (self.force_pub, self.state_sub):
            if part is not None:
                part.unregister()
        if self.set_state is not None:
            self.set_state.close()
        self.force_pub = self.state_sub = self.set_state = None
        if self.leased:
            release(self.ns, SIM_NODE, self.token)
            self.leased = False


class RosCartPoleEnv(CartPoleEnv):
    """gymnasium's CartPoleEnv whose every step and reset is made by the cartpole_sim in robot_ns.

    Spaces, reward, termination, rendering and reset distribution are CartPoleEnv's own; the physics runs in the
    sim. Registered as robot_ai/RosCartPole-v0 (200 steps) and -v1 (500): gymnasium.make adds the TimeLimit."""

    def __init__(self, robot_ns: str = '', env_id: str = 'CartPole-v1', timeout: float = DEFAULT_TIMEOUT,
                 render_mode: str | None = None, sutton_barto_reward: bool = False):
        super().__init__(sutton_barto_reward=sutton_barto_reward, render_mode=render_mode)
        if env_id not in ('CartPole-v0', 'CartPole-v1'):
            raise ValueError(f'env_id must be CartPole-v0 or CartPole-v1, got {env_id!r}')
        if not (isinstance(timeout, (int, float)) and 0 < timeout <= 3600):
            raise ValueError(f'timeout must be a number of seconds in (0, 3600], got {timeout!r}')
        self.robot_ns = robot_ns
        self.env_id = env_id
        self.timeout = float(timeout)
        self.link: SimLink | None = None
        self._pending = None          # what begin_step / begin_reset left for their finish
        self._failure = ''            # why the last call failed: every call but reset() raises until the next one

    @property
    def sim_namespace(self) -> str | None:
        """The namespace of the sim this env holds (robot_ns, or the one it claimed); None before a reset."""
        return self.link.ns if self.link is not None else None

    # ------------------------------------------------------------------------------------- gymnasium's API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.begin_reset(seed=seed, options=options)
        return self.finish_reset()

    def step(self, action):
        self.begin_step(action)
        return self.finish_step()

    def close(self):
        if self.link is not None:
            self.link.close()
            self.link = None
        super().close()

    # ------------------------------------------------------------------------------------- halves, for the vector env
    def _linked(self) -> SimLink:
        if self.link is None:
            self.link = SimLink(self.robot_ns, self.timeout)
        return self.link

    def _broken(self, error: RosCartPoleError) -> None:
        """After a failure every call raises until the next reset, which connects anew (the sim may have been
        restarted)."""
        if self.link is not None:
            self.link.close()
            self.link = None
        self._pending = None
        self.state = None
        self._failure = str(error)

    def _check_usable(self) -> None:
        if self._failure:
            raise RosCartPoleError(f'{self._failure} [this env failed: call reset() to start again]')

    def begin_reset(self, *, seed: int | None = None, options: dict | None = None) -> None:
        gymnasium.Env.reset(self, seed=seed)
        low, high = utils.maybe_parse_reset_bounds(options, -0.05, 0.05)
        state = self.np_random.uniform(low=low, high=high, size=(4,))
        self._failure = ''
        try:
            self._linked().begin_start(state)
        except RosCartPoleError as e:
            self._broken(e)
            raise
        self.state = None             # no step until the sim has the new start state
        self._pending = ('reset', state)

    def finish_reset(self):
        self._check_usable()
        _, state = self._pending
        self._pending = None
        try:
            self.link.finish_start(state)
        except RosCartPoleError as e:
            self._broken(e)
            raise
        self.state = state
        self.steps_beyond_terminated = None
        if self.render_mode == 'human':
            self.render()
        return np.array(self.state, dtype=np.float32), {}

    def begin_step(self, action) -> None:
        # a plain int in range is what contains() accepts in 20 us; anything else goes through contains() itself
        if not (type(action) is int and 0 <= action < 2):
            assert self.action_space.contains(action), f'{action!r} ({type(action)}) invalid'
        self._check_usable()
        assert self.state is not None, 'Call reset before using step method.'
        force = self.force_mag if action == 1 else -self.force_mag
        try:
            if self.steps_beyond_terminated is not None:
                # gymnasium integrates on after a terminal state; the sim waits for a new episode then: give it the
                # state it ended in
                self.link.begin_start(self.state)
                self.link.finish_start(self.state)
            self.link.begin_step(force)
            self._pending = ('step',)
        except RosCartPoleError as e:
            self._broken(e)
            raise

    def finish_step(self):
        self._check_usable()
        self._pending = None
        try:
            state = self.link.finish_step()
        except RosCartPoleError as e:
            self._broken(e)
            raise
        self.state = np.array(state, dtype=np.float64)
        x, _, theta, _ = state
        terminated = bool(x < -self.x_threshold or x > self.x_threshold
                          or theta < -self.theta_threshold_radians or theta > self.theta_threshold_radians)
        if not terminated:
            reward = 0.0 if self._sutton_barto_reward else 1.0
        elif self.steps_beyond_terminated is None:
            self.steps_beyond_terminated = 0
            reward = -1.0 if self._sutton_barto_reward else 1.0
        else:
            if self.steps_beyond_terminated == 0:
                gymnasium.logger.warn(
                    "You are calling 'step()' even though this environment has already returned terminated = True. "
                    "You should always call 'reset()' once you receive 'terminated = True' -- any further steps are "
                    "undefined behavior.")
            self.steps_beyond_terminated += 1
            reward = -1.0 if self._sutton_barto_reward else 0.0
        if self.render_mode == 'human':
            self.render()
        return np.array(self.state, dtype=np.float32), reward, terminated, False, {}


def default_namespaces(num_envs: int) -> list[str]:
    """cartpole_gym.launch's namespaces: /cartpole_0 ... /cartpole_<n-1>."""
    return [f'/cartpole_{i}' for i in range(num_envs)]


class RosCartPoleVectorEnv(VectorEnv):
    """num_envs RosCartPoleEnvs, one sim each (robot_namespaces, or free sims of the running ones, claimed at the
    first reset), stepped together (all actions out, then all states in), as gymnasium's SyncVectorEnv steps them:
    autoreset next-step, reset(seed=s) seeds env i with s + i."""

    def __init__(self, num_envs: int = 1, robot_namespaces: list[str] | None = None, env_id: str = 'CartPole-v1',
                 max_episode_steps: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 render_mode: str | None = None, sutton_barto_reward: bool = False):
        if robot_namespaces is None:
            robot_namespaces = [''] * num_envs      # each claims a free sim at its first reset
        if len(robot_namespaces) != num_envs:
            raise ValueError(f'{num_envs} envs need {num_envs} robot namespaces, got {len(robot_namespaces)}')
        named = [ns for ns in robot_namespaces if ns]
        if len(set(named)) != len(named):
            raise ValueError(f'each env needs a sim of its own: {robot_namespaces} repeats a namespace')
        self.envs = [RosCartPoleEnv(ns, env_id, timeout, render_mode if render_mode != 'human' else None,
                                    sutton_barto_reward) for ns in robot_namespaces]
        if max_episode_steps is None:
            max_episode_steps = gymnasium.spec(env_id).max_episode_steps
        self.max_episode_steps = int(max_episode_steps)
        self.num_envs = num_envs
        self.render_mode = render_mode
        self.metadata = dict(CartPoleEnv.metadata, autoreset_mode=AutoresetMode.NEXT_STEP)
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space: Discrete = self.envs[0].action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._elapsed = np.zeros(num_envs, dtype=np.int64)
        self._autoreset = np.zeros(num_envs, dtype=np.bool_)
        self._observations = np.zeros((num_envs, 4), dtype=np.float32)

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        seeds, mask = vector_reset_args(self.num_envs, seed, options)
        if options is not None and 'reset_mask' in options:   # the envs take the other options
            options = {k: v for k, v in options.items() if k != 'reset_mask'}
        chosen = np.flatnonzero(mask)
        for i in chosen:
            self.envs[i].begin_reset(seed=seeds[i], options=options)
        for i in chosen:
            self._observations[i], _ = self.envs[i].finish_reset()
        self._elapsed[mask] = 0
        self._autoreset[mask] = False
        return self._observations.copy(), {}

    def step(self, actions):
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,):
            raise AssertionError(f'{actions!r} invalid: {self.num_envs} actions expected')
        for a in actions:   # every action checked before any is sent: a bad one leaves every env as it was
            assert self.single_action_space.contains(a), f'{a!r} ({type(a)}) invalid'
        rewards = np.zeros(self.num_envs, dtype=np.float64)
        terminations = np.zeros(self.num_envs, dtype=np.bool_)
        truncations = np.zeros(self.num_envs, dtype=np.bool_)
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                env.begin_reset()
            else:
                env.begin_step(actions[i])
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                self._observations[i], _ = env.finish_reset()
                self._elapsed[i] = 0
            else:
                self._observations[i], rewards[i], terminations[i], _, _ = env.finish_step()
                self._elapsed[i] += 1
                truncations[i] = self._elapsed[i] >= self.max_episode_steps
        self._autoreset = terminations | truncations
        return self._observations.copy(), rewards, terminations, truncations, {}

    @property
    def robot_namespaces(self) -> list[str | None]:
        """The sims the envs hold (None for one that has none yet)."""
        return [env.sim_namespace for env in self.envs]

    def render(self):
        if self.render_mode != 'rgb_array':
            return None
        return tuple(env.render() for env in self.envs)

    def close_extras(self, **kwargs):
        for env in self.envs:
            env.close()


def episode_lengths(push_right, robot_ns: str, env_id: str, episodes: int, max_steps: int, seed: int,
                    timeout: float = DEFAULT_TIMEOUT) -> np.ndarray:
    """Lengths (episodes,) of episodes played on the sim in robot_ns through RosCartPoleEnv: the first reset seeded
    with seed (as rng_for seeds the package's own evaluation, so the start states are the same), the others not.

    push_right: the policy as CartPoleDynamics.episode_lengths calls it, observations (4, n) float32 -> (n,) bool."""
    env = RosCartPoleEnv(robot_ns, env_id, timeout)
    try:
        lengths = np.zeros(episodes, dtype=np.int64)
        for e in range(episodes):
            obs, _ = env.reset(seed=int(seed) % 2 ** 64 if e == 0 else None)
            for t in range(1, max_steps + 1):
                obs, _, terminated, _, _ = env.step(int(push_right(obs.reshape(4, 1))[0]))
                if terminated:
                    break
            lengths[e] = t
        return lengths
    finally:
        env.close()
