#!/usr/bin/env python3
"""stable-baselines3's PPO trains on the ROS cart-pole through robot_ai.envs, and saves its model.

Start the sims first (one per env), then run this in a venv that has stable-baselines3 (see docs/install.md: torch is
gigabytes, so it is not a dependency of robot_ai):

    roslaunch robot_ai cartpole_gym.launch sims:=8
    python examples/sb3_ppo_ros_cartpole.py --model ppo_ros_cartpole.zip
    python examples/sb3_ppo_ros_cartpole.py --in-process     # the same PPO on gymnasium's CartPole-v1, to compare
    python examples/sb3_ppo_ros_cartpole.py --sb3-make-vec-env   # stable-baselines3's own make_vec_env(env_id)

The envs are the package's vector env through robot_ai.sb3.GymnasiumVecEnv (each env leases a free sim), or, with
--sb3-make-vec-env, stable-baselines3's make_vec_env over gymnasium.make (one leased sim per env, stepped in turn).

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

from robot_ai.sb3 import GymnasiumVecEnv

# 'robot_ai.envs:robot_ai/RosCartPole-v1': gymnasium imports robot_ai.envs, which registers the env
ROS_ENV = 'robot_ai.envs:robot_ai/RosCartPole-v1'


def linear(start: float):
    return lambda progress: progress * start


def evaluate(model, env_id: str, episodes: int, seed: int, robot_ns: str | None) -> float:
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
    p.add_argument('--sb3-make-vec-env', action='store_true',
                   help='stable-baselines3\'s make_vec_env(env_id) (DummyVecEnv over gymnasium.make) instead')
    a = p.parse_args()
    torch.set_num_threads(1)
    if a.sb3_make_vec_env:
        from stable_baselines3.common.env_util import make_vec_env
        env = make_vec_env('CartPole-v1' if a.in_process else ROS_ENV, n_envs=a.envs, seed=a.seed)
        where = ('gymnasium CartPole-v1 in-process' if a.in_process else 'the ROS cart-pole') + ' (sb3 make_vec_env)'
    else:
        if a.in_process:
            venv = gymnasium.make_vec('CartPole-v1', num_envs=a.envs, vectorization_mode='sync')
            where = 'gymnasium CartPole-v1 in-process'
        else:
            venv = gymnasium.make_vec(ROS_ENV, num_envs=a.envs)
            where = 'the ROS cart-pole (robot_ai.sb3 over the package\'s vector env)'
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
    env.close()    # gives the sims back: the evaluation leases one
    mean = evaluate(model, 'CartPole-v1', a.eval_episodes, a.seed, None if a.in_process else '')
    weights = sum(float(v.double().abs().sum()) for v in model.policy.state_dict().values())
    print(f'PPO on {where}: {model.num_timesteps} steps in {elapsed:.1f} s '
          f'({model.num_timesteps / elapsed:,.0f} steps/s); greedy evaluation over {a.eval_episodes} episodes: '
          f'mean reward {mean:.1f}; sum of |weights| {weights!r} (the same seed gives the same model, in-process or '
          f'through ROS)' + (f'; model saved to {a.model}' if a.model else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
