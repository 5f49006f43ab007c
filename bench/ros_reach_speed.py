#!/usr/bin/env python3
"""How fast an agent steps an arm of the ROS graph through robot_ai/RosReach-v0, beside what bounds it, in one run:

- Reach-v0 in this process (one env): what an agent gets without ROS;
- a plain rospy ping-pong (a Float64 out, a JointState back from a bare echo node): one ROS round trip;
- the bare exchange the env makes (a command to a lockstep arm_sim, its joint_states to forward_kinematics, the
  frames back to the reader): two hops, what a step cannot beat;
- RosReach-v0 on one arm (steps per second), and its ratio to the ping-pong (target: at least 0.4);
- reach_controller's loop (reach.launch, 20 steps a second of ROS time) over --seconds of goals, quiet and with two
  busy loops on the cores (started here): the intervals between its commands.

It starts its own master on a free port, reach_gym.launch sims:=1 (the package's UR5, or --model) and an echo node;
random actions; steps per second of wall time over --steps steps after a warm-up. Run it alone, or beside busy loops
to see a loaded machine.

    python bench/ros_reach_speed.py [--steps 3000] [--model FILE]
"""
import argparse
import os
import subprocess
import sys
import threading
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
sys.path.insert(0, HERE)
from ros_env_speed import echo_node, ping_pong_rate, rate, start_graph, stop_all  # noqa: E402


def bare_exchange_rate(steps: int) -> float:
    """Commands to /arm_0's arm_sim, each answered by forward_kinematics' frames on /arm_0/tf."""
    import rospy
    from std_msgs.msg import Float64MultiArray
    from tf2_msgs.msg import TFMessage
    from robot_ai.tf_wire import encode_float64_array, raw_message_class
    command_type, frames_type = raw_message_class(Float64MultiArray), raw_message_class(TFMessage)
    got, count = threading.Condition(), [0]

    def on_frames(msg):
        with got:
            count[0] += 1
            got.notify()
    joints = rospy.get_param('/arm_0/arm_sim/joints')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        pub = rospy.Publisher('/arm_0/joint_group_position_controller/command', command_type, queue_size=None,
                              tcp_nodelay=True)
    sub = rospy.Subscriber('/arm_0/tf', frames_type, on_frames, tcp_nodelay=True)
    deadline = time.time() + 60
    while (pub.get_num_connections() == 0 or sub.get_num_connections() == 0) and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    data = command_type(encode_float64_array(np.zeros(len(joints))))

    def one():
        with got:
            seen = count[0]
        pub.publish(data)
        with got:
            if not got.wait_for(lambda: count[0] > seen, 5.0):
                raise RuntimeError('the arm_sim or forward_kinematics stopped answering')
    result = rate(one, steps)
    pub.unregister()
    sub.unregister()
    return result


def env_rate(env, steps: int) -> float:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (64,) + env.action_space.shape).astype(np.float32)
    env.reset(seed=0)
    count = [0]

    def one():
        _, _, terminated, truncated, _ = env.step(actions[count[0] % 64])
        count[0] += 1
        if terminated or truncated:
            env.reset()
    return rate(one, steps)


def controller_intervals(seconds: float) -> np.ndarray:
    """Seconds between reach_controller's commands while it chases a new goal every second."""
    import rospy
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import Float64MultiArray
    from robot_ai.reach import ReachSetup
    stamps = []
    sub = rospy.Subscriber('/joint_group_position_controller/command', Float64MultiArray,
                           lambda m: stamps.append(time.monotonic()), queue_size=100)
    pub = rospy.Publisher('/reach_controller/goal', PointStamped, queue_size=1)
    time.sleep(1.0)
    setup = ReachSetup()
    rng = np.random.default_rng(0)
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        goal = setup.arm.tip_positions(rng.uniform(setup.arm.lower, setup.arm.upper))
        msg = PointStamped()
        msg.header.frame_id = setup.arm.base
        msg.point.x, msg.point.y, msg.point.z = (float(v) for v in goal)
        pub.publish(msg)
        time.sleep(1.0)
    sub.unregister()
    pub.unregister()
    return np.diff(np.array(stamps))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, default=3000, help='steps measured in each case')
    parser.add_argument('--model', default='', help='the arm (default: the package\'s UR5)')
    parser.add_argument('--seconds', type=float, default=15.0, help='seconds of the controller\'s loop, each load')
    a = parser.parse_args()
    procs = []
    try:
        env, port = start_graph(['reach_gym.launch', 'sims:=1'] + ([f'model:={os.path.abspath(a.model)}'] if a.model
                                                                   else []), 'ros_reach_speed', procs)
        import importlib
        import gymnasium
        import rospy
        for module in ('robot_ai.envs', 'robot_ai.reach'):    # register robot_ai/RosReach-v0 and Reach-v0
            importlib.import_module(module)
        rospy.wait_for_service('/arm_0/arm_sim/lease', 120)
        print(f'reach env speed through ROS, {a.steps} steps a case, {os.cpu_count()} cores (load average '
              f'{os.getloadavg()[0]:.2f})   [bench/ros_reach_speed.py, {time.strftime("%Y-%m-%d")}]')
        model = os.path.abspath(a.model) if a.model else None
        local = env_rate(gymnasium.make('robot_ai/Reach-v0', model=model), a.steps)
        print(f'  Reach-v0 in-process, one env:                        {local:10,.0f} steps/s')
        pp = ping_pong_rate(a.steps)
        print(f'  rospy ping-pong (Float64 out, JointState back):      {pp:10,.0f} round trips/s  (reference)')
        bare = bare_exchange_rate(a.steps)
        print(f'  command -> arm_sim -> forward_kinematics -> reader:  {bare:10,.0f} exchanges/s  '
              f'({bare / pp:.2f} of the ping-pong)')
        ros = gymnasium.make('robot_ai/RosReach-v0', robot_ns='/arm_0', timeout=30.0)
        through = env_rate(ros, a.steps)
        ros.close()
        print(f'  RosReach-v0, one arm:                                {through:10,.0f} steps/s  '
              f'({through / pp:.2f} of the ping-pong; target 0.4)')
        procs.append(subprocess.Popen(['roslaunch', '-p', str(port), 'robot_ai', 'reach.launch', 'rviz:=false'],
                                      env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      preexec_fn=os.setsid))
        rospy.wait_for_service('/reach_controller/home', 300)
        print('  reach_controller loop, 20 steps/s wanted: intervals between its commands (ms)')
        for label, loops in (('quiet', 0), ('two busy loops', 2)):
            busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(loops)]
            try:
                gaps = controller_intervals(a.seconds) * 1000
            finally:
                for b in busy:
                    b.kill()
                    b.wait()
            p50, p99, worst = np.percentile(gaps, 50), np.percentile(gaps, 99), gaps.max()
            print(f'    {label:15s} {len(gaps) / a.seconds:5.1f} commands/s   p50 {p50:6.1f}   p99 {p99:6.1f}   '
                  f'max {worst:6.1f}')
        return 0
    finally:
        stop_all(procs)


if __name__ == '__main__':
    if '--echo' in sys.argv:
        echo_node()
    else:
        sys.exit(main())
