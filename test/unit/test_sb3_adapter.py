"""robot_ai.sb3's VecEnv semantics without stable-baselines3 installed (it needs torch; the package's venv has
neither): a stand-in for stable_baselines3.common.vec_env.VecEnv with its constructor, then the adapter over
ReachVectorEnv checked against SyncVectorEnv-stepped gymnasium envs as stable-baselines3's DummyVecEnv steps them
(reset in the same step, terminal_observation, TimeLimit.truncated, is_success, compute_reward for HER). The real
stable-baselines3 run is on docs/benchmarks.md (PPO and SAC + HER, by hand in a venv of its own)."""
import sys
import types

import gymnasium
import numpy as np
import pytest

import robot_ai.reach  # noqa: F401  (registers robot_ai/Reach-v0)


class StandInVecEnv:
    """stable_baselines3.common.vec_env.VecEnv's constructor and step(), as 2.x has them."""

    def __init__(self, num_envs, observation_space, action_space):
        self.num_envs = num_envs
        self.observation_space = observation_space
        self.action_space = action_space
        self.reset_infos = [{} for _ in range(num_envs)]

    def step(self, actions):
        self.step_async(actions)
        return self.step_wait()


@pytest.fixture
def sb3(monkeypatch):
    for name in ('stable_baselines3', 'stable_baselines3.common', 'stable_baselines3.common.vec_env'):
        monkeypatch.setitem(sys.modules, name, types.ModuleType(name))
    sys.modules['stable_baselines3.common.vec_env'].VecEnv = StandInVecEnv
    monkeypatch.delitem(sys.modules, 'robot_ai.sb3', raising=False)
    import robot_ai.sb3
    return robot_ai.sb3


def test_steps_as_stable_baselines3s_dummy_vec_env_over_the_single_envs(sb3):
    n = 3
    env = sb3.make_vec_env('robot_ai/Reach-v0', n_envs=n, seed=4, reward_type='dense')
    singles = [gymnasium.make('robot_ai/Reach-v0', reward_type='dense') for _ in range(n)]
    obs = env.reset()
    ref = [s.reset(seed=4 + i)[0] for i, s in enumerate(singles)]
    rng = np.random.default_rng(0)
    dones_seen = 0
    for t in range(120):
        for k in obs:
            np.testing.assert_array_equal(obs[k], np.stack([r[k] for r in ref]))
        actions = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        obs, rewards, dones, infos = env.step(actions)
        for i, s in enumerate(singles):
            o, r, terminated, truncated, info = s.step(actions[i])
            assert rewards[i] == np.float32(r) and dones[i] == (terminated or truncated)
            assert infos[i]['is_success'] == info['is_success']
            if dones[i]:
                dones_seen += 1
                for k in o:
                    np.testing.assert_array_equal(infos[i]['terminal_observation'][k], o[k])
                assert infos[i]['TimeLimit.truncated'] is True
                o, _ = s.reset()
            ref[i] = o
    assert dones_seen == 2 * n          # 50-step episodes, 120 steps
    achieved = np.stack([obs['achieved_goal'][0]] * 4)
    desired = achieved + [[0, 0, 0], [0.06, 0, 0], [0, 0.01, 0], [1, 1, 1]]
    (rewards,) = env.env_method('compute_reward', achieved, desired, [{}] * 4, indices=[0])
    np.testing.assert_allclose(rewards, [0.0, -0.06, -0.01, -np.sqrt(3)])
    assert env.get_attr('num_envs') == [n] * n
