#!/usr/bin/env python3
"""What a policy costs the robot: one action's latency (median and 99th percentile, one observation at a time, as
the controllers ask) and the memory loading it adds, for

- the package's .npz policies (the CartPole's linear policy, the UR5's ARS reach policy): numpy;
- ONNX models through robot_ai.policies.onnx (onnxruntime, one thread): stable-baselines3's default shapes, built with
  onnx.helper so that no torch is needed: PPO's CartPole MLP (4-64-64-2, tanh) and SAC's reach actor on the UR5
  (15-256-256-3, ReLU, tanh), plus the SAC actor with rl-baselines3-zoo's two layers of 64;
- the reference: the same SAC actor in torch, model.predict as stable-baselines3 runs it, where torch and
  stable-baselines3 are installed (they are not dependencies: run this script with that venv's python and
  PYTHONPATH=src to see it).

The controllers' budget is one action per step: 20 ms at the CartPole's 50 steps/s, 50 ms at reach_controller's 20.

    python bench/policy_latency.py [--actions 2000]
"""
import argparse
import json
import os
import resource
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', 'src'))

import onnx  # noqa: E402
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from robot_ai import policies  # noqa: E402
from robot_ai.cartpole import linear_search, policy_kinds  # noqa: E402
from robot_ai.policies import onnx as onnx_policy  # noqa: E402
from robot_ai.reach import ReachSetup, learn, policy_files  # noqa: E402


def rss_mib() -> float:
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024
    return float('nan')


def mlp(sizes, hidden: str, out: str, env: dict, integer_action=False) -> onnx.ModelProto:
    """An MLP as stable-baselines3 exports it: Gemm layers, `hidden` activations, `out` on the last (or an ArgMax to
    an int64 action)."""
    rng = np.random.default_rng(0)
    nodes, inits, x = [], [], 'obs'
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        inits += [numpy_helper.from_array((rng.normal(size=(a, b)) / np.sqrt(a)).astype(np.float32), f'W{i}'),
                  numpy_helper.from_array(np.zeros(b, np.float32), f'b{i}')]
        nodes.append(helper.make_node('Gemm', [x, f'W{i}', f'b{i}'], [f'z{i}']))
        last = i == len(sizes) - 2
        act = out if last else hidden
        if act and not (last and integer_action):
            nodes.append(helper.make_node(act, [f'z{i}'], [f'h{i}']))
            x = f'h{i}'
        else:
            x = f'z{i}'
    if integer_action:
        nodes.append(helper.make_node('ArgMax', [x], ['action'], axis=1, keepdims=0))
        output = helper.make_tensor_value_info('action', TensorProto.INT64, ['batch'])
    else:
        nodes.append(helper.make_node('Identity', [x], ['action']))
        output = helper.make_tensor_value_info('action', TensorProto.FLOAT, ['batch', sizes[-1]])
    graph = helper.make_graph(nodes, 'mlp', [helper.make_tensor_value_info('obs', TensorProto.FLOAT,
                                                                           ['batch', sizes[0]])], [output], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 17)], producer_name='bench')
    m.ir_version = 8
    helper.set_model_props(m, {onnx_policy.METADATA_KEY: json.dumps(env)})
    return m


def latency(act, observations) -> tuple[float, float]:
    """(median, 99th percentile) in microseconds of act(one observation)."""
    for o in observations[:50]:
        act(o)
    times = np.empty(len(observations))
    for i, o in enumerate(observations):
        t = time.perf_counter()
        act(o)
        times[i] = time.perf_counter() - t
    return float(np.median(times) * 1e6), float(np.percentile(times, 99) * 1e6)


def row(name: str, act, observations, before: float) -> None:
    med, p99 = latency(act, observations)
    print(f'  {name:<58} {med:9.1f} µs {p99:9.1f} µs {rss_mib() - before:8.1f} MiB', flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--actions', type=int, default=2000, help='actions timed per policy')
    a = p.parse_args()
    n = a.actions
    rng = np.random.default_rng(0)
    folder = tempfile.mkdtemp()
    setup = ReachSetup()
    d = 9 + setup.arm.n
    cart = (rng.normal(size=(n, 4)) * [1, 1, 0.1, 1]).astype(np.float32)
    reach_obs = [setup.observation_space.sample() for _ in range(n)]
    reach_flat = rng.uniform(-1, 1, (n, d)).astype(np.float32)
    print(f'One action at a time ({n:,} timed each, one thread; memory: resident set added by loading it)')
    print(f'  {"policy":<58} {"median":>12} {"p99":>12} {"memory":>12}')

    before = rss_mib()
    linear = policies.Policy(linear_search.LinearPolicy(np.array([0.02, 0.35, 1.0, 0.55])),
                             dict(kind='linear', env_id='CartPole-v1', seed=0))
    row('.npz linear policy, CartPole (numpy)', linear.act, cart, before)
    actor = learn.p_controller(setup)        # an ars_linear policy: ARS's reach policies compute just this
    row('.npz ARS linear reach policy, UR5 (numpy, act_batch of one)', lambda o: actor.act_batch(o[None]),
        reach_flat, rss_mib())

    cases = [('ONNX PPO CartPole MLP 4-64-64-2 tanh, int64 action', [4, 64, 64, 2], 'Tanh', '',
              {'env_id': 'CartPole-v1'}, True, cart),
             ('ONNX SAC reach actor 15-256-256-3 ReLU, tanh (sb3 default)', [d, 256, 256, 3], 'Relu', 'Tanh',
              {'env_id': 'robot_ai/Reach-v0'}, False, reach_obs),
             ('ONNX SAC reach actor 15-64-64-3 (rl-zoo\'s net_arch)', [d, 64, 64, 3], 'Relu', 'Tanh',
              {'env_id': 'robot_ai/Reach-v0'}, False, reach_obs)]
    for name, sizes, hidden, out, env, integer, obs in cases:
        path = os.path.join(folder, 'm.onnx')
        with open(path, 'wb') as f:
            f.write(mlp(sizes, hidden, out, env, integer).SerializeToString())
        before = rss_mib()
        policy = policy_kinds.load(path) if integer else policy_files.load(path)[0]
        row(name, policy.act, obs, before)

    before = rss_mib()           # torch's own footprint counts: it is what the robot would carry
    try:
        import gymnasium
        import torch
        from stable_baselines3 import SAC
    except ImportError:
        print('  torch / stable-baselines3: not installed here (the reference; a venv of their own, see the docstring)')
        return 0
    torch.set_num_threads(1)
    env = gymnasium.make('robot_ai/Reach-v0')
    model = SAC('MultiInputPolicy', env, seed=0, device='cpu')
    row('torch SAC MultiInputPolicy 256-256, model.predict (reference)',
        lambda o: model.predict(o, deterministic=True), reach_obs, before)
    print(f'  (peak resident set of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
