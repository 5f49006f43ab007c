"""robot_ai.cartpole.linear_search: the course's search, its statistics, reproducibility and limits."""
import numpy as np
import pytest

from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError, start_states
from robot_ai.cartpole.linear_search import act, evaluate, random_search, resolve


def test_course_experiment_pinned_bit_for_bit():
    """The 100 x 100 seed-0 search of docs/nodes/cartpole_search.md: these numbers must never move."""
    search = resolve()
    res = random_search(search.dynamics, search.iterations, search.episodes, search.max_steps, 0,
                        search.final_episodes)
    assert [float(w).hex() for w in res.best_weights] == [
        '-0x1.5d91d3fec1b48p-3', '0x1.e038ec4241404p-2', '0x1.b06bad5dfe8dcp-2', '0x1.ba6ddabfb2a7ep-1']
    assert res.best_avg_length == 493.8 and res.final_avg_length == 492.37
    assert res.best_index == 21 and res.baseline_avg_length == 22.35


def test_same_seed_same_result_bit_for_bit_and_batching_invisible():
    dynamics = CartPoleDynamics.of('CartPole-v1')
    a = random_search(dynamics, 30, 20, seed=7, final_episodes=10)
    b = random_search(dynamics, 30, 20, seed=7, final_episodes=10, batch_envs=50)  # 2 candidates a batch
    for field in ('weights', 'avg_lengths', 'best_weights', 'final_lengths'):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field
    assert a.best_avg_length == b.best_avg_length and a.baseline_avg_length == b.baseline_avg_length
    c = random_search(dynamics, 30, 20, seed=8, final_episodes=10)
    assert c.weights.tobytes() != a.weights.tobytes()
    d = random_search(dynamics, 30, 20, seed=-1, final_episodes=10)
    assert d.seed == -1 and d.weights.tobytes() != a.weights.tobytes()


def test_search_selects_like_the_course_loop():
    dynamics = CartPoleDynamics.of('CartPole-v1')
    res = random_search(dynamics, 50, 10, seed=3, final_episodes=20)
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
        lengths = dynamics.episode_lengths(starts[i][None], 500, weights=res.weights[i][None])[0]
        assert lengths.mean() == res.avg_lengths[i]
    assert len(res.final_lengths) == 20 and res.final_avg_length == res.final_lengths.mean()
    assert 15 < res.baseline_avg_length < 30  # random actions last about 22 steps
    assert res.best_avg_length > res.baseline_avg_length


def test_progress_and_cancel():
    dynamics = CartPoleDynamics.of('CartPole-v1')
    seen = []
    res = random_search(dynamics, 20, 5, seed=0, final_episodes=5, progress=lambda *a: seen.append(a),
                        batch_envs=25)
    assert [s[0] for s in seen] == list(range(1, 21))
    assert all(s[2] >= s[1] for s in seen) and seen[-1][2] == res.best_avg_length
    calls = []
    res = random_search(dynamics, 20, 5, seed=0, batch_envs=25,
                        should_stop=lambda: calls.append(1) or len(calls) > 2)
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
    with pytest.raises(RequestError, match=message):
        resolve(**kwargs)


def test_work_limit_message_shows_the_sum():
    """Issue 12: the message showed the same number on both sides ('= 20000000 ... limit of 20000000')."""
    with pytest.raises(RequestError) as e:
        resolve(iterations=100000, episodes=200)
    assert '100000 x 200 + 100 = 20000100 episodes is more than the limit of 20000000' in str(e.value)


def test_defaults_are_the_course_experiment():
    search = resolve()
    assert (search.dynamics.env_id, search.iterations, search.episodes, search.max_steps,
            search.final_episodes) == ('CartPole-v1', 100, 100, 500, 100)
    assert resolve(defaults=dict(iterations=7)).iterations == 7


def test_act_and_evaluate():
    w = np.array([0.1, 0.5, 1.0, 0.9])
    assert act(w, [0, 0, 0.1, 0]) == 1 and act(w, [0, 0, -0.1, 0]) == 0
    for bad in ([1, 2, 3], [0, 0, float('nan'), 0]):
        with pytest.raises(RequestError):
            act(w, bad)
    dynamics = CartPoleDynamics.of('CartPole-v1')
    for bad, message in (([1.0, float('inf'), 0, 0], 'finite'), ([1.0, 2.0], '4 numbers')):
        with pytest.raises(RequestError, match=message):
            evaluate(dynamics, bad, 3, 500, 0)
    lengths = evaluate(dynamics, w, 5, 500, 0)
    assert lengths.shape == (5,) and lengths.tobytes() == evaluate(dynamics, w, 5, 500, 0).tobytes()
