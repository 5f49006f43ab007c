"""stable-baselines3 over the package's vector envs: a VecEnv over any gymnasium 1.x vector env (next-step autoreset).

stable-baselines3 is not a dependency of robot_ai (it needs torch: gigabytes); this module imports it, so only a venv
that has it can import this module:

    from robot_ai.sb3 import make_vec_env
    env = make_vec_env('robot_ai/RosCartPole-v1', n_envs=8)        # the package's vector env over 8 leased sims
    env = make_vec_env('robot_ai/Reach-v0', n_envs=64, model='/path/arm.urdf')    # ReachVectorEnv: HER works
    model = PPO('MlpPolicy', env).learn(100_000)

stable-baselines3's own ``make_vec_env('robot_ai/RosCartPole-v1', n_envs=8)`` works too (one gymnasium.make per env,
each leasing a sim of its own); this adapter steps the package's vector env instead: all the sims' round trips at
once, or every arm in one numpy pass.

Semantics are stable-baselines3's: reset in the same step as an episode's end, the last observation in
``info['terminal_observation']``, a truncation in ``info['TimeLimit.truncated']``, the env's ``is_success`` in each
info; ``env_method('compute_reward', ...)`` reaches the vector env's (HER relabels goals with it).
"""
from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.vec_env import VecEnv


def _take(obs, i: int):
    """Env i's observation out of a batch (a dict of arrays for a Dict space)."""
    if isinstance(obs, dict):
        return {k: v[i].copy() for k, v in obs.items()}
    return obs[i].copy()


class GymnasiumVecEnv(VecEnv):
    """A gymnasium 1.x vector env (autoreset next-step) as stable-baselines3's VecEnv."""

    def __init__(self, venv: gymnasium.vector.VectorEnv):
        self.venv = venv          # first: VecEnv's constructor asks for render_mode
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions = None
        self._seed = None
        self._options = None

    def reset(self):
        obs, infos = self.venv.reset(seed=self._seed, options=self._options)
        self._seed = None
        self.reset_infos = self._infos(infos)
        return obs

    def step_async(self, actions) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, rewards, terminated, truncated, vector_infos = self.venv.step(self._actions)
        dones = np.asarray(terminated) | np.asarray(truncated)
        infos = self._infos(vector_infos)
        if dones.any():
            for i in np.flatnonzero(dones):
                infos[i]['terminal_observation'] = _take(obs, i)
                infos[i]['TimeLimit.truncated'] = bool(truncated[i] and not terminated[i])
            obs, reset_infos = self.venv.reset(options={'reset_mask': dones})
            for i, info in enumerate(self._infos(reset_infos)):
                if dones[i]:
                    self.reset_infos[i] = info
        return obs, np.asarray(rewards, dtype=np.float32), dones, infos

    def _infos(self, vector_infos: dict) -> list[dict]:
        """A vector env's dict of arrays (with their '_key' masks) as one dict per env."""
        infos = [{} for _ in range(self.num_envs)]
        for key, values in vector_infos.items():
            if key.startswith('_') or isinstance(values, dict):
                continue
            mask = vector_infos.get(f'_{key}', np.ones(self.num_envs, dtype=bool))
            for i in np.flatnonzero(mask):
                value = values[i]
                infos[i][key] = value.item() if isinstance(value, np.generic) else value
        return infos

    def seed(self, seed: int | None = None):
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def close(self) -> None:
        self.venv.close()

    def render(self, mode: str | None = None):
        return self.venv.render()

    def get_images(self):
        frames = self.venv.render()
        return list(frames) if frames is not None else [None] * self.num_envs

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.venv, attr_name) if hasattr(self.venv, attr_name) else \
            self.venv.get_attr(attr_name)
        return [value] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """The vector env's method (compute_reward for HER), once per index asked."""
        method = getattr(self.venv, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, **kwargs) -> GymnasiumVecEnv:
    """The env's own vector env (gymnasium.make_vec's vector entry point) of n_envs, as a stable-baselines3 VecEnv;
    kwargs go to the env (robot_ns is not one: each env leases a free sim)."""
    import importlib
    importlib.import_module('robot_ai.reach')      # registers robot_ai/Reach-v0 (no ROS needed)
    if env_id.startswith('robot_ai/Ros'):
        importlib.import_module('robot_ai.envs')   # registers the envs over ROS (rospy, the workspace sourced)
    env = GymnasiumVecEnv(gymnasium.make_vec(env_id, num_envs=n_envs, vectorization_mode='vector_entry_point',
                                             **kwargs))
    if seed is not None:
        env.seed(seed)
    return env
