#!/usr/bin/env python3
"""stable-baselines3's PPO learns the CartPole, and its policy leaves as an ONNX file that drives the ROS cart-pole.

Run it in a venv that has stable-baselines3 (torch is gigabytes, so it is not a dependency of robot_ai; the robot
runs the file with onnxruntime only):

    python examples/sb3_ppo_cartpole_onnx.py --output ppo_cartpole.onnx
    python -m robot_ai.cartpole evaluate ppo_cartpole.onnx               # 100 greedy episodes, no torch
    roslaunch robot_ai cartpole.launch policy:=$PWD/ppo_cartpole.onnx rviz:=true

The export follows stable-baselines3's export guide: the policy's forward(observation, deterministic=True) traced
with opset 17, whose first output is the action (int64, (batch,)). torch 2.9 and later export with torch.export by
default, which stops at the Categorical distribution's argument checks; the TorchScript exporter (dynamo=False)
traces it. The file's metadata robot_ai_env names the env ({"env_id": "CartPole-v1"}), so that the package's
controllers know what it plays. The script checks the file before it says it is done: onnxruntime's actions equal
model.predict's on 10,000 observations, and the package's loader takes it.
"""
import argparse
import json
import sys
import time

import gymnasium
import numpy as np
import onnx
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

from robot_ai.cartpole import policy_kinds
from robot_ai.policies import onnx as onnx_policy


class OnnxablePolicy(torch.nn.Module):
    """The export guide's wrapper: the greedy action (and the value and log-probability, which the robot ignores)."""

    def __init__(self, policy):
        super().__init__()
        self.policy = policy

    def forward(self, observation):
        return self.policy(observation, deterministic=True)


def linear(start: float):
    return lambda progress: progress * start


def export(model, path: str, env_id: str, figures: dict) -> None:
    observation = torch.zeros((1, *model.observation_space.shape), dtype=torch.float32)
    torch.onnx.export(OnnxablePolicy(model.policy).eval(), (observation,), path, opset_version=17,
                      input_names=['observation'], output_names=['action', 'value', 'log_prob'],
                      dynamic_axes={'observation': {0: 'batch'}}, dynamo=False)
    exported = onnx.load(path)
    onnx.helper.set_model_props(exported, {onnx_policy.METADATA_KEY: json.dumps(dict(env_id=env_id, **figures))})
    onnx.save(exported, path)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--output', default='ppo_cartpole.onnx', help='the ONNX file')
    p.add_argument('--steps', type=int, default=100_000, help='training steps, all 8 envs together')
    p.add_argument('--seed', type=int, default=0)
    a = p.parse_args()
    torch.set_num_threads(1)
    env_id = 'CartPole-v1'
    # rl-baselines3-zoo's settings for CartPole-v1
    model = PPO('MlpPolicy', make_vec_env(env_id, n_envs=8, seed=a.seed), n_steps=32, batch_size=256, gae_lambda=0.8,
                gamma=0.98, n_epochs=20, ent_coef=0.0, learning_rate=linear(1e-3), clip_range=linear(0.2),
                seed=a.seed, device='cpu')
    t = time.monotonic()
    model.learn(a.steps)
    print(f'PPO: {a.steps:,} steps in {time.monotonic() - t:.1f} s')

    env = gymnasium.make(env_id)
    lengths = []
    for episode in range(20):
        obs, _ = env.reset(seed=10_000 + episode)
        done, n = False, 0
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, _ = env.step(int(action))
            n += 1
            done = terminated or truncated
        lengths.append(n)
    print(f'model.predict: average length {np.mean(lengths):.1f} over 20 episodes')

    export(model, a.output, env_id, dict(mean_length=float(np.mean(lengths)), algorithm='PPO', steps=a.steps))
    policy = policy_kinds.load(a.output)
    rng = np.random.default_rng(a.seed)
    observations = (rng.normal(size=(10_000, 4)) * [1.0, 1.0, 0.1, 1.0]).astype(np.float32)
    expected, _ = model.predict(observations, deterministic=True)
    got = policy.act_batch(observations)
    if not np.array_equal(expected, got):
        print(f'the ONNX file differs from model.predict on {int((expected != got).sum())} of 10,000 observations',
              file=sys.stderr)
        return 1
    print(f'{a.output}: onnxruntime acts as model.predict on 10,000 observations; {policy.describe()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
