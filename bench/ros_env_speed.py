#!/usr/bin/env python3
"""How fast an agent steps the ROS cart-pole through robot_ai.envs, beside what bounds it, all in one run:

- gymnasium's CartPole-v1 in this process (one env, and SyncVectorEnv over N): what an agent gets without ROS;
- a plain rospy ping-pong (a Float64 out, a JointState back from a bare echo node): one ROS round trip, the
  least a lockstep step can cost;
- RosCartPoleEnv on one sim, and RosCartPoleVectorEnv over N sims (steps of all envs per second);
- gymnasium's standard per-env vectorisers over gymnasium.make('robot_ai/RosCartPole-v1') with 4 sims (each env
  leases one: SyncVectorEnv, as CleanRL builds it, and AsyncVectorEnv, spawned workers), beside the same
  vectorisers over gymnasium's CartPole-v1 in this process.

It starts its own master on a free port and cartpole_gym.launch sims:=N. Random actions; steps per second of wall
time over --steps steps (after a warm-up).

    python bench/ros_env_speed.py [--sims 8] [--steps 20000]
"""
import argparse
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def stop_all(procs) -> None:
    """The benchmark's launches and nodes (each a process group of its own) ended: Ctrl-C, then SIGKILL after 20 s."""
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGINT)
    for p in procs:
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)


def start_graph(launch: list, name: str, procs: list) -> tuple[dict, int]:
    """A master of the benchmark's own on a free port: `roslaunch -p PORT robot_ai <launch>` and the echo node, each a
    process group of its own appended to procs (stop_all ends them), then this process's node name once the master
    answers (init_node before it prints a warning into the table); (the environment they share, the port)."""
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
    os.environ['ROS_MASTER_URI'] = env['ROS_MASTER_URI']
    for argv in (['roslaunch', '-p', str(port), 'robot_ai', *launch],
                 [sys.executable, os.path.realpath(__file__), '--echo']):
        procs.append(subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      preexec_fn=os.setsid))
    import rosgraph
    import rospy
    deadline = time.time() + 60
    while not rosgraph.Master(f'/{name}').is_online() and time.time() < deadline:
        time.sleep(0.2)
    rospy.init_node(name, disable_signals=True)
    return env, port


def echo_node() -> None:
    """The reference peer: answers every Float64 on /ping with a JointState on /pong, as a lockstep sim does."""
    import rospy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    rospy.init_node('ping_pong_echo')
    pub = rospy.Publisher('/pong', JointState, queue_size=10, tcp_nodelay=True)

    def answer(msg):
        pub.publish(JointState(name=['cart_slider', 'pole_hinge'], position=[msg.data, 0.0], velocity=[0.0, 0.0]))
    rospy.Subscriber('/ping', Float64, answer, queue_size=10, tcp_nodelay=True)
    rospy.spin()


def rate(step, n: int) -> float:
    for _ in range(min(200, n // 10)):
        step()
    t = time.perf_counter()
    for _ in range(n):
        step()
    return n / (time.perf_counter() - t)


def gymnasium_rates(sims: int, steps: int) -> tuple[float, float]:
    import gymnasium
    rng = np.random.default_rng(0)
    env = gymnasium.make('CartPole-v1')
    env.reset(seed=0)

    def one():
        if any(env.step(int(rng.integers(2)))[2:4]):
            env.reset()
    vec = gymnasium.make_vec('CartPole-v1', num_envs=sims, vectorization_mode='sync')
    vec.reset(seed=0)
    return rate(one, steps), sims * rate(lambda: vec.step(rng.integers(2, size=sims)), steps // sims)


def ping_pong_rate(steps: int) -> float:
    import threading
    import warnings
    import rospy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    got = threading.Condition()
    count = [0]

    def on_pong(msg):
        with got:
            count[0] += 1
            got.notify()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        pub = rospy.Publisher('/ping', Float64, queue_size=None, tcp_nodelay=True)
    rospy.Subscriber('/pong', JointState, on_pong, tcp_nodelay=True)
    deadline = time.time() + 60
    while pub.get_num_connections() == 0 and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)

    def one():
        with got:
            seen = count[0]
        pub.publish(Float64(1.0))
        with got:
            if not got.wait_for(lambda: count[0] > seen, 5.0):
                raise RuntimeError('the echo node stopped answering')
    return rate(one, steps)


def ros_env_rates(sims: int, steps: int) -> tuple[float, float]:
    import gymnasium
    rng = np.random.default_rng(0)
    env = gymnasium.make('robot_ai.envs:robot_ai/RosCartPole-v1', robot_ns='/cartpole_0', timeout=30.0)
    env.reset(seed=0)

    def one():
        if any(env.step(int(rng.integers(2)))[2:4]):
            env.reset()
    single = rate(one, steps)
    env.close()
    vec = gymnasium.make_vec('robot_ai.envs:robot_ai/RosCartPole-v1', num_envs=sims, timeout=30.0)
    vec.reset(seed=0)
    vector = sims * rate(lambda: vec.step(rng.integers(2, size=sims)), steps // sims)
    vec.close()
    return single, vector


ROS_ENV = 'robot_ai.envs:robot_ai/RosCartPole-v1'


def make_ros_env():
    import gymnasium
    return gymnasium.make(ROS_ENV, timeout=30.0)


def make_cartpole():
    import gymnasium
    return gymnasium.make('CartPole-v1')


def vectoriser_rates(n: int, steps: int) -> dict[str, float]:
    """Steps per second (all envs) of SyncVectorEnv and AsyncVectorEnv (spawned workers) over n envs made one by
    one, through ROS and in-process."""
    import gymnasium
    rng = np.random.default_rng(0)
    out = {}
    for name, make in (('ros', make_ros_env), ('gymnasium', make_cartpole)):
        for kind in ('sync', 'async'):
            vec = (gymnasium.vector.SyncVectorEnv([make] * n) if kind == 'sync' else
                   gymnasium.vector.AsyncVectorEnv([make] * n, context='spawn'))
            vec.reset(seed=0)
            out[f'{name} {kind}'] = n * rate(lambda: vec.step(rng.integers(2, size=n)), steps // n)
            vec.close()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--sims', type=int, default=8, help='sims of the vector env (cartpole_gym.launch sims:=N)')
    parser.add_argument('--steps', type=int, default=20000, help='steps measured in each case')
    parser.add_argument('--echo', action='store_true', help=argparse.SUPPRESS)
    a = parser.parse_args()
    if a.echo:
        echo_node()
        return 0
    procs = []
    try:
        start_graph(['cartpole_gym.launch', f'sims:={a.sims}'], 'ros_env_speed', procs)
        import rospy
        for i in range(a.sims):
            rospy.wait_for_service(f'/cartpole_{i}/cartpole_sim/set_state', 120)
        print(f'ROS cart-pole env speed, {a.steps} steps a case, {os.cpu_count()} cores '
              f'(load average {os.getloadavg()[0]:.2f})')
        g1, gn = gymnasium_rates(a.sims, a.steps)
        print(f'  gymnasium CartPole-v1 in-process, one env:          {g1:10,.0f} steps/s')
        print(f'  gymnasium SyncVectorEnv, {a.sims} envs:                   {gn:10,.0f} steps/s')
        pp = ping_pong_rate(a.steps)
        print(f'  rospy ping-pong (Float64 out, JointState back):     {pp:10,.0f} round trips/s  (reference)')
        r1, rn = ros_env_rates(a.sims, a.steps)
        print(f'  RosCartPoleEnv, one sim:                            {r1:10,.0f} steps/s  '
              f'({r1 / pp:.0%} of the ping-pong)')
        print(f'  RosCartPoleVectorEnv, {a.sims} sims:                      {rn:10,.0f} steps/s  '
              f'({rn / r1:.1f} x one env)')
        v = vectoriser_rates(4, a.steps // 2)
        for kind, name in (('sync', 'SyncVectorEnv '), ('async', 'AsyncVectorEnv')):
            print(f'  {name} over gymnasium.make, 4 envs: through ROS {v[f"ros {kind}"]:8,.0f} steps/s, '
                  f'in-process {v[f"gymnasium {kind}"]:8,.0f} ({v[f"gymnasium {kind}"] / v[f"ros {kind}"]:.1f} x)')
        return 0
    finally:
        stop_all(procs)


if __name__ == '__main__':
    sys.exit(main())
