#!/usr/bin/env python3
"""How fast an agent steps an arm with physics through robot_ai/RosPush-v0 and RosPickAndPlace-v0, beside what bounds
it, in one run:

- Push-v0 in this process (one env): what an agent gets without ROS (20 MuJoCo steps and the damped least squares);
- a plain rospy ping-pong (a Float64 out, a JointState back from a bare echo node): one ROS round trip;
- RosPush-v0 and RosPickAndPlace-v0 on one arm (steps per second), random actions; and whether their observations
  equal the in-process env's bit for bit over the same steps (the rostest's claim, at length).

It starts its own master on a free port, manipulation_gym.launch sims:=1 (the package's UR5 with a Robotiq, or
--model) and an echo node; steps per second of wall time over --steps steps after a reset. Run it alone, or beside
busy loops to see a loaded machine.

    python bench/ros_manipulation_speed.py [--steps 2000] [--model FILE]
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, HERE)
from ros_env_speed import echo_node, ping_pong_rate, start_graph, stop_all  # noqa: E402
from ros_reach_speed import env_rate  # noqa: E402  (random actions, resets at the episode's end)


def equal_steps(ros, local, steps: int) -> tuple[int, float]:
    """(steps whose observations were equal bit for bit, the largest difference) of the two envs side by side."""
    rng = np.random.default_rng(1)
    a, _ = ros.reset(seed=3)
    b, _ = local.reset(seed=3)
    equal, worst = 0, 0.0
    for _ in range(steps):
        difference = max(float(np.abs(a[k] - b[k]).max()) for k in b)
        equal += difference == 0.0
        worst = max(worst, difference)
        action = rng.uniform(-1, 1, 4)
        a, _, _, cut, _ = ros.step(action)
        b, *_ = local.step(action)
        if cut:
            a, _ = ros.reset()
            b, _ = local.reset()
    return equal, worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, default=2000, help='steps measured in each case')
    parser.add_argument('--model', default='', help='the arm with a gripper (default: the package\'s UR5 + Robotiq)')
    a = parser.parse_args()
    procs = []
    try:
        start_graph(['manipulation_gym.launch', 'sims:=1'] + ([f'model:={os.path.abspath(a.model)}'] if a.model
                                                              else []), 'ros_manipulation_speed', procs)
        import gymnasium
        import rosgraph
        import rospy
        import robot_ai.envs  # noqa: F401  (registers the envs over ROS)
        import robot_ai.physics  # noqa: F401  (registers the envs over MuJoCo)
        rospy.wait_for_service('/arm_0/arm_sim/set_object_pose', 300)
        urdf = rosgraph.Master('/ros_manipulation_speed').getParam('/arm_0/robot_description')
        print(f'manipulation env speed through ROS, {a.steps} steps a case, {os.cpu_count()} cores (load average '
              f'{os.getloadavg()[0]:.2f})   [bench/ros_manipulation_speed.py, {time.strftime("%Y-%m-%d")}]')
        pp = ping_pong_rate(a.steps)
        print(f'  {"rospy ping-pong (Float64 out, JointState back):":46s}{pp:10,.0f} round trips/s  (reference)')
        for name in ('Push-v0', 'PickAndPlace-v0'):
            local = gymnasium.make(f'robot_ai/{name}', urdf=urdf)
            alone = env_rate(local, a.steps)
            ros = gymnasium.make(f'robot_ai/Ros{name}', robot_ns='/arm_0', timeout=30.0)
            through = env_rate(ros, a.steps)
            equal, worst = equal_steps(ros, local, a.steps // 4)
            ros.close()
            local.close()
            print(f'  {name + " in-process, one env:":46s}{alone:10,.0f} steps/s')
            print(f'  {"Ros" + name + ", one arm:":46s}{through:10,.0f} steps/s  ({through / alone:.2f} of '
                  f'in-process); {equal} of {a.steps // 4} observations equal bit for bit (largest difference '
                  f'{worst:g})')
        return 0
    finally:
        stop_all(procs)


if __name__ == '__main__':
    if '--echo' in sys.argv:
        echo_node()
    else:
        sys.exit(main())
