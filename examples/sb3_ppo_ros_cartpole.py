#!/usr/bin/env python3
"""stable-baselines3's PPO trains on the ROS cart-pole through robot_ai.envs, and saves its model.

Start the sims first (one per env), then run this in a venv that has stable-baselines3 (see the README: torch is
gigabytes, so it is not a dependency of robot_ai):

    roslaunch robot_ai cartpole_gym.launch sims:=8
    python examples/sb3_ppo_ros_cartpole.py --model ppo_ros_cartpole.zip
    python examples/sb3_ppo_ros_cartpole.py --in-process     # the same PPO on gymnasium's CartPole-v1, to compare

The settings are rl-baselines3-zoo's for CartPole-v1 (8 envs, 1e5 steps, n_steps 32, batch 256, 20 epochs, gamma
0.98, GAE lambda 0.8, learning rate and clip range decaying linearly from 1e-3 and 0.2), on one torch thread. At the
end the model plays --eval-episodes greedy episodes on the env it trained on, and the script prints the steps, the
wall time of the training and the evaluation's mean reward.
"""
import argparse
import sys
import time

import gymnasium
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv

# 'robot_ai.envs:robot_ai/RosCartPole-v1': gymnasium imports robot_ai.envs, which registers the env
ROS_ENV = 'robot_ai.envs:robot_ai/RosCartPole-v1'


class GymnasiumVecEnv(VecEnv):
    """A gymnasium 1.x vector env (autoreset next-step) as stable-baselines3's VecEnv (reset in the same step,
    the last observation in info['terminal_observation'], truncation in info['TimeLimit.truncated'])."""

    def __init__(self, venv: gymnasium.vector.VectorEnv):
        self.venv = venv          # first: VecEnv's constructor asks for render_mode
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions = None
        self._seed = None

    def reset(self):
        obs, _ = self.venv.reset(seed=self._seed)
        self._seed = None
        return obs

    def step_async(self, actions):
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, rewards, terminated, truncated, _ = self.venv.step(self._actions)
        dones = terminated | truncated
        infos = [{} for _ in range(self.num_envs)]
        if dones.any():
            for i in np.flatnonzero(dones):
                infos[i] = {'terminal_observation': obs[i].copy(),
                            'TimeLimit.truncated': bool(truncated[i] and not terminated[i])}
            obs, _ = self.venv.reset(options={'reset_mask': dones})
        return obs, rewards.astype(np.float32), dones, infos

    def seed(self, seed=None):
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def close(self):
        self.venv.close()

    def get_attr(self, attr_name, indices=None):
        return [getattr(self.venv, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        raise NotImplementedError(method_name)

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))

    def _get_indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


def linear(start: float):
    return lambda progress: progress * start


def evaluate(model, env_id: str, episodes: int, seed: int, robot_ns: str) -> float:
    env = (gymnasium.make(env_id) if robot_ns is None else
           gymnasium.make(ROS_ENV, robot_ns=robot_ns))
    total = []
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + 1000 + e)
        done, reward = False, 0.0
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, terminated, truncated, _ = env.step(int(action))
            reward += r
            done = terminated or truncated
        total.append(reward)
    env.close()
    return float(np.mean(total))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--envs', type=int, default=8, help='envs (sims /cartpole_0 ... of cartpole_gym.launch sims:=N)')
    p.add_argument('--steps', type=int, default=100_000, help='training steps, all envs together')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--eval-episodes', type=int, default=10)
    p.add_argument('--in-process', action='store_true', help='train on gymnasium\'s CartPole-v1 instead of ROS')
    p.add_argument('--model', default='', help='where to save the model (.zip); "" = not saved')
    a = p.parse_args()
    torch.set_num_threads(1)
    if a.in_process:
        venv = gymnasium.make_vec('CartPole-v1', num_envs=a.envs, vectorization_mode='sync')
        where = 'gymnasium CartPole-v1 in-process'
    else:
        venv = gymnasium.make_vec(ROS_ENV, num_envs=a.envs)
        where = f'the ROS cart-pole ({", ".join(venv.robot_namespaces)})'
    env = GymnasiumVecEnv(venv)
    env.seed(a.seed)
    model = PPO('MlpPolicy', env, n_steps=32, batch_size=256, gae_lambda=0.8, gamma=0.98, n_epochs=20,
                ent_coef=0.0, learning_rate=linear(1e-3), clip_range=linear(0.2), seed=a.seed, verbose=0,
                device='cpu')
    t = time.perf_counter()
    model.learn(total_timesteps=a.steps)
    elapsed = time.perf_counter() - t
    if a.model:
        model.save(a.model)
    mean = evaluate(model, 'CartPole-v1', a.eval_episodes, a.seed, None if a.in_process else '/cartpole_0')
    env.close()
    weights = sum(float(v.double().abs().sum()) for v in model.policy.state_dict().values())
    print(f'PPO on {where}: {model.num_timesteps} steps in {elapsed:.1f} s '
          f'({model.num_timesteps / elapsed:,.0f} steps/s); greedy evaluation over {a.eval_episodes} episodes: '
          f'mean reward {mean:.1f}; sum of |weights| {weights!r} (the same seed gives the same model, in-process or '
          f'through ROS)' + (f'; model saved to {a.model}' if a.model else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
