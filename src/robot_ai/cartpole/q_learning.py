"""The course's Q-learning agent with RBF features (its "TensorFlow warm-up"), and many learners at once. No rospy.

The course's q_learning.py, with the warm-up's TensorFlow regressor as the default:

- features: a StandardScaler fitted on 20,000 samples of U[-1, 1]^4, then four banks of random Fourier
  features (scikit-learn's RBFSampler, gamma 0.05, 1.0, 0.5, 0.1, ``components`` each):
  ``x = sqrt(2 / components) * cos(scaled(s) . W + b)``, W ~ sqrt(2 gamma) N(0, 1), b ~ U[0, 2 pi);
  written here as one matrix product and a cosine (the scaler folded into W and b), in float32;
- one linear regressor per action: ``tf`` (w ~ N(0, 1); gradient descent with rate 0.1 on the summed squared
  error, so ``w += 0.2 (G - x.w) x``) or ``sgd`` (q_learning.py's: w ~ N(0, 1) / sqrt(D), ``w += 0.1 (G - x.w) x``);
- epsilon-greedy with eps = 1 / sqrt(n + 1) in episode n; target ``G = r + gamma max_a Q(s', a)``; the course
  sets r = -200 on the last step of every episode (the time limit included) and counts the +1 steps as the
  episode's total reward, so a full CartPole-v0 episode totals 199. ``bootstrap_at_time_limit`` makes a
  time-limit truncation an ordinary step (r = +1, counted), the textbook-correct version.

Episodes are played with ``CartPoleDynamics.step`` (gymnasium's equations, bit for bit). Every random number a
learner uses comes from ``rng_for(seed)`` in a fixed order (scaler samples, RBF banks, regressors, then per
step the epsilon draw and the random action, per episode the start state), so learner k of a batch (seed + k)
is exactly the single run with seed + k, in this process or in a worker process.

    training = resolve(episodes=500)                         # defaults filled in, every value checked
    result = train(training, seed=0)                         # result.total_rewards, result.last100_averages
    result.agent.act(state)                                  # learner 0's greedy policy
"""
import collections
import math
import multiprocessing
import os
import queue
import signal
import time

import numpy as np

from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError, check_state, rng_for, start_states

DEFAULTS = dict(env_id='CartPole-v0', episodes=500, gamma=0.99, regressor='tf', components=1000, learners=1)
REGRESSORS = {'tf': 0.2, 'sgd': 0.1}            # the rate of w += rate (G - x.w) x
RBF_GAMMAS = (0.05, 1.0, 0.5, 0.1)
SCALER_SAMPLES = 20000
FAILURE_REWARD = -200.0
MAX_EPISODES = 10000
MAX_COMPONENTS = 10000           # per bank: 40,000 features, 0.5 MiB of weights per learner
MAX_LEARNERS = 64
MAX_WORK = 64 * 1000             # learners x episodes: about two minutes on 2 cores at the default size
MAX_EVAL_EPISODES = 1000         # greedy episodes stepped together: (1,000 x 4,000) float32 features a step

Training = collections.namedtuple('Training', 'dynamics episodes gamma regressor components learners '
                                              'bootstrap_at_time_limit max_steps')


def resolve(env_id='', episodes=0, gamma=0.0, regressor='', components=0, learners=0,
            bootstrap_at_time_limit=False, defaults=None):
    """A Training with zero/empty fields filled from defaults (DEFAULTS, then the given dict) and every value
    checked; RequestError says what is allowed."""
    d = dict(DEFAULTS, **(defaults or {}))
    dynamics = CartPoleDynamics.of(env_id or d['env_id'])
    episodes = int(episodes or d['episodes'])
    gamma = float(gamma or d['gamma'])
    regressor = regressor or d['regressor']
    components = int(components or d['components'])
    learners = int(learners or d['learners'])
    if regressor not in REGRESSORS:
        raise RequestError('regressor must be one of %s ("" = %s), got %r' % (
            ', '.join(sorted(REGRESSORS)), d['regressor'], regressor))
    if not 0.0 < gamma <= 1.0:  # NaN fails too
        raise RequestError('gamma must be in (0, 1] (0 = %g), got %s' % (d['gamma'], gamma))
    for name, value, limit in (('episodes', episodes, MAX_EPISODES), ('components', components, MAX_COMPONENTS),
                               ('learners', learners, MAX_LEARNERS)):
        if not 1 <= value <= limit:
            raise RequestError('%s must be 1 to %d (0 = %d), got %d' % (name, limit, d[name], value))
    if learners * episodes > MAX_WORK:
        raise RequestError('learners x episodes = %d is more than the limit of %d; use fewer learners or '
                           'episodes' % (learners * episodes, MAX_WORK))
    return Training(dynamics, episodes, gamma, regressor, components, learners, bool(bootstrap_at_time_limit),
                    dynamics.max_episode_steps)


class RBFFeatures(object):
    """The course's FeatureTransformer: StandardScaler, then a union of RBFSamplers, as one affine map and a cosine.

    mean, scale: the scaler's; weights (4, D), offsets (D,): the RBF banks side by side (scikit-learn's
    random_weights_ and random_offset_); D = len(gammas) * components."""

    def __init__(self, rng, components, gammas=RBF_GAMMAS, samples=SCALER_SAMPLES):
        examples = rng.random((samples, 4)) * 2 - 1          # the course: np.random.random((20000, 4))*2 - 1
        self.mean = examples.mean(axis=0)
        self.scale = examples.std(axis=0)                    # StandardScaler: population std
        banks = [(math.sqrt(2.0 * g) * rng.normal(size=(4, components)), rng.uniform(0, 2 * np.pi, components))
                 for g in gammas]                            # RBFSampler.fit draws its weights, then its offsets
        self.weights = np.hstack([w for w, _ in banks])
        self.offsets = np.hstack([b for _, b in banks])
        self.components = components
        self.dimensions = self.weights.shape[1]
        self.amplitude = math.sqrt(2.0) / math.sqrt(components)
        # ((s - mean) / scale) . W + b  ==  s . (W / scale) + (b - (mean / scale) . W)
        folded_weights = self.weights / self.scale[:, None]
        folded_offsets = self.offsets - (self.mean / self.scale).dot(self.weights)
        self.folded_weights32 = folded_weights.astype(np.float32)
        self.folded_offsets32 = folded_offsets.astype(np.float32)

    def transform(self, states):
        """Features (n, D) float32 of states (n, 4), or (D,) of one state (4,): the agent sees gymnasium's
        float32 observation."""
        z = np.asarray(states, dtype=np.float32).dot(self.folded_weights32)
        z += self.folded_offsets32
        np.cos(z, out=z)
        z *= np.float32(self.amplitude)
        return z


class LinearQ(object):
    """One linear regressor per action, Q(s, a) = x(s).w[a], trained one sample at a time.

    'tf': the warm-up's TensorFlow regressor: w ~ N(0, 1); gradient descent with rate 0.1 on the summed
    squared error (G - x.w)^2, whose gradient is -2 (G - x.w) x: w += 0.2 (G - x.w) x.
    'sgd': q_learning.py's numpy regressor: w ~ N(0, 1) / sqrt(D), w += 0.1 (G - x.w) x."""

    def __init__(self, regressor, dimensions, rng, actions=2):
        w = rng.standard_normal((actions, dimensions))
        if regressor == 'sgd':
            w /= math.sqrt(dimensions)
        self.w = w.astype(np.float32)
        self.rate = REGRESSORS[regressor]

    def predict(self, x):
        """Q of every action (actions,) for features x (D,), or (n, actions) for x (n, D)."""
        return x.dot(self.w.T)

    def update(self, x, action, target, prediction):
        """w[action] += rate (target - prediction) x, where prediction is x.w[action] before the update."""
        self.w[action] += np.float32(self.rate * (target - prediction)) * x


class Agent(object):
    """A trained learner's greedy policy: features and regressors."""

    def __init__(self, features, q):
        self.features, self.q = features, q

    def act(self, state):
        """The greedy action (0 or 1) for one state; ties go to action 0, as numpy's argmax."""
        values = self.q.predict(self.features.transform(check_state(state)))
        return int(values[1] > values[0])

    def push_right(self, observations):
        """The greedy policy for CartPoleDynamics.episode_lengths: observations (4, n) -> (n,) bool."""
        values = self.q.predict(self.features.transform(observations.T))
        return values[:, 1] > values[:, 0]

    def evaluate(self, dynamics, episodes, max_steps, seed):
        """Lengths (episodes,) of greedy episodes, start states from rng_for(seed), stepped together."""
        starts = start_states(rng_for(seed), 1, episodes)
        return dynamics.episode_lengths(starts, max_steps, policy=self.push_right)[0]


def new_learner(training, seed):
    """(rng, features, regressors) of a learner before its first episode: its random parameters, drawn from
    rng_for(seed) in the fixed order every run of that seed draws them."""
    rng = rng_for(seed)
    features = RBFFeatures(rng, training.components)
    return rng, features, LinearQ(training.regressor, features.dimensions, rng)


def train_one(training, seed, progress=None, should_stop=None):
    """One learner, the course's loop. Returns (total rewards (episodes played,), Agent).

    progress(episode, total_reward, epsilon) after every episode (1-based); should_stop() is asked before
    every episode, and a learner it stops returns the episodes played so far."""
    rng, features, q = new_learner(training, seed)
    step, gamma, max_steps = training.dynamics.step, training.gamma, training.max_steps
    bootstrap = training.bootstrap_at_time_limit
    totals = np.zeros(training.episodes)
    for n in range(training.episodes):
        if should_stop is not None and should_stop():
            return totals[:n], Agent(features, q)
        eps = 1.0 / math.sqrt(n + 1)
        state = tuple(float(v) for v in rng.uniform(-0.05, 0.05, 4))  # gymnasium's reset distribution
        x = features.transform(state)
        values = q.predict(x)
        total = 0
        for t in range(1, max_steps + 1):
            if rng.random() < eps:
                action = int(rng.integers(2))
            else:
                action = int(values[1] > values[0])
            state, terminated = step(state, action)
            failed = terminated or (t == max_steps and not bootstrap)
            reward = FAILURE_REWARD if failed else 1.0
            next_x = features.transform(state)
            next_values = q.predict(next_x)
            target = reward + gamma * float(next_values.max())  # the course bootstraps from s' on every step
            q.update(x, action, target, float(values[action]))
            if not failed:
                total += 1
            if terminated or t == max_steps:
                break
            x = next_x
            values = q.predict(x)  # Q(s') after the update, for the next action
        totals[n] = total
        if progress is not None:
            progress(n + 1, total, eps)
    return totals, Agent(features, q)


def running_average(values, window=100):
    """Average of the last `window` values (fewer at the start) at every index."""
    c = np.concatenate(([0.0], np.cumsum(values, dtype=np.float64)))
    i = np.arange(1, len(values) + 1)
    return (c[i] - c[np.maximum(0, i - window)]) / np.minimum(i, window)


# Student's t, 97.5% quantile, for 1..30 degrees of freedom (two-sided 95% interval)
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
         2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)


def ci95_half_width(values):
    """Half-width of the 95% confidence interval of the mean of values (Student's t); 0 for one value."""
    n = len(values)
    if n < 2:
        return 0.0
    df = n - 1
    if df <= len(_T975):
        t = _T975[df - 1]
    else:  # Cornish-Fisher expansion around the normal quantile: within 1e-4 of t for df > 30
        z = 1.959964
        t = z + (z ** 3 + z) / (4 * df) + (5 * z ** 5 + 16 * z ** 3 + 3 * z) / (96 * df ** 2)
    return float(t * np.std(values, ddof=1) / math.sqrt(n))


class TrainingResult(object):
    """K learners' total rewards (K, episodes played), their last-100 averages, learner 0's agent."""
    __slots__ = ('env_id', 'seed', 'training', 'total_rewards', 'last100_averages', 'mean_last100', 'ci95_last100',
                 'agent', 'baseline_total_reward', 'elapsed', 'cancelled')

    def __init__(self, **kw):
        for k in self.__slots__:
            setattr(self, k, kw.get(k))


def summary(result):
    """One line of what a training gave, ending as the course's script does."""
    t = result.training
    head = '%s, %s regressor, %d x %d RBF features, gamma %g, %d episodes%s' % (
        result.env_id, t.regressor, len(RBF_GAMMAS), t.components, t.gamma, t.episodes,
        ', bootstrap at the time limit' if t.bootstrap_at_time_limit else '')
    if len(result.last100_averages) == 1:
        return '%s, seed %d: avg reward for last 100 episodes: %.2f' % (head, result.seed, result.mean_last100)
    return '%s, %d learners (seeds %d to %d): avg reward for last 100 episodes: %.2f ± %.2f (95%%), from %.2f to %.2f' % (
        head, len(result.last100_averages), result.seed, result.seed + len(result.last100_averages) - 1,
        result.mean_last100, result.ci95_last100, result.last100_averages.min(), result.last100_averages.max())


def random_baseline(training, episodes=1000):
    """The average total reward of random actions, counted as the training counts it (its own fixed draws)."""
    rng = np.random.default_rng(0)
    lengths = training.dynamics.episode_lengths(start_states(rng, 1, episodes), training.max_steps, rng=rng)[0]
    full = lengths == training.max_steps
    return float(np.where(full & training.bootstrap_at_time_limit, lengths, lengths - 1).mean())


def worker_count(learners):
    """Processes for a batch: one per core this process may use, at most one per learner."""
    return max(1, min(learners, len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity')
                      else os.cpu_count() or 1))


def train(training, seed=0, progress=None, should_stop=None, workers=None):
    """Train training.learners independent learners, seeds seed, seed + 1, ...; return a TrainingResult.

    progress(learner, episode, total_reward, epsilon) after every episode of every learner (learner 0's in
    order); should_stop() is asked often, and a training it stops returns cancelled=True with the episodes
    played. More than one learner: `workers` processes (default: one per core) share them."""
    t0 = time.time()
    k = training.learners
    workers = worker_count(k) if workers is None else max(1, min(workers, k))
    if workers == 1:
        rewards, agent, cancelled = [], None, False
        for j in range(k):
            report = None if progress is None else (lambda e, r, eps, j=j: progress(j, e, r, eps))
            totals, a = train_one(training, seed + j, report, should_stop)
            rewards.append(totals)
            agent = agent or a
            if len(totals) < training.episodes:
                cancelled = True
                break
    else:
        rewards, agent, cancelled = _train_in_processes(training, seed, workers, progress, should_stop)
    return _result(training, seed, rewards, agent, cancelled, time.time() - t0)


def _result(training, seed, rewards, agent, cancelled, elapsed):
    last100 = np.array([r[-100:].mean() for r in rewards]) if not cancelled else np.zeros(0)  # all complete
    return TrainingResult(
        env_id=training.dynamics.env_id, seed=seed, training=training,
        total_rewards=rewards, last100_averages=last100,
        mean_last100=float(last100.mean()) if len(last100) else 0.0,
        ci95_last100=ci95_half_width(last100) if len(last100) else 0.0,
        agent=agent, baseline_total_reward=random_baseline(training), elapsed=elapsed, cancelled=cancelled)


# ------------------------------------------------------------------------------------------ worker processes
def _context():
    """fork: a worker needs nothing but this module's objects, and is not a fresh interpreter that would run the
    caller's main script again (spawn and forkserver do, and a ROS node's script then fails to import)."""
    return multiprocessing.get_context('fork')


def _worker(training, seed, next_learner, results, stop):
    """Train the learners next_learner hands out until none is left; report every episode and each learner's end.

    A forked worker inherits its parent's signal handlers (a ROS node's would only flag a shutdown): it takes
    the default ones, so a Ctrl-C or a SIGTERM ends it at once, quietly; the parent then ends the training."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    while True:
        with next_learner.get_lock():  # a shared counter: a queue's items may not have arrived yet
            j = next_learner.value
            next_learner.value += 1
        if j >= training.learners:
            return
        totals, agent = train_one(training, seed + j,
                                  lambda e, r, eps: results.put(('episode', j, e, r, eps)), stop.is_set)
        results.put(('done', j, totals, agent.q.w if j == 0 else None))


def _stopping(should_stop, grace=1.0):
    """Whether should_stop() says yes within grace seconds: the signal that ended the workers may reach the
    caller a moment later."""
    deadline = time.time() + grace
    while should_stop is not None and time.time() < deadline:
        if should_stop():
            return True
        time.sleep(0.05)
    return False


def _train_in_processes(training, seed, workers, progress, should_stop):
    ctx = _context()
    next_learner, results, stop = ctx.Value('l', 0), ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=_worker, args=(training, seed, next_learner, results, stop), daemon=True)
             for _ in range(workers)]
    for p in procs:
        p.start()
    rewards, weights0, cancelled = {}, None, False
    try:
        while len(rewards) < training.learners:
            if should_stop is not None and not stop.is_set() and should_stop():
                stop.set()
                cancelled = True
            try:
                msg = results.get(timeout=0.1)
            except queue.Empty:
                if not any(p.is_alive() for p in procs) and results.empty():
                    if stop.is_set() or _stopping(should_stop):  # a Ctrl-C ends the workers and the caller
                        cancelled = True
                        break
                    raise RuntimeError('the learner processes ended before their learners (%d of %d done)'
                                       % (len(rewards), training.learners))
                continue
            if msg[0] == 'episode':
                if progress is not None:
                    progress(*msg[1:])
            else:
                rewards[msg[1]] = msg[2]
                if msg[3] is not None:
                    weights0 = msg[3]
    finally:
        stop.set()
        for p in procs:
            p.join(5)
            if p.is_alive():
                p.terminate()
    ordered = [rewards.get(j, np.zeros(0)) for j in range(training.learners)]
    cancelled = cancelled or any(len(r) < training.episodes for r in ordered)
    if weights0 is None:
        return ordered, None, cancelled
    # learner 0's agent, rebuilt here from its seed (the same draws) and the weights it learned
    _, features, q = new_learner(training, seed)
    q.w = weights0
    return ordered, Agent(features, q), cancelled
