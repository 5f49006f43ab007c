#!/usr/bin/env python3
"""How fast ARS learns to reach, on every reference robot and an arm of the tests, beside its baselines in the same
run; and ARS on CartPole beside the course's random search.

Per robot (control 'ee', 1000 held-out goals, seed 0):
- ARS from home (python -m robot_ai.reach train's defaults): wall time (model loading included), the seconds until
  an iteration's evaluation first reached 95 % and 99 %, steps, the held-out success rate;
- that policy and the plain P-controller on the tip error from random starts and chained (each goal from where
  the last left the arm, as rviz clicks come), and the P-controller from both without the limit recovery
  (ReachSetup.recover: what it adds).
Where stable-baselines3 and sb3-contrib are installed (a venv of their own: torch is gigabytes): sb3-contrib's ARS
(LinearPolicy, its defaults, 8 envs) and SAC with HER (rl-baselines3-zoo's settings for PandaReach: gamma 0.95,
learning rate 1e-3, tau 0.05, batch 256, two layers of 64) on the UR5's Reach-v0, steps and seconds.
Pose goals (goal='pose', within 0.05 m and 0.1 rad): ARS from home on its feature layer beside the P-controller on
the pose error, from home, random starts and chained.
Among a table and two boxes (test/world.yaml), the KUKA LWR and the PR2 (the reference arms whose collision geometry
is here): ARS trained with the obstacles and the P-controller, from home, random starts and chained, and the
P-controller without the recovery.
Through the safety layer (Reach-v0 velocity_scale: the arm moved as reach_controller's layer and a trajectory
controller move it, one 0.05 s control period per step, episodes of 200 steps / scale): ARS trained as reach_controller
trains it at start (at once, from home) and the P-controller, from home and chained, at scales 1, 0.5 and 0.25; and
ARS trained through the layer at 0.5.
CartPole-v1: ARS (the course's policy) over several seeds: episodes, steps and the 100-episode average, beside the
course's random search (100 x 100).

    python bench/reach_ars.py [--robots ur5,panda,...] [--seeds 10] [--sb3-steps 200000] [--sac-steps 20000]
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', 'src'))

from robot_ai.cartpole import linear_search  # noqa: E402
from robot_ai.cartpole.dynamics import CartPoleDynamics  # noqa: E402
from robot_ai.reach import ReachSetup, learn  # noqa: E402

SHARED = os.path.abspath(os.path.join(HERE, '..', '..', 'shared', 'robots'))
ROBOTS = {
    'ur5_package': (None, None),
    'ur5': (os.path.join(SHARED, 'ur5.urdf'), None),
    'kuka_lwr': (os.path.join(SHARED, 'kuka_lwr_arm.urdf'), None),
    'panda': (os.path.join(SHARED, 'panda.urdf'), None),
    'pr2': (os.path.join(SHARED, 'pr2.urdf'), None),
    'arm7_xacro': (os.path.abspath(os.path.join(HERE, '..', 'test', 'urdf', 'reach_arm7.urdf.xacro')), None),
    'arm7_xacro_2.8m': (os.path.abspath(os.path.join(HERE, '..', 'test', 'urdf', 'reach_arm7.urdf.xacro')),
                        'scale:=2.5 tool:=true'),
}


def first_reached(history, rate):
    hit = next((h for h in history if h.success_rate >= rate), None)
    return f'{hit.elapsed:5.1f} s' if hit else '   never'


def reach_section(names, extra_models):
    print('reach: ARS (robot_ai.reach train, seed 0, from home) beside the P-controller on the tip error, 1000 '
          'held-out goals from home, from random starts')
    print('  and chained (each goal from where the last left the arm, as rviz clicks come); "no recovery": the '
          'P-controller without the limit recovery (limit_recovery=False)')
    print(f'  {"robot":16s} {"joints":>6s} {"ee_step":>7s} {"ARS wall":>8s} {"to 95%":>7s} {"to 99%":>7s} '
          f'{"steps":>10s} {"ARS home":>8s} {"ARS rand":>8s} {"ARS chain":>9s} {"P home":>6s} {"P rand":>6s} '
          f'{"P chain":>7s}  no recovery: {"P rand":>6s} {"P chain":>7s}')
    models = [(n, *ROBOTS[n]) for n in names] + [(os.path.basename(m), m, None) for m in extra_models]
    for name, model, args in models:
        t0 = time.monotonic()
        home = learn.train(dict(model=model, xacro_args=args), seed=0)
        wall = time.monotonic() - t0
        setup = home.setup
        p = learn.p_controller(setup)
        rates = [learn.evaluate(policy, setup, start=start).success_rate
                 for policy in (home.policy, p) for start in ('random', 'chained')]
        plain = ReachSetup(model=model, xacro_args=args, limit_recovery=False)
        plain_rates = [learn.evaluate(learn.p_controller(plain), plain, start=start).success_rate
                       for start in ('random', 'chained')]
        print(f'  {name:16s} {setup.arm.n:6d} {setup.ee_step:7.3f} {wall:6.1f} s '
              f'{first_reached(home.result.history, 0.95):>7s} {first_reached(home.result.history, 0.99):>7s} '
              f'{home.result.steps:10,d} {100 * home.held_out.success_rate:7.1f}% {100 * rates[0]:7.1f}% '
              f'{100 * rates[1]:8.1f}% {100 * home.p_controller.success_rate:5.1f}% {100 * rates[2]:5.1f}% '
              f'{100 * rates[3]:6.1f}%               {100 * plain_rates[0]:5.1f}% {100 * plain_rates[1]:6.1f}%',
              flush=True)


POSE_ROBOTS = ('ur5_package', 'kuka_lwr', 'panda', 'pr2')


def timed_training(name: str, **kwargs) -> tuple:
    """(learn.train's Training of robot `name` with env kwargs, seed 0; its wall time in seconds)."""
    model, args = ROBOTS[name]
    t0 = time.monotonic()
    training = learn.train(dict(model=model, xacro_args=args, **kwargs), seed=0)
    return training, time.monotonic() - t0


def pose_section(names):
    print('pose goals: ARS (train --goal pose, seed 0) beside the P-controller on the pose error, 1000 held-out goals '
          'within 0.05 m and 0.1 rad')
    print(f'  {"robot":16s} {"ARS wall":>8s} {"ARS home":>8s} {"P home":>6s} {"ARS rand":>8s} {"P rand":>6s} '
          f'{"ARS chain":>9s} {"P chain":>7s}')
    for name in names:
        tip = 'r_gripper_tool_frame' if name == 'pr2' else None
        home, wall = timed_training(name, tip=tip, goal='pose')
        setup, p = home.setup, learn.p_controller(home.setup)
        rates = [learn.evaluate(policy, setup, start=start).success_rate
                 for start in ('random', 'chained') for policy in (home.policy, p)]
        print(f'  {name:16s} {wall:6.1f} s {100 * home.held_out.success_rate:7.1f}% '
              f'{100 * home.p_controller.success_rate:5.1f}% {100 * rates[0]:7.1f}% {100 * rates[1]:5.1f}% '
              f'{100 * rates[2]:8.1f}% {100 * rates[3]:6.1f}%', flush=True)


WORLD = os.path.abspath(os.path.join(HERE, '..', 'test', 'world.yaml'))
WORLD_ROBOTS = ('kuka_lwr', 'pr2')      # the reference arms whose collision geometry is on this machine


def world_section(names):
    print('among a table and two boxes (test/world.yaml, in each arm\'s base frame), the arm\'s body checked every '
          'step: ARS (train --obstacles, seed 0)')
    print('  beside the P-controller, 1000 held-out goals (the arm never touches: a motion that would is not made); '
          'the misses by reason; "no recovery": the P-controller without it')
    print(f'  {"robot":16s} {"ARS wall":>8s} {"ARS home":>8s} {"ARS rand":>8s} {"ARS chain":>9s} {"P home":>6s} '
          f'{"P rand":>6s} {"P chain":>7s}  no recovery: {"P rand":>6s} {"P chain":>7s}  misses of P rand')
    for name in names:
        model, args = ROBOTS[name]
        home, wall = timed_training(name, obstacles=WORLD)
        setup, p = home.setup, learn.p_controller(home.setup)
        ars_rates = [learn.evaluate(home.policy, setup, start=start).success_rate for start in ('random', 'chained')]
        p_random = learn.evaluate(p, setup, start='random')
        p_chained = learn.evaluate(p, setup, start='chained')
        plain = ReachSetup(model=model, xacro_args=args, obstacles=WORLD, limit_recovery=False)
        plain_rates = [learn.evaluate(learn.p_controller(plain), plain, start=start).success_rate
                       for start in ('random', 'chained')]
        print(f'  {name:16s} {wall:6.1f} s {100 * home.held_out.success_rate:7.1f}% {100 * ars_rates[0]:7.1f}% '
              f'{100 * ars_rates[1]:8.1f}% {100 * home.p_controller.success_rate:5.1f}% '
              f'{100 * p_random.success_rate:5.1f}% {100 * p_chained.success_rate:6.1f}%  {"":13s}'
              f'{100 * plain_rates[0]:5.1f}% {100 * plain_rates[1]:6.1f}%  {p_random.misses_text() or "none"}',
              flush=True)


def layer_section(names):
    print('through the safety layer (velocity_scale): ARS as reach_controller trains it at start (joints reached at '
          'once, from home) / the P-controller,')
    print('  1000 held-out goals within 0.05 m in 200 / scale steps of 0.05 s; "at once": the env without the layer '
          '(50 steps); "ARS@0.5": ARS trained through the layer at 0.5 (its wall time)')
    print(f'  {"robot":16s} {"at once":>13s} {"1.0 home":>13s} {"1.0 chain":>13s} {"0.5 home":>13s} {"0.5 chain":>13s} '
          f'{"0.25 home":>13s} {"0.25 chain":>13s} {"ARS@0.5 home":>13s} {"chain":>7s} {"wall":>7s}')
    pair = lambda a, b: f'{100 * a:5.1f}/{100 * b:5.1f}%'     # noqa: E731
    for name in names:
        model, args = ROBOTS[name]
        kwargs = dict(model=model, xacro_args=args)
        instant = learn.train(kwargs, seed=0)
        cells = [pair(instant.held_out.success_rate, instant.p_controller.success_rate)]
        for scale in (1.0, 0.5, 0.25):
            setup = ReachSetup(**kwargs, velocity_scale=scale)
            for start in ('home', 'chained'):
                cells.append(pair(learn.evaluate(instant.policy, setup, start=start).success_rate,
                                  learn.evaluate(learn.p_controller(setup), setup, start=start).success_rate))
        t0 = time.monotonic()
        layered = learn.train(dict(kwargs, velocity_scale=0.5), seed=0)
        wall = time.monotonic() - t0
        chained = learn.evaluate(layered.policy, layered.setup, start='chained').success_rate
        print(f'  {name:16s} {" ".join(f"{c:>13s}" for c in cells)} {100 * layered.held_out.success_rate:12.1f}% '
              f'{100 * chained:6.1f}% {wall:5.1f} s', flush=True)


def sb3_section(sb3_steps, sac_steps):
    try:
        import gymnasium
        from gymnasium.wrappers import FlattenObservation
        from sb3_contrib import ARS
        from stable_baselines3 import SAC, HerReplayBuffer
        from stable_baselines3.common.env_util import make_vec_env
    except ImportError:
        print('stable-baselines3 / sb3-contrib: not installed here (a venv of their own: pip install '
              'stable-baselines3 sb3-contrib)')
        return
    import torch
    torch.set_num_threads(1)
    setup = ReachSetup()

    def held_out(predict):
        class Adapter:
            def act_batch(self, x):
                return predict(x)
        return learn.evaluate(Adapter(), setup, 1000).success_rate
    print('stable-baselines3 on the package UR5\'s robot_ai/Reach-v0 (ee control), 1000 held-out goals')
    env = make_vec_env(lambda: FlattenObservation(gymnasium.make('robot_ai/Reach-v0', reward_type='dense')), n_envs=8,
                       seed=0)
    t0 = time.monotonic()
    model = ARS('LinearPolicy', env, seed=0, verbose=0)
    model.learn(total_timesteps=sb3_steps)
    seconds = time.monotonic() - t0
    rate = held_out(lambda x: model.predict(x.astype(np.float32), deterministic=True)[0])
    print(f'  sb3-contrib ARS (LinearPolicy, its defaults, 8 envs, dense reward): {sb3_steps:,} steps in '
          f'{seconds:.1f} s, '
          f'held-out {100 * rate:.1f}%', flush=True)
    env = gymnasium.make('robot_ai/Reach-v0')
    t0 = time.monotonic()
    model = SAC('MultiInputPolicy', env, replay_buffer_class=HerReplayBuffer, seed=0, verbose=0,
                replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy='future'), learning_starts=1000,
                batch_size=256, gamma=0.95, learning_rate=1e-3, tau=0.05, policy_kwargs=dict(net_arch=[64, 64]),
                device='cpu')
    model.learn(total_timesteps=sac_steps)
    seconds = time.monotonic() - t0
    keys = ('achieved_goal', 'desired_goal', 'observation')
    n = setup.arm.n

    def sac_predict(x):
        obs = {'achieved_goal': x[:, :3], 'desired_goal': x[:, 3:6], 'observation': x[:, 6:9 + n]}
        return model.predict({k: obs[k] for k in keys}, deterministic=True)[0]
    rate = held_out(sac_predict)
    print(f'  SAC + HER (rl-zoo\'s PandaReach settings, sparse reward, 4 future goals): {sac_steps:,} steps in '
          f'{seconds:.1f} s, '
          f'held-out {100 * rate:.1f}%', flush=True)


def cartpole_section(seeds):
    dynamics = CartPoleDynamics.of('CartPole-v1')
    print(f'CartPole-v1: ARS (the course\'s 4 weights) beside the course\'s random search, seeds 0-{seeds - 1}, 100 '
          f'episodes each')
    ars_avg, ars_steps, ars_eps, ars_time, rs_avg, rs_steps, rs_eps, rs_time = ([] for _ in range(8))
    s = linear_search.ARS_SETTINGS
    for seed in range(seeds):
        r = linear_search.ars_search('CartPole-v1', seed)
        ars_avg.append(linear_search.evaluate(dynamics, r.policy.weights[0], 100, 500, seed).mean())
        ars_steps.append(r.steps)
        ars_eps.append(2 * s.directions * s.episodes * len(r.history))
        ars_time.append(r.elapsed)
        search = linear_search.random_search(dynamics, seed=seed)
        rs_avg.append(search.final_avg_length)
        e, st = linear_search.episodes_used(search)
        rs_eps.append(e)
        rs_steps.append(st)
        rs_time.append(search.elapsed)
    for name, avg, eps, steps, secs in (('ARS', ars_avg, ars_eps, ars_steps, ars_time),
                                        ('random search', rs_avg, rs_eps, rs_steps, rs_time)):
        print(f'  {name:14s} average {min(avg):6.1f} (worst seed) to {max(avg):6.1f}, median {np.median(avg):6.1f}; '
              f'episodes {int(np.median(eps)):7,d}, steps {int(np.median(steps)):10,d}, {np.median(secs):.2f} s '
              f'(medians)')
    print(f'  seeds at 475 or more: ARS {sum(a >= 475 for a in ars_avg)} of {seeds}, random search '
          f'{sum(a >= 475 for a in rs_avg)} of {seeds}')


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--robots', default=','.join(ROBOTS), help=f'of {", ".join(ROBOTS)}')
    p.add_argument('--model', action='append', default=[], help='another URDF or xacro file (repeatable)')
    p.add_argument('--seeds', type=int, default=10, help='CartPole seeds')
    p.add_argument('--sb3-steps', type=int, default=200000, help='sb3-contrib ARS steps')
    p.add_argument('--sac-steps', type=int, default=20000, help='SAC + HER steps')
    p.add_argument('--skip', default='', help='sections to skip: reach, pose, world, layer, sb3, cartpole')
    a = p.parse_args()
    load = open('/proc/loadavg').read().split()[0]
    print(f'reach and ARS, {os.cpu_count()} cores (load average {load})   [bench/reach_ars.py, '
          f'{time.strftime("%Y-%m-%d")}]')
    if 'reach' not in a.skip:
        reach_section([n for n in a.robots.split(',') if n], a.model)
    if 'pose' not in a.skip:
        pose_section([n for n in a.robots.split(',') if n in POSE_ROBOTS])
    if 'world' not in a.skip:
        world_section([n for n in a.robots.split(',') if n in WORLD_ROBOTS])
    if 'layer' not in a.skip:
        layer_section([n for n in a.robots.split(',') if n in POSE_ROBOTS])
    if 'cartpole' not in a.skip:
        cartpole_section(a.seeds)
    if 'sb3' not in a.skip:
        sb3_section(a.sb3_steps, a.sac_steps)
    return 0


if __name__ == '__main__':
    sys.exit(main())
