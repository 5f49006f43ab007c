"""Physics under the arms: MuJoCo models built from the package's own robot model (physics.model), an arm stepped
in them (physics.sim) and the manipulation envs (physics.env). Beside reach/, above it. No rospy.

``import robot_ai.physics`` registers ``robot_ai/Push-v0`` and ``robot_ai/PickAndPlace-v0`` (50 steps each) with a
vector entry point::

    import gymnasium, robot_ai.physics
    env = gymnasium.make('robot_ai/Push-v0', model='/path/panda.urdf')
    envs = gymnasium.make_vec('robot_ai/PickAndPlace-v0', num_envs=16, model='/path/panda.urdf')
"""
from gymnasium.envs.registration import register, registry

from robot_ai.physics.model import Physics, PhysicsError, build_physics, parse_objects

__all__ = ['Physics', 'PhysicsError', 'build_physics', 'parse_objects']

ENV_IDS = {'push': 'robot_ai/Push-v0', 'pick_and_place': 'robot_ai/PickAndPlace-v0'}

for _task, _id in ENV_IDS.items():
    if _id not in registry:
        register(id=_id, entry_point='robot_ai.physics.env:ManipulationEnv',
                 vector_entry_point='robot_ai.physics.env:ManipulationVectorEnv', max_episode_steps=50,
                 kwargs={'task': _task, 'model': None, 'xacro_args': None, 'tip': None, 'reward_type': 'sparse',
                         'distance_threshold': 0.05})

# registers the learner's policy kind (mlp) and Push-v0 and PickAndPlace-v0 as envs a policy acts in
from robot_ai.physics import policy_files  # noqa: E402,F401
