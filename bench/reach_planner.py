"""The motion planner with the arms' real bodies (issue 54): success and planning time of robot_ai.reach.planning
(OMPL RRT-Connect over the batched sphere check, TOPP-RA timing) on the UR5 and the Panda with their real collision
meshes (../shared/robots/meshes), the KUKA LWR and the PR2's right arm; among a table under the base and two objects,
and with the body alone; from home, random starts and chained (each goal from where the last plan left the arm).
Beside it, in the same run, the reference a MoveIt user gets: OMPL's RRT-Connect with a one-at-a-time state check
(OMPL's discrete motion validator, the same spacing) on the same starts and goal configurations. Then Reach-v0's
P-controller among the same world, with and without the planned way round, and the planner's share, in-process and
through the safety layer (each goal planned first, as reach_controller plans it, beside the policy first); goals planned
and followed through the safety layer as reach_controller drives them; and how tight the spheres are against the
meshes themselves (python-fcl through trimesh, the FCL MoveIt uses): the share of random configurations the spheres
refuse while every pair they flag is more than 2 cm apart by the meshes (over-conservative), and contacts missed.

A goal counts when its drawn configuration is clear of contacts by the margin (it has a clear reaching configuration).

    python bench/reach_planner.py [--problems 30] [--reference-limit 1.0] [--episodes 200] [--follow 40]
                                  [--tightness 3000]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROBOTS = os.path.join(HERE, '..', '..', 'shared', 'robots')
os.environ['ROS_PACKAGE_PATH'] = os.path.join(ROBOTS, 'meshes') + os.pathsep + os.environ.get('ROS_PACKAGE_PATH', '')

from robot_ai.reach import learn  # noqa: E402
from robot_ai.reach.env import ReachSetup  # noqa: E402
from robot_ai.reach.planning import ReachPlanner, follow_through_layer  # noqa: E402

WORLD = [{'box': [2.0, 2.0, 0.05], 'position': [0, 0, -0.105], 'name': 'table'},
         {'box': [0.2, 0.2, 0.5], 'position': [0.45, 0.15, 0.25], 'rpy': [0, 0, 0.5], 'name': 'box'},
         {'sphere': 0.12, 'position': [-0.2, -0.45, 0.4], 'name': 'ball'}]
ARMS = [('ur5.urdf', None, [1.57, -1.57, 1.57, -1.57, 1.57, 0.0]), ('panda.urdf', 'panda_hand', None),
        ('kuka_lwr_arm.urdf', None, None), ('pr2.urdf', 'r_gripper_tool_frame', None)]


def reference(planner: ReachPlanner, start: np.ndarray, goal_q: np.ndarray, limit: float) -> tuple[bool, float]:
    """OMPL RRT-Connect as MoveIt runs it: a state validity checker called one state at a time, OMPL's own discrete
    motion validator at the same spacing of states."""
    from ompl import base as ob, geometric as og
    joints = planner.joints
    n = joints.n
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(joints.lower[i]))
        bounds.setHigh(i, float(joints.upper[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda s: bool(planner.clear(np.array([[s[i] for i in range(n)]]))[0]))
    # OMPL's resolution is a share of the space's extent: the one that checks a motion as finely as ours
    per_rad = float(joints.sweep.max()) / joints.spacing
    si.setStateValidityCheckingResolution(min(0.5, 1.0 / (per_rad * space.getMaximumExtent())))
    si.setup()
    ss = og.SimpleSetup(si)
    a, b = space.allocState(), space.allocState()
    for i in range(n):
        a[i], b[i] = float(start[i]), float(goal_q[i])
    ss.setStartAndGoalStates(a, b)
    ss.setPlanner(og.RRTConnect(si))
    began = time.monotonic()
    ss.solve(limit)
    ok = ss.haveExactSolutionPath()
    if ok:
        ss.simplifySolution(0.05)
    return bool(ok), time.monotonic() - began


def run(robot, tip, home, world, start_kind, problems, reference_limit, seed=0):
    setup = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, home=home, obstacles=world, collision=True,
                       start='random' if start_kind == 'random' else 'home')
    planner = ReachPlanner(setup)
    goals, starts = setup.first_states([np.random.default_rng(seed + i) for i in range(4 * problems)])
    counted = np.flatnonzero(planner.clear(goals.T) & (planner.clear(starts.T) if start_kind == 'random' else True))
    counted = counted[:problems]
    q = setup.home.copy()
    ok, times, reasons, ref_ok, ref_times = 0, [], {}, 0, []
    for i in counted:
        goal = setup.goals_of(goals[:, i:i + 1])[:, 0]
        start = starts[:, i] if start_kind == 'random' else (setup.home if start_kind == 'home' else q)
        plan = planner.plan(start, goal)
        times.append(plan.seconds)
        if plan.found:
            ok += 1
            q = plan.timed.end.copy()
            if reference_limit:
                configurations, _ = planner.goal_configurations(goal, start)
                r_ok, r_time = reference(planner, start, configurations[0], reference_limit)
                ref_ok += r_ok
                ref_times.append(r_time)
        else:
            reasons[plan.reason] = reasons.get(plan.reason, 0) + 1
    return len(counted), ok, np.array(times), reasons, ref_ok, np.array(ref_times)


def follow(robot, tip, home, start_kind, goals_wanted, seed=2000):
    """(goals counted, reached, refused steps, reasons missed) of goals planned and followed through the safety
    layer at velocity_scale 0.25 as reach_controller drives them (planning.follow_through_layer), among the world."""
    setup = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, home=home, obstacles=WORLD, collision=True,
                       start='random' if start_kind == 'random' else 'home')
    goals, starts = setup.first_states([np.random.default_rng(seed + i) for i in range(4 * goals_wanted)])
    clear = ~setup.body.in_collision(goals.T, 0.02) & (~setup.body.in_collision(starts.T, 0.02)
                                                       if start_kind == 'random' else True)
    counted = np.flatnonzero(clear)[:goals_wanted]
    q, reached, refused, reasons = setup.home.copy(), 0, 0, {}
    for i in counted:
        goal = setup.goals_of(goals[:, i:i + 1])[:, 0]
        start = starts[:, i] if start_kind == 'random' else (setup.home if start_kind == 'home' else q)
        done = follow_through_layer(setup, goal, start)
        refused += done.refused
        if not done.way.found:
            reasons[done.way.reason] = reasons.get(done.way.reason, 0) + 1
            continue
        q = done.end
        reached += np.linalg.norm(setup.goals_of(q[:, None])[:, 0] - goal) < setup.task.distance_threshold
    return len(counted), reached, refused, reasons


def tightness(robot, tip, samples, seed=3):
    """(refused, over-conservative, missed) shares of random configurations: the sphere body against the meshes
    themselves (the tests' exact check: python-fcl through trimesh's collision manager), the checked pairs only."""
    sys.path.insert(0, os.path.join(HERE, '..', 'test', 'unit'))
    from exact_meshes import Exact
    setup = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, collision=True)
    body = setup.body
    exact = Exact(body)
    q = np.random.default_rng(seed).uniform(setup.arm.lower, setup.arm.upper, (samples, setup.arm.n))
    hit = body.in_collision(q)
    poses = body.link_poses(q)
    over = missed = 0
    for n in range(samples):
        touching = exact.contacts(poses, n)
        missed += bool(touching) and not hit[n]
        if hit[n] and not touching:
            apart = [exact.distance(poses, n, *c.split(' - ')) for c in body.contacts(q[n])]
            over += min(apart) > 0.02
    return hit.mean(), over / samples, missed / samples


def planning(a) -> None:
    """Goals planned by robot_ai.reach.planning beside the reference, per arm, world and start."""
    print(f'{"arm":<22s}{"world":<8s}{"start":<9s}{"reached":>12s}{"median":>9s}{"p95":>9s}   '
          f'{"reference reached":>18s}{"median":>9s}{"p95":>9s}')
    all_times, all_ok, all_n = [], 0, 0
    for robot, tip, home in ARMS:
        for name, world in (('table+2', WORLD), ('body', [])):
            for start in ('home', 'random', 'chained'):
                n, ok, times, reasons, ref_ok, ref_times = run(robot, tip, home, world, start, a.problems,
                                                                a.reference_limit if start == 'random' else 0)
                all_times.append(times)
                all_ok, all_n = all_ok + ok, all_n + n
                ref = (f'{ref_ok:>8d}/{len(ref_times):<9d}{np.median(ref_times) * 1000:>7.0f}ms'
                       f'{np.percentile(ref_times, 95) * 1000:>7.0f}ms' if len(ref_times) else '')
                print(f'{robot:<22s}{name:<8s}{start:<9s}{ok:>6d}/{n:<5d}{np.median(times) * 1000:>7.0f}ms'
                      f'{np.percentile(times, 95) * 1000:>7.0f}ms   {ref}'
                      + (f'   missed: {reasons}' if reasons else ''))
                sys.stdout.flush()
    times = np.concatenate(all_times)
    print(f'all: {all_ok}/{all_n} reached ({100.0 * all_ok / max(all_n, 1):.1f} %), planning time median '
          f'{np.median(times) * 1000:.0f} ms, 95th percentile {np.percentile(times, 95) * 1000:.0f} ms')


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--problems', type=int, default=30, help='goals per arm, world and start (0: none)')
    p.add_argument('--reference-limit', type=float, default=1.0,
                   help='seconds the reference may take per problem (0: no reference)')
    p.add_argument('--episodes', type=int, default=200, help='Reach-v0 goals per arm and start (0: none)')
    p.add_argument('--follow', type=int, default=40,
                   help='goals per arm and start planned and followed through the safety layer (0: none)')
    p.add_argument('--tightness', type=int, default=3000,
                   help='random configurations the spheres are held to the meshes on (0: none)')
    a = p.parse_args(argv)
    if a.problems:
        planning(a)
    if a.episodes:
        print(f'\nReach-v0 among the table and two objects, the P-controller on {a.episodes} goals (seed 1000), its '
              f'recovery going round by a planned way where its via points find none, beside the same without it')
        print(f'{"arm":<22s}{"start":<9s}{"reached":>9s}{"planner share":>15s}{"without the planner":>21s}'
              f'{"through the layer (0.25)":>26s}{"policy first":>14s}')
        for robot, tip, home in ARMS:
            setup = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, home=home, obstacles=WORLD, collision=True)
            layered = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, home=home, obstacles=WORLD, collision=True,
                                 velocity_scale=0.25)
            policy_first = ReachSetup(os.path.join(ROBOTS, robot), tip=tip, home=home, obstacles=WORLD,
                                      collision=True, velocity_scale=0.25, plan_first=False)
            for start in ('home', 'random', 'chained'):
                on = learn.evaluate(learn.p_controller(setup), setup, a.episodes, 1000, start=start)
                through = learn.evaluate(learn.p_controller(layered), layered, a.episodes, 1000, start=start)
                policy = learn.evaluate(learn.p_controller(policy_first), policy_first, a.episodes, 1000, start=start)
                planned_way = ReachSetup._planned_way
                ReachSetup._planned_way = lambda self, goal, q: None
                try:
                    off = learn.evaluate(learn.p_controller(setup), setup, a.episodes, 1000, start=start)
                finally:
                    ReachSetup._planned_way = planned_way
                print(f'{robot:<22s}{start:<9s}{100 * on.success_rate:>8.1f}%{100 * on.planned:>14.1f}%'
                      f'{100 * off.success_rate:>20.1f}%{100 * through.success_rate:>25.1f}%'
                      f'{100 * policy.success_rate:>13.1f}%')
                sys.stdout.flush()
    if a.follow:
        print(f'\nGoals planned and followed through the safety layer (velocity_scale 0.25) as reach_controller '
              f'drives them, among the table and two objects, {a.follow} per arm and start (seed 2000)')
        print(f'{"arm":<22s}{"start":<9s}{"reached":>12s}{"steps refused":>15s}')
        for robot, tip, home in ARMS:
            for start in ('home', 'random', 'chained'):
                n, ok, refused, reasons = follow(robot, tip, home, start, a.follow)
                print(f'{robot:<22s}{start:<9s}{ok:>6d}/{n:<5d}{refused:>15d}'
                      + (f'   missed: {reasons}' if reasons else ''))
                sys.stdout.flush()
    if a.tightness:
        print(f'\nThe spheres against the meshes (python-fcl), {a.tightness} random configurations, the body alone')
        print(f'{"arm":<22s}{"refused":>9s}{"over-conservative":>19s}{"missed":>9s}')
        for robot, tip, _ in ARMS[:2]:                       # the arms whose real meshes are here
            refused, over, missed = tightness(robot, tip, a.tightness)
            print(f'{robot:<22s}{100 * refused:>8.1f}%{100 * over:>18.1f}%{100 * missed:>8.2f}%')
            sys.stdout.flush()
    return 0


if __name__ == '__main__':
    sys.exit(main())
