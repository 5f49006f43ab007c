"""robot_ai.ars without ROS: Augmented Random Search on gymnasium's CartPole (the course's policy, within
rl-baselines3-zoo's 50,000 steps), its statistics, its reproducibility, and `python -m robot_ai.cartpole ars`."""
import os
import subprocess
import sys

import gymnasium
import numpy as np
import pytest

from robot_ai import ars
from robot_ai import policies
from robot_ai.cartpole import linear_search
from robot_ai.cartpole.dynamics import CartPoleDynamics


@pytest.mark.parametrize('seed', [0, 1, 2, 3, 4, 5])
def test_ars_solves_cartpole_within_50000_steps(seed):
    result = linear_search.ars_search('CartPole-v1', seed)
    assert result.steps <= 50000
    weights = result.policy.weights[0]
    assert weights.shape == (4,) and result.policy.bias is None      # the course's policy: 4 weights
    lengths = linear_search.evaluate(CartPoleDynamics.of('CartPole-v1'), weights, 100, 500, seed + 100)
    assert lengths.mean() >= 475, lengths.mean()


def test_ars_policy_acts_as_the_course_policy_on_gymnasiums_env():
    result = linear_search.ars_search('CartPole-v1', 7)
    w = result.policy.weights[0]
    env = gymnasium.make('CartPole-v1')
    obs, _ = env.reset(seed=3)
    for _ in range(200):
        assert result.policy.act(obs) == linear_search.act(w, obs)
        obs, _, terminated, truncated, _ = env.step(result.policy.act(obs))
        if terminated or truncated:
            obs, _ = env.reset()


def test_same_seed_same_policy_other_seed_other_policy():
    a, b, c = (linear_search.ars_search('CartPole-v1', s).policy.weights for s in (11, 11, 12))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_running_statistics_pool_groups_and_keep_fixed_ones():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(1000, 5)) * [1, 2, 3, 4, 5] + [10, 20, 30, 40, 50]
    stats = ars.RunningStats(5, groups=[[0, 2]], fixed={4: (1.0, 7.0)})
    for chunk in np.array_split(x, 7):
        stats.add(chunk)
    mean, std = stats.mean_std()
    pooled = np.concatenate((x[:, 0], x[:, 2]))
    np.testing.assert_allclose(mean[[0, 2]], pooled.mean())
    np.testing.assert_allclose(std[[0, 2]], pooled.std())
    np.testing.assert_allclose(mean[[1, 3]], x[:, [1, 3]].mean(axis=0))
    np.testing.assert_allclose(std[[1, 3]], x[:, [1, 3]].std(axis=0))
    assert (mean[4], std[4]) == (1.0, 7.0)


def test_new_statistics_keep_a_policys_actions():
    rng = np.random.default_rng(1)
    w, b = rng.normal(size=(3, 6)), rng.normal(size=3)
    m0, s0, m1, s1 = rng.normal(size=6), rng.uniform(0.5, 2, 6), rng.normal(size=6), rng.uniform(0.5, 2, 6)
    w1, b1 = ars._renormalise(w, b, m0, s0, m1, s1)
    x = rng.normal(size=(20, 6))
    np.testing.assert_allclose((x - m0) / s0 @ w.T + b, (x - m1) / s1 @ w1.T + b1, atol=1e-12)


def test_settings_are_checked():
    with pytest.raises(ars.ARSError, match='top_directions'):
        ars.ARSSettings(directions=4, top_directions=5).check()
    with pytest.raises(ars.ARSError, match='noise'):
        ars.ARSSettings(noise=0).check()


def test_command_line_prints_ars_beside_the_random_search_and_writes_a_linear_policy(tmp_path):
    done = subprocess.run([sys.executable, '-m', 'robot_ai.cartpole', 'ars', '--seed', '2', '--output-dir',
                           str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert 'ARS               average' in out and 'random search     average' in out and 'fewer episodes    ARS' in out
    policy_file = next(f for f in os.listdir(tmp_path) if f.endswith('.npz'))
    policy = policies.load(str(tmp_path / policy_file))
    assert policy.kind == 'linear' and 0 < policy.metadata['figures']['training_steps'] <= 50000
    assert {os.path.splitext(f)[1] for f in os.listdir(tmp_path)} == {'.npz', '.csv', '.png'}
