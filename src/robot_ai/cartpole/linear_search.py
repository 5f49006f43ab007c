"""The course's linear CartPole policy and its random search, batched over every candidate and episode. No rospy.

The course's exercise: draw weight vectors w uniformly in [-1, 1]^4, play episodes with the policy
``action = 1 if obs.dot(w) > 0 else 0``, keep the best average episode length (the first best wins ties),
then evaluate the best on final episodes. Here every (candidate, episode) pair is stepped together with
gymnasium's own CartPole equations (``dynamics.CartPoleDynamics``), so a 100 x 100 search takes a fraction
of a second instead of the course loop's seconds.

The same seed gives the same result bit for bit: weights, start states and the random-action baseline all
come from ``numpy.random.default_rng(seed)`` in a fixed order, and the batching does not change which
numbers are drawn.

    search = resolve(iterations=100, episodes=100)          # defaults filled in, every value checked
    result = random_search(search.dynamics, search.iterations, search.episodes, search.max_steps, seed=0)
    result.best_weights, result.best_avg_length, result.final_avg_length
"""
import math
import time
from dataclasses import dataclass
from typing import Callable, ClassVar, NamedTuple

import numpy as np

from robot_ai import ars
from robot_ai.cartpole.dynamics import (CartPoleDynamics, RequestError, check_observation, check_state, rng_for,
                                       start_states)

DEFAULTS = dict(env_id='CartPole-v1', iterations=100, episodes=100, final_episodes=100)
MAX_ITERATIONS = 100000
MAX_EPISODES = 10000
MAX_WORK = 20000000            # iterations * episodes (+ final episodes): about a minute or two on 2 cores
BATCH_ENVS = 131072            # episodes stepped together: bounds memory (~40 MiB of state) whatever the size

class Search(NamedTuple):
    dynamics: CartPoleDynamics
    iterations: int
    episodes: int
    max_steps: int
    final_episodes: int


def resolve(env_id: str = '', iterations: int = 0, episodes: int = 0, max_steps: int = 0, final_episodes: int = 0,
            defaults: dict | None = None) -> Search:
    """A Search with zero/empty fields filled from defaults (DEFAULTS, then the given dict) and every value
    checked; RequestError says what is allowed."""
    d = dict(DEFAULTS, **(defaults or {}))
    dynamics = CartPoleDynamics.of(env_id or d['env_id'])
    iterations = int(iterations or d['iterations'])
    episodes = int(episodes or d['episodes'])
    final_episodes = int(final_episodes or d['final_episodes'])
    max_steps = dynamics.resolve_max_steps(max_steps)
    if not 1 <= iterations <= MAX_ITERATIONS:
        raise RequestError(f'iterations must be 1 to {MAX_ITERATIONS} (0 = {d["iterations"]}), got {iterations}')
    for name, value in (('episodes', episodes), ('final_episodes', final_episodes)):
        if not 1 <= value <= MAX_EPISODES:
            raise RequestError(f'{name} must be 1 to {MAX_EPISODES} (0 = {d[name]}), got {value}')
    if iterations * episodes + final_episodes > MAX_WORK:
        raise RequestError(f'iterations x episodes + final_episodes = {iterations} x {episodes} + {final_episodes} = '
                           f'{iterations * episodes + final_episodes} episodes is more than the limit of {MAX_WORK}; '
                           'use fewer iterations or episodes')
    return Search(dynamics, iterations, episodes, max_steps, final_episodes)


def check_weights(weights) -> np.ndarray:
    """The policy's weights as 4 finite floats, or RequestError saying what is wrong."""
    return check_state(weights, 'weights')


def act(weights, state) -> int:
    """The course's policy: 1 (push right) if state.w > 0, else 0."""
    return 1 if float(np.dot(check_observation(state), weights)) > 0 else 0


def evaluate(dynamics: CartPoleDynamics, weights, episodes: int, max_steps: int, seed: int) -> np.ndarray:
    """Lengths (episodes,) of one linear policy's episodes; start states from rng_for(seed).

    dynamics: a CartPoleDynamics; weights: 4 numbers; max_steps: at most the environment's limit."""
    rng = rng_for(seed)
    w = check_weights(weights)
    return dynamics.episode_lengths(start_states(rng, 1, episodes), max_steps, weights=w[None, :])[0]


@dataclass(frozen=True, eq=False)
class LinearPolicy:
    """The course's linear policy with given weights (4,): the same interface as q_learning.Agent."""
    weights: np.ndarray
    kind: ClassVar[str] = 'linear'

    def act(self, state) -> int:
        return act(self.weights, state)

    def push_right(self, observations: np.ndarray) -> np.ndarray:
        """observations (4, n) float32 -> (n,) bool, as episode_lengths computes it for weights."""
        return np.einsum('ij,ij->j', observations, np.repeat(self.weights[:, None], observations.shape[1], 1)) > 0

    def evaluate(self, dynamics: CartPoleDynamics, episodes: int, max_steps: int, seed: int) -> np.ndarray:
        return evaluate(dynamics, self.weights, episodes, max_steps, seed)


@dataclass
class SearchResult:
    """What a search found: every candidate's weights and average length, the best, its final evaluation."""
    env_id: str
    seed: int
    iterations: int
    episodes: int
    max_steps: int
    weights: np.ndarray                  # (candidates evaluated, 4)
    avg_lengths: np.ndarray              # (candidates evaluated,)
    best_index: int                      # -1 if no candidate was evaluated
    best_weights: np.ndarray
    best_avg_length: float
    final_lengths: np.ndarray
    final_avg_length: float
    baseline_avg_length: float
    elapsed: float
    cancelled: bool

    def settings(self) -> dict:
        """The settings that made the search, as plain values (a policy file's metadata keeps them)."""
        return dict(env_id=self.env_id, iterations=self.iterations, episodes=self.episodes,
                    max_steps=self.max_steps, final_episodes=len(self.final_lengths))

    def figures(self) -> dict:
        return dict(best_avg_length=self.best_avg_length, final_avg_length=self.final_avg_length,
                    best_candidate=self.best_index + 1, candidates=len(self.avg_lengths))


def random_search(dynamics: CartPoleDynamics, iterations: int = 100, episodes: int = 100, max_steps: int | None = None,
                  seed: int = 0, final_episodes: int = 100, progress: Callable | None = None,
                  should_stop: Callable[[], bool] | None = None, batch_envs: int = BATCH_ENVS) -> SearchResult:
    """The course's random search, batched.

    progress(i, avg, best, elapsed) is called for every candidate i (1-based) in order; should_stop() is
    asked between batches, and a search it stops returns the candidates evaluated so far (cancelled=True).
    seed: any integer (see dynamics.rng_for); the result keeps it as given.
    """
    t0 = time.time()
    max_steps = max_steps or dynamics.max_episode_steps
    rng = rng_for(seed)
    weights = rng.uniform(-1.0, 1.0, size=(iterations, 4))
    per_batch = max(1, batch_envs // episodes)
    avgs = np.empty(iterations)
    best_index, best, done, cancelled = -1, -math.inf, 0, False
    while done < iterations:
        if should_stop is not None and should_stop():
            cancelled = True
            break
        k = min(per_batch, iterations - done)
        lengths = dynamics.episode_lengths(start_states(rng, k, episodes), max_steps, weights=weights[done:done + k])
        batch_avgs = lengths.mean(axis=1)
        avgs[done:done + k] = batch_avgs
        for j, avg in enumerate(batch_avgs):
            if avg > best:  # strictly better, as the course: the first of equal candidates stays the best
                best, best_index = avg, done + j
            if progress is not None:
                progress(done + j + 1, float(avg), float(best), time.time() - t0)
        done += k
    avgs = avgs[:done]
    final = np.zeros(0, np.int64)
    baseline = float('nan')
    if best_index >= 0 and not cancelled:
        final = dynamics.episode_lengths(start_states(rng, 1, final_episodes), max_steps,
                                         weights=weights[best_index][None, :])[0]
        baseline = float(dynamics.episode_lengths(start_states(rng, 1, episodes), max_steps, rng=rng).mean())
    return SearchResult(env_id=dynamics.env_id, seed=seed, iterations=iterations, episodes=episodes,
                        max_steps=max_steps, weights=weights[:done], avg_lengths=avgs, best_index=best_index,
                        best_weights=weights[best_index] if best_index >= 0 else np.zeros(4),
                        best_avg_length=float(best) if best_index >= 0 else 0.0, final_lengths=final,
                        final_avg_length=float(final.mean()) if len(final) else 0.0,
                        baseline_avg_length=baseline, elapsed=time.time() - t0, cancelled=cancelled)


# ARS (robot_ai.ars) on the course's policy: V1 (raw observations), no bias, so that its policy is the course's 4
# weights; CartPole-v1 solved (475 or more over 100 episodes) within rl-baselines3-zoo's 50,000 steps on every seed
# tried (50 seeds: 487 to 500).
ARS_SETTINGS = ars.ARSSettings(iterations=1000, directions=8, top_directions=8, step_size=0.02, noise=0.03,
                               normalize=False, bias=False, episodes=1, max_steps=50000)


def ars_search(env_id: str = 'CartPole-v1', seed: int = 0, settings: ars.ARSSettings = ARS_SETTINGS,
               progress: Callable | None = None, should_stop: Callable[[], bool] | None = None, chunks: int = 0,
               ray_address: str = '') -> ars.ARSResult:
    """Augmented Random Search of the course's linear policy on gymnasium's CartPole (its native vector env: every
    rollout of an iteration in one pass). result.policy.weights[0] are the 4 weights. chunks, ray_address: the
    rollouts in that many envs, on a Ray cluster (ars.train); the native env draws every start state of an env from
    one generator, so other chunks give other numbers (the same chunks give the same, here and on Ray)."""
    import gymnasium
    CartPoleDynamics.of(env_id)      # RequestError for anything but the course's CartPoles

    def make(n: int):
        return gymnasium.make_vec(env_id, num_envs=n, vectorization_mode='vector_entry_point')
    return ars.train(make, settings, seed, progress=progress, should_stop=should_stop, chunks=chunks,
                     ray_address=ray_address)


def episodes_used(result: SearchResult) -> tuple[int, int]:
    """(episodes, steps) a random search played: every candidate's episodes, the final evaluation and the
    random-action baseline."""
    episodes = len(result.avg_lengths) * result.episodes + len(result.final_lengths)
    steps = int(round(float(np.sum(result.avg_lengths)) * result.episodes)) + int(np.sum(result.final_lengths))
    if np.isfinite(result.baseline_avg_length):
        episodes += result.episodes
        steps += int(round(result.baseline_avg_length * result.episodes))
    return episodes, steps
