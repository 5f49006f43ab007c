"""cartpole_controller: a saved policy driving the cart-pole, one cart_force for every joint_states.

It answers every cart-pole state (joint_states with cart_slider and pole_hinge) with cart_force = +force_mag or
-force_mag, the policy's action on the state as gymnasium shows it to an agent (float32). Disabled, it answers 0 N
and the pole falls on its own.

ROS Parameters
    ~policy (str, ""): a policy file (.npz) of either kind, written by a search, a training or the CLI, or an ONNX
        model (.onnx) exported from another library (stable-baselines3's PPO or DQN, say; see robot_ai.policies.onnx).
        Empty: the course's random search (100 x 100, CartPole-v1, seed 0) runs at start and its best weights drive.
        A bad file ends the node with one line.
    ~env_id (str, ""): the CartPole (CartPole-v0 or CartPole-v1) an ONNX model plays when its metadata names none.

ROS Subscribers
    joint_states (sensor_msgs/JointState): the cart-pole's state; messages without both joints are skipped.

ROS Publishers
    cart_force (std_msgs/Float64): newtons, one message per state.

ROS Services
    ~enable (std_srvs/SetBool): switch the controller on (true) or off (false).
    ~load_policy (robot_ai/LoadPolicy): drive with another policy file (either kind) or ONNX model; a bad file
        changes nothing.
"""
import time

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, SetBoolResponse

from robot_ai import policies

from robot_ai.cartpole import linear_search, policy_kinds
from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.nodes.agent_common import answer_load
from robot_ai.nodes.cartpole_sim import JOINTS
from robot_ai.nodes.params import publish, run_node, str_param
from robot_ai.srv import LoadPolicy

SIM_CONNECT = 2.0    # seconds the first answer waits for the sim to connect to cart_force


def course_policy() -> policies.Policy:
    """The course's random search (linear_search.DEFAULTS), seed 0: the policy the controller drives with when
    none is given."""
    d = linear_search.DEFAULTS
    result = linear_search.random_search(CartPoleDynamics.of(d['env_id']), d['iterations'], d['episodes'], seed=0)
    metadata = dict(kind='linear', env_id=d['env_id'], seed=0, settings=result.settings(),
                    figures=result.figures(), source='the course\'s random search, run at start')
    return policies.Policy(LinearPolicy(result.best_weights), metadata)


class CartPoleController:

    def __init__(self):
        path = str_param('~policy', '')
        self.env_id = str_param('~env_id', '')
        if path:
            try:
                self.policy = policy_kinds.load(path, self.env_id)
            except policies.PolicyError as e:
                raise policies.PolicyError(f'~policy: {e}')
        else:
            self.policy = course_policy()
        self.force_mag = CartPoleDynamics.of(self.policy.env_id).force_mag
        self.enabled = True
        self.layout = None                    # (names, indices of cart_slider and pole_hinge) of the last message
        self.waited_for_sim = False           # a state came while no sim listened to cart_force, and we waited
        self.force_pub = rospy.Publisher('cart_force', Float64, queue_size=10, tcp_nodelay=True)
        self.sub = rospy.Subscriber('joint_states', JointState, self._on_state, queue_size=10, tcp_nodelay=True)
        self.services = [rospy.Service('~enable', SetBool, self._on_enable),
                         rospy.Service('~load_policy', LoadPolicy, self._on_load_policy)]
        rospy.loginfo(f'cartpole_controller ready: {self.policy.describe()}')

    def _indices(self, names) -> tuple[int, int] | None:
        if self.layout is None or self.layout[0] != names:
            try:
                self.layout = (names, tuple(names.index(j) for j in JOINTS))
            except ValueError:
                return None
        return self.layout[1]

    def _on_state(self, msg: JointState) -> None:
        indices = self._indices(msg.name)
        if indices is None or len(msg.position) != len(msg.name) or len(msg.velocity) != len(msg.name):
            rospy.logwarn_throttle(5.0, f'joint_states without positions and velocities of {" and ".join(JOINTS)} '
                                        'skipped: not a cart-pole state')
            return
        (i, j), policy = indices, self.policy
        if not self.enabled:
            self._wait_for_sim()
            publish(self.force_pub, Float64(0.0))
            return
        # the agents saw gymnasium's float32 observation: the policy sees the same here
        state = np.array([msg.position[i], msg.velocity[i], msg.position[j], msg.velocity[j]], dtype=np.float32)
        try:
            action = policy.act(state)
        except RequestError as e:
            rospy.logwarn_throttle(5.0, f'state skipped: {e}')
            return
        except policies.PolicyError as e:     # a model that answers no action for this state (issue 40)
            rospy.logerr_throttle(60.0, f'the policy gave no action for this state, so no force was sent: {e}')
            return
        if action not in (0, 1):
            rospy.logerr_throttle(60.0, f'the policy answered {action!r}, not 0 or 1: no force was sent')
            return
        self._wait_for_sim()
        publish(self.force_pub, Float64(self.force_mag if action == 1 else -self.force_mag))

    def _wait_for_sim(self) -> None:
        """A state can reach this node before the sim has connected to its cart_force: the answer would be lost,
        and a lockstep sim would wait for it for ever. Wait for the connection, once, up to SIM_CONNECT seconds."""
        if self.force_pub.get_num_connections() > 0:
            self.waited_for_sim = False
            return
        if self.waited_for_sim:
            return
        deadline = time.monotonic() + SIM_CONNECT
        while self.force_pub.get_num_connections() == 0 and time.monotonic() < deadline and not rospy.is_shutdown():
            time.sleep(0.01)
        self.waited_for_sim = self.force_pub.get_num_connections() == 0

    def _on_enable(self, req) -> SetBoolResponse:
        self.enabled = bool(req.data)
        return SetBoolResponse(success=True, message=('driving with ' + self.policy.describe()) if self.enabled
                               else 'disabled: 0 N on every state')

    def _install(self, policy: policies.Policy) -> str:
        self.policy = policy
        self.force_mag = CartPoleDynamics.of(policy.env_id).force_mag
        return f'driving with {policy.describe()}'

    def _on_load_policy(self, req):
        return answer_load(req.path, '', self._install, self.env_id)


def main():
    run_node('cartpole_controller', CartPoleController)
