"""cartpole_sim: gymnasium's CartPole as a robot in the ROS graph, stepped in ROS time.

Every tau = 0.02 s of ROS time divided by ~real_time_factor it steps ``CartPoleDynamics.step_force`` (gymnasium's
equations) with the last force received, and publishes the state as joint_states. When gymnasium's episode would
terminate (the pole past 12 degrees, or the cart past 2.4 m) it publishes that terminal state, then the episode on
~episodes, pauses ~reset_pause seconds of ROS time and publishes a new start state from gymnasium's reset
distribution. There is no time limit: a robot has none.

ROS Parameters
    ~real_time_factor (float, 1.0): simulated seconds per second of ROS time (5: five times faster than real time).
    ~seed (int, 0): seed of the start states (numpy's default_rng, as gymnasium's reset(seed) draws them).
    ~reset_pause (float, 0.5): seconds of ROS time between the end of an episode and the next start state.
    ~lockstep (bool, false): true = no clock: one step per cart_force message, for exact comparisons. After a
        terminal state, the next cart_force message brings the new start state instead of a step.

ROS Publishers
    joint_states (sensor_msgs/JointState): names cart_slider, pole_hinge; position (x, theta); velocity
        (x_dot, theta_dot): the agents' observation. After every step.
    ~episodes (robot_ai/CartPoleEpisode): every episode that ended, and why.

ROS Subscribers
    cart_force (std_msgs/Float64): the force on the cart in newtons (+ toward +x); the last value holds, 0 before
        any. NaN or infinite values are ignored with a throttled warning.

ROS Services
    ~reset (std_srvs/Trigger): end the episode (reason "reset") and start a new one at once.
    ~push (robot_ai/PushPole): add angular_velocity (rad/s) to theta_dot before the next step's integration.
"""
import math
import threading

import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger, TriggerResponse

from robot_ai.cartpole.dynamics import CartPoleDynamics, rng_for, start_states
from robot_ai.msg import CartPoleEpisode
from robot_ai.nodes.params import bool_param, int_param, number_param, publish
from robot_ai.srv import PushPole, PushPoleResponse

JOINTS = ('cart_slider', 'pole_hinge')
ENV_ID = 'CartPole-v1'       # the physics of both CartPole versions is the same; only their step limits differ


class CartPoleSim:

    def __init__(self):
        self.dynamics = CartPoleDynamics.of(ENV_ID)
        self.real_time_factor = number_param('~real_time_factor', 1.0, 'a positive number', lambda v: 0 < v <= 1000)
        self.reset_pause = number_param('~reset_pause', 0.5, 'a number of seconds, at least 0', lambda v: v >= 0)
        self.lockstep = bool_param('~lockstep', False)
        self.rng = rng_for(int_param('~seed', 0, 'a whole number', lambda v: True))
        self.lock = threading.Lock()          # state, force, push and counters: the loop, callbacks and services
        self.force = 0.0
        self.push = 0.0
        self.forces_since_state = 0           # cart_force messages since the last published state
        self.awaiting_reset = False           # a terminal state was published, its episode too: the next start
                                              # state comes after the pause (lockstep: with the next force)
        self.state = self._start_state()
        self.steps = self.missed_steps = 0
        self.state_pub = rospy.Publisher('joint_states', JointState, queue_size=10, tcp_nodelay=True)
        self.episode_pub = rospy.Publisher('~episodes', CartPoleEpisode, queue_size=100, latch=True)
        self.force_sub = rospy.Subscriber('cart_force', Float64, self._on_force, queue_size=100, tcp_nodelay=True)
        self.services = [rospy.Service('~reset', Trigger, self._on_reset),
                         rospy.Service('~push', PushPole, self._on_push)]
        rospy.loginfo(f'cartpole_sim ready: {50 * self.real_time_factor:g} steps per second of ROS time'
                      f'{" (lockstep: one step per cart_force message)" if self.lockstep else ""}')

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
        self.forces_since_state = 0
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
        rospy.loginfo(f'episode ended: {reason} after {self.steps} steps ({self.steps * self.dynamics.tau:.2f} s)'
                      + (f', {self.missed_steps} steps without a fresh cart_force' if self.missed_steps else ''))

    def _new_episode(self) -> None:
        self.state = self._start_state()
        self.steps = self.missed_steps = 0
        self.push = 0.0
        self._publish_state()

    def run(self) -> None:
        """Step in ROS time until shutdown (lockstep: the cart_force callback steps)."""
        with self.lock:
            self._publish_state()
        if self.lockstep:
            rospy.spin()
            return
        period = self.dynamics.tau / self.real_time_factor
        rate = rospy.Rate(1.0 / period)
        try:
            while not rospy.is_shutdown():
                rate.sleep()
                with self.lock:
                    if self.forces_since_state == 0 and self.force_sub.get_num_connections() > 0:
                        self.missed_steps += 1   # a controller is there but did not answer the last state in time
                    ended = self._advance(self.force)
                if ended:
                    rospy.sleep(self.reset_pause)
                    with self.lock:
                        if self.awaiting_reset:       # not already started by ~reset during the pause
                            self.awaiting_reset = False
                            self._new_episode()
                    rate = rospy.Rate(1.0 / period)   # the pause is not a backlog of steps to catch up
        except rospy.ROSInterruptException:
            pass

    # ------------------------------------------------------------------------------------- callbacks
    def _on_force(self, msg: Float64) -> None:
        force = msg.data
        if not math.isfinite(force):
            rospy.logwarn_throttle(5.0, f'cart_force {force} ignored: a force must be a finite number of newtons')
            return
        with self.lock:
            self.force = force
            self.forces_since_state += 1
            if not self.lockstep:
                return
            if self.awaiting_reset:
                self.awaiting_reset = False
                self._new_episode()
                return
            self._advance(force)

    def _on_reset(self, req) -> TriggerResponse:
        with self.lock:
            steps = self.steps
            if not self.awaiting_reset:               # after a fall its episode is published already
                self._end_episode('reset')
            self.awaiting_reset = False
            self._new_episode()
        return TriggerResponse(success=True, message=f'reset after {steps} steps; new start state '
                                                     f'{[round(v, 4) for v in self.state]}')

    def _on_push(self, req) -> PushPoleResponse:
        if not math.isfinite(req.angular_velocity):
            return PushPoleResponse(success=False, message='angular_velocity must be a finite number of rad/s')
        with self.lock:
            self.push += req.angular_velocity
        return PushPoleResponse(success=True, message=f'{req.angular_velocity:+g} rad/s added to theta_dot at the '
                                                      'next step')


def main():
    rospy.init_node('cartpole_sim')
    CartPoleSim().run()
