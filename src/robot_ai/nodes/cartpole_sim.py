"""cartpole_sim: gymnasium's CartPole as a robot in the ROS graph, stepped in ROS time, paced by its controller.

Every tau = 0.02 s of ROS time divided by ~real_time_factor it steps ``CartPoleDynamics.step_force`` (gymnasium's
equations) with the last force received, and publishes the state as joint_states. A simulator can wait for its
controller where a real robot cannot: with ~wait_for_controller (the default) each step also waits for the
controller's answer to the state before it, up to ~answer_timeout seconds of wall time, so on a busy machine the
loop slows down instead of acting on stale states (real_time_factor is then the most it runs). A step taken without
an answer is counted (missed_steps in ~episodes, and a throttled warning). When gymnasium's episode would terminate
(the pole past 12 degrees, or the cart past 2.4 m) it publishes that terminal state, then the episode on ~episodes,
pauses ~reset_pause seconds of ROS time and publishes a new start state from gymnasium's reset distribution. There
is no time limit: a robot has none.

The controller is the node whose cart_force answers the states (the first to send one; another node takes over when
it is the only publisher left or the controller has been silent for DRIVER_SILENCE seconds): forces from other nodes
(a `rostopic pub` by hand while a controller drives) are ignored with a throttled warning. An env (robot_ai.envs)
takes the sim's ~lease: while it holds it, only its forces count, and ~reset, ~set_state and ~push from any other
node are refused (robot_ai.nodes.lease).

ROS Parameters
    ~real_time_factor (float, 1.0): simulated seconds per second of ROS time (5: five times faster than real time);
        with ~wait_for_controller, the most it runs.
    ~wait_for_controller (bool, true): each step waits for the controller's answer to the last state (while a node
        publishes cart_force), and the first step waits for the first cart_force of all (the start state is
        published again every second meanwhile): a sim started beside its controller loses no episode before the
        controller is up. false: a real robot's semantics, steps on the clock whatever the controller does.
    ~answer_timeout (float, 1.0): wall seconds a step waits for that answer before it goes on without it.
    ~seed (int, 0): seed of the start states (numpy's default_rng, as gymnasium's reset(seed) draws them).
    ~reset_pause (float, 0.5): seconds of ROS time between the end of an episode and the next start state.
    ~lockstep (bool, false): true = no clock: one step per state, taken on the controller's first cart_force after
        it. After a terminal state, the next cart_force brings the new start state instead of a step. joint_states
        is latched then: a node that subscribes gets the state that waits for its answer.

ROS Publishers
    joint_states (sensor_msgs/JointState): names cart_slider, pole_hinge; position (x, theta); velocity
        (x_dot, theta_dot): the agents' observation. After every step.
    ~episodes (robot_ai/CartPoleEpisode): every episode that ended, and why.

ROS Subscribers
    cart_force (std_msgs/Float64): the force on the cart in newtons (+ toward +x); the last value holds, 0 before
        any. NaN, infinite values and forces beyond MAX_FORCE are ignored with a throttled warning: such a force
        still answers the state (the last valid force held), so a flood of them never stalls the sim.

ROS Services
    ~reset (std_srvs/Trigger): end the episode (reason "reset") and start a new one at once (a reset pause too).
    ~push (robot_ai/PushPole): add angular_velocity (rad/s) to theta_dot before the next step's integration; refused
        when theta_dot would leave +-MAX_ANGULAR_VELOCITY.
    ~set_state (robot_ai/SetCartPoleState): end the episode (reason "reset") and start a new one at the given state
        (x, x_dot, theta, theta_dot), published at once on joint_states; refused unless 4 finite numbers within
        +-MAX_STATE_VALUE. robot_ai.envs resets the sim through it, with start states it draws as gymnasium does.
    ~lease (robot_ai/Lease): an env takes the sim (or gives it back); see robot_ai.nodes.lease.

Bounds: with forces within +-MAX_FORCE and theta_dot within +-MAX_ANGULAR_VELOCITY after a push, every state stays
finite (an episode ends within a step or two of any such input), so a command can never make the state NaN or inf.
ROS time going backwards (a /clock restarted under use_sim_time) resets the pacing, as robot_state_publisher does.
"""
import math
import threading
import time

import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger, TriggerResponse

from robot_ai.cartpole.dynamics import CartPoleDynamics, rng_for, start_states
from robot_ai.msg import CartPoleEpisode
from robot_ai.lease import Lease, caller_of
from robot_ai.nodes.params import (bool_param, init_node, int_param, number_param, numpy_service, publish,
                                  quiet_on_shutdown)
from robot_ai.srv import Lease as LeaseService
from robot_ai.srv import PushPole, PushPoleResponse, SetCartPoleState, SetCartPoleStateResponse

JOINTS = ('cart_slider', 'pole_hinge')
ENV_ID = 'CartPole-v1'       # the physics of both CartPole versions is the same; only their step limits differ
MAX_FORCE = 1e4              # N: 1,000 x force_mag; beyond it a cart_force is ignored
MAX_ANGULAR_VELOCITY = 1e3   # rad/s: a push that would take theta_dot beyond it is refused
MAX_STATE_VALUE = 1e3        # ~set_state's bound on each of x, x_dot, theta, theta_dot (theta_dot's is the push's)
DRIVER_SILENCE = 1.0         # wall seconds without a force from the controller before another node may take over


class CartPoleSim:

    def __init__(self):
        self.dynamics = CartPoleDynamics.of(ENV_ID)
        self.real_time_factor = number_param('~real_time_factor', 1.0, 'a positive number', lambda v: 0 < v <= 1000)
        self.reset_pause = number_param('~reset_pause', 0.5, 'a number of seconds, at least 0', lambda v: v >= 0)
        self.lockstep = bool_param('~lockstep', False)
        self.wait_for_controller = bool_param('~wait_for_controller', True)
        self.answer_timeout = number_param('~answer_timeout', 1.0, 'a positive number of seconds',
                                           lambda v: 0 < v <= 3600)
        self.rng = rng_for(int_param('~seed', 0, 'a whole number', lambda v: True))
        self.lock = threading.Lock()          # state, force, push and counters: the loop, callbacks and services
        self.changed = threading.Condition(self.lock)   # an answer came, an episode was reset
        self.force = 0.0
        self.push = 0.0
        self.answered = False                 # the controller answered the last published state
        self.driver = ''                      # the node whose forces answer the states
        self.driver_heard = 0.0               # wall time of its last force
        self.episode = 0                      # episodes started: a reset during a wait or a pause is noticed
        self.awaiting_reset = False           # a terminal state was published, its episode too: the next start
                                              # state comes after the pause (lockstep: with the next force)
        self.state = self._start_state()
        self.steps = self.missed_steps = 0
        self.lease = Lease(rospy.get_name())
        # lockstep: latched, so that a controller that subscribes after the sim's last state still gets it
        self.state_pub = rospy.Publisher('joint_states', JointState, queue_size=10, tcp_nodelay=True,
                                         latch=self.lockstep)
        self.episode_pub = rospy.Publisher('~episodes', CartPoleEpisode, queue_size=100, latch=True)
        self.force_sub = rospy.Subscriber('cart_force', Float64, self._on_force, queue_size=100, tcp_nodelay=True)
        self.services = [rospy.Service('~reset', Trigger, self._on_reset),
                         rospy.Service('~push', PushPole, self._on_push),
                         rospy.Service('~set_state', numpy_service(SetCartPoleState), self._on_set_state),
                         rospy.Service('~lease', LeaseService, self.lease.handle)]
        mode = (' (lockstep: one step per state, on the controller\'s cart_force)' if self.lockstep else
                f', each waiting up to {self.answer_timeout:g} s for the controller\'s answer'
                if self.wait_for_controller else ' (on the clock, whatever the controller does)')
        rospy.loginfo(f'cartpole_sim ready: {50 * self.real_time_factor:g} steps per second of ROS time{mode}')

    def _start_state(self) -> tuple:
        return tuple(float(v) for v in start_states(self.rng, 1, 1)[0, 0])

    # ------------------------------------------------------------------------------------- stepping
    def _step(self, force: float) -> str:
        """One step with force, the pending push first; publish the state; '' or why the episode ended."""
        x, x_dot, theta, theta_dot = self.state
        self.state, _ = self.dynamics.step_force((x, x_dot, theta, theta_dot + self.push), force)
        self.push = 0.0
        self.steps += 1
        self._publish_state()
        return self.dynamics.termination(self.state[0], self.state[2])

    def _publish_state(self) -> None:
        x, x_dot, theta, theta_dot = self.state
        msg = JointState(name=list(JOINTS), position=[x, theta], velocity=[x_dot, theta_dot])
        msg.header.stamp = rospy.Time.now()
        self.answered = False
        publish(self.state_pub, msg)

    def _advance(self, force: float) -> bool:
        """One step; where it ends the episode, publish the episode and wait for a new start (True)."""
        reason = self._step(force)
        if reason:
            self._end_episode(reason)
            self.awaiting_reset = True
        return bool(reason)

    def _end_episode(self, reason: str) -> None:
        publish(self.episode_pub, CartPoleEpisode(steps=self.steps, reason=reason,
                                                 sim_seconds=self.steps * self.dynamics.tau,
                                                 missed_steps=self.missed_steps))
        line = (f'episode ended: {reason} after {self.steps} step{"s" if self.steps != 1 else ""} '
                f'({self.steps * self.dynamics.tau:.2f} s)'
                + (f', {self.missed_steps} taken without the controller\'s answer' if self.missed_steps else ''))
        if self.lockstep:   # an agent trains at thousands of steps a second: ~episodes has every one
            rospy.loginfo_throttle(1.0, line)
        else:
            rospy.loginfo(line)

    def _new_episode(self, state: tuple | None = None) -> None:
        self.state = self._start_state() if state is None else state
        self.steps = self.missed_steps = 0
        self.push = 0.0
        self.episode += 1
        self.awaiting_reset = False
        self._publish_state()
        self.changed.notify_all()

    def _wait_for_answer(self) -> str:
        """With the lock held: wait (wall time) for the controller's answer to the last state, when a node publishes
        cart_force. 'answered' (or nobody to wait for), 'missed' (none within ~answer_timeout), 'reset' (~reset
        published a new start state meanwhile: its answer is the one to wait for)."""
        if self.answered or self.force_sub.get_num_connections() == 0:
            return 'answered'
        if not self.wait_for_controller:
            return 'missed'
        episode = self.episode
        deadline = time.monotonic() + self.answer_timeout
        while not self.answered and not rospy.is_shutdown():
            if self.episode != episode:
                return 'reset'
            left = deadline - time.monotonic()
            if left <= 0:
                return 'missed'
            self.changed.wait(min(left, 0.1))
        return 'answered'

    def _pause(self) -> None:
        """~reset_pause of ROS time after a terminal state, cut short by ~reset or a shutdown."""
        with self.lock:
            episode = self.episode
        start = rospy.Time.now()
        while not rospy.is_shutdown():
            now = rospy.Time.now()
            if now < start:                       # time went backwards: the pause starts again
                start = now
            left = self.reset_pause - (now - start).to_sec()
            with self.lock:
                if self.episode != episode:       # ~reset started the new episode already
                    return
                if left <= 0:
                    self._new_episode()
                    return
                self.changed.wait(min(left, 0.05))    # wall seconds: ROS time may be /clock's

    def _wait_for_first_answer(self) -> None:
        """~wait_for_controller: no step before the first cart_force, the start state published again every second
        for a controller that subscribes after it (joint_states is not latched on the clock)."""
        published = time.monotonic()
        with self.lock:
            while not self.answered and not rospy.is_shutdown():
                self.changed.wait(0.1)
                if not self.answered and time.monotonic() - published >= 1.0:
                    if not self.force_sub.get_num_connections():
                        rospy.loginfo_once('cartpole_sim waits for its controller: the first step comes with the '
                                           'first cart_force (~wait_for_controller)')
                    published = time.monotonic()
                    self._publish_state()

    def run(self) -> None:
        """Step in ROS time until shutdown (lockstep: the cart_force callback steps)."""
        with self.lock:
            self._publish_state()
        if self.lockstep:
            rospy.spin()
            return
        if self.wait_for_controller:
            self._wait_for_first_answer()
        period = self.dynamics.tau / self.real_time_factor
        next_tick = last_step = rospy.get_time()
        while not rospy.is_shutdown():
            try:
                now = rospy.get_time()
                if now < last_step:                  # ROS time went backwards (a /clock restarted): pace anew
                    rospy.loginfo('ROS time moved backwards: the sim\'s pacing starts again')
                    next_tick = last_step = now
                if next_tick > now:
                    rospy.sleep(next_tick - now)
                with self.lock:
                    answer = self._wait_for_answer()
                    if answer == 'reset' or rospy.is_shutdown():
                        continue
                    if answer == 'missed':
                        self.missed_steps += 1
                    if answer == 'missed' and self.wait_for_controller:
                        rospy.logwarn_throttle(5.0, f'no cart_force answered the last state within '
                                                    f'{self.answer_timeout:g} s: stepping with the last force held')
                    ended = self.awaiting_reset or self._advance(self.force)
                if ended:
                    self._pause()
                last_step = rospy.get_time()
                # a late step is caught up, but never closer than half a period to the one before: the states
                # never come faster than forward_kinematics' publish_frequency lets every one through
                next_tick = last_step + period if ended else max(next_tick + period, last_step + period / 2)
            except rospy.ROSTimeMovedBackwardsException:
                next_tick = last_step = rospy.get_time()
            except rospy.ROSInterruptException:
                break

    # ------------------------------------------------------------------------------------- callbacks
    def _from_driver(self, msg) -> bool:
        """Whether msg came from the controller (see the module's docstring); a new controller takes over here."""
        sender = caller_of(msg)
        now = time.monotonic()
        if sender != self.driver and (not self.driver or now - self.driver_heard > DRIVER_SILENCE
                                      or self.force_sub.get_num_connections() <= 1):
            if self.driver:
                rospy.loginfo(f'{sender or "a node"} drives the cart now ({self.driver} is silent or gone)')
            self.driver = sender
        if sender == self.driver:
            self.driver_heard = now
            return True
        rospy.logwarn_throttle(5.0, f'cart_force from {sender} ignored: {self.driver} drives the cart')
        return False

    def _on_force(self, msg: Float64) -> None:
        caller = caller_of(msg)
        if not self.lease.allows(caller):
            rospy.logwarn_throttle(5.0, f'cart_force from {caller} ignored: {self.lease.refusal(caller)}')
            return
        force = msg.data
        valid = math.isfinite(force) and abs(force) <= MAX_FORCE
        if not valid:
            rospy.logwarn_throttle(5.0, f'cart_force {force} ignored: a force must be a finite number of newtons, '
                                        f'at most {MAX_FORCE:g} in size; the last valid force holds')
        with self.lock:
            if not self._from_driver(msg):
                return
            if not valid:
                force = self.force
            if not self.lockstep:
                self.force = force
                if not self.answered:
                    self.answered = True
                    self.changed.notify_all()
                return
            if self.answered:                  # one step per published state, whatever else arrives
                return
            self.answered = True
            self.force = force
            if self.awaiting_reset:
                self._new_episode()
                return
            self._advance(force)

    def _on_reset(self, req) -> TriggerResponse:
        if not self.lease.allows(caller_of(req)):
            return TriggerResponse(success=False, message=self.lease.refusal(caller_of(req)))
        with self.lock:
            steps = self.steps
            if not self.awaiting_reset:               # after a fall its episode is published already
                self._end_episode('reset')
            self._new_episode()
            state = self.state
        return TriggerResponse(success=True, message=f'reset after {steps} step{"s" if steps != 1 else ""}; new '
                                                     f'start state {[round(v, 4) for v in state]}')

    def _on_set_state(self, req) -> SetCartPoleStateResponse:
        if not self.lease.allows(caller_of(req)):
            return SetCartPoleStateResponse(success=False, message=self.lease.refusal(caller_of(req)))
        if len(req.state) != 4:      # counted before anything is converted: a request may hold millions
            return SetCartPoleStateResponse(success=False, message=f'a state is 4 numbers (x, x_dot, theta, '
                                                                   f'theta_dot), got {len(req.state)}')
        state = tuple(float(v) for v in req.state)
        if not all(math.isfinite(v) and abs(v) <= MAX_STATE_VALUE for v in state):
            return SetCartPoleStateResponse(success=False, message=f'a state is 4 finite numbers (x, x_dot, theta, '
                                                                   f'theta_dot) within +-{MAX_STATE_VALUE:g}, got '
                                                                   f'{list(state)[:8]}')
        with self.lock:
            steps = self.steps
            if not self.awaiting_reset:
                self._end_episode('reset')
            self._new_episode(state)
        return SetCartPoleStateResponse(success=True, message=f'new episode at {list(state)} after '
                                                              f'{steps} step{"s" if steps != 1 else ""}')

    def _on_push(self, req) -> PushPoleResponse:
        if not self.lease.allows(caller_of(req)):
            return PushPoleResponse(success=False, message=self.lease.refusal(caller_of(req)))
        v = req.angular_velocity
        if not math.isfinite(v):
            return PushPoleResponse(success=False, message='angular_velocity must be a finite number of rad/s')
        with self.lock:
            pushed = self.state[3] + self.push + v
            if not abs(pushed) <= MAX_ANGULAR_VELOCITY:
                return PushPoleResponse(success=False, message=f'a push of {v:+g} rad/s would make theta_dot '
                                                               f'{pushed:+.4g} rad/s: beyond +-{MAX_ANGULAR_VELOCITY:g}'
                                                               ' rad/s, refused')
            self.push += v
        return PushPoleResponse(success=True, message=f'{v:+g} rad/s added to theta_dot at the next step')


@quiet_on_shutdown
def main():
    init_node('cartpole_sim')
    CartPoleSim().run()
