#!/usr/bin/env python3
"""stable-baselines3's SAC with HER learns an arm's reach, and its actor leaves as an ONNX file for reach_controller.

Run it in a venv that has stable-baselines3 (torch is gigabytes, so it is not a dependency of robot_ai; the robot
runs the file with onnxruntime only):

    python examples/sb3_sac_her_reach_onnx.py --output sac_reach.onnx             # the package's UR5
    python examples/sb3_sac_her_reach_onnx.py --model my_arm.urdf --output sac_my_arm.onnx
    python -m robot_ai.reach evaluate sac_reach.onnx                               # 1000 fresh goals, no torch
    roslaunch robot_ai reach.launch policy:=$PWD/sac_reach.onnx                    # click points in rviz

SAC learns on robot_ai/Reach-v0's goal-env observation (a Dict) with HER relabelling 4 future goals, with
rl-baselines3-zoo's settings for PandaReach (gamma 0.95, learning rate 1e-3, tau 0.05, batch 256, two layers of 64).
The export follows stable-baselines3's export guide for SAC: only the actor, deterministic, its tanh-squashed
action mapped to the action space's bounds. ONNX takes one input here, the observation flattened as
gymnasium.spaces.flatten does (achieved_goal, desired_goal, observation), so a small wrapper splits it into the
Dict the actor takes. The file's metadata robot_ai_env names the env (env_id, env_kwargs with the robot file, tip and
control), the robot, its joints and the held-out success rate, so that reach_controller refuses it for another arm.
The script checks the file before it says it is done: onnxruntime's actions equal model.predict's on 10,000
observations (to 1e-5), and the package's loader takes it.

SAC is slower than the package's ARS here, but gets there with tip control: measured on this machine's UR5, 20,000
steps in 146 s on one core, 99.2 % of 1000 fresh goals (`python -m robot_ai.reach train`: 7 s, 99.9 %;
docs/benchmarks.md). Joint control (`--control joints`, six actions) is harder for it: 1.7 % after 20,000 steps,
42.4 % after 60,000 (8.5 minutes); its ONNX file drives reach_controller all the same. The point is the way a policy
of any library reaches the robot.
"""
import argparse
import json
import os
import sys
import time

import gymnasium
import numpy as np
import onnx
import torch
from gymnasium import spaces
from stable_baselines3 import SAC, HerReplayBuffer

from robot_ai.policies import onnx as onnx_policy
from robot_ai.reach import learn, policy_files          # registers robot_ai/Reach-v0


class FlatActor(torch.nn.Module):
    """The SAC actor on one flattened observation (batch, achieved 3 + desired 3 + observation n + 3): split into the
    Dict it was trained on, the deterministic action, unscaled from [-1, 1] to the action space's bounds."""

    def __init__(self, actor, observation_space: spaces.Dict, action_space: spaces.Box):
        super().__init__()
        self.actor = actor
        self.keys = list(observation_space.spaces)
        self.sizes = [spaces.flatdim(s) for s in observation_space.spaces.values()]
        self.register_buffer('low', torch.as_tensor(action_space.low, dtype=torch.float32))
        self.register_buffer('high', torch.as_tensor(action_space.high, dtype=torch.float32))

    def forward(self, flat):
        parts = torch.split(flat, self.sizes, dim=1)
        action = self.actor(dict(zip(self.keys, parts)), deterministic=True)
        return self.low + 0.5 * (action + 1.0) * (self.high - self.low)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--model', default=None, help='a URDF or xacro file; default: the package\'s UR5')
    p.add_argument('--tip', default=None, help='the link that reaches; default: the link below the most joints')
    p.add_argument('--control', default='ee', choices=('ee', 'joints'))
    p.add_argument('--steps', type=int, default=20_000, help='SAC steps')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--output', default='sac_reach.onnx', help='the ONNX file')
    a = p.parse_args()
    torch.set_num_threads(1)
    kwargs = dict(model=os.path.abspath(a.model) if a.model else None, tip=a.tip, control=a.control)
    env = gymnasium.make('robot_ai/Reach-v0', **{k: v for k, v in kwargs.items() if v is not None})
    setup = env.unwrapped.setup
    model = SAC('MultiInputPolicy', env, replay_buffer_class=HerReplayBuffer,
                replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy='future'), learning_starts=1000,
                batch_size=256, gamma=0.95, learning_rate=1e-3, tau=0.05, policy_kwargs=dict(net_arch=[64, 64]),
                seed=a.seed, device='cpu')
    t = time.monotonic()
    model.learn(a.steps)
    print(f'SAC + HER: {a.steps:,} steps in {time.monotonic() - t:.1f} s on {setup.arm.describe()}')

    wrapper = FlatActor(model.policy.actor, model.observation_space, model.action_space).eval()
    d = spaces.flatdim(model.observation_space)
    torch.onnx.export(wrapper, (torch.zeros((1, d)),), a.output, opset_version=17, input_names=['observation'],
                      output_names=['action'], dynamic_axes={'observation': {0: 'batch'}}, dynamo=False)

    keys, sizes = wrapper.keys, wrapper.sizes

    def predict(flat):
        parts = np.split(np.asarray(flat, dtype=np.float32), np.cumsum(sizes)[:-1], axis=1)
        return model.predict(dict(zip(keys, parts)), deterministic=True)[0]

    class Predictor:
        act_batch = staticmethod(predict)
    rate = learn.evaluate(Predictor(), setup, learn.HELD_OUT_EPISODES).success_rate
    print(f'model.predict: {100 * rate:.1f} % of {learn.HELD_OUT_EPISODES} fresh goals within '
          f'{setup.task.distance_threshold:g} m')

    exported = onnx.load(a.output)
    env_kwargs = dict(model=setup.model.path, tip=setup.arm.tip, control=setup.control,
                      limit_avoidance=setup.limit_avoidance)      # a file without it acts with none
    onnx.helper.set_model_props(exported, {onnx_policy.METADATA_KEY: json.dumps(dict(
        env_id=policy_files.ENV_ID, env_kwargs=env_kwargs, robot=setup.model.tree.name, joints=list(setup.arm.joints),
        success_rate=rate, algorithm='SAC + HER (stable-baselines3)', steps=a.steps))})
    onnx.save(exported, a.output)

    policy, _, note = policy_files.load(a.output, setup)
    rng = np.random.default_rng(a.seed)
    n, arm = setup.arm.n, setup.arm          # flattened: achieved goal, desired goal, joints, tip
    flat = np.concatenate((rng.uniform(-1, 1, (10_000, 6)), rng.uniform(arm.lower, arm.upper, (10_000, n)),
                           rng.uniform(-1, 1, (10_000, 3))), axis=1)
    expected, got = predict(flat), policy.act_batch(flat)
    worst = float(np.abs(expected - got).max())
    if worst > 1e-5:
        print(f'the ONNX file differs from model.predict by up to {worst:g} on 10,000 observations', file=sys.stderr)
        return 1
    print(f'{a.output}: onnxruntime acts as model.predict on 10,000 observations (within {worst:.1g}); '
          f'{policy.describe()}' + (f'\n{note}' if note else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
