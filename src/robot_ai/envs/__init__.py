"""gymnasium environments over ROS: the cart-pole robot as gymnasium's CartPole, any arm as the reach task.

``import robot_ai.envs`` registers ``robot_ai/RosCartPole-v0`` (200 steps) and ``robot_ai/RosCartPole-v1`` (500),
each with a vector entry point::

    import gymnasium, robot_ai.envs
    env = gymnasium.make('robot_ai/RosCartPole-v1')                          # the first free sim of the running ones
    env = gymnasium.make('robot_ai/RosCartPole-v1', robot_ns='/cartpole_0')  # that one
    envs = gymnasium.make_vec('robot_ai/RosCartPole-v1', num_envs=4)         # 4 free sims, stepped together

with the sims of ``roslaunch robot_ai cartpole_gym.launch sims:=4`` (lockstep) running; and
``robot_ai/RosReach-v0`` (robot_ai.envs.ros_reach), robot_ai/Reach-v0 through an arm_sim of
``roslaunch robot_ai reach_gym.launch``; ``robot_ai/RosPush-v0`` and ``robot_ai/RosPickAndPlace-v0``
(robot_ai.envs.ros_manipulation), Push-v0 and PickAndPlace-v0 through an arm_sim with physics of
``roslaunch robot_ai manipulation_gym.launch``. Every standard vectoriser
works unchanged (SyncVectorEnv and AsyncVectorEnv over gymnasium.make, make_vec's 'sync' and 'async', and
stable-baselines3's make_vec_env): each env leases a sim of its own. robot_ai.envs.sb3 offers stable-baselines3 a
VecEnv over the package's vector env.
"""
from gymnasium.envs.registration import register, registry

from robot_ai.envs.link import RosEnvError
from robot_ai.envs.ros_cartpole import RosCartPoleEnv, RosCartPoleError, RosCartPoleVectorEnv, default_namespaces
from robot_ai.envs.ros_reach import RosReachEnv, RosReachError

__all__ = ['RosCartPoleEnv', 'RosCartPoleError', 'RosCartPoleVectorEnv', 'RosEnvError', 'RosReachEnv', 'RosReachError',
           'default_namespaces']

for _version, _steps, _threshold in (('v0', 200, 195.0), ('v1', 500, 475.0)):
    if f'robot_ai/RosCartPole-{_version}' not in registry:
        register(id=f'robot_ai/RosCartPole-{_version}', entry_point='robot_ai.envs.ros_cartpole:RosCartPoleEnv',
                 vector_entry_point='robot_ai.envs.ros_cartpole:RosCartPoleVectorEnv',
                 max_episode_steps=_steps, reward_threshold=_threshold, kwargs={'env_id': f'CartPole-{_version}'})
if 'robot_ai/RosReach-v0' not in registry:
    register(id='robot_ai/RosReach-v0', entry_point='robot_ai.envs.ros_reach:RosReachEnv', max_episode_steps=50)
for _name, _task in (('RosPush-v0', 'push'), ('RosPickAndPlace-v0', 'pick_and_place')):
    if f'robot_ai/{_name}' not in registry:
        register(id=f'robot_ai/{_name}', entry_point='robot_ai.envs.ros_manipulation:RosManipulationEnv',
                 max_episode_steps=50, kwargs={'task': _task})
