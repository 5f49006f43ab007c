"""robot_ai.cartpole_search against gymnasium's own single CartPole env, and the search's statistics."""
import os

import gymnasium as gym
import numpy as np
import pytest

from robot_ai.cartpole_search import (CartPoleModel, SearchError, act, evaluate, plot_learning_curve,
                                      random_search, record_video, resolve, start_states)


def gym_episode_length(env_id, start, w, max_steps):
    """The course's loop on gymnasium's env, from a given start state."""
    env = gym.make(env_id, max_episode_steps=max_steps)
    env.reset(seed=0)
    env.unwrapped.state = np.array(start, dtype=np.float64)
    obs = np.array(start, dtype=np.float32)
    steps = 0
    while True:
        obs, _, terminated, truncated, _ = env.step(1 if obs.dot(w) > 0 else 0)
        steps += 1
        if terminated or truncated:
            env.close()
            return steps


@pytest.mark.parametrize('env_id, max_steps', [('CartPole-v1', None), ('CartPole-v0', None), ('CartPole-v1', 77)])
def test_episode_lengths_equal_gymnasium(env_id, max_steps):
    model = CartPoleModel(env_id)
    max_steps = max_steps or model.max_episode_steps
    rng = np.random.default_rng(42)
    weights = rng.uniform(-1, 1, (40, 4))
    weights[:5] = [[0.1, 0.5, 1.0, 0.9], [0.0, 0.3, 0.9, 0.6], [-0.1, 0.4, 0.8, 0.7], [0.2, 0.2, 0.9, 0.4],
                   [0.05, 0.6, 0.95, 0.8]]  # policies that balance: long episodes are compared too
    starts = start_states(rng, 40, 3)
    got = model.episode_lengths(weights, starts, max_steps)
    want = np.array([[gym_episode_length(env_id, starts[c, e], weights[c], max_steps) for e in range(3)]
                     for c in range(40)])
    np.testing.assert_array_equal(got, want)
    assert (want == max_steps).any() and (want < 30).any()  # both short and full-length episodes were compared
    assert model.max_episode_steps == {'CartPole-v0': 200, 'CartPole-v1': 500}[env_id]


def test_same_seed_same_result_bit_for_bit_and_batching_invisible():
    model = CartPoleModel('CartPole-v1')
    a = random_search(model, 30, 20, seed=7, final_episodes=10)
    b = random_search(model, 30, 20, seed=7, final_episodes=10, batch_envs=50)  # 2 candidates a batch
    for field in ('weights', 'avg_lengths', 'best_weights', 'final_lengths'):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field
    assert a.best_avg_length == b.best_avg_length and a.baseline_avg_length == b.baseline_avg_length
    c = random_search(model, 30, 20, seed=8, final_episodes=10)
    assert c.weights.tobytes() != a.weights.tobytes()


def test_search_selects_like_the_course_loop():
    model = CartPoleModel('CartPole-v1')
    res = random_search(model, 50, 10, seed=3, final_episodes=20)
    # the course: weights in [-1, 1]^4; best = the first candidate with the highest average
    assert res.weights.shape == (50, 4) and (np.abs(res.weights) <= 1).all()
    assert res.best_index == int(np.argmax(res.avg_lengths))
    assert res.best_avg_length == res.avg_lengths.max()
    np.testing.assert_array_equal(res.best_weights, res.weights[res.best_index])
    # each candidate's average is the mean of its own episodes, replayed one candidate at a time
    rng = np.random.default_rng(3)
    rng.uniform(-1, 1, (50, 4))
    starts = start_states(rng, 50, 10)
    for i in (0, 17, res.best_index):
        lengths = model.episode_lengths(res.weights[i][None], starts[i][None], 500)[0]
        assert lengths.mean() == res.avg_lengths[i]
    assert len(res.final_lengths) == 20 and res.final_avg_length == res.final_lengths.mean()
    # random actions last about 22 steps in CartPole (the course's Gym exercise)
    assert 15 < res.baseline_avg_length < 30
    assert res.best_avg_length > res.baseline_avg_length


def test_progress_and_cancel():
    model = CartPoleModel('CartPole-v1')
    seen = []
    res = random_search(model, 20, 5, seed=0, final_episodes=5, progress=lambda *a: seen.append(a), batch_envs=25)
    assert [s[0] for s in seen] == list(range(1, 21))
    assert all(s[2] >= s[1] for s in seen) and seen[-1][2] == res.best_avg_length
    calls = []
    res = random_search(model, 20, 5, seed=0, batch_envs=25, should_stop=lambda: calls.append(1) or len(calls) > 2)
    assert res.cancelled and len(res.avg_lengths) == 10  # two batches of 5 candidates before the stop


@pytest.mark.parametrize('kwargs, message', [
    (dict(env_id='CartPole-v9'), 'unknown'),
    (dict(env_id='MountainCar-v0'), 'not a CartPole'),
    (dict(iterations=200000), 'iterations must be 1 to'),
    (dict(episodes=20000), 'episodes must be 1 to'),
    (dict(max_steps=501), "limit 500"),
    (dict(env_id='CartPole-v0', max_steps=201), "limit 200"),
    (dict(iterations=100000, episodes=1000), 'more than the limit'),
])
def test_bad_requests_say_what_is_allowed(kwargs, message):
    with pytest.raises(SearchError, match=message):
        resolve(**kwargs)


def test_defaults_are_the_course_experiment():
    model, iterations, episodes, max_steps, final = resolve()
    assert (model.env_id, iterations, episodes, max_steps, final) == ('CartPole-v1', 100, 100, 500, 100)


def test_act_and_evaluate():
    w = np.array([0.1, 0.5, 1.0, 0.9])
    assert act(w, [0, 0, 0.1, 0]) == 1 and act(w, [0, 0, -0.1, 0]) == 0
    for bad in ([1, 2, 3], [0, 0, float('nan'), 0]):
        with pytest.raises(SearchError):
            act(w, bad)
    with pytest.raises(SearchError):
        evaluate(CartPoleModel(), [1.0, float('inf'), 0, 0], 3, 500, 0)
    lengths = evaluate(CartPoleModel(), w, 5, 500, 0)
    assert lengths.shape == (5,) and lengths.tobytes() == evaluate(CartPoleModel(), w, 5, 500, 0).tobytes()


def test_plot_and_video(tmp_path):
    model = CartPoleModel('CartPole-v1')
    res = random_search(model, 20, 5, seed=1, final_episodes=5)
    png = plot_learning_curve(res, str(tmp_path / 'curve.png'))
    with open(png, 'rb') as f:
        assert f.read(8) == b'\x89PNG\r\n\x1a\n'
    path, steps = record_video('CartPole-v1', res.best_weights, 40, 1, str(tmp_path / 'best.mp4'))
    assert os.path.getsize(path) > 1000 and 1 <= steps <= 40
    with open(path, 'rb') as f:
        assert b'ftyp' in f.read(64)
    assert sorted(os.listdir(str(tmp_path))) == ['best.mp4', 'curve.png']  # the temporary folder is gone


def test_plot_worker_process(tmp_path):
    """The node's plot process: one JSON job a line; a bad job is reported and the next one still drawn."""
    import subprocess
    import sys
    from robot_ai.plot_worker import job_of
    res = random_search(CartPoleModel('CartPole-v1'), 10, 5, seed=2, final_episodes=5)
    good = str(tmp_path / 'curve.png')
    proc = subprocess.run([sys.executable, '-m', 'robot_ai.plot_worker'], input='{"not": "a job"}\n'
                          + job_of(res, good), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0
    assert 'failed' in proc.stderr and proc.stdout.strip() == 'written %s' % good
    with open(good, 'rb') as f:
        assert f.read(8) == b'\x89PNG\r\n\x1a\n'
