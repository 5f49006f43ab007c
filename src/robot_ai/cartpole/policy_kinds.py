"""The cart-pole's policy files: the course's linear policy and Q-learning agent as kinds of robot_ai.policies, the
CartPoles as envs a policy acts in, and the loader the cart-pole's nodes and CLI call. No rospy.

    policy = load('best.npz')                 # linear, q_learning (or ars_linear of a CartPole), or
    policy = load('ppo.onnx', 'CartPole-v1')  # an ONNX model: env_id names its CartPole when its metadata does not
    lengths = evaluate(policy, CartPoleDynamics.of(policy.env_id), 100, 500, seed=0)

Kind ``linear``: ``weights`` (4,). Kind ``q_learning``: ``feature_weights`` (4, D), ``feature_offsets`` (D,) (the
scaler folded in), ``amplitude`` (0-d) and ``q_weights`` (2, D): everything it needs to act, nothing re-drawn from a
seed. Their metadata's ``env_id`` is CartPole-v0 or -v1, and their figures are what that env can give.
"""
from __future__ import annotations

import numpy as np
from gymnasium import spaces

from robot_ai.cartpole.dynamics import SUPPORTED_ENVS, CartPoleDynamics, rng_for, start_states
from robot_ai.policies import Kind, PolicyError, Target, is_onnx_path, load as load_policy, register_env, register_kind
from robot_ai.policies.files import shown

KINDS = ('linear', 'q_learning')
MAX_DIMENSIONS = 4 * 10000               # q_learning.MAX_COMPONENTS banks of 4
AVERAGE_FIGURES = ('best_avg_length', 'final_avg_length', 'last100_average', 'greedy_average')
# the ids a cart-pole policy may name, and the CartPole of the package's dynamics each acts as
CARTPOLE_ENVS = {'CartPole-v0': 'CartPole-v0', 'CartPole-v1': 'CartPole-v1',
                 'robot_ai/RosCartPole-v0': 'CartPole-v0', 'robot_ai/RosCartPole-v1': 'CartPole-v1'}


def _check_env(metadata: dict) -> None:
    if metadata.get('env_id') not in SUPPORTED_ENVS:
        raise PolicyError(f'env_id is {shown(metadata.get("env_id"))}, not one of {", ".join(SUPPORTED_ENVS)}')


def _check_figures(metadata: dict) -> None:
    """A file's claimed figures are within what its env can give: an average length or reward from 0 to the env's
    step limit (CartPole-v1: 500). A node never compares with a figure nobody could have measured."""
    limit = CartPoleDynamics.of(metadata['env_id']).max_episode_steps
    for key in AVERAGE_FIGURES:
        if key not in metadata['figures']:
            continue
        v = metadata['figures'][key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= limit:
            raise PolicyError(f'figures.{key} is {shown(v)}: {metadata["env_id"]} gives 0 to {limit}')


def _linear_shapes(key_shape, names) -> dict:
    return {'weights': ((4,), np.float64)}


def _linear(arrays: dict):
    from robot_ai.cartpole.linear_search import LinearPolicy
    return LinearPolicy(arrays['weights'])


def _q_shapes(key_shape, names) -> dict:
    if key_shape is None:
        raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}: a q_learning '
                          'policy holds it, this file does not')
    if len(key_shape) != 1 or not 1 <= key_shape[0] <= MAX_DIMENSIONS:
        raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}, got '
                          f'{shown(key_shape)}')
    d = key_shape[0]
    return {'feature_weights': ((4, d), np.float32), 'feature_offsets': ((d,), np.float32),
            'amplitude': ((), np.float64), 'q_weights': ((2, d), np.float32)}


def _q_arrays(actor) -> dict:
    return dict(feature_weights=actor.feature_weights, feature_offsets=actor.feature_offsets,
                amplitude=np.array(actor.amplitude, dtype=np.float64), q_weights=actor.q_weights)


def _q_agent(arrays: dict):
    from robot_ai.cartpole.q_learning import Agent
    return Agent(arrays['feature_weights'], arrays['feature_offsets'], float(arrays['amplitude']), arrays['q_weights'])


def _q_values(arrays: dict) -> None:
    amplitude = float(arrays['amplitude'])
    if not amplitude > 0:
        raise PolicyError(f'amplitude must be positive, got {amplitude:g}')
    with np.errstate(over='ignore', invalid='ignore'):     # the agent computes in float32 (rbf_transform)
        bound = np.float32(amplitude) * np.abs(arrays['q_weights']).sum(axis=1, dtype=np.float32)
    if not np.isfinite(bound).all():
        raise PolicyError('amplitude x q_weights exceed float32: the Q-values would be infinite')


register_kind(Kind('linear', None, _linear_shapes, _linear,
                   lambda actor: dict(weights=np.asarray(actor.weights, dtype=np.float64).reshape(4)),
                   check_metadata=_check_env, check_figures=_check_figures))
register_kind(Kind('q_learning', 'feature_offsets', _q_shapes, _q_agent, _q_arrays, check_metadata=_check_env,
                   check_figures=_check_figures, check_values=_q_values))


def target(env_id: str, env_kwargs: dict | None = None) -> Target:
    """A CartPole as the env a policy acts in: the CartPole of the package's dynamics the id acts as (the ROS
    cart-pole's ids act as gymnasium's), Box(4) observations, Discrete(2) actions, the cart-pole's kinds."""
    if env_id not in CARTPOLE_ENVS:
        raise PolicyError(f'{env_id} is not a cart-pole ({", ".join(CARTPOLE_ENVS)})')
    plays = CARTPOLE_ENVS[env_id]
    return Target(plays, {}, spaces.Box(-np.inf, np.inf, (4,), np.float32), spaces.Discrete(2), KINDS,
                  metadata={'exported_for': env_id} if plays != env_id else {})


register_env(CARTPOLE_ENVS, target)


def load(path: str, env_id: str = ''):
    """A cart-pole policy of either format: a policy file (.npz) as it is, or an ONNX model acting in env_id (or
    the CartPole its metadata names: CartPole-v0/v1, or the ROS cart-pole's ids, which act as they do). Both
    act(state), push_right(observations) and describe(); evaluate() plays them. PolicyError: one line."""
    def choose(file) -> Target:
        given = env_id or file.env_id
        if not given:
            raise PolicyError(f'{file.path} names no env (its metadata has no robot_ai_env): give the CartPole it '
                              f'plays (--env-id or ~env_id: CartPole-v1)')
        if given not in CARTPOLE_ENVS:
            raise PolicyError(f'{file.path} acts in {given}, not a cart-pole ({", ".join(CARTPOLE_ENVS)})')
        return target(given)
    return load_policy(path, choose if is_onnx_path(path) else None)


def evaluate(policy, dynamics: CartPoleDynamics, episodes: int, max_steps: int, seed: int) -> np.ndarray:
    """Lengths (episodes,) of a cart-pole policy's episodes (a file's or an ONNX model's), start states from
    rng_for(seed), stepped together."""
    if policy.kind in KINDS:
        return policy.evaluate(dynamics, episodes, max_steps, seed)
    return dynamics.episode_lengths(start_states(rng_for(seed), 1, episodes), max_steps, policy=policy.push_right)[0]

