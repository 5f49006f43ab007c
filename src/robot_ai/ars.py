"""Augmented Random Search (Mania, Guy and Recht 2018) of a linear policy over any batched env. No rospy.

The course's random search drew whole policies at random and kept the best; ARS walks instead: each iteration it
perturbs the current weights M along N random directions delta_k (both signs, noise nu), plays every perturbed policy,
keeps the b directions whose better sign did best, and steps

    M += alpha / (b sigma_R) * sum_k (r(+k) - r(-k)) delta_k          (sigma_R: the std of those 2b returns)

V1 acts on raw observations; V2 on observations normalised by the running mean and standard deviation of every
state seen in training (frozen during an iteration; when they change, the weights are re-expressed in the new
statistics, so that the policy's actions do not jump). Coordinates may share statistics (``shared_statistics``: the
x, y and z of a goal and of the tip, so that a P-controller on their difference is a linear policy), have fixed ones
(``fixed_statistics``: a scale known in advance) or start from states known to be typical (``prior_states``).
alpha and nu may shrink linearly over the run (``decay``), as schedules do in stable-baselines3-contrib's ARS.
Every rollout of an iteration (2 N directions x episodes, and
the evaluation of the current policy) is one pass of one vector env, so an iteration costs one batch of episodes.
The same seed gives the same policy, bit for bit.

    settings = ARSSettings(iterations=50, directions=16, top_directions=8, step_size=0.02, noise=0.03)
    result = train(lambda n: gymnasium.make_vec('CartPole-v1', num_envs=n, vectorization_mode='vector_entry_point'),
                   settings, seed=0, progress=print, should_stop=lambda: False)
    result.policy.act(observation)          # the best policy seen (cancel keeps it too)

A policy: Box actions ``clip(M ((x - mean) / std) + bias, low, high)``; Discrete(2) the course's ``1 if
M . ((x - mean) / std) + bias > 0 else 0``; Discrete(k) the argmax. x is ``gymnasium.spaces.flatten`` of the
observation (a Dict in its key order).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import gymnasium
import numpy as np
from gymnasium import spaces

from robot_ai.policies import Kind, PolicyError, register_kind
from robot_ai.policies.envs import flat_size, flatten_batch
from robot_ai.policies.npz import MAX_LIST, MAX_TEXT, plain, shown

MIN_STD = 1e-6          # coordinates that hardly vary are divided by 1 instead (they carry no information)


class ARSError(ValueError):
    """Settings or an env ARS cannot work with; one line."""


@dataclass(frozen=True)
class ARSSettings:
    """ARS's hyperparameters, named as in the paper (N, b, alpha, nu), and the size of a run."""
    iterations: int = 100             # most iterations (a step budget may end the run first)
    directions: int = 16              # N: directions sampled per iteration
    top_directions: int = 8           # b: the best directions kept for the step (b = N: ARS without the top-b)
    step_size: float = 0.02           # alpha
    noise: float = 0.03               # nu: the perturbations' standard deviation
    normalize: bool = True            # V2 (observations normalised by running statistics) or V1
    episodes: int = 1                 # episodes per direction and sign, from the same seeds for every direction
    eval_episodes: int = 0            # episodes of the current policy per iteration (progress and best so far)
    bias: bool = True                 # a constant term beside the weights
    max_steps: int = 0                # stop before an iteration would take the run past this many steps (0: none)
    decay: float = 0.0                # alpha and nu shrink linearly by this fraction over the iterations

    def check(self) -> None:
        for name in ('iterations', 'directions', 'top_directions', 'episodes'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ARSError(f'{name} must be a whole number of at least 1, got {value!r}')
        if self.top_directions > self.directions:
            raise ARSError(f'top_directions (b = {self.top_directions}) must be at most directions (N = '
                           f'{self.directions})')
        for name in ('eval_episodes', 'max_steps'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ARSError(f'{name} must be a whole number of at least 0, got {value!r}')
        for name in ('step_size', 'noise'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float('inf'):
                raise ARSError(f'{name} must be a positive number, got {value!r}')

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True, eq=False)
class LinearPolicy:
    """A linear policy over flattened observations (see the module's docstring). weights (act, obs), obs_mean and
    obs_std (obs,), bias (act,) or None; low/high: a Box's bounds (None for Discrete, whose size is `choices`)."""
    weights: np.ndarray
    obs_mean: np.ndarray
    obs_std: np.ndarray
    bias: np.ndarray | None = None
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    choices: int = 0

    kind = 'ars_linear'

    @classmethod
    def zeros(cls, observation_space: spaces.Space, action_space: spaces.Space, bias: bool) -> LinearPolicy:
        d = flat_size(observation_space)
        if isinstance(action_space, spaces.Box):
            a = int(np.prod(action_space.shape))
            low = np.broadcast_to(action_space.low, action_space.shape).reshape(-1).astype(np.float64)
            high = np.broadcast_to(action_space.high, action_space.shape).reshape(-1).astype(np.float64)
            return cls(np.zeros((a, d)), np.zeros(d), np.ones(d), np.zeros(a) if bias else None, low, high)
        if isinstance(action_space, spaces.Discrete):
            k = int(action_space.n)
            rows = 1 if k == 2 else k
            return cls(np.zeros((rows, d)), np.zeros(d), np.ones(d), np.zeros(rows) if bias else None, choices=k)
        raise ARSError(f'ARS takes Box and Discrete actions, not {type(action_space).__name__}')

    @property
    def action_size(self) -> int:
        return self.weights.shape[0]

    def scores(self, x: np.ndarray) -> np.ndarray:
        """(M, act) linear scores of flattened observations x (M, obs)."""
        out = ((x - self.obs_mean) / self.obs_std) @ self.weights.T
        return out + self.bias if self.bias is not None else out

    def act_batch(self, x: np.ndarray) -> np.ndarray:
        """Actions of flattened observations x (M, obs): (M, act) for a Box, (M,) integers for Discrete."""
        return _actions(self.scores(np.asarray(x, dtype=np.float64)), self.low, self.high, self.choices)

    def act(self, x) -> np.ndarray | int:
        """The action of one flattened observation (obs,)."""
        a = self.act_batch(np.asarray(x, dtype=np.float64).reshape(1, -1))[0]
        return int(a) if self.choices else a


def _actions(scores: np.ndarray, low, high, choices: int) -> np.ndarray:
    if choices == 2:
        return (scores[:, 0] > 0).astype(np.int64)
    if choices:
        return np.argmax(scores, axis=1)
    return np.minimum(np.maximum(scores, low), high)


class RunningStats:
    """Mean and variance of every coordinate of the states seen (Chan et al.'s batch merge), groups of coordinates
    pooled (their samples taken as one variable's)."""

    def __init__(self, size: int, groups: list[list[int]] | None = None, fixed: dict | None = None):
        self.fixed = dict(fixed or {})        # index -> (mean, std) that the states seen do not change
        self.count = 0
        self.mean = np.zeros(size)
        self.m2 = np.zeros(size)
        self.groups = [list(g) for g in (groups or [])]

    def add(self, x: np.ndarray) -> None:
        if not len(x):
            return
        n = len(x)
        batch_mean = x.mean(axis=0)
        batch_m2 = ((x - batch_mean) ** 2).sum(axis=0)
        total = self.count + n
        delta = batch_mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self.m2 = self.m2 + batch_m2 + delta ** 2 * (self.count * n / total)
        self.count = total

    def mean_std(self) -> tuple[np.ndarray, np.ndarray]:
        if self.count < 2:
            mean, var = np.zeros_like(self.mean), np.ones_like(self.mean)
        else:
            mean, var = self.mean.copy(), self.m2 / self.count
        for g in self.groups:
            pooled = mean[g].mean()
            var[g] = (var[g] + (mean[g] - pooled) ** 2).mean()
            mean[g] = pooled
        std = np.where(np.sqrt(var) < MIN_STD, 1.0, np.sqrt(var))
        for i, (m, sd) in self.fixed.items():
            mean[i], std[i] = m, sd
        return mean, std


@dataclass
class IterationStats:
    """One iteration: its number, steps so far, seconds so far, the mean return of the perturbed rollouts, and of
    the current policy's evaluation (with its success rate and final metric, where the env gives them; NaN where
    not measured)."""
    iteration: int
    steps: int
    elapsed: float
    rollout_return: float
    eval_return: float = float('nan')
    success_rate: float = float('nan')
    final_metric: float = float('nan')


@dataclass
class ARSResult:
    """A run: its best policy (the one the evaluations rated best; without evaluations, the last), the last one,
    every iteration's figures, the steps it took and whether it was cancelled."""
    policy: LinearPolicy
    last_policy: LinearPolicy
    history: list[IterationStats] = field(default_factory=list)
    steps: int = 0
    elapsed: float = 0.0
    cancelled: bool = False
    best_iteration: int = 0
    settings: ARSSettings = field(default_factory=ARSSettings)
    seed: int = 0


@dataclass
class _Rollouts:
    returns: np.ndarray        # (M,) total reward of each slot's first episode
    lengths: np.ndarray        # (M,) its steps
    success: np.ndarray        # (M,) is_success at its end (NaN where the env gives none)
    metric: np.ndarray         # (M,) final_metric of its last observation (NaN without one)
    states: list               # flattened observations the training slots saw (for V2's statistics)


def _rollouts(env, weights: np.ndarray, biases: np.ndarray | None, mean: np.ndarray, std: np.ndarray,
              policy: LinearPolicy, seeds: list[int], train_slots: int, final_metric) -> _Rollouts:
    """Play one episode in every slot of env, slot m acting with weights[m] (and biases[m]); slot m's env reset with
    seeds[m] (a vector env that takes one seed only gets the first). Slots that end early are left to autoreset and
    ignored."""
    m = env.num_envs
    try:
        obs, _ = env.reset(seed=seeds)
    except (TypeError, gymnasium.error.Error):   # a native vector env with one generator (CartPole's): one seed
        obs, _ = env.reset(seed=seeds[0])
    alive = np.ones(m, dtype=bool)
    returns, lengths = np.zeros(m), np.zeros(m, dtype=np.int64)
    success, metric = np.full(m, np.nan), np.full(m, np.nan)
    states = []
    space = env.single_observation_space
    while alive.any():
        x = flatten_batch(space, obs)
        states.append(x[:train_slots][alive[:train_slots]])
        scores = np.einsum('mad,md->ma', weights, (x - mean) / std)
        if biases is not None:
            scores += biases
        obs, rewards, terminated, truncated, infos = env.step(_actions(scores, policy.low, policy.high,
                                                                       policy.choices))
        returns += np.where(alive, rewards, 0.0)
        lengths += alive
        ended = alive & (np.asarray(terminated) | np.asarray(truncated))
        if ended.any():
            if 'is_success' in infos:
                success[ended] = np.asarray(infos['is_success'], dtype=np.float64)[ended]
            if final_metric is not None:
                metric[ended] = np.asarray(final_metric(obs), dtype=np.float64)[ended]
        alive &= ~ended
    return _Rollouts(returns, lengths, success, metric, states)


def chunk_sizes(total: int, chunks: int) -> list[int]:
    """total slots split into `chunks` envs (at most one per slot), the first ones one slot larger."""
    chunks = max(1, min(chunks, total))
    return [total // chunks + (i < total % chunks) for i in range(chunks)]


class _Players:
    """The envs that play an iteration's slots: one env (chunks 0 or 1), or `chunks` envs each holding a run of the
    slots, played one after another here or, with a Ray address, by actors on the cluster (robot_ai.fleet), each
    keeping its env from one iteration to the next. The same chunks give the same numbers here and on Ray."""

    def __init__(self, make_env: Callable[[int], object], total: int, chunks: int = 0, ray_address: str = ''):
        self.ray = None
        if ray_address:
            from robot_ai import fleet
            self.ray = fleet.connect(ray_address)
            chunks = chunks or int(sum(fleet.cluster_cpus(self.ray).values()))
        self.sizes = chunk_sizes(total, chunks or 1)
        if ray_address:
            actor = self.ray.remote(_RolloutActor).options(num_cpus=1, max_restarts=RAY_RESTARTS,
                                                           max_task_retries=RAY_RESTARTS)
            self.envs = [actor.remote(make_env, n) for n in self.sizes]
            probe = make_env(1)          # the spaces, here
            try:
                self.single_observation_space = probe.single_observation_space
                self.single_action_space = probe.single_action_space
            finally:
                probe.close()
        else:
            self.envs = [make_env(n) for n in self.sizes]
            self.single_observation_space = self.envs[0].single_observation_space
            self.single_action_space = self.envs[0].single_action_space

    def play(self, weights, biases, mean, std, policy, seeds, train_slots, final_metric) -> _Rollouts:
        if len(self.envs) == 1 and self.ray is None:
            return _rollouts(self.envs[0], weights, biases, mean, std, policy, seeds, train_slots, final_metric)
        jobs, start = [], 0
        for n in self.sizes:
            end = start + n
            jobs.append((weights[start:end], None if biases is None else biases[start:end], mean, std, policy,
                         seeds[start:end], max(0, min(end, train_slots) - start), final_metric))
            start = end
        if self.ray is None:
            parts = [_rollouts(env, *job) for env, job in zip(self.envs, jobs)]
        else:
            parts = self.ray.get([env.play.remote(*job) for env, job in zip(self.envs, jobs)])
        steps = max(len(p.states) for p in parts)      # each step's states in slot order, as one env gives them
        states = [np.concatenate([p.states[t] for p in parts if t < len(p.states)]) for t in range(steps)]
        return _Rollouts(np.concatenate([p.returns for p in parts]), np.concatenate([p.lengths for p in parts]),
                         np.concatenate([p.success for p in parts]), np.concatenate([p.metric for p in parts]),
                         states)

    def close(self) -> None:
        for env in self.envs:
            if self.ray is None:
                env.close()
            else:
                self.ray.kill(env)


RAY_RESTARTS = 2      # an actor whose node or worker dies is made again (its env anew) this many times


class _RolloutActor:
    """A Ray actor (robot_ai.fleet): one chunk's env, kept between iterations (a chained start goes on from where its
    arms stopped)."""

    def __init__(self, make_env: Callable[[int], object], size: int):
        from threadpoolctl import threadpool_limits
        threadpool_limits(1)
        self.env = make_env(size)

    def play(self, *job) -> _Rollouts:
        return _rollouts(self.env, *job)


def train(make_env: Callable[[int], object], settings: ARSSettings, seed: int = 0,
          progress: Callable[[IterationStats], None] | None = None, should_stop: Callable[[], bool] | None = None,
          shared_statistics: list[list[int]] | None = None, final_metric=None,
          initial: LinearPolicy | None = None, prior_states: np.ndarray | None = None,
          fixed_statistics: dict | None = None, chunks: int = 0, ray_address: str = '',
          zero_sum: list[list[int]] | None = None) -> ARSResult:
    """ARS with settings, reproducible from seed.

    make_env(num_envs) -> a gymnasium vector env (next-step autoreset) of that many copies; it is made once.
    progress(stats) is called after every iteration; should_stop() is asked before each one, and a run it stops
    returns the best policy so far (cancelled=True). shared_statistics: groups of flattened-observation indices that
    share V2's mean and std. final_metric(observations) -> (M,) a figure of each env's last observation (the reach
    task's final distance). initial: a policy to start from (its statistics too), instead of zeros.
    prior_states (K, obs): flattened observations that seed V2's statistics; fixed_statistics {index: (mean, std)}:
    coordinates whose statistics are given, not measured. zero_sum: groups of flattened-observation indices (each
    group sharing its statistics) whose weights sum to zero in every row, so that the policy sees their differences
    only: the reach task's achieved goal, desired goal and tip, whose sum of weights is otherwise a random walk that
    makes the action depend on where the arm is, not only on its error (the perturbations are projected so; an
    initial policy too). chunks: the slots played by that many envs of their own
    (make_env(size) each; 0: one env, or one per CPU of the Ray cluster); ray_address: those envs kept by actors on
    the Ray cluster there (robot_ai.fleet), one CPU each, with the same numbers as the same chunks here. An env whose
    slots are seeded one by one (reset(seed=[...])) and that starts every episode afresh (not a chained start) gives
    the same numbers in any chunks."""
    settings.check()
    n_dir, episodes = settings.directions, settings.episodes
    train_slots = 2 * n_dir * episodes
    env = _Players(make_env, train_slots + settings.eval_episodes, chunks, ray_address)
    try:
        policy = initial or LinearPolicy.zeros(env.single_observation_space, env.single_action_space, settings.bias)
        stats = RunningStats(policy.weights.shape[1], shared_statistics, fixed_statistics)
        mean, std = policy.obs_mean.copy(), policy.obs_std.copy()
        if settings.normalize and initial is None:
            mean, std = stats.mean_std()
        if prior_states is not None and settings.normalize and initial is None:
            stats.add(np.asarray(prior_states, dtype=np.float64))
            mean, std = stats.mean_std()
        weights = _zero_sum(policy.weights.copy(), zero_sum)
        bias = None if policy.bias is None else policy.bias.copy()
        rng = np.random.default_rng(int(seed) % 2 ** 64)
        t0 = time.monotonic()
        result = ARSResult(policy, policy, settings=settings, seed=seed)
        best_score = (-np.inf, -np.inf)
        for iteration in range(1, settings.iterations + 1):
            if should_stop is not None and should_stop():
                result.cancelled = True
                break
            deltas = _zero_sum(rng.standard_normal((n_dir,) + weights.shape), zero_sum)
            bias_deltas = rng.standard_normal((n_dir,) + bias.shape) if bias is not None else None
            episode_seeds = [int(s) for s in rng.integers(0, 2 ** 31, size=episodes)]
            eval_seeds = [int(s) for s in rng.integers(0, 2 ** 31, size=settings.eval_episodes)]
            shrink = 1.0 - settings.decay * (iteration - 1) / max(1, settings.iterations - 1)
            nu = settings.noise * shrink
            signs = np.repeat(np.array([1.0, -1.0]), n_dir * episodes)
            per_slot = np.tile(np.repeat(np.arange(n_dir), episodes), 2)
            slot_w = weights[None] + nu * signs[:, None, None] * deltas[per_slot]
            slot_b = None if bias is None else bias[None] + nu * signs[:, None] * bias_deltas[per_slot]
            if settings.eval_episodes:
                slot_w = np.concatenate((slot_w, np.broadcast_to(weights, (settings.eval_episodes,) + weights.shape)))
                if slot_b is not None:
                    slot_b = np.concatenate((slot_b, np.broadcast_to(bias, (settings.eval_episodes,) + bias.shape)))
            seeds = episode_seeds * (2 * n_dir) + eval_seeds
            rollouts = env.play(slot_w, slot_b, mean, std, policy, seeds, train_slots, final_metric)
            steps = int(rollouts.lengths.sum())
            if settings.max_steps and result.steps + steps > settings.max_steps and iteration > 1:
                break
            result.steps += steps
            returns = rollouts.returns[:train_slots].reshape(2, n_dir, episodes).mean(axis=2)
            plus, minus = returns
            top = np.argsort(-np.maximum(plus, minus), kind='stable')[:settings.top_directions]
            sigma = np.concatenate((plus[top], minus[top])).std()
            if sigma > 0:
                scale = settings.step_size * shrink / (settings.top_directions * sigma)
                diff = (plus - minus)[top]
                weights = weights + scale * np.tensordot(diff, deltas[top], axes=1)
                if bias is not None:
                    bias = bias + scale * np.tensordot(diff, bias_deltas[top], axes=1)
            current = replace(policy, weights=weights.copy(), obs_mean=mean.copy(), obs_std=std.copy(),
                              bias=None if bias is None else bias.copy())
            if settings.normalize:
                stats.add(np.concatenate(rollouts.states))
                mean, std = stats.mean_std()
                # the policy keeps its actions through the change of statistics (exactly, when it has a bias)
                weights, bias = _renormalise(weights, bias, current.obs_mean, current.obs_std, mean, std)
            figures = IterationStats(iteration, result.steps, time.monotonic() - t0, float(returns.mean()))
            evaluated = rollouts.returns[train_slots:]
            if settings.eval_episodes:
                figures.eval_return = float(evaluated.mean())
                figures.success_rate = float(np.mean(rollouts.success[train_slots:]))
                figures.final_metric = float(np.mean(rollouts.metric[train_slots:]))
                # the evaluation played the policy of the start of this iteration: the one before the step
                score = (figures.success_rate if np.isfinite(figures.success_rate) else 0.0, figures.eval_return)
                if score > best_score:
                    best_score, result.best_iteration = score, iteration - 1
                    result.policy = result.last_policy
            else:
                result.policy, result.best_iteration = current, iteration
            result.last_policy = replace(current, weights=weights.copy(), obs_mean=mean.copy(), obs_std=std.copy(),
                                         bias=None if bias is None else bias.copy())
            result.history.append(figures)
            if progress is not None:
                progress(figures)
        result.elapsed = time.monotonic() - t0
        return result
    finally:
        env.close()


def _zero_sum(weights: np.ndarray, groups: list[list[int]] | None) -> np.ndarray:
    """weights (..., obs) with each group's columns less their mean: the nearest weights whose group sums to zero
    (in place; returned)."""
    for group in groups or ():
        weights[..., group] -= weights[..., group].mean(axis=-1, keepdims=True)
    return weights


def _renormalise(weights, bias, old_mean, old_std, new_mean, new_std):
    """The same affine policy in terms of new statistics: W' (x - m') / s' + b' == W (x - m) / s + b for every x."""
    scale = new_std / old_std
    new_weights = weights * scale
    shift = weights @ ((new_mean - old_mean) / old_std)
    if bias is None:
        return new_weights, None
    return new_weights, bias + shift


def history_log(result, settings) -> tuple[list, list]:
    """(header, rows) of an ARS run's CSV log: one row per iteration."""
    header = ['iteration', 'steps', 'episodes', 'seconds', 'rollout_return', 'eval_return', 'success_rate',
              'final_metric']
    per_iteration = 2 * settings.directions * settings.episodes + settings.eval_episodes
    return header, [[h.iteration, h.steps, h.iteration * per_iteration, f'{h.elapsed:.3f}', repr(h.rollout_return),
                     repr(h.eval_return), repr(h.success_rate), repr(h.final_metric)] for h in result.history]



# ------------------------------------------------------------------------------------------------- policy files
MAX_ACTIONS = 64                     # an arm's joints (joint control) or a tip's 3 coordinates
MAX_INPUTS = 1024                    # an arm's joints + 9


def _shapes(key_shape: tuple | None, names: set) -> dict:
    if key_shape is None:
        raise PolicyError('an ars_linear policy holds weights (actions, observations): this file does not')
    if len(key_shape) != 2 or not (1 <= key_shape[0] <= MAX_ACTIONS and 1 <= key_shape[1] <= MAX_INPUTS):
        raise PolicyError(f'weights must have shape (actions, observations), at most ({MAX_ACTIONS}, '
                          f'{MAX_INPUTS}), got {shown(key_shape)}')
    a, d = key_shape
    want = {'weights': ((a, d), np.float64), 'obs_mean': ((d,), np.float64), 'obs_std': ((d,), np.float64)}
    if 'bias' in names:
        want['bias'] = ((a,), np.float64)
    return want


def _arrays(actor: LinearPolicy) -> dict:
    arrays = dict(weights=actor.weights, obs_mean=actor.obs_mean, obs_std=actor.obs_std)
    if actor.bias is not None:
        arrays['bias'] = actor.bias
    return {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}


def _build(arrays: dict) -> LinearPolicy:
    a = arrays['weights'].shape[0]
    return LinearPolicy(arrays['weights'], arrays['obs_mean'], arrays['obs_std'], arrays.get('bias'),
                        low=-np.ones(a), high=np.ones(a))


def _check_metadata(metadata: dict) -> None:
    """An ars_linear policy's env: env_id a short text, env_kwargs short names to plain values, joints names."""
    env_id = metadata.get('env_id')
    if not isinstance(env_id, str) or not 0 < len(env_id) <= 200:
        raise PolicyError(f'env_id is {shown(env_id)}, not the id of an env')
    kwargs = metadata.setdefault('env_kwargs', {})
    if not isinstance(kwargs, dict) or not all(isinstance(k, str) and len(k) <= 100 and plain(v)
                                               for k, v in kwargs.items()):
        raise PolicyError('env_kwargs must map short names to numbers, short texts, true/false, null or lists of them')
    joints = metadata.setdefault('joints', [])
    if not isinstance(joints, list) or len(joints) > MAX_LIST or not all(isinstance(j, str) and len(j) <= MAX_TEXT
                                                                         for j in joints):
        raise PolicyError('joints must be a list of joint names')
    for name in ('robot', 'model', 'model_sha256'):
        value = metadata.setdefault(name, '')
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            raise PolicyError(f'{name} must be text of at most {MAX_TEXT} characters')


def _check_values(arrays: dict) -> None:
    if not (arrays['obs_std'] > 0).all():
        raise PolicyError('obs_std must hold positive numbers: a policy divides by them')


# Kind ars_linear: ARS's linear policy for any env with a Box(-1, 1) action (the reach task): weights (act, obs),
# obs_mean and obs_std (obs,), an optional bias (act,); its metadata names the env it acts in (env_id, env_kwargs)
# and, for a reach policy, the robot, its file and the joints in order (robot_ai.reach.policy_files checks them).
register_kind(Kind('ars_linear', 'weights', _shapes, _build, _arrays, check_metadata=_check_metadata,
                   check_values=_check_values))
