#!/usr/bin/env python3
"""The anchor for bench/manipulation.py: stable-baselines3's TQC + HER on panda-gym's PandaPush-v3 or
PandaPickAndPlace-v3 for a wall-clock budget, then its success rate over fresh episodes; one JSON line on stdout.

It runs in a Python that has stable-baselines3, sb3-contrib and panda-gym (torch: gigabytes, never the package's
dependency; a venv of its own: `python3 -m venv ~/sb3 && ~/sb3/bin/pip install stable-baselines3 sb3-contrib
panda-gym`), started by bench/manipulation.py --sb3-python ~/sb3/bin/python. The hyperparameters are
rl-baselines3-zoo's for the Fetch and Panda push and pick-and-place tasks (hyperparams/tqc.yml): MultiInputPolicy,
HER (future, 4 goals), buffer 1e6, batch 2048 (pick and place: 1024), gamma 0.95, learning rate 1e-3, tau 0.05,
three layers of 512, two critics.

    python bench/sb3_panda_gym.py --env PandaPush-v3 --minutes 30
    python bench/sb3_panda_gym.py --speed          # PandaPush-v3's steps per second only
"""
import argparse
import json
import time

import gymnasium
import numpy as np


def speed(seconds: float, env_id: str = 'PandaPush-v3', **kwargs) -> float:
    """Steps per second of one env made by gymnasium.make, random actions, for seconds (bench/manipulation.py times
    Push-v0 with it too)."""
    if env_id.startswith('Panda'):
        import panda_gym  # noqa: F401 (registers the envs)
    env = gymnasium.make(env_id, **kwargs)
    env.reset(seed=0)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps += 1
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument('--env', default='PandaPush-v3')
    p.add_argument('--minutes', type=float, default=30.0)
    p.add_argument('--episodes', type=int, default=100)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--speed', action='store_true')
    a = p.parse_args()
    import panda_gym  # noqa: F401 (registers the envs)
    if a.speed:
        print(json.dumps({'env': 'PandaPush-v3', 'steps_per_second': speed(5.0)}))
        return
    from sb3_contrib import TQC
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.callbacks import BaseCallback

    class Budget(BaseCallback):
        def __init__(self, seconds: float):
            super().__init__()
            self.end = time.monotonic() + seconds

        def _on_step(self) -> bool:
            return time.monotonic() < self.end

    env = gymnasium.make(a.env)
    model = TQC('MultiInputPolicy', env, buffer_size=1_000_000,
                batch_size=1024 if 'PickAndPlace' in a.env else 2048, gamma=0.95, learning_rate=1e-3, tau=0.05,
                replay_buffer_class=HerReplayBuffer,
                replay_buffer_kwargs=dict(goal_selection_strategy='future', n_sampled_goal=4),
                policy_kwargs=dict(net_arch=[512, 512, 512], n_critics=2), seed=a.seed, verbose=0)
    t0 = time.monotonic()
    model.learn(total_timesteps=10 ** 8, callback=Budget(a.minutes * 60.0))
    trained = time.monotonic() - t0
    successes = []
    for episode in range(a.episodes):
        obs, _ = env.reset(seed=10 ** 6 + episode)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        successes.append(bool(info.get('is_success', False)))
    print(json.dumps({'env': a.env, 'train_seconds': trained, 'env_steps': int(model.num_timesteps),
                      'success_rate': float(np.mean(successes)), 'episodes': a.episodes}))


if __name__ == '__main__':
    main()
