"""robot_ai.envs without a roscore: registration, spaces and arguments (the env connects at its first reset)."""
import gymnasium
import pytest

import robot_ai.envs
from robot_ai.envs import RosCartPoleEnv, RosCartPoleVectorEnv, default_namespaces


@pytest.mark.parametrize('version, steps, threshold', [('v0', 200, 195.0), ('v1', 500, 475.0)])
def test_registered_as_gymnasiums_cartpole_is(version, steps, threshold):
    ours, theirs = gymnasium.spec(f'robot_ai/RosCartPole-{version}'), gymnasium.spec(f'CartPole-{version}')
    assert (ours.max_episode_steps, ours.reward_threshold) == (theirs.max_episode_steps, theirs.reward_threshold)
    assert (ours.max_episode_steps, ours.reward_threshold) == (steps, threshold)
    assert ours.vector_entry_point == 'robot_ai.envs.ros_cartpole:RosCartPoleVectorEnv'
    assert ours.kwargs == {'env_id': f'CartPole-{version}'}
    assert not ours.disable_env_checker     # gymnasium's passive checker stays on: a failed call raises the env's own
    # error until the next reset(), never a TypeError from the checker


def test_make_connects_nothing_and_has_cartpoles_spaces():
    env = gymnasium.make('robot_ai/RosCartPole-v1', robot_ns='/cartpole_0')
    ref = gymnasium.make('CartPole-v1')
    assert env.observation_space == ref.observation_space and env.action_space == ref.action_space
    assert env.unwrapped.link is None          # no master needed until reset()
    env.close()


def test_make_vec_passes_the_step_limit_and_claims_its_sims_at_the_first_reset():
    v0 = gymnasium.make_vec('robot_ai/RosCartPole-v0', num_envs=3)
    assert isinstance(v0, RosCartPoleVectorEnv)
    assert v0.max_episode_steps == 200
    assert v0.robot_namespaces == [None, None, None]        # no sim is held before a reset
    assert default_namespaces(3) == ['/cartpole_0', '/cartpole_1', '/cartpole_2']   # cartpole_gym.launch's
    ref = gymnasium.make_vec('CartPole-v0', num_envs=3, vectorization_mode='sync')
    assert (v0.observation_space, v0.action_space) == (ref.observation_space, ref.action_space)
    v0.close()


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match='CartPole-v0 or CartPole-v1'):
        RosCartPoleEnv('/a', env_id='MountainCar-v0')
    with pytest.raises(ValueError, match='timeout'):
        RosCartPoleEnv('/a', timeout=0)
    with pytest.raises(ValueError, match='need 3 robot namespaces, got 2'):
        RosCartPoleVectorEnv(3, robot_namespaces=['/a', '/b'])
    with pytest.raises(ValueError, match='repeats'):
        RosCartPoleVectorEnv(2, robot_namespaces=['/a', '/a'])
    assert robot_ai.envs.RosCartPoleError.__mro__[1:3] == (robot_ai.envs.RosEnvError, RuntimeError)
