"""The envs a policy acts in, as the parts of the package that own them describe them, and their observations as a
policy takes them (flattened). No rospy; nothing here knows a robot: robot_ai.cartpole and robot_ai.reach register
their envs (``register_env``), any other gymnasium env is made and closed to read its spaces.

    register_env(('CartPole-v0', 'CartPole-v1'), cartpole_target)      # target(env_id, env_kwargs) -> Target
    target = target_of('robot_ai/Reach-v0', {'model': '/path/arm.urdf'})
    target.observation_space, target.action_space
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from gymnasium import spaces

from robot_ai.policies.files import PolicyError


@dataclass(eq=False)
class Target:
    """An env a policy is loaded to act in. kinds: the .npz kinds that can act in it (() any); check(policy) -> a
    note ('' or a line worth showing), PolicyError (one line) when the policy does not fit (another robot, tip or
    size); context: what the env's owner wants back with the policy (a reach task's setup)."""
    env_id: str
    env_kwargs: dict
    observation_space: spaces.Space
    action_space: spaces.Space
    kinds: tuple[str, ...] = ()
    check: Callable[[object], str] | None = None
    context: object = None
    metadata: dict = field(default_factory=dict)    # what a loaded policy's metadata gains (exported_for, ...)


_ENVS: dict[str, Callable[[str, dict], Target]] = {}


def register_env(env_ids, target: Callable[[str, dict], Target]) -> None:
    """target(env_id, env_kwargs) -> the Target of these env ids (PolicyError, one line, for kwargs it refuses)."""
    for env_id in env_ids:
        _ENVS[env_id] = target


def target_of(env_id: str, env_kwargs: dict | None = None) -> Target:
    """The Target of an env: a registered one's, or any other gymnasium env's spaces (made and closed)."""
    env_kwargs = dict(env_kwargs or {})
    if env_id in _ENVS:
        return _ENVS[env_id](env_id, env_kwargs)
    import gymnasium
    try:
        env = gymnasium.make(env_id, **env_kwargs)
    except Exception as e:       # an unknown id, bad kwargs: one line
        raise PolicyError(f'its env {env_id} cannot be made: {str(e).splitlines()[0][:200]}') from None
    try:
        return Target(env_id, env_kwargs, env.observation_space, env.action_space)
    finally:
        env.close()


def flat_size(space: spaces.Space) -> int:
    return int(spaces.flatdim(space))


def flatten_batch(space: spaces.Space, obs) -> np.ndarray:
    """A vector env's batch of observations (M, ...) -> (M, flatdim) float64, each row gymnasium.spaces.flatten's."""
    if isinstance(space, spaces.Dict):
        return np.concatenate([flatten_batch(sub, obs[key]) for key, sub in space.spaces.items()], axis=1)
    if isinstance(space, spaces.Box):
        a = np.asarray(obs, dtype=np.float64)
        return a.reshape(a.shape[0], -1)
    if isinstance(space, spaces.Discrete):
        a = np.asarray(obs, dtype=np.int64) - space.start
        out = np.zeros((a.shape[0], int(space.n)))
        out[np.arange(a.shape[0]), a] = 1.0
        return out
    raise ValueError(f'a policy takes Box, Discrete and Dict observations, not {type(space).__name__}')
