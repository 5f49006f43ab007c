"""robot_ai.cartpole.dynamics against gymnasium's own single CartPole env."""
import gymnasium as gym
import numpy as np
import pytest

from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError, check_state, rng_for, start_states

GOOD_WEIGHTS = [[0.1, 0.5, 1.0, 0.9], [0.0, 0.3, 0.9, 0.6], [-0.1, 0.4, 0.8, 0.7], [0.2, 0.2, 0.9, 0.4],
                [0.05, 0.6, 0.95, 0.8]]  # policies that balance: long episodes are compared too


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
def test_batched_episode_lengths_equal_gymnasium(env_id, max_steps):
    dynamics = CartPoleDynamics.of(env_id)
    max_steps = max_steps or dynamics.max_episode_steps
    rng = np.random.default_rng(42)
    weights = rng.uniform(-1, 1, (40, 4))
    weights[:5] = GOOD_WEIGHTS
    starts = start_states(rng, 40, 3)
    got = dynamics.episode_lengths(starts, max_steps, weights=weights)
    want = np.array([[gym_episode_length(env_id, starts[c, e], weights[c], max_steps) for e in range(3)]
                     for c in range(40)])
    np.testing.assert_array_equal(got, want)
    assert (want == max_steps).any() and (want < 30).any()  # both short and full-length episodes were compared
    assert dynamics.max_episode_steps == {'CartPole-v0': 200, 'CartPole-v1': 500}[env_id]


def test_single_step_equals_gymnasium_bit_for_bit():
    """The single-state step (the Q-learning agent's) gives gymnasium's states exactly, and its terminations."""
    dynamics = CartPoleDynamics.of('CartPole-v1')
    env = gym.make('CartPole-v1').unwrapped
    rng = np.random.default_rng(5)
    steps = terminations = 0
    for episode in range(60):
        env.reset(seed=episode)
        state = tuple(float(v) for v in env.state)
        for _ in range(500):
            action = int(rng.integers(2)) if episode % 2 else int(state[2] + 0.3 * state[3] > 0)
            _, _, terminated, _, _ = env.step(action)
            state, done = dynamics.step(state, action)
            assert np.array(state).tobytes() == env.state.tobytes()
            assert done == terminated
            steps += 1
            if done:
                terminations += 1
                break
    env.close()
    assert steps > 10000 and terminations >= 30  # long balanced episodes and every random one ending


def test_policy_callable_and_random_actions():
    dynamics = CartPoleDynamics.of('CartPole-v1')
    starts = start_states(np.random.default_rng(1), 2, 5)
    w = np.array([GOOD_WEIGHTS[0], GOOD_WEIGHTS[1]])
    by_weights = dynamics.episode_lengths(starts, 500, weights=w)
    # the same policy as a function of the float32 observations of the live episodes, one candidate at a time
    for c in range(2):
        got = dynamics.episode_lengths(starts[c:c + 1], 500, policy=lambda obs: w[c].dot(obs) > 0)
        np.testing.assert_array_equal(got[0], by_weights[c])
    lengths = dynamics.episode_lengths(start_states(np.random.default_rng(2), 1, 2000), 500,
                                       rng=np.random.default_rng(3))
    assert 20 < lengths.mean() < 25  # random actions last about 22 steps (the course's Gym exercise)


def test_built_once_per_env_id_and_bad_env_ids():
    assert CartPoleDynamics.of('CartPole-v0') is CartPoleDynamics.of('CartPole-v0')
    assert CartPoleDynamics.of('CartPole-v0') is not CartPoleDynamics.of('CartPole-v1')
    with pytest.raises(RequestError, match='unknown'):
        CartPoleDynamics.of('CartPole-v9')
    with pytest.raises(RequestError, match='not a CartPole'):
        CartPoleDynamics.of('MountainCar-v0')


def test_start_states_check_state_and_seeds():
    s = start_states(np.random.default_rng(0), 3, 7)
    assert s.shape == (3, 7, 4) and (np.abs(s) <= 0.05).all()
    assert check_state([0, 1, 2, 3]).tolist() == [0, 1, 2, 3]
    for bad, message in (([1, 2, 3], '4 numbers'), ([0, 0, float('nan'), 0], r'finite numbers, got \[0.0, 0.0, nan')):
        with pytest.raises(RequestError, match=message):
            check_state(bad)
    assert rng_for(7).random() == np.random.default_rng(7).random()
    assert rng_for(-1).random() == np.random.default_rng(2 ** 64 - 1).random()


def test_step_force_is_the_action_step_at_force_mag_and_any_force_otherwise():
    """A ROS robot's cart_force (any newtons) goes through the same equations; +-force_mag is gymnasium's step."""
    import gymnasium as gym
    dyn = CartPoleDynamics.of('CartPole-v1')
    rng = np.random.default_rng(2)
    env = gym.make('CartPole-v1').unwrapped
    env.reset(seed=0)
    for _ in range(200):
        state = tuple(float(v) for v in rng.uniform(-0.2, 0.2, 4))
        for action in (0, 1):
            want = dyn.step(state, action)
            assert dyn.step_force(state, dyn.force_mag if action else -dyn.force_mag) == want
            env.state = np.array(state)
            _, _, terminated, _, _ = env.step(action)
            assert want == (tuple(float(v) for v in env.state), terminated)
    # no force: the pole falls the way it leans; a larger push accelerates the cart more
    (x, x_dot, theta, theta_dot), _ = dyn.step_force((0.0, 0.0, 0.05, 0.0), 0.0)
    assert theta_dot > 0 and x_dot < 0   # the cart recoils as the pole falls toward +x
    assert dyn.step_force((0, 0, 0, 0), 25.0)[0][1] > dyn.step_force((0, 0, 0, 0), 10.0)[0][1] > 0


def test_termination_says_why():
    dyn = CartPoleDynamics.of('CartPole-v1')
    assert dyn.termination(0.0, 0.0) == ''
    assert dyn.termination(0.0, 0.21) == 'pole fell' and dyn.termination(0.0, -0.21) == 'pole fell'
    assert dyn.termination(2.41, 0.0) == 'cart left the rail' and dyn.termination(-2.41, 0.0) == 'cart left the rail'
    assert dyn.termination(2.4, 0.2094) == ''   # gymnasium's thresholds are strict


def test_one_float32_rule_for_both_kinds_of_policy():
    """Issue 27: cartpole_search's ~act took a state of 1.0e+39 (beyond float32, the observation type) and
    cartpole_q_learning's refused it: one rule, one message."""
    from robot_ai.cartpole import linear_search, q_learning
    from robot_ai.cartpole.dynamics import RequestError
    agent = q_learning.train_one(q_learning.resolve(episodes=2, components=5), 0)[1]
    messages = set()
    for act in (lambda s: linear_search.act(np.ones(4), s), agent.act):
        assert act([0.0, 0.0, 0.01, 0.0]) in (0, 1)
        assert act([3.4e38, 0.0, 0.0, 0.0]) in (0, 1)
        with pytest.raises(RequestError) as e:
            act([1.0e39, 0.0, 0.0, 0.0])
        messages.add(str(e.value))
    assert len(messages) == 1 and 'float32' in messages.pop()
