#!/usr/bin/env python3
"""Push-v0 and PickAndPlace-v0 (robot_ai.physics) beside panda-gym and stable-baselines3, measured in the same run:

- env steps per second on one core (BLAS held to one thread): one Push-v0 env made by gymnasium.make, and
  ManipulationVectorEnv at 32 and 128 worlds, random actions, on the Panda of ../shared/robots with its real meshes;
  MuJoCo alone on the same 128 worlds (their physics stepped, no Python between: the env's ceiling);
  panda-gym's PandaPush-v3 (PyBullet) the same way, where panda-gym is installed here or in --sb3-python;
- learning (robot_ai.physics.learn: DAgger of the scripted expert): on the Panda and on the package's UR5 with a
  Robotiq 2F-85, push and pick and place, the wall time until the held-out success first reaches 90 % (push) and
  80 % (pick and place), where it stopped, and the success over 200 fresh goals beside the expert's;
- stable-baselines3's TQC + HER on PandaPush-v3 and PandaPickAndPlace-v3 with rl-baselines3-zoo's hyperparameters
  and the same wall-clock budget (--minutes), where --sb3-python names a Python that has them (bench/sb3_panda_gym.py:
  torch is never the package's dependency).

    python bench/manipulation.py [--minutes 30] [--quick] [--sb3-python ~/sb3/bin/python] [--skip-sb3]
"""
import argparse
import importlib.util
import json
import os
import subprocess
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', 'src'))
sys.path.insert(0, HERE)

import robot_ai.physics  # noqa: E402,F401  (registers the envs)
from robot_ai.physics.env import ManipulationSetup, ManipulationVectorEnv  # noqa: E402
from robot_ai.physics.learn import FINAL_SEED, LearnSettings, evaluate, expert_policy, learn  # noqa: E402
from sb3_panda_gym import speed  # noqa: E402  (bench/: the same loop in SB3's Python)

ROBOTS = os.path.join(HERE, '..', '..', 'shared', 'robots')
PANDA = os.path.join(ROBOTS, 'panda.urdf')
UR5_ROBOTIQ = os.path.join(HERE, '..', 'urdf', 'ur5_robotiq_2f85.urdf.xacro')
THRESHOLDS = {'push': 0.9, 'pick_and_place': 0.8}
SB3_ENVS = {'push': 'PandaPush-v3', 'pick_and_place': 'PandaPickAndPlace-v3'}


def vector_rate(n: int, seconds: float) -> float:
    env = ManipulationVectorEnv(n, 'push', model=PANDA)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (16, n, 4))
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        env.step(actions[steps % 16])
        steps += 1
    return n * steps / (time.perf_counter() - t0)


def physics_rate(n: int, seconds: float) -> tuple[float, float, int]:
    """(env steps per second of MuJoCo alone: n worlds, 20 random steps in, stepped an env step's substeps each with
    the commands they last had, no Python between; microseconds a MuJoCo step; substeps an env step): the ceiling of
    the env's rate at MuJoCo's step."""
    import mujoco
    env = ManipulationVectorEnv(n, 'push', model=PANDA)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (20, n, 4))
    for a in actions:
        env.step(a)
    model, substeps = env.setup.physics.model, env.setup.substeps
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for data in env.datas:
            mujoco.mj_step(model, data, nstep=substeps)
        steps += 1
    elapsed = time.perf_counter() - t0
    return n * steps / elapsed, elapsed / (n * steps * substeps) * 1e6, substeps


def panda_gym_rate(sb3_python: str) -> tuple[float | None, str]:
    if importlib.util.find_spec('panda_gym') is not None:
        return speed(5.0), 'here'
    if sb3_python:
        out = subprocess.run([sb3_python, os.path.join(HERE, 'sb3_panda_gym.py'), '--speed'], capture_output=True,
                             text=True, timeout=600, env={**os.environ, 'OMP_NUM_THREADS': '1'})
        if out.returncode == 0:
            return json.loads(out.stdout.strip().splitlines()[-1])['steps_per_second'], sb3_python
    return None, 'panda-gym not installed (pip install panda-gym, or --sb3-python)'


def learning(name: str, model: str, task: str, minutes: float) -> None:
    setup = ManipulationSetup(task, model=model)
    first = {}

    def on_round(r) -> None:
        if r.eval_success is not None and r.eval_success >= THRESHOLDS[task] and 'seconds' not in first:
            first['seconds'] = r.seconds
    training = learn(setup, LearnSettings(minutes=minutes), seed=0, on_round=on_round)
    env = ManipulationVectorEnv(32, task, setup=setup)
    held, _ = evaluate(training.net.act_batch, env, 200, FINAL_SEED)
    expert, _ = evaluate(expert_policy(setup), env, 200, FINAL_SEED)
    reached = f'{first["seconds"]:7.0f} s' if 'seconds' in first else '  never'
    print(f'{name:<22}{task:<16}{reached:>10}  {training.elapsed:7.0f} s  {100 * held:6.1f} %  {100 * expert:6.1f} %  '
          f'{training.steps:>10,d}', flush=True)


def sb3(sb3_python: str, task: str, minutes: float) -> None:
    out = subprocess.run([sb3_python, os.path.join(HERE, 'sb3_panda_gym.py'), '--env', SB3_ENVS[task],
                          '--minutes', str(minutes)], capture_output=True, text=True, timeout=minutes * 60 + 1800)
    if out.returncode != 0:
        print(f'{"SB3 TQC+HER":<22}{SB3_ENVS[task]:<22} failed: {out.stderr.strip().splitlines()[-1:]}')
        return
    r = json.loads(out.stdout.strip().splitlines()[-1])
    print(f'{"SB3 TQC+HER":<22}{SB3_ENVS[task]:<22}{r["train_seconds"]:7.0f} s  {100 * r["success_rate"]:6.1f} % '
          f'of {r["episodes"]} episodes  {r["env_steps"]:>10,d} steps', flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--minutes', type=float, default=30.0, help='the learning budget, ours and SB3\'s')
    p.add_argument('--quick', action='store_true', help='the env speeds and the Panda\'s learning only, 5 minutes')
    p.add_argument('--sb3-python', default=os.environ.get('SB3_PYTHON', ''),
                   help='a Python with stable-baselines3, sb3-contrib and panda-gym (bench/sb3_panda_gym.py)')
    p.add_argument('--skip-sb3', action='store_true',
                   help='panda-gym\'s speed only, not SB3\'s learning (2 x --minutes; its figures do not depend on '
                        'this package)')
    a = p.parse_args()
    print('== Push-v0 and PickAndPlace-v0 (MuJoCo) beside panda-gym (PyBullet) and SB3 ==')
    with threadpool_limits(limits=1):
        single = speed(5.0, 'robot_ai/Push-v0', model=PANDA)     # the loop that times PandaPush-v3
        vectors = {n: vector_rate(n, 5.0) for n in (32, 128)}
        ceiling, step_us, substeps = physics_rate(128, 5.0)
        reference, where = panda_gym_rate(a.sb3_python)
    print('env steps per second, one core (random actions, the Panda with its meshes):')
    print(f'  Push-v0, one env (gymnasium.make)     {single:9,.0f}')
    for n, rate in vectors.items():
        print(f'  ManipulationVectorEnv, {n:3d} worlds     {rate:9,.0f}' +
              (f'   {rate / reference:5.1f} x PandaPush-v3' if reference else ''))
    print(f'  MuJoCo alone, 128 worlds (no Python)  {ceiling:9,.0f}' +
          (f'   {ceiling / reference:5.1f} x PandaPush-v3' if reference else '') +
          f'   ({step_us:.1f} us a MuJoCo step, {substeps} an env step: the ceiling at MuJoCo\'s 2 ms)')
    print(f'  PandaPush-v3 (panda-gym), one env      {reference:9,.0f}' if reference else
          f'  PandaPush-v3: {where}')
    minutes = 5.0 if a.quick else a.minutes
    print(f'learning (DAgger, budget {minutes:g} min; first: the wall time to {100 * THRESHOLDS["push"]:.0f} % push, '
          f'{100 * THRESHOLDS["pick_and_place"]:.0f} % pick and place, held-out):')
    print(f'{"robot":<22}{"task":<16}{"first":>10}  {"stopped":>9}  {"held-out":>8}  {"expert":>8}  {"env steps":>10}')
    arms = [('panda', PANDA)] + ([] if a.quick else [('ur5 + robotiq 2f-85', UR5_ROBOTIQ)])
    for name, model in arms:
        for task in ('push', 'pick_and_place'):
            learning(name, model, task, minutes)
    if a.sb3_python and not (a.quick or a.skip_sb3):
        for task in ('push', 'pick_and_place'):
            sb3(a.sb3_python, task, minutes)
    elif a.skip_sb3:
        print('SB3 TQC+HER: not run (--skip-sb3)')
    elif not a.quick:
        print('SB3 TQC+HER: not run (give --sb3-python: a Python with stable-baselines3, sb3-contrib and panda-gym)')


if __name__ == '__main__':
    main()
