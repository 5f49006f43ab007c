#!/usr/bin/env python3
"""Speed of the reach envs beside panda-gym's PandaReach-v3 (PyBullet), measured in the same run:

- ReachVectorEnv steps per second at N = 1, 64 and 4096 arms (the package's UR5 and the Panda of ../shared/robots),
  tip control ('ee': Jacobian and damped least squares every step) and joint control, random actions;
- one ReachEnv made by gymnasium.make (TimeLimit, order and passive-checker wrappers), as an agent steps it;
- the same with collisions: the KUKA LWR's body (its URDF collision geometry as spheres) checked against itself and a
  table and two boxes every step;
- PandaReach-v3, one env by gymnasium.make, where panda-gym is installed (it is not a dependency: install it in a
  venv of its own, `pip install panda-gym`, and run this script with that venv's python and PYTHONPATH=src).

    python bench/reach_speed.py [--seconds 3]
"""
import argparse
import importlib
import os
import sys
import time

import gymnasium
import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', 'src'))

from robot_ai.reach import ReachVectorEnv  # noqa: E402  (the import registers robot_ai/Reach-v0)

PANDA = os.path.join(HERE, '..', '..', 'shared', 'robots', 'panda.urdf')
KUKA = os.path.join(HERE, '..', '..', 'shared', 'robots', 'kuka_lwr_arm.urdf')
# a table and two boxes in the arm's base frame: the KUKA LWR's URDF carries its collision geometry (boxes, cylinders,
# spheres), so its body is checked against itself and them every step
WORLD = [{'box': [2.0, 2.0, 0.05], 'position': [0, 0, -0.03], 'name': 'table'},
         {'box': [0.2, 0.3, 0.4], 'position': [0.45, 0.1, 0.3], 'rpy': [0, 0, 0.5], 'name': 'box 1'},
         {'box': [0.1, 0.1, 0.6], 'position': [-0.3, -0.4, 0.5], 'name': 'box 2'}]


def vector_rate(n: int, seconds: float, **kwargs) -> float:
    env = ReachVectorEnv(n, **kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (64,) + env.action_space.shape).astype(np.float32)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        env.step(actions[steps % 64])
        steps += 1
    return n * steps / (time.perf_counter() - t0)


def single_rate(env, seconds: float) -> float:
    env.reset(seed=0)
    actions = [env.action_space.sample() for _ in range(64)]
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, terminated, truncated, _ = env.step(actions[steps % 64])
        steps += 1
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - t0)
    env.close()
    return rate


def panda_reach(seconds: float) -> float | None:
    try:
        importlib.import_module('panda_gym')      # registers PandaReach-v3
    except ImportError:
        return None
    return single_rate(gymnasium.make('PandaReach-v3'), seconds)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--seconds', type=float, default=3.0, help='seconds of stepping per case')
    a = p.parse_args()
    load = open('/proc/loadavg').read().split()[0]
    print(f'reach env speed, {a.seconds:g} s a case, {os.cpu_count()} cores (load average {load})   '
          f'[bench/reach_speed.py, {time.strftime("%Y-%m-%d")}]')
    reference = panda_reach(a.seconds)
    if reference is None:
        print('  PandaReach-v3 (panda-gym, PyBullet), one env:        not installed here (pip install panda-gym in a '
              'venv of its own)')
    else:
        print(f'  PandaReach-v3 (panda-gym, PyBullet), one env:   {reference:12,.0f} steps/s  (reference)')

    def versus(rate):
        return f'  {rate / reference:7.0f} x PandaReach' if reference else ''
    for name, model in (('UR5 (package)', None), ('Panda', os.path.abspath(PANDA))):
        rate = single_rate(gymnasium.make('robot_ai/Reach-v0', model=model), a.seconds)
        print(f'  Reach-v0 {name:14s} gymnasium.make, one env: {rate:12,.0f} steps/s{versus(rate)}')
        for control in ('ee', 'joints'):
            for n in (1, 64, 4096):
                rate = vector_rate(n, a.seconds, model=model, control=control)
                print(f'  ReachVectorEnv {name:14s} {control:6s} N = {n:4d}: {rate:12,.0f} steps/s{versus(rate)}')
    name = 'KUKA + world'
    rate = single_rate(gymnasium.make('robot_ai/Reach-v0', model=os.path.abspath(KUKA), obstacles=WORLD), a.seconds)
    print(f'  Reach-v0 {name:14s} gymnasium.make, one env: {rate:12,.0f} steps/s{versus(rate)}  (its body and a '
          f'table and two boxes checked every step)')
    for n in (1, 64, 4096):
        rate = vector_rate(n, a.seconds, model=os.path.abspath(KUKA), obstacles=WORLD)
        print(f'  ReachVectorEnv {name:14s} ee     N = {n:4d}: {rate:12,.0f} steps/s{versus(rate)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
