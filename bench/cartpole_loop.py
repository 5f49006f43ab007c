#!/usr/bin/env python3
"""The cart-pole's closed loop: cartpole_controller's latency, and how fast the loop can run.

1. Latency, joint_states in -> cart_force out: this script publishes one cart-pole state, waits for the controller's
   cart_force, and sends the next (one at a time, so nothing queues). Measured for the course's linear policy, a
   Q-learning agent (4 x 1,000 RBF features) and, as the reference in the same run, a bare rospy node that answers
   every state with a constant (`--echo`): the cost of ROS's transport, which any Python controller pays.
2. The closed loop at rising real_time_factor: cartpole.launch (sim, forward_kinematics, controller with the
   Q-learning agent), each for a few seconds of wall time, in both of the sim's modes: paced by the controller as
   well as the clock (the default: each step waits for the answer to the state before it, so the loop slows down
   where it cannot keep up) and on the clock alone (wait_for_controller:=false, a real robot's semantics: a step is
   missed when the sim steps before any cart_force answered the state before it).

    python bench/cartpole_loop.py [--states 2000] [--seconds 6]
"""
import argparse
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
FACTORS = (1, 2, 5, 10, 20, 40, 80)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def echo_node() -> None:
    """The reference: a bare rospy node answering every joint_states with a constant cart_force."""
    import rospy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    rospy.init_node('echo_controller')
    pub = rospy.Publisher('cart_force', Float64, queue_size=10, tcp_nodelay=True)
    rospy.Subscriber('joint_states', JointState, lambda m: pub.publish(Float64(10.0)), queue_size=10,
                     tcp_nodelay=True)
    rospy.spin()


def start(cmd: list, env: dict) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=os.setsid)


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def latency(ns: str, states: int) -> np.ndarray:
    """Seconds from publishing each state on ns/joint_states to receiving the answer on ns/cart_force."""
    import rospy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    answers = queue.Queue()
    pub = rospy.Publisher(f'{ns}/joint_states', JointState, queue_size=10, tcp_nodelay=True)
    sub = rospy.Subscriber(f'{ns}/cart_force', Float64, lambda m: answers.put(time.perf_counter()), queue_size=10,
                           tcp_nodelay=True)
    deadline = time.time() + 60
    while (pub.get_num_connections() < 1 or sub.get_num_connections() < 1) and time.time() < deadline:
        time.sleep(0.05)
    if pub.get_num_connections() < 1 or sub.get_num_connections() < 1:
        raise RuntimeError(f'no controller connected on {ns}/joint_states and {ns}/cart_force')
    rng = np.random.default_rng(0)
    out = []
    for k in range(states + 50):
        x, x_dot, theta, theta_dot = (float(v) for v in rng.uniform(-0.05, 0.05, 4))
        msg = JointState(name=['cart_slider', 'pole_hinge'], position=[x, theta], velocity=[x_dot, theta_dot])
        msg.header.stamp = rospy.Time.now()
        t = time.perf_counter()
        pub.publish(msg)
        try:
            got = answers.get(timeout=2.0)
        except queue.Empty:
            continue
        if k >= 50:                                           # the first answers warm the connections up
            out.append(got - t)
    pub.unregister()
    sub.unregister()
    return np.array(out)


def q_policy_file(folder: str) -> str:
    """The course's Q-learning agent (500 episodes of CartPole-v0, seed 0), saved as a policy file."""
    from robot_ai import policies
    from robot_ai.cartpole import q_learning
    training = q_learning.resolve()
    result = q_learning.train(training, 0)
    return policies.save(os.path.join(folder, 'q_agent.npz'), result.agents[0], 'CartPole-v0', 0,
                         training.settings(), result.figures_of(0))


def loop_at(factor: float, policy: str, seconds: float, env: dict, wait: bool = True) -> dict:
    """cartpole.launch at real_time_factor factor for `seconds` (wait: the sim waits for its controller):
    states/s, missed steps, how episodes ended."""
    port = free_port()
    env = dict(env, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
    proc = start(['roslaunch', '-p', str(port), 'robot_ai', 'cartpole.launch', f'real_time_factor:={factor}',
                  f'policy:={policy}', f'wait_for_controller:={str(wait).lower()}'], env)
    try:
        # a second node in this process cannot join another master: ask through a child with that master
        code = f'''
import time, rospy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from robot_ai.msg import CartPoleEpisode
rospy.init_node('bench_watch', disable_signals=True)
rospy.wait_for_service('/cartpole_controller/load_policy', 60)
rospy.wait_for_service('/cartpole_sim/reset', 60)
episodes, count = [], [0]
rospy.Subscriber('/cartpole_sim/episodes', CartPoleEpisode, episodes.append, queue_size=100)
rospy.Subscriber('/joint_states', JointState, lambda m: count.__setitem__(0, count[0] + 1), queue_size=1000)
time.sleep(1.0)
rospy.ServiceProxy('/cartpole_sim/reset', Trigger)()
time.sleep(0.2)
n0, t0 = count[0], time.time()
first = len(episodes)
time.sleep({seconds})
n1, t1 = count[0], time.time()
rospy.ServiceProxy('/cartpole_sim/reset', Trigger)()
time.sleep(0.5)
ended = episodes[first + 1:]
print(repr(dict(states=(n1 - n0) / (t1 - t0), missed=sum(e.missed_steps for e in ended),
                fell=sum(e.reason == 'pole fell' for e in ended),
                left=sum(e.reason == 'cart left the rail' for e in ended),
                steps=sum(e.steps for e in ended))))
'''
        out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True, timeout=120)
        if out.returncode != 0:
            raise RuntimeError(out.stderr[-2000:])
        return eval(out.stdout.strip().splitlines()[-1])
    finally:
        stop(proc)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--states', type=int, default=2000, help='round trips per controller')
    parser.add_argument('--seconds', type=float, default=6.0, help='wall seconds per real_time_factor')
    parser.add_argument('--echo', action='store_true', help='run the reference echo node (used by this script)')
    a, _ = parser.parse_known_args()   # ROS remappings (__ns:=...) pass through to the echo node
    if a.echo:
        echo_node()
        return 0
    import rospy
    # SIGTERM (what `timeout` sends) ends it through the finally below: its roscore and nodes stop too
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(143))
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}', ROS_HOSTNAME='localhost')
    os.environ.update(env)
    folder = tempfile.mkdtemp(prefix='robot_ai_bench_')
    policy = q_policy_file(folder)
    core = start(['roscore', '-p', str(port)], env)
    procs = []
    try:
        time.sleep(2.0)
        rospy.init_node('bench_cartpole_loop', disable_signals=True)
        controllers = [('reference: bare rospy echo node', [sys.executable, os.path.abspath(__file__), '--echo']),
                       ('cartpole_controller, linear policy (course search)', ['rosrun', 'robot_ai',
                                                                              'cartpole_controller']),
                       ('cartpole_controller, Q-learning agent (4,000 features)', ['rosrun', 'robot_ai',
                                                                                  'cartpole_controller',
                                                                                  f'_policy:={policy}'])]
        print('cartpole_controller loop latency: joint_states in -> cart_force out, one state at a time '
              f'({a.states} round trips)')
        print(f'  {"controller":<58}{"p50 ms":>8}{"p99 ms":>8}{"max ms":>8}')
        for k, (name, cmd) in enumerate(controllers):
            ns = f'/c{k}'
            procs.append(start(cmd + [f'__ns:={ns}'], env))
            lat = latency(ns, a.states) * 1e3
            print(f'  {name:<58}{np.percentile(lat, 50):8.3f}{np.percentile(lat, 99):8.3f}{lat.max():8.3f}')
            stop(procs.pop())
        print(f'closed loop (cartpole.launch, Q-learning agent), {a.seconds:g} s of wall time per real_time_factor:')
        print(f'  {"real_time_factor":>16}{"steps/s wanted":>16}  {"sim paced by":<12}{"states/s seen":>15}'
              f'{"missed steps":>14}{"pole fell":>11}{"cart left rail":>16}')
        best = {True: 0, False: 0}
        for factor in FACTORS:
            for wait in (True, False):
                r = loop_at(factor, policy, a.seconds, env, wait)
                print(f'  {factor:>16g}{50 * factor:>16g}  {"controller" if wait else "clock only":<12}'
                      f'{r["states"]:>15.0f}{r["missed"]:>14d}{r["fell"]:>11d}{r["left"]:>16d}')
                if r['missed'] == 0 and r['fell'] == 0 and r['states'] > 0.9 * 50 * factor:
                    best[wait] = factor
        print(f'highest real_time_factor that balances at full speed with no missed step: {best[True]:g} paced by '
              f'the controller, {best[False]:g} on the clock only (beyond it the paced loop slows down, the other '
              'misses steps)')
    finally:
        for p in procs:
            stop(p)
        rospy.signal_shutdown('done')
        stop(core)
    return 0


if __name__ == '__main__':
    sys.exit(main())
