"""Any arm the user brings learns to reach: the chain, its Jacobian, the reach task and its gymnasium envs. No rospy.

``import robot_ai.reach`` registers ``robot_ai/Reach-v0`` (50 steps) with a vector entry point::

    import gymnasium, robot_ai.reach
    env = gymnasium.make('robot_ai/Reach-v0', model='/path/arm.urdf.xacro', xacro_args='hand:=true', tip='tool0')
    envs = gymnasium.make_vec('robot_ai/Reach-v0', num_envs=4096)     # one numpy pass per step for all arms

    python -m robot_ai.reach train --model /path/arm.urdf     # ARS learns to reach; evaluate, show: see --help
"""
from gymnasium.envs.registration import register, registry

from robot_ai.reach.arm import Arm, ReachError
from robot_ai.reach.env import ReachEnv, ReachSetup, ReachVectorEnv
from robot_ai.reach.model import load_model
from robot_ai.reach.task import ReachTask, goal_distance
# registers Reach-v0 and RosReach-v0 as envs a policy acts in
from robot_ai.reach import policy_files  # noqa: E402,F401

__all__ = ['Arm', 'ReachEnv', 'ReachError', 'ReachSetup', 'ReachTask', 'ReachVectorEnv', 'goal_distance', 'load_model']

ENV_ID = 'robot_ai/Reach-v0'

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point='robot_ai.reach.env:ReachEnv',
             vector_entry_point='robot_ai.reach.env:ReachVectorEnv', max_episode_steps=50,
             kwargs={'model': None, 'xacro_args': None, 'tip': None, 'control': 'ee', 'reward_type': 'sparse',
                     'distance_threshold': 0.05})
