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

When a learner finishes, its greedy agent plays GREEDY_EPISODES greedy episodes whose start states come from the
learner's own seed, so that every figure of learner k equals the single run's with seed + k. Two figures say how
a learner did, and they answer different questions: its last-100 average is the exploring agent's total reward
over its last 100 training episodes (epsilon-greedy, learning as it goes); its greedy average is how long the
final agent, acting greedily and learning no more, keeps the pole up. A learner whose greedy average is far below
its last-100 average collapsed at the end of its training (its last updates undid what it had learnt):

    training = resolve(episodes=500, learners=4)             # defaults filled in, every value checked
    result = train(training, seed=0)                         # result.total_rewards, result.last100_averages
    best = result.best_learner()                             # greedy average first, then last-100 average
    result.agents[best].act(state)                           # its greedy policy
"""
import math
import os
import select
import signal
import subprocess
import time
from dataclasses import dataclass, field
from typing import Callable, ClassVar, NamedTuple

import numpy as np

from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError, check_observation, rng_for, start_states
from robot_ai.child_process import FrameReader, process_stat, spawn, write_frame
from robot_ai.text import counted

DEFAULTS = dict(env_id='CartPole-v0', episodes=500, gamma=0.99, regressor='tf', components=1000, learners=1)
REGRESSORS = {'tf': 0.2, 'sgd': 0.1}            # the rate of w += rate (G - x.w) x
RBF_GAMMAS = (0.05, 1.0, 0.5, 0.1)
SCALER_SAMPLES = 20000
FAILURE_REWARD = -200.0
MAX_EPISODES = 10000
MAX_COMPONENTS = 10000           # per bank: 40,000 features, 0.5 MiB of weights per learner
MAX_LEARNERS = 64
# The work limit: a training's longest possible time (every episode lasting the step limit), from the cost of a step
# measured on this project's 2-core machine: 9 us plus 2 ns per feature (17 us at the default 4,000 features, 88 us
# at the largest, 40,000), spread over the cores that train it. A learner's early episodes are short, so a training
# takes less. A service call cannot be cancelled: this keeps one from holding the node for long.
STEP_SECONDS = 9e-6
FEATURE_SECONDS = 2e-9
MAX_SECONDS = 120.0
MAX_EVAL_EPISODES = 1000         # greedy episodes stepped together: (1,000 x 4,000) float32 features a step
GREEDY_EPISODES = 100            # greedy episodes that compare the learners when a training ends
CHUNK_FEATURES = 4 * 1024 * 1024  # float32 features computed at once by a batched policy: 16 MiB, whatever the batch


class Training(NamedTuple):
    dynamics: CartPoleDynamics
    episodes: int
    gamma: float
    regressor: str
    components: int
    learners: int
    bootstrap_at_time_limit: bool
    max_steps: int
    start: 'Agent | None' = None      # an agent to train on (its features and weights), None: a new one
    start_episode: int = 0            # episodes the start agent has played: epsilon goes on from there
    started_from: str = ''            # the policy file the start agent came from

    def settings(self) -> dict:
        """The settings that made a training, as plain values (a policy file's metadata keeps them; the start
        agent itself is not among them)."""
        return dict(env_id=self.dynamics.env_id, episodes=self.episodes, gamma=self.gamma, regressor=self.regressor,
                    components=self.components, learners=self.learners,
                    bootstrap_at_time_limit=self.bootstrap_at_time_limit, max_steps=self.max_steps,
                    start_episode=self.start_episode, **({'started_from': self.started_from} if self.started_from
                                                          else {}))

    def origin(self) -> str:
        """'' or the words a policy file's source adds for a training that went on from another file."""
        return f', trained on from {self.started_from}' if self.started_from else ''


def resolve(env_id: str = '', episodes: int = 0, gamma: float = 0.0, regressor: str = '', components: int = 0,
            learners: int = 0, bootstrap_at_time_limit: bool = False, defaults: dict | None = None,
            start: 'Agent | None' = None, start_settings: dict | None = None, started_from: str = '') -> Training:
    """A Training with zero/empty fields filled from defaults (DEFAULTS, then the given dict) and every value
    checked; RequestError says what is allowed.

    start: an agent to train on, as stable-baselines3's load() then learn() (its features and weights are the
    start of every learner; the learners' seeds drive only their exploration); start_settings: the settings it was
    trained with (a policy file's), whose env, regressor and components are the defaults then, and whose episodes
    (plus its own start_episode) are where epsilon goes on from; started_from: the file it came from."""
    d = dict(DEFAULTS, **(defaults or {}))
    start_episode = 0
    if start is not None:
        s = start_settings or {}
        start_components = start.q_weights.shape[1] // len(RBF_GAMMAS)
        if start.q_weights.shape[1] != start_components * len(RBF_GAMMAS):
            raise RequestError(f'the start agent has {start.q_weights.shape[1]} features: not {len(RBF_GAMMAS)} '
                               'banks of RBF features')
        if components and int(components) != start_components:
            raise RequestError(f'components must be the start agent\'s {start_components} (or 0), got {components}')
        d.update({k: s[k] for k in ('env_id', 'regressor') if isinstance(s.get(k), str) and s[k]})
        d['components'] = start_components
        start_episode = sum(int(s.get(k) or 0) for k in ('episodes', 'start_episode')
                            if isinstance(s.get(k), int) and not isinstance(s.get(k), bool))
    dynamics = CartPoleDynamics.of(env_id or d['env_id'])
    episodes = int(episodes or d['episodes'])
    gamma = float(gamma or d['gamma'])
    regressor = regressor or d['regressor']
    components = int(components or d['components'])
    learners = int(learners or d['learners'])
    if regressor not in REGRESSORS:
        raise RequestError(f'regressor must be one of {", ".join(sorted(REGRESSORS))} ("" = {d["regressor"]}), '
                           f'got {regressor!r}')
    if not 0.0 < gamma <= 1.0:  # NaN fails too
        raise RequestError(f'gamma must be in (0, 1] (0 = {d["gamma"]:g}), got {gamma}')
    for name, value, limit in (('episodes', episodes, MAX_EPISODES), ('components', components, MAX_COMPONENTS),
                               ('learners', learners, MAX_LEARNERS)):
        if not 1 <= value <= limit:
            raise RequestError(f'{name} must be 1 to {limit} (0 = {d[name]}), got {value}')
    seconds = longest_seconds(learners, episodes, dynamics.max_episode_steps, len(RBF_GAMMAS) * components)
    if seconds > MAX_SECONDS:
        raise RequestError(f'{learners} learners x {episodes} episodes of up to {dynamics.max_episode_steps} steps '
                           f'with {len(RBF_GAMMAS) * components} features could take {seconds / 60:.1f} minutes on '
                           f'{worker_count(learners)} cores, more than the limit of {MAX_SECONDS / 60:.0f}: use fewer '
                           'learners, episodes or components')
    return Training(dynamics, episodes, gamma, regressor, components, learners, bool(bootstrap_at_time_limit),
                    dynamics.max_episode_steps, start, max(0, start_episode), started_from if start is not None else '')


def longest_seconds(learners: int, episodes: int, max_steps: int, features: int) -> float:
    """The longest a training can take on this machine: every episode lasting max_steps (see MAX_SECONDS)."""
    steps = learners * episodes * max_steps / worker_count(learners)
    return steps * (STEP_SECONDS + FEATURE_SECONDS * features)


def rbf_transform(states, weights32: np.ndarray, offsets32: np.ndarray, amplitude: float) -> np.ndarray:
    """amplitude * cos(states . weights + offsets) in float32: (n, D) for states (n, 4), (D,) for one state (4,)."""
    z = np.asarray(states, dtype=np.float32).dot(weights32)
    z += offsets32
    np.cos(z, out=z)
    z *= np.float32(amplitude)
    return z


class FoldedFeatures:
    """RBF features with the scaler folded in: amplitude cos(s . folded_weights32 + folded_offsets32)."""
    folded_weights32: np.ndarray
    folded_offsets32: np.ndarray
    amplitude: float

    def transform(self, states) -> np.ndarray:
        """Features (n, D) float32 of states (n, 4), or (D,) of one state (4,): the agent sees gymnasium's
        float32 observation."""
        return rbf_transform(states, self.folded_weights32, self.folded_offsets32, self.amplitude)


class RBFFeatures(FoldedFeatures):
    """The course's FeatureTransformer: StandardScaler, then a union of RBFSamplers, as one affine map and a cosine.

    mean, scale: the scaler's; weights (4, D), offsets (D,): the RBF banks side by side (scikit-learn's
    random_weights_ and random_offset_); D = len(gammas) * components."""

    def __init__(self, rng: np.random.Generator, components: int, gammas=RBF_GAMMAS, samples: int = SCALER_SAMPLES):
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


class StartFeatures(FoldedFeatures):
    """The features of an agent a training goes on from: its folded RBF banks, as RBFFeatures computes them."""

    def __init__(self, agent: 'Agent'):
        self.folded_weights32 = agent.feature_weights
        self.folded_offsets32 = agent.feature_offsets
        self.amplitude = agent.amplitude
        self.dimensions = agent.q_weights.shape[1]


class LinearQ:
    """One linear regressor per action, Q(s, a) = x(s).w[a], trained one sample at a time.

    'tf': the warm-up's TensorFlow regressor: w ~ N(0, 1); gradient descent with rate 0.1 on the summed
    squared error (G - x.w)^2, whose gradient is -2 (G - x.w) x: w += 0.2 (G - x.w) x.
    'sgd': q_learning.py's numpy regressor: w ~ N(0, 1) / sqrt(D), w += 0.1 (G - x.w) x."""

    def __init__(self, regressor: str, dimensions: int, rng: np.random.Generator, actions: int = 2):
        w = rng.standard_normal((actions, dimensions))
        if regressor == 'sgd':
            w /= math.sqrt(dimensions)
        self.w = w.astype(np.float32)
        self.rate = REGRESSORS[regressor]

    @classmethod
    def of(cls, regressor: str, weights: np.ndarray) -> 'LinearQ':
        """Regressors that start from given weights (actions, D) (a copy), to train an agent on."""
        q = cls.__new__(cls)
        q.w = np.array(weights, dtype=np.float32)
        q.rate = REGRESSORS[regressor]
        return q

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Q of every action (actions,) for features x (D,), or (n, actions) for x (n, D)."""
        return x.dot(self.w.T)

    def update(self, x: np.ndarray, action: int, target: float, prediction: float) -> None:
        """w[action] += rate (target - prediction) x, where prediction is x.w[action] before the update."""
        self.w[action] += np.float32(self.rate * (target - prediction)) * x


@dataclass(frozen=True, eq=False)
class Agent:
    """A learner's greedy policy: everything it needs to act, as arrays (a policy file holds exactly these).

    feature_weights (4, D) and feature_offsets (D,) float32 are the RBF banks with the scaler folded in;
    q_weights (2, D) float32 the regressors; Q(s) = q_weights . (amplitude cos(s . feature_weights + offsets))."""
    feature_weights: np.ndarray
    feature_offsets: np.ndarray
    amplitude: float
    q_weights: np.ndarray
    kind: ClassVar[str] = 'q_learning'

    @classmethod
    def of(cls, features: RBFFeatures, q: LinearQ) -> 'Agent':
        return cls(features.folded_weights32, features.folded_offsets32, features.amplitude, q.w.copy())

    def values(self, states) -> np.ndarray:
        """Q of both actions: (2,) for one state, (n, 2) for states (n, 4)."""
        return rbf_transform(states, self.feature_weights, self.feature_offsets, self.amplitude).dot(self.q_weights.T)

    def act(self, state) -> int:
        """The greedy action (0 or 1) for one state; ties go to action 0, as numpy's argmax."""
        values = self.values(check_observation(state))
        return int(values[1] > values[0])

    def push_right(self, observations: np.ndarray) -> np.ndarray:
        """The greedy policy for CartPoleDynamics.episode_lengths: observations (4, n) -> (n,) bool. The features
        are computed CHUNK_FEATURES at a time: 1,000 episodes at 40,000 features would take 160 MB a step."""
        rows = max(1, CHUNK_FEATURES // self.q_weights.shape[1])
        states = observations.T
        out = np.empty(len(states), dtype=bool)
        for i in range(0, len(states), rows):
            values = self.values(states[i:i + rows])
            out[i:i + rows] = values[:, 1] > values[:, 0]
        return out

    def evaluate(self, dynamics: CartPoleDynamics, episodes: int, max_steps: int, seed: int) -> np.ndarray:
        """Lengths (episodes,) of greedy episodes, start states from rng_for(seed), stepped together."""
        starts = start_states(rng_for(seed), 1, episodes)
        return dynamics.episode_lengths(starts, max_steps, policy=self.push_right)[0]


def new_learner(training: Training, seed: int) -> tuple[np.random.Generator, RBFFeatures, LinearQ]:
    """(rng, features, regressors) of a learner before its first episode: its random parameters, drawn from
    rng_for(seed) in the fixed order every run of that seed draws them."""
    rng = rng_for(seed)
    if training.start is not None:      # train on: the start agent's features and weights, copied
        return rng, StartFeatures(training.start), LinearQ.of(training.regressor, training.start.q_weights)
    features = RBFFeatures(rng, training.components)
    return rng, features, LinearQ(training.regressor, features.dimensions, rng)


def epsilon(episode: int) -> float:
    """The course's exploration rate in episode n (0-based): 1 / sqrt(n + 1)."""
    return 1.0 / math.sqrt(episode + 1)


def train_one(training: Training, seed: int, progress: Callable | None = None,
              should_stop: Callable[[], bool] | None = None) -> tuple[np.ndarray, Agent]:
    """One learner, the course's loop. Returns (total rewards (episodes played,), Agent).

    progress(episode, total_reward, epsilon) after every episode (1-based); should_stop() is asked before
    every episode, and a learner it stops returns the episodes played so far."""
    rng, features, q = new_learner(training, seed)
    step, gamma, max_steps = training.dynamics.step, training.gamma, training.max_steps
    bootstrap = training.bootstrap_at_time_limit
    totals = np.zeros(training.episodes)
    for n in range(training.episodes):
        if should_stop is not None and should_stop():
            return totals[:n], Agent.of(features, q)
        eps = epsilon(training.start_episode + n)
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
    return totals, Agent.of(features, q)


def greedy_average(agent: Agent, training: Training, seed: int, episodes: int = GREEDY_EPISODES) -> float:
    """The average length of `episodes` greedy episodes of agent on the training's env and step limit, start states
    from seed (a learner's own: batch seed + k), the final agent's figure beside its last-100 average."""
    return float(agent.evaluate(training.dynamics, episodes, training.max_steps, seed).mean())


def running_average(values, window: int = 100) -> np.ndarray:
    """Average of the last `window` values (fewer at the start) at every index."""
    c = np.concatenate(([0.0], np.cumsum(values, dtype=np.float64)))
    i = np.arange(1, len(values) + 1)
    return (c[i] - c[np.maximum(0, i - window)]) / np.minimum(i, window)


# Student's t, 97.5% quantile, for 1..30 degrees of freedom (two-sided 95% interval)
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
         2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)


def ci95_half_width(values) -> float:
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


@dataclass
class TrainingResult:
    """K learners' total rewards (K, episodes played); the learners that finished every episode, with their
    last-100 averages, greedy averages and agents (indexed by learner; None where a learner did not finish); the
    learners that failed (their process died or stopped answering) and why."""
    env_id: str
    seed: int
    training: Training
    total_rewards: list
    finished: list                       # learner indices that played every episode, in order
    last100_averages: np.ndarray         # of the finished learners, in the order of `finished`
    greedy_averages: np.ndarray          # of the finished learners: GREEDY_EPISODES greedy episodes each
    agents: list
    baseline_total_reward: float
    elapsed: float
    cancelled: bool                      # stopped by should_stop
    failed: dict = field(default_factory=dict)   # {learner: why} of learners whose process died or hung
    mean_last100: float = field(init=False)
    ci95_last100: float = field(init=False)

    def __post_init__(self):
        self.mean_last100 = float(self.last100_averages.mean()) if len(self.last100_averages) else 0.0
        self.ci95_last100 = ci95_half_width(self.last100_averages) if len(self.last100_averages) else 0.0

    @property
    def learner_seeds(self) -> list[int]:
        """The seeds of the finished learners (learner k has seed + k)."""
        return [self.seed + j for j in self.finished]

    def best_learner(self) -> int:
        """The finished learner with the best greedy average, then the best last-100 average (the first of equals);
        -1 if none finished."""
        if not self.finished:
            return -1
        order = max(range(len(self.finished)), key=lambda i: (self.greedy_averages[i], self.last100_averages[i], -i))
        return self.finished[order]

    def figures_of(self, learner: int) -> dict:
        """A finished learner's figures, for its policy file."""
        i = self.finished.index(learner)
        return dict(last100_average=float(self.last100_averages[i]), greedy_average=float(self.greedy_averages[i]),
                    greedy_episodes=GREEDY_EPISODES, learner=learner, batch_seed=self.seed)


COLLAPSED = 0.5    # a final greedy agent below this fraction of its last-100 average has collapsed


def collapsed_learners(result: TrainingResult) -> list[int]:
    """The finished learners whose final greedy agent is far below their last-100 average: the exploring agent did
    well at the end of its training, the final agent does not."""
    return [j for j, greedy, last100 in zip(result.finished, result.greedy_averages, result.last100_averages)
            if greedy < COLLAPSED * last100]


def collapse_note(result: TrainingResult) -> str:
    """'' or a sentence naming the collapsed learners."""
    bad = collapsed_learners(result)
    if not bad:
        return ''
    return (f'collapsed at the end of training: {"learners" if len(bad) > 1 else "learner"} '
            f'{", ".join(map(str, bad))} (the final greedy agent far below the last-100 average, the exploring '
            'agent\'s)')


def summary(result: TrainingResult) -> str:
    """One line of what a training gave, ending as the course's script does."""
    t = result.training
    head = (f'{result.env_id}, {t.regressor} regressor, {len(RBF_GAMMAS)} x {t.components} RBF features, '
            f'gamma {t.gamma:g}, {counted(t.episodes, "episode")}' + (', bootstrap at the time limit'
                                                            if t.bootstrap_at_time_limit else ''))
    avg = result.last100_averages
    last = f'avg reward for last {min(100, t.episodes)} episodes: {result.mean_last100:.2f}'  # the course's words
    seeds = result.learner_seeds
    if not seeds:
        return f'{head}: no learner finished'
    if len(avg) == 1:
        return f'{head}, seed {seeds[0]}: {last}'
    which = (f'seeds {seeds[0]} to {seeds[-1]}' if seeds == list(range(seeds[0], seeds[0] + len(seeds)))
             else f'seeds {", ".join(map(str, seeds))}')
    return (f'{head}, {len(avg)} learners ({which}): {last} +/- '
            f'{result.ci95_last100:.2f} (95%), from {avg.min():.2f} to {avg.max():.2f}')


def random_baseline(training: Training, episodes: int = 1000) -> float:
    """The average total reward of random actions, counted as the training counts it (its own fixed draws)."""
    rng = np.random.default_rng(0)
    lengths = training.dynamics.episode_lengths(start_states(rng, 1, episodes), training.max_steps, rng=rng)[0]
    full = lengths == training.max_steps
    return float(np.where(full & training.bootstrap_at_time_limit, lengths, lengths - 1).mean())


def worker_count(learners: int) -> int:
    """Processes for a batch: one per core this process may use, at most one per learner."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count() or 1
    return max(1, min(learners, cores))


def _finish(training: Training, batch_seed: int, j: int, totals: np.ndarray, agent: Agent):
    """What a learner sends back: its totals, and its agent and greedy average if it played every episode."""
    if len(totals) < training.episodes:
        return totals, None, None
    return totals, agent, greedy_average(agent, training, batch_seed + j)


def train(training: Training, seed: int = 0, progress: Callable | None = None,
          should_stop: Callable[[], bool] | None = None, workers: int | None = None,
          ray_address: str = '') -> TrainingResult:
    """Train training.learners independent learners, seeds seed, seed + 1, ...; return a TrainingResult.

    progress(learner, episode, total_reward, epsilon) after every episode of every learner (each learner's in
    order); should_stop() is asked often, and a training it stops returns cancelled=True with the episodes
    played and the learners that had finished. More than one learner: `workers` processes (default: one per
    core) share them (see _train_in_processes); a learner whose process dies or hangs is in result.failed, the
    others go on. RuntimeError if every learner failed. ray_address: every learner a task on that Ray cluster
    (robot_ai.fleet; _train_on_ray), with the same numbers as here for the same seed; a learner's episodes are reported
    when it ends. FleetError when the cluster cannot be reached."""
    t0 = time.time()
    k = training.learners
    workers = worker_count(k) if workers is None else max(1, min(workers, k))
    failed = {}
    if ray_address:
        learners, cancelled = _train_on_ray(training, seed, ray_address, progress, should_stop, failed)
        if len(failed) == k:
            whys = sorted(set(failed.values()))
            raise RuntimeError(f'every learner failed: {"; ".join(whys[:3])}')
    elif workers == 1:
        learners, cancelled = {}, False
        for j in range(k):
            report = None if progress is None else (lambda e, r, eps, j=j: progress(j, e, r, eps))
            learners[j] = _finish(training, seed, j, *train_one(training, seed + j, report, should_stop))
            if learners[j][1] is None:
                cancelled = True
                break
    else:
        learners, cancelled = _train_in_processes(training, seed, workers, progress, should_stop, failed)
        if len(failed) == k:
            whys = sorted(set(failed.values()))
            raise RuntimeError(f'every learner failed: {"; ".join(whys[:3])}')
    return _result(training, seed, learners, cancelled, time.time() - t0, failed)


def _result(training: Training, seed: int, learners: dict, cancelled: bool, elapsed: float,
            failed: dict) -> TrainingResult:
    """learners: {j: (totals, agent or None, greedy average or None)}; failed: {j: why}."""
    k = training.learners
    rewards = [learners[j][0] if j in learners else np.zeros(0) for j in range(k)]
    agents = [learners[j][1] if j in learners else None for j in range(k)]
    finished = [j for j in range(k) if agents[j] is not None]
    return TrainingResult(
        env_id=training.dynamics.env_id, seed=seed, training=training, total_rewards=rewards, finished=finished,
        last100_averages=np.array([rewards[j][-100:].mean() for j in finished]),
        greedy_averages=np.array([learners[j][2] for j in finished]), agents=agents,
        baseline_total_reward=random_baseline(training), elapsed=elapsed,
        cancelled=cancelled or len(finished) + len(failed) < k, failed=dict(sorted(failed.items())))


# ------------------------------------------------------------------------------------------ worker processes
SILENCE_SECONDS = 10.0  # a worker that sends nothing for this long (stopped, hung) is killed: its learner failed
# Silence counts only while the parent listens: when more than _PARENT_STALL_SECONDS passes between two of its polls
# beyond the poll's own wait (the parent starved of the CPU, the machine paused), that time is nobody's silence: the
# workers may not have run either.
_POLL_SECONDS = 0.1
_PARENT_STALL_SECONDS = 1.0


@dataclass
class _Worker:
    """A learner process (robot_ai.cartpole.learner_worker) and what the parent knows of it."""
    proc: subprocess.Popen
    reader: FrameReader = field(default_factory=FrameReader)
    learner: int | None = None           # the learner it trains now
    heard: float = field(default_factory=time.monotonic)

    def send(self, message) -> bool:
        try:
            write_frame(self.proc.stdin, message)
            return True
        except (BrokenPipeError, OSError, ValueError):
            return False

    def end(self) -> None:
        """Close its input and kill it (it has nothing to save), then reap it."""
        for close in (self.proc.stdin.close, self.proc.kill):
            try:
                close()
            except OSError:
                pass
        self.proc.wait()
        self.proc.stdout.close()

    def why_silent(self, seconds: float) -> str:
        stat = process_stat(self.proc.pid)
        return f'its process sent nothing for {seconds:.0f} s ({stat.in_words if stat else "gone"}) and was killed'

    def why_gone(self) -> str:
        code = self.proc.wait()
        if code < 0:
            return f'its process was killed by {signal.Signals(-code).name}'
        return f'its process ended with status {code}'


def _train_in_processes(training, seed, workers, progress, should_stop, failed):
    """Learners in `workers` processes; returns (learners, cancelled) as train() and fills failed {j: why}.

    A worker that ends or falls silent for SILENCE_SECONDS loses only the learner it was training (killed, reported
    in `failed`); the learners not yet started go to the workers left."""
    pool = [_Worker(spawn('robot_ai.cartpole.learner_worker')) for _ in range(workers)]
    waiting = list(range(training.learners))
    totals = {j: [] for j in waiting}
    finished, cancelled = {}, False

    def hand_out(w: _Worker) -> None:
        w.learner = waiting.pop(0) if waiting else None
        if w.learner is None:
            w.proc.stdin.close()  # nothing left: the worker ends at the end of its input
        elif not w.send(('learner', w.learner)):
            lose(w, 'its process could not be reached')

    def lose(w: _Worker, why: str) -> None:
        w.end()
        pool.remove(w)
        if w.learner is not None:
            failed[w.learner] = why
        if not pool:
            failed.update({j: 'not started: every learner process had ended' for j in waiting})
            waiting.clear()

    try:
        for w in list(pool):
            if w.send(('training', training.settings(), seed, training.start)):
                hand_out(w)
            else:
                lose(w, 'its process could not be reached')
        polled = time.monotonic()
        while len(finished) + len(failed) < training.learners:
            if not cancelled and should_stop is not None and should_stop():
                # Cancel: the learners that played every episode still send their agents; the others end now.
                cancelled = True
                waiting.clear()
                for w in [w for w in pool if w.learner is None or len(totals[w.learner]) < training.episodes]:
                    w.learner = None
                    lose(w, '')
            if cancelled and not pool:
                break
            ready, _, _ = select.select([w.proc.stdout for w in pool], [], [], _POLL_SECONDS)
            now = time.monotonic()
            stalled, polled = now - polled - _POLL_SECONDS, now  # time the parent itself did not run, if any
            if stalled > _PARENT_STALL_SECONDS:
                for w in pool:
                    w.heard += stalled
            for stream in ready:
                w = next(w for w in pool if w.proc.stdout is stream)
                chunk = os.read(stream.fileno(), 1 << 20)
                if not chunk:
                    lose(w, w.why_gone() + (' while sending its result' if w.reader.partial else ''))
                    continue
                w.heard = time.monotonic()
                for message in w.reader.feed(chunk):
                    if message[0] == 'episode':
                        totals[message[1]].append(message[3])
                        if progress is not None:
                            progress(*message[1:])
                    elif message[0] == 'done':
                        finished[message[1]] = message[2:]
                        hand_out(w)
            for w in [w for w in pool if polled - w.heard > SILENCE_SECONDS]:
                lose(w, w.why_silent(polled - w.heard))
    finally:
        for w in pool:
            w.end()
    return {j: (np.array(t, dtype=float),) + finished.get(j, (None, None)) for j, t in totals.items() if t}, cancelled


# ------------------------------------------------------------------------------------------ learners on Ray
RAY_RETRIES = 2       # runs of a learner's task after the first when its node or worker dies


def learn_one(settings: dict, start, batch_seed: int, j: int) -> tuple[list, Agent, float]:
    """Learner j of a batch, as a learner process trains it (robot_ai.cartpole.learner_worker: BLAS on one thread):
    ([(episode, total_reward, epsilon), ...], its agent, its greedy average). A Ray task's body."""
    from threadpoolctl import threadpool_limits
    settings = dict(settings)
    training = Training(dynamics=CartPoleDynamics.of(settings.pop('env_id')), start=start, **settings)
    episodes = []
    with threadpool_limits(1):
        _, agent = train_one(training, batch_seed + j, lambda e, r, eps: episodes.append((e, r, eps)))
        return episodes, agent, greedy_average(agent, training, batch_seed + j)


def _train_on_ray(training, seed, address, progress, should_stop, failed):
    """Every learner a task on the Ray cluster at address; returns (learners, cancelled) as _train_in_processes and
    fills failed {j: why}. A learner whose node dies runs again elsewhere (RAY_RETRIES); a cancel keeps the learners
    that had finished."""
    from robot_ai import fleet
    ray = fleet.connect(address)
    task = ray.remote(learn_one).options(num_cpus=1, max_retries=RAY_RETRIES, retry_exceptions=False)
    settings = training.settings()
    pending = {task.remote(settings, training.start, seed, j): j for j in range(training.learners)}
    learners, cancelled = {}, False
    try:
        while pending:
            if should_stop is not None and should_stop():
                cancelled = True
                break
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.1)
            for ref in done:
                j = pending.pop(ref)
                try:
                    episodes, agent, greedy = ray.get(ref)
                except ray.exceptions.RayError as e:
                    failed[j] = f'its Ray task failed ({type(e).__name__}: {str(e).strip().splitlines()[0][:200]})'
                    continue
                if progress is not None:
                    for e, r, eps in episodes:
                        progress(j, e, r, eps)
                learners[j] = (np.array([r for _, r, _ in episodes], dtype=float), agent, greedy)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
    return learners, cancelled
