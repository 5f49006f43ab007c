#!/usr/bin/env python3
"""Speed benchmark of the CartPole random search, 100 candidates x 100 episodes on CartPole-v1, in one run:

- the course's loop: gymnasium's single env, one episode after another, as the course wrote it;
- robot_ai.cartpole.linear_search.random_search called directly;
- the cartpole_search node's ~random_search service, round trip included (median of several calls);
- peak memory and time of the 10,000 x 1,000 search, in a process of its own.

    python bench/search_speed.py [--skip-large]
"""
import argparse
import os
import signal
import socket
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np


def course_loop(seed=0):
    """The course's random search, unchanged but for gymnasium's five-value step API."""
    np.random.seed(seed)
    env = gym.make('CartPole-v1')
    env.reset(seed=seed)

    def play_one_episode(env, params):
        observation, _ = env.reset()
        done = False
        t = 0
        while not done:
            t += 1
            action = 1 if observation.dot(params) > 0 else 0
            observation, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        return t

    def play_multiple_episodes(env, T, params):
        return np.mean([play_one_episode(env, params) for _ in range(T)])

    episode_lengths, best, params = [], 0, None
    for _ in range(100):
        new_params = np.random.random(4) * 2 - 1
        avg_length = play_multiple_episodes(env, 100, new_params)
        episode_lengths.append(avg_length)
        if avg_length > best:
            params, best = new_params, avg_length
    final = play_multiple_episodes(env, 100, params)
    return best, final


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


LARGE = """
import resource, time
from robot_ai.cartpole.dynamics import CartPoleDynamics
from robot_ai.cartpole.linear_search import random_search
t = time.time()
r = random_search(CartPoleDynamics.of('CartPole-v1'), 10000, 1000, seed=0, final_episodes=100)
print('%.1f %.1f %.2f' % (time.time() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                          r.best_avg_length))
"""


VIDEO = """
import resource, time
import numpy as np
from robot_ai.cartpole import outputs
from robot_ai.cartpole.linear_search import act
w = np.array([-0.1707, 0.4690, 0.4223, 0.8641])
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.time()
path, steps = outputs.record_video('CartPole-v1', lambda obs: act(w, obs), 500, 0, '%s')
print('%%.1f %%.0f %%.0f %%d' %% (time.time() - t, before / 1024.0,
                             resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, steps))
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--skip-large', action='store_true', help='skip the 10,000 x 1,000 run')
    ap.add_argument('--calls', type=int, default=7)
    args = ap.parse_args()
    from robot_ai.cartpole.dynamics import CartPoleDynamics
    from robot_ai.cartpole.linear_search import random_search

    t = time.time()
    best, final = course_loop()
    course = time.time() - t
    print('course loop (gymnasium single env)   %8.3f s   best %.1f, final %.1f' % (course, best, final))

    dynamics = CartPoleDynamics.of('CartPole-v1')
    times = []
    for i in range(args.calls):
        t = time.time()
        res = random_search(dynamics, 100, 100, seed=i)
        times.append(time.time() - t)
    lib = float(np.median(times))
    print('random_search, library (median)      %8.3f s   %6.0fx   best %.1f' % (
        lib, course / lib, res.best_avg_length))

    port = free_port()
    os.environ['ROS_MASTER_URI'] = 'http://127.0.0.1:%d' % port
    out_dir = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'output', 'bench')
    master = subprocess.Popen(['rosmaster', '--core', '-p', str(port)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
    node = None
    try:
        import rospy
        from robot_ai.srv import RandomSearch
        time.sleep(1.0)
        node = subprocess.Popen(['rosrun', 'robot_ai', 'cartpole_search', '_output_dir:=' + out_dir],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
        rospy.init_node('bench_search_speed', disable_signals=True)
        rospy.wait_for_service('/cartpole_search/random_search', 60)
        call = rospy.ServiceProxy('/cartpole_search/random_search', RandomSearch, persistent=True)
        call(iterations=5, episodes=5)  # warm-up: gymnasium's spec, matplotlib's import in the plot process
        time.sleep(1.0)
        rt, inside = [], []
        for i in range(args.calls):
            t = time.time()
            res = call(seed=i)  # "{}" but the seed: the course experiment
            rt.append(time.time() - t)
            inside.append(res.elapsed)
            time.sleep(0.5)  # let the background plot finish, as a user's next call would
        service = float(np.median(rt))
        print('~random_search service, round trip   %8.3f s   %6.0fx   (inside the node %.3f s)' % (
            service, course / service, float(np.median(inside))))
    finally:
        if node is not None:
            os.killpg(node.pid, signal.SIGINT)
            node.wait(10)
        os.killpg(master.pid, signal.SIGINT)
        master.wait(10)

    video = os.path.join(out_dir, 'bench_video.mp4')
    os.makedirs(out_dir, exist_ok=True)
    out = subprocess.run([sys.executable, '-W', 'ignore', '-c', VIDEO % video], capture_output=True, text=True,
                         check=True).stdout.split()
    print('video of a %s-step episode              %8.1f s   peak memory %s MiB (%s before recording)' % (
        out[3], float(out[0]), out[2], out[1]))
    os.unlink(video)

    if not args.skip_large:
        out = subprocess.run([sys.executable, '-c', LARGE], capture_output=True, text=True, check=True).stdout.split()
        print('10,000 x 1,000 search                %8.1f s   peak memory %.0f MiB   best %s' % (
            float(out[0]), float(out[1]), out[2]))


if __name__ == '__main__':
    main()
