#!/usr/bin/env python3
"""Picks clicked in rviz, as pick_place carries them out, measured in MuJoCo (robot_ai.physics.pick.run_in_physics:
the world arm_sim runs, every command the safety layer's plan, followed in time by the servos), beside the same
driver in PickAndPlace-v0 without the layer (50 steps, the env's own episodes), in the same run:

- on the Panda of ../shared/robots with its real meshes and the package's UR5 with a Robotiq 2F-85, the scripted
  expert, --picks picks each (a cube from the world command's draws, a place on the table drawn in the workspace);
- placed (within the env's 5 cm once at rest, the gripper open and the arm risen), the distance to the click, the
  pick's duration (simulated seconds), the fastest joint as a share of its URDF velocity limit, the servos' largest
  lag behind the plans, the contacts of the robot with anything but the cube it picks (the layer's promise: none);
- objects other than the task's cube (OBJECTS: cans short and tall, a brick either way round, a flat box, cubes of 3
  and 6 cm, one of 0.5 kg, one of friction 0.3, a pen, a 3x8x3 cm bar along the fingers' closing axis, a ball), one
  pick each from the same start to the same place,
  each alone on the table: placed or why not.

    python bench/pick_place.py [--picks 20]
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', 'src'))

from robot_ai.physics.env import ManipulationSetup, ManipulationVectorEnv  # noqa: E402
from robot_ai.physics.learn import FINAL_SEED, evaluate, expert_policy  # noqa: E402
from robot_ai.physics.model import build_physics  # noqa: E402
from robot_ai.physics.pick import PickPlace, run_in_physics, world  # noqa: E402
from robot_ai.physics.sim import ArmPhysics  # noqa: E402

ROBOTS = os.path.join(HERE, '..', '..', 'shared', 'robots')
OBJECTS = [{'cylinder': [0.02, 0.06], 'name': 'can'}, {'cylinder': [0.025, 0.16], 'name': 'tall_can'},
           {'box': [0.03, 0.05, 0.05], 'name': 'brick'}, {'box': [0.05, 0.03, 0.05], 'name': 'brick_turned'},
           {'box': [0.05, 0.05, 0.02], 'name': 'flat_box'}, {'box': [0.03] * 3, 'name': 'cube_3cm'},
           {'box': [0.06] * 3, 'name': 'cube_6cm'}, {'box': [0.04] * 3, 'mass': 0.5, 'name': 'heavy_cube'},
           {'box': [0.04] * 3, 'friction': 0.3, 'name': 'slippery_cube'}, {'cylinder': [0.015, 0.08], 'name': 'pen'},
           {'box': [0.03, 0.08, 0.03], 'name': 'bar'}, {'sphere': 0.022, 'name': 'ball'}]
ARMS = {'panda (its meshes)': os.path.join(ROBOTS, 'panda.urdf'),
        'ur5 + robotiq 2f-85': os.path.join(HERE, '..', 'urdf', 'ur5_robotiq_2f85.urdf.xacro')}


def picks(setup: ManipulationSetup, count: int) -> dict:
    rng = np.random.default_rng(0)
    placed, distances, seconds, fastest, lag, others = 0, [], [], 0.0, 0.0, set()
    for k in range(count):
        made = world(setup, 1, k)
        physics = build_physics(setup.robot, obstacles=made['obstacles'], objects=made['objects'],
                                home=made['home'])
        arm = ArmPhysics(physics, setup.arm.joints)
        picking = PickPlace(setup, obstacles=made['obstacles'])
        place = [*(setup.space.centre[:2] + rng.uniform(-0.15, 0.15, 2)), setup.space.table_top]
        run = run_in_physics(picking, arm, 'cube', place)
        placed += run.outcome.startswith('placed')
        distances.append(float(np.linalg.norm(arm.object_poses()['cube'][:3, 3] - picking.place)))
        seconds.append(run.seconds)
        fastest, lag = max(fastest, run.fastest), max(lag, run.tracking)
        others |= {c for c in run.contacts if not c.endswith(' - cube')}
    return dict(placed=placed, distance=float(np.median(distances)), seconds=float(np.median(seconds)),
                fastest=fastest, lag=lag, others=sorted(others))


def objects(setup: ManipulationSetup) -> list[tuple[str, str]]:
    """(name, outcome) of one pick of each of OBJECTS, standing on the table 5 cm on from the workspace's middle in x
    and back in y, to a click 10 cm back in x and on in y."""
    c, top = setup.space.centre, setup.space.table_top
    out = []
    for spec in OBJECTS:
        thing = {'mass': 0.1, **spec, 'position': [c[0] + 0.05, c[1] - 0.05, top]}
        picking = PickPlace(setup, obstacles=[setup.table()], objects=[thing])      # its size: how high it stands
        thing['position'][2] += picking.half_height(spec['name'])
        physics = build_physics(setup.robot, obstacles=[setup.table()], objects=[thing],
                                home=dict(zip(setup.arm.joints, picking.ready)))
        arm = ArmPhysics(physics, setup.arm.joints)
        run = run_in_physics(picking, arm, spec['name'], [c[0] - 0.1, c[1] + 0.1, top])
        out.append((spec['name'], run.outcome))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--picks', type=int, default=20)
    a = p.parse_args()
    os.environ['ROS_PACKAGE_PATH'] = os.pathsep.join((os.path.join(ROBOTS, 'meshes'),
                                                      os.environ.get('ROS_PACKAGE_PATH', '')))
    print('== picks clicked in rviz (pick_place), through the safety layer in MuJoCo, beside PickAndPlace-v0 ==')
    print(f'{"robot":<22}{"placed":>8}  {"median miss":>11}  {"median time":>11}  {"fastest":>8}  {"lag":>7}  '
          f'{"other contacts":>14}  {"env, no layer":>13}')
    for name, model in ARMS.items():
        setup = ManipulationSetup('pick_and_place', model=model)
        r = picks(setup, a.picks)
        env = ManipulationVectorEnv(min(32, a.picks), 'pick_and_place', setup=setup)
        reference = evaluate(expert_policy(setup), env, a.picks, FINAL_SEED)[0]
        print(f'{name:<22}{r["placed"]:>4} / {a.picks:<2} {1000 * r["distance"]:8.1f} mm  {r["seconds"]:9.1f} s  '
              f'{r["fastest"]:8.2f}  {r["lag"]:5.3f}  {len(r["others"]) or "none":>14}  '
              f'{100 * reference:11.1f} %')
        for c in r['others']:
            print(f'    contact: {c}')
    print('(fastest: the largest joint speed over its URDF velocity limit, the layer allowing 0.5; lag: the servos\' '
          'largest distance from the plans, rad; env, no layer: the expert\'s success in the env, 50 steps)')
    print('\n== objects other than the task\'s cube, one pick each, the scripted expert ==')
    for name, model in ARMS.items():
        done = objects(ManipulationSetup('pick_and_place', model=model))
        placed = [n for n, outcome in done if outcome.startswith('placed')]
        print(f'{name:<22}{len(placed):>4} / {len(done):<2} placed: {", ".join(placed) or "none"}')
        for n, outcome in done:
            if not outcome.startswith('placed'):
                print(f'    {n}: {outcome}')


if __name__ == '__main__':
    main()
