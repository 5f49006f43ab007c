"""robot_ai.cartpole.q_learning: features = scikit-learn's, the regressors' updates = the course's formulas, the
course's loop and counting, learners in a batch = single runs, reproducibility, limits."""
import math

import numpy as np
import pytest
from sklearn.kernel_approximation import RBFSampler
from sklearn.pipeline import FeatureUnion
from sklearn.preprocessing import StandardScaler

from robot_ai.cartpole import q_learning as ql
from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError


def sklearn_transformer(features, examples):
    """The course's FeatureTransformer built by scikit-learn itself, given our random parameters."""
    scaler = StandardScaler().fit(examples)
    banks = []
    n = features.components
    for i, gamma in enumerate(ql.RBF_GAMMAS):
        rbf = RBFSampler(gamma=gamma, n_components=n).fit(scaler.transform(examples))
        rbf.random_weights_ = features.weights[:, i * n:(i + 1) * n]
        rbf.random_offset_ = features.offsets[i * n:(i + 1) * n]
        banks.append(('rbf%d' % (i + 1), rbf))
    return lambda states: FeatureUnion(banks).transform(scaler.transform(states))


@pytest.mark.parametrize('components', [1000, 37])
def test_features_equal_scikit_learn(components):
    rng = np.random.default_rng(3)
    features = ql.RBFFeatures(rng, components)
    examples = np.random.default_rng(3).random((ql.SCALER_SAMPLES, 4)) * 2 - 1  # the same scaler samples
    reference = sklearn_transformer(features, examples)
    # the scaler is the one scikit-learn fits on those samples
    np.testing.assert_allclose(features.mean, StandardScaler().fit(examples).mean_, rtol=0, atol=1e-15)
    np.testing.assert_allclose(features.scale, StandardScaler().fit(examples).scale_, rtol=0, atol=1e-15)
    # RBFSampler's draws: weights sqrt(2 gamma) N(0, 1), offsets in [0, 2 pi)
    n = components
    for i, gamma in enumerate(ql.RBF_GAMMAS):
        std = features.weights[:, i * n:(i + 1) * n].std()
        assert abs(std / math.sqrt(2 * gamma) - 1) < (0.1 if n > 100 else 0.5)
    assert (features.offsets >= 0).all() and (features.offsets < 2 * np.pi).all()
    # states like an episode's: within the thresholds, and well beyond the scaler's samples for the velocities
    states = np.random.default_rng(4).uniform([-2.4, -3, -0.21, -3.5], [2.4, 3, 0.21, 3.5], (500, 4))
    states = states.astype(np.float32).astype(np.float64)  # the agent sees gymnasium's float32 observation
    want = reference(states)
    assert want.shape == (500, 4 * components)
    np.testing.assert_allclose(features.transform(states), want, rtol=0, atol=1e-6)
    for s in states[:20]:
        np.testing.assert_allclose(features.transform(s), reference(s[None])[0], rtol=0, atol=1e-6)


@pytest.mark.parametrize('regressor, rate, scale', [('tf', 0.2, 1.0), ('sgd', 0.1, 1 / math.sqrt(3))])
def test_regressor_updates_are_the_course_formulas(regressor, rate, scale):
    q = ql.LinearQ(regressor, 3, np.random.default_rng(0))
    w0 = np.random.default_rng(0).standard_normal((2, 3)) * scale  # the initial draw: N(0, 1), or / sqrt(D)
    np.testing.assert_allclose(q.w, w0.astype(np.float32))
    # a hand-checked case
    q.w = np.array([[0.5, -1.0, 2.0], [1.0, 1.0, 1.0]], dtype=np.float32)
    x = np.array([1.0, 2.0, 0.5], dtype=np.float32)
    prediction = q.predict(x)
    np.testing.assert_allclose(prediction, [0.5 - 2.0 + 1.0, 3.5])  # x.w per action
    q.update(x, 0, 10.0, float(prediction[0]))                    # G - x.w = 10.5
    step = rate * 10.5
    np.testing.assert_allclose(q.w[0], [0.5 + step * 1.0, -1.0 + step * 2.0, 2.0 + step * 0.5], rtol=1e-6)
    np.testing.assert_array_equal(q.w[1], [1.0, 1.0, 1.0])       # the other action's regressor is untouched
    # tf: one step of gradient descent, rate 0.1, on the summed squared error (G - x.w)^2
    if regressor == 'tf':
        w = np.array([0.5, -1.0, 2.0])
        gradient = -2 * (10.0 - x.dot(w)) * x
        np.testing.assert_allclose(q.w[0], w - 0.1 * gradient, rtol=1e-6)


def small(episodes=30, components=50, learners=1, env_id='CartPole-v0', **kw):
    return ql.resolve(env_id=env_id, episodes=episodes, components=components, learners=learners, **kw)


def test_the_course_loop_counts_and_epsilon():
    seen = []
    totals, agent = ql.train_one(small(episodes=40), 5, progress=lambda *a: seen.append(a))
    assert [s[0] for s in seen] == list(range(1, 41))
    assert [s[2] for s in seen] == [1 / math.sqrt(n + 1) for n in range(40)]   # eps = 1/sqrt(n+1)
    assert [s[1] for s in seen] == list(totals)
    # the course counts the +1 steps: the last step (-200) is never counted, so a v0 episode totals at most 199
    training = small(episodes=60)._replace(max_steps=5)
    totals, _ = ql.train_one(training, 1)
    assert totals.max() == 4 and (totals <= 4).all()
    # bootstrapping at the time limit makes a truncated episode's last step an ordinary +1
    totals, _ = ql.train_one(training._replace(bootstrap_at_time_limit=True), 1)
    assert totals.max() == 5


def test_the_course_result_for_seed_0():
    """500 episodes of CartPole-v0, the tf regressor: the course printed 198.79 for its run."""
    result = ql.train(ql.resolve(), 0)
    assert result.last100_averages.shape == (1,) and result.total_rewards[0].shape == (500,)
    assert 190 < result.mean_last100 <= 199 and result.ci95_last100 == 0.0
    assert result.total_rewards[0][:20].mean() < 100          # it starts near random actions
    assert 15 < result.baseline_total_reward < 30
    assert result.agents[0].evaluate(CartPoleDynamics.of('CartPole-v0'), 50, 200, 1).mean() > 190  # greedy balances
    assert result.greedy_averages[0] == ql.greedy_average(result.agents[0], result.training, 0) > 190
    assert 'avg reward for last 100 episodes: %.2f' % result.mean_last100 in ql.summary(result)


def test_learner_in_a_batch_is_the_single_run_with_its_seed_and_seeds_repeat():
    training = small(episodes=40, learners=3)
    batch = ql.train(training, 10, workers=2)                  # processes
    inline = ql.train(training, 10, workers=1)                 # this process, one after another
    for k in range(3):
        single, agent = ql.train_one(training, 10 + k)
        assert batch.total_rewards[k].tobytes() == single.tobytes() == inline.total_rewards[k].tobytes()
        for name in ('q_weights', 'feature_weights', 'feature_offsets'):  # every learner's agent comes back whole
            assert getattr(batch.agents[k], name).tobytes() == getattr(agent, name).tobytes()
        # issue 27: every figure of learner k is the single run's with seed + k, its greedy average too
        assert batch.greedy_averages[k] == inline.greedy_averages[k] == ql.greedy_average(agent, training, 10 + k)
    assert list(batch.last100_averages) == [r[-100:].mean() for r in batch.total_rewards]
    assert batch.finished == [0, 1, 2] and batch.learner_seeds == [10, 11, 12]
    best = batch.best_learner()
    assert (batch.greedy_averages[best], batch.last100_averages[best]) == max(
        zip(batch.greedy_averages, batch.last100_averages))
    other = ql.train(training, 11, workers=2)
    assert other.total_rewards[0].tobytes() == batch.total_rewards[1].tobytes()  # seed 11 = learner 1 of seed 10
    assert other.greedy_averages[0] == batch.greedy_averages[1] and other.figures_of(0)['greedy_average'] == \
        batch.figures_of(1)['greedy_average']
    assert ql.train_one(training, -1)[0].tobytes() != ql.train_one(training, 1)[0].tobytes()


def test_progress_and_cancel_in_processes():
    training = small(episodes=400, learners=4)
    seen, asked = [], []
    result = ql.train(training, 0, progress=lambda *a: seen.append(a), workers=2,
                      should_stop=lambda: asked.append(1) or len(seen) > 30)
    assert result.cancelled and len(result.last100_averages) == 0 and result.finished == []
    assert all(len(r) < 400 for r in result.total_rewards) and result.best_learner() == -1
    learner0 = [s[1] for s in seen if s[0] == 0]
    assert learner0 == list(range(1, len(learner0) + 1))       # learner 0's episodes in order


def test_greedy_agent_acts_and_evaluates():
    _, agent = ql.train_one(small(), 0)
    features = ql.new_learner(small(), 0)[1]        # the learner's features, drawn again from its seed
    for state in ([0, 0, 0.1, 0], [0, 0, -0.1, 0]):
        values = features.transform(state).dot(agent.q_weights.T)
        assert agent.act(state) == int(np.argmax(values))
    with pytest.raises(RequestError, match='4 numbers'):
        agent.act([1, 2])
    dynamics = CartPoleDynamics.of('CartPole-v0')
    lengths = agent.evaluate(dynamics, 20, 200, 3)
    # the batched greedy episodes are the single-state greedy episodes
    single = []
    for start in np.random.default_rng(3).uniform(-0.05, 0.05, (20, 4)):
        state = tuple(start)
        for t in range(1, 201):
            state, done = dynamics.step(state, agent.act(np.array(state, np.float32)))
            if done:
                break
        single.append(t)
    assert list(lengths) == single and len(set(single)) > 1
    assert lengths.tobytes() == agent.evaluate(dynamics, 20, 200, 3).tobytes()


def test_running_average_and_interval():
    values = np.arange(250, dtype=float)
    avg = ql.running_average(values)
    assert avg[0] == 0 and avg[9] == 4.5 and avg[249] == values[150:].mean()
    from scipy import stats as scipy_stats  # installed with scikit-learn, a test requirement
    for n in (2, 8, 31, 32, 64):
        sample = np.random.default_rng(n).normal(190, 5, n)
        want = scipy_stats.t.ppf(0.975, n - 1) * sample.std(ddof=1) / math.sqrt(n)
        assert abs(ql.ci95_half_width(sample) - want) < 1e-3 * want
    assert ql.ci95_half_width([198.0]) == 0.0


@pytest.mark.parametrize('kwargs, message', [
    (dict(regressor='adam'), 'regressor must be one of sgd, tf'),
    (dict(env_id='MountainCar-v0'), 'not a CartPole'),
    (dict(env_id='CartPole-v9'), 'unknown'),
    (dict(gamma=1.5), r'gamma must be in \(0, 1\]'),
    (dict(gamma=-0.1), r'gamma must be in \(0, 1\]'),
    (dict(gamma=float('nan')), r'gamma must be in \(0, 1\]'),
    (dict(episodes=10 ** 6), 'episodes must be 1 to 10000'),
    (dict(components=10 ** 6), 'components must be 1 to 10000'),
    (dict(learners=1000), 'learners must be 1 to 64'),
    (dict(learners=64, episodes=10000), 'more than the limit'),
    # the hostile round's 31-minute training: learners x episodes was within the old limit, the features were not
    (dict(env_id='CartPole-v1', learners=64, episodes=1000, components=10000), r'could take [0-9.]+ minutes'),
])
def test_bad_requests_say_what_is_allowed(kwargs, message):
    with pytest.raises(RequestError, match=message):
        ql.resolve(**kwargs)


def test_the_work_limit_counts_steps_and_features():
    """The limit is the longest time a training can take, every episode at the step limit, from the step cost."""
    cores = ql.worker_count(64)
    assert ql.longest_seconds(1, 500, 200, 4000) == pytest.approx(500 * 200 * (9e-6 + 2e-9 * 4000))  # 1.7 s
    assert ql.longest_seconds(16, 4000, 200, 4000) == pytest.approx(16 * 4000 * 200 * 17e-6 / cores)
    if cores >= 2:
        ql.resolve(learners=16, episodes=4000)                  # the node test's long batch is allowed on 2 cores
    ql.resolve(env_id='CartPole-v1', learners=2, episodes=500, components=10000)   # a big single run too
    with pytest.raises(RequestError, match='more than the limit of 2'):
        ql.resolve(env_id='CartPole-v1', learners=8, episodes=2000, components=10000)


def test_defaults_are_the_course():
    t = ql.resolve()
    assert (t.dynamics.env_id, t.episodes, t.gamma, t.regressor, t.components, t.learners, t.max_steps,
            t.bootstrap_at_time_limit) == ('CartPole-v0', 500, 0.99, 'tf', 1000, 1, 200, False)


def test_cancel_keeps_the_learners_that_finished():
    """A training stopped after two of its learners finished returns theirs: averages, seeds, agents."""
    training = small(episodes=60, learners=5)
    done = []
    result = ql.train(training, 3, progress=lambda j, e, r, eps: done.append(j) if e == 60 else None, workers=2,
                      should_stop=lambda: len(done) >= 2)
    assert result.cancelled and len(result.finished) >= 2 and len(result.finished) < 5
    for i, j in enumerate(result.finished):
        single, agent = ql.train_one(training, 3 + j)
        assert result.last100_averages[i] == single[-100:].mean()
        assert result.agents[j].q_weights.tobytes() == agent.q_weights.tobytes()
    assert result.learner_seeds == [3 + j for j in result.finished]
    assert all(result.agents[j] is None for j in range(5) if j not in result.finished)


def test_agent_refuses_states_float32_cannot_hold():
    _, agent = ql.train_one(small(episodes=2), 0)
    assert agent.act([0.0, 0.0, 0.01, 0.0]) in (0, 1)
    with pytest.raises(RequestError, match='float32 range'):
        agent.act([1e308, 0.0, 0.0, 0.0])


def test_a_collapsed_learner_is_named():
    """A learner whose final greedy agent is far below its last-100 average is named as collapsed (issue 27:
    learners with 190-195 last-100 averages and 18-46 greedy averages looked contradictory)."""
    import numpy as np
    training = small(episodes=40, learners=2)
    result = ql.train(training, 0, workers=1)
    result.greedy_averages = np.array([10.0, result.last100_averages[1]])
    result.last100_averages = np.array([190.0, result.last100_averages[1]])
    assert ql.collapsed_learners(result) == [0]
    assert ql.collapse_note(result).startswith('collapsed at the end of training: learner 0 (the final greedy agent')


def test_train_on_from_an_agent_as_load_then_learn():
    """Issue 27: ~train and the CLI's q-learning take an initial policy and continue its agent: the same features,
    its weights as the start, epsilon going on from its episodes; in worker processes as in this one."""
    first = small(episodes=30)
    _, agent = ql.train_one(first, 3)
    on = ql.resolve(episodes=20, components=0, learners=2, start=agent, start_settings=first.settings())
    assert on.components == first.components and on.start_episode == 30 and on.start is agent
    eps = []
    totals, continued = ql.train_one(on, 5, progress=lambda n, total, e: eps.append(e))
    assert eps[0] == ql.epsilon(30) and eps[-1] == ql.epsilon(49)
    assert continued.feature_weights.tobytes() == agent.feature_weights.tobytes()
    assert continued.feature_offsets.tobytes() == agent.feature_offsets.tobytes()
    assert continued.q_weights.tobytes() != agent.q_weights.tobytes()          # trained on
    assert agent.q_weights.tobytes() == ql.train_one(first, 3)[1].q_weights.tobytes()   # the start is not modified
    batch = ql.train(on, 5, workers=2)
    assert batch.total_rewards[0].tobytes() == totals.tobytes()
    assert batch.agents[0].q_weights.tobytes() == continued.q_weights.tobytes()
    with pytest.raises(RequestError, match="components must be the start agent's"):
        ql.resolve(components=first.components + 1, start=agent, start_settings=first.settings())
