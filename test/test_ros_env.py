#!/usr/bin/env python3
"""robot_ai.envs: the ROS cart-pole as gymnasium's CartPole, checked against gymnasium's own env and vector env
(bit for bit), gymnasium's env checker, the faults a user meets, worker processes and the CLI."""
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import unittest
import warnings
import xmlrpc.client

import gymnasium
import numpy as np
import rosgraph
import rospy
import rostest
from gymnasium.utils.env_checker import check_env
from sensor_msgs.msg import JointState

from robot_ai.envs import RosCartPoleError, RosCartPoleVectorEnv  # registers robot_ai/RosCartPole-v0, -v1

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from doc_blocks import python_blocks, run_as_written  # noqa: E402

VECTORISERS = os.path.join(os.path.dirname(os.path.realpath(__file__)), 'ros_env_vectorisers.py')
GOOD = np.array([0.1, 0.5, 10.0, 2.0])      # a linear policy that balances the pole: episodes end by truncation


def good(obs) -> int:
    return int(np.dot(GOOD, obs) > 0)


def same(a, b) -> bool:
    """Equal values of equal types: arrays element for element (and dtype), the rest with ==."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype and \
            a.shape == b.shape and bool((a == b).all())
    return type(a) is type(b) and a == b


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def make_ros(ns='', **kwargs):
    return gymnasium.make('robot_ai/RosCartPole-v1', robot_ns=ns, **kwargs)


def async_run(context, seed=7, steps=300):
    """(observations, rewards, terminations, truncations) of an AsyncVectorEnv over two RosCartPoleEnvs made in
    its workers, and of gymnasium's SyncVectorEnv over CartPole-v1, under the same random actions."""
    fns = [lambda i=i: make_ros(f'/cartpole_{i}') for i in (2, 3)]
    ros = gymnasium.vector.AsyncVectorEnv(fns, context=context)
    ref = gymnasium.make_vec('CartPole-v1', num_envs=2, vectorization_mode='sync')
    try:
        rng = np.random.default_rng(seed)
        out = [[ros.reset(seed=seed)[0]], [ref.reset(seed=seed)[0]]]
        for _ in range(steps):
            a = rng.integers(2, size=2)
            out[0].append(ros.step(a)[:4])
            out[1].append(ref.step(a)[:4])
        return out
    finally:
        ros.close()
        ref.close()


class TestRosEnv(unittest.TestCase):
    """Each test closes the envs it made (self.ros): an env holds its sim's lease until it is closed."""

    def setUp(self):
        self.opened = []

    def tearDown(self):
        for env in self.opened:
            env.close()

    def ros(self, ns='', **kwargs):
        env = make_ros(ns, **kwargs)
        self.opened.append(env)
        return env

    @classmethod
    def setUpClass(cls):
        # the launch's sims start beside this test: an env's own timeout (5 s) is for sims that are up
        for ns in ('/cartpole_0', '/cartpole_1', '/cartpole_2', '/cartpole_3', '/free', '/driven'):
            rospy.wait_for_service(f'{ns}/cartpole_sim/set_state', 120)
        deadline = time.monotonic() + 120   # the driven sim's controller, publishing its cart_force
        while not any(t == '/driven/cart_force' for t, _ in rospy.get_published_topics()):
            assert time.monotonic() < deadline, 'the driven sim\'s controller never published'
            time.sleep(0.5)

    def assert_same_run(self, ros, ref, seeds, policy, max_steps=600):
        """Episodes of both envs from the same seeds under the same actions: every result equal."""
        for seed in seeds:
            o1, i1 = ros.reset(seed=seed)
            o2, i2 = ref.reset(seed=seed)
            self.assertTrue(same(o1, o2), (seed, o1, o2))
            self.assertEqual(i1, i2)
            for t in range(max_steps):
                a = policy(o1, t)
                r1, r2 = ros.step(a), ref.step(a)
                for x, y in zip(r1, r2):
                    self.assertTrue(same(x, y), (seed, t, r1, r2))
                o1 = r1[0]
                if r1[2] or r1[3]:
                    break

    def test_steps_equal_gymnasiums_bit_for_bit(self):
        ros, ref = self.ros('/cartpole_0'), gymnasium.make('CartPole-v1')
        rng = np.random.default_rng(0)
        self.assert_same_run(ros, ref, range(6), lambda o, t: int(rng.integers(2)))
        self.assert_same_run(ros, ref, [11, 12], lambda o, t: good(o))   # truncated at 500
        self.assertEqual(ros.unwrapped.state.tolist(), ref.unwrapped.state.tolist())
        ros.close()

    def test_v0_truncates_at_200(self):
        ros = gymnasium.make('robot_ai/RosCartPole-v0', robot_ns='/cartpole_1')
        self.opened.append(ros)
        ref = gymnasium.make('CartPole-v0')
        self.assertEqual(ros.spec.max_episode_steps, 200)
        ros.reset(seed=3)
        n = 0
        truncated = False
        obs, _ = ros.reset(seed=3)
        while not truncated:
            obs, _, terminated, truncated, _ = ros.step(good(obs))
            n += 1
            self.assertFalse(terminated)
        self.assertEqual(n, 200)
        self.assert_same_run(ros, ref, [3], lambda o, t: good(o))
        ros.close()

    def test_check_env_warns_as_gymnasiums_own_cartpole(self):
        """gymnasium's env checker passes; its only warnings are those it gives gymnasium's own CartPole (the Box
        observation space's infinite velocity bounds, which the ROS env must share to be the same env)."""
        def warned(env):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter('always')
                check_env(env)
            return sorted({str(w.message) for w in caught if issubclass(w.category, UserWarning)})
        ours = warned(self.ros().unwrapped)   # check_env makes a second env from the spec: it claims another sim
        theirs = warned(gymnasium.make('CartPole-v1').unwrapped)
        self.assertEqual(ours, theirs)
        self.assertTrue(all('infinity' in w for w in theirs), theirs)

    def test_step_after_terminated_as_gymnasium(self):
        """step() after terminated, before reset(): gymnasium's warning, reward 0.0, the state integrated on."""
        ros = self.ros('/cartpole_0', disable_env_checker=True)
        ref = gymnasium.make('CartPole-v1', disable_env_checker=True)
        for env in (ros, ref):
            env.reset(seed=4)
        results = []
        for env in (ros, ref):
            out = []
            while not (out and out[-1][2]):
                out.append(env.step(1))
            for _ in range(3):
                out.append(env.step(0))
            results.append(out)
        self.assertEqual(len(results[0]), len(results[1]))
        for r1, r2 in zip(*results):
            for x, y in zip(r1, r2):
                self.assertTrue(same(x, y), (r1, r2))
        self.assertEqual([r[1] for r in results[0][-3:]], [0.0, 0.0, 0.0])
        ros.close()

    def test_a_bad_action_raises_and_the_env_goes_on(self):
        ros, ref = self.ros('/cartpole_2').unwrapped, gymnasium.make('CartPole-v1').unwrapped
        ros.reset(seed=9)
        ref.reset(seed=9)
        for bad in (2, -1, 0.5, 'left', None):
            with self.assertRaises(AssertionError):
                ref.step(bad)
            with self.assertRaises(AssertionError):
                ros.step(bad)
        for a in (1, 0, 0, 1, np.int64(1)):
            for x, y in zip(ros.step(a), ref.step(a)):
                self.assertTrue(same(x, y))
        ros.close()

    def test_vector_env_equals_gymnasiums_sync_vector_env(self):
        for env_id, n, seed in (('CartPole-v1', 4, 5), ('CartPole-v0', 3, 0)):
            ros = gymnasium.make_vec(f'robot_ai/{env_id.replace("CartPole", "RosCartPole")}', num_envs=n)
            self.opened.append(ros)
            ref = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode='sync')
            self.assertIsInstance(ros, RosCartPoleVectorEnv)
            self.assertEqual((ros.observation_space, ros.action_space), (ref.observation_space, ref.action_space))
            self.assertEqual(ros.metadata['autoreset_mode'], ref.metadata['autoreset_mode'])
            rng = np.random.default_rng(seed)
            o1, i1 = ros.reset(seed=seed)
            o2, i2 = ref.reset(seed=seed)
            self.assertTrue(same(o1, o2))
            self.assertEqual(i1, i2)
            truncated = 0
            for t in range(1200):
                # mostly the balancing policy (episodes reach the step limit), random actions now and then
                a = np.array([good(o) if rng.random() > 0.02 else int(rng.integers(2)) for o in o1])
                r1, r2 = ros.step(a), ref.step(a)
                for x, y in zip(r1[:4], r2[:4]):
                    self.assertTrue(same(x, y), (env_id, t, r1, r2))
                self.assertEqual(r1[4], r2[4])
                o1 = r1[0]
                truncated += int(r1[3].sum())
            self.assertGreater(truncated, 0, env_id)
            with self.assertRaises(AssertionError):
                ros.step(np.array([0, 3] + [0] * (n - 2)))
            r1, r2 = ros.step(np.zeros(n, dtype=np.int64)), ref.step(np.zeros(n, dtype=np.int64))
            for x, y in zip(r1[:4], r2[:4]):
                self.assertTrue(same(x, y))
            mask = np.arange(n) % 2 == 0     # gymnasium 1.1's partial reset, as stable-baselines3 adapters use it
            o1, o2 = ros.reset(options={'reset_mask': mask})[0], ref.reset(options={'reset_mask': mask})[0]
            self.assertTrue(same(o1, o2))
            for _ in range(50):
                a = np.array([good(o) for o in o1])
                r1, r2 = ros.step(a), ref.step(a)
                for x, y in zip(r1[:4], r2[:4]):
                    self.assertTrue(same(x, y))
                o1 = r1[0]
            with self.assertRaises(ValueError):
                ros.reset(options={'reset_mask': np.zeros(n, dtype=np.bool_)})
            ros.close()

    def test_async_vector_env_workers(self):
        """Envs made in gymnasium's AsyncVectorEnv workers (spawned) equal gymnasium's; forked from this process,
        where rospy runs, they refuse with a message that says what to do."""
        ours, theirs = async_run('spawn')
        for a, b in zip(ours, theirs):
            for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
                self.assertTrue(same(x, y))
        with self.assertRaises(Exception) as caught:
            async_run('fork', steps=1)
        self.assertIn('forked', str(caught.exception))
        self.assertIn('spawn', str(caught.exception))

    def test_no_sim_raises_within_the_timeout_naming_the_namespace(self):
        t = time.monotonic()
        env = gymnasium.make('robot_ai/RosCartPole-v1', robot_ns='/nobody_here', timeout=1.5)
        with self.assertRaises(RosCartPoleError) as caught:
            env.reset(seed=0)
        self.assertLess(time.monotonic() - t, 1.5 + 3.0)
        self.assertIn('/nobody_here', str(caught.exception))
        self.assertIn('cartpole_gym.launch', str(caught.exception))

    def test_a_sim_not_in_lockstep_is_refused(self):
        with self.assertRaises(RosCartPoleError) as caught:   # asked for by name
            self.ros('/free').reset(seed=0)
        self.assertIn('/free', str(caught.exception))
        self.assertIn('lockstep', str(caught.exception))

    def test_a_sim_with_a_controller_is_refused(self):
        with self.assertRaises(RosCartPoleError) as caught:
            self.ros('/driven').reset(seed=0)
        self.assertIn('/driven', str(caught.exception))
        self.assertIn('cartpole_controller', str(caught.exception))

    def test_a_sim_killed_mid_episode_raises_then_a_new_sim_serves(self):
        def start_sim():
            return subprocess.Popen(['rosrun', 'robot_ai', 'cartpole_sim', '__ns:=/victim', '_lockstep:=true'],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
        sim = start_sim()
        try:
            # issue 41: the first reset of an env that gymnasium.make wrapped in its passive env checker must find its
            # sim (the checker keeps nothing of a first reset that raised, and its first step then fails inside the
            # checker: docs/envs/RosCartPole.md), so the sim's start on a loaded machine is waited for first, as a
            # user's script waits for its launch
            rospy.wait_for_service('/victim/cartpole_sim/lease', 120)
            env = gymnasium.make('robot_ai/RosCartPole-v1', robot_ns='/victim', timeout=2.0)
            ref = gymnasium.make('CartPole-v1')
            env.reset(seed=1)
            for _ in range(5):
                env.step(1)
            os.killpg(sim.pid, signal.SIGKILL)
            sim.wait()
            t = time.monotonic()
            with self.assertRaises(RosCartPoleError) as caught:
                for _ in range(1000):
                    env.step(0)
            self.assertLess(time.monotonic() - t, 2.0 + 3.0)
            self.assertIn('/victim', str(caught.exception))
            with self.assertRaises(RosCartPoleError):   # gone: the reset says so too
                env.reset(seed=1)
            sim = start_sim()
            deadline = time.monotonic() + 60
            while True:
                try:
                    o1, _ = env.reset(seed=1)
                    break
                except RosCartPoleError:
                    self.assertLess(time.monotonic(), deadline)
            self.assert_same_run(env, ref, [1, 2], lambda o, t: good(o))
            env.close()
        finally:
            os.killpg(sim.pid, signal.SIGKILL)
            sim.wait()

    def test_cli_evaluate_on_the_ros_env_prints_the_same_average(self):
        with tempfile.TemporaryDirectory() as folder:
            cli = [sys.executable, '-m', 'robot_ai.cartpole']
            for run in (['random-search', '--iterations', '30', '--episodes', '20'],
                        ['q-learning', '--episodes', '150']):
                subprocess.run(cli + run + ['--seed', '0', '--output-dir', folder], check=True, capture_output=True)
            files = sorted(os.path.join(folder, f) for f in os.listdir(folder) if f.endswith('.npz'))
            self.assertEqual(len(files), 2)
            for path in files:
                for seed in (0, 3):
                    args = cli + ['evaluate', path, '--episodes', '12', '--seed', str(seed)]
                    here = subprocess.run(args, capture_output=True, text=True, check=True).stdout
                    ros = subprocess.run(args + ['--ros-env', '/cartpole_3'], capture_output=True, text=True)
                    self.assertEqual(ros.returncode, 0, ros.stderr)
                    self.assertIn('on the ROS cart-pole /cartpole_3', ros.stdout)
                    average = [line for line in here.splitlines() if line.startswith('average length')]
                    self.assertEqual(len(average), 1, here)
                    self.assertIn(average[0], ros.stdout.splitlines(), (path, seed))
            gone = subprocess.run(cli + ['evaluate', files[0], '--ros-env', '/nobody_here', '--timeout', '1'],
                                  capture_output=True, text=True)
            self.assertEqual(gone.returncode, 1)
            self.assertIn('/nobody_here', gone.stderr)
            self.assertNotIn('Traceback', gone.stderr)


    # ----------------------------------------------------------------------- leases: every vectoriser, third parties
    def test_envs_without_a_namespace_claim_free_sims_and_more_than_sims_is_an_error_naming_the_holders(self):
        envs = [self.ros(timeout=2.0) for _ in range(4)]
        for env in envs:
            env.reset(seed=0)
        claimed = [env.unwrapped.sim_namespace for env in envs]
        self.assertEqual(sorted(claimed), ['/cartpole_0', '/cartpole_1', '/cartpole_2', '/cartpole_3'])
        with self.assertRaises(RosCartPoleError) as caught:
            self.ros(timeout=2.0).reset(seed=0)
        message = str(caught.exception)
        self.assertIn('no running cartpole_sim is free', message)
        for ns in claimed:
            self.assertIn(f'{ns} leased to {rospy.get_name()}#', message)
        self.assertIn('/free is not in lockstep', message)
        self.assertIn('/driven is driven already: /driven/cartpole_controller', message)
        with self.assertRaises(RosCartPoleError) as caught:     # a held sim, asked by name: who holds it
            self.ros('/cartpole_2', timeout=2.0).reset(seed=0)
        self.assertIn('/cartpole_2', str(caught.exception))
        self.assertIn('leased to', str(caught.exception))
        envs[0].close()                                         # a closed env gives its sim back
        again = self.ros(timeout=2.0)
        again.reset(seed=0)
        self.assertEqual(again.unwrapped.sim_namespace, claimed[0])

    def test_the_docs_rl_blocks_run_as_written(self):
        """Issue 41: the README's block wanted 17 sims of `sims:=8`. It now runs as written on the sims its roslaunch
        line starts (this file's cartpole_gym.launch has as many), every line of it. Issue 57: so does every python
        block of the docs that leases a CartPole sim (docs/envs/RosCartPole.md), each in a process of its own."""
        with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'README.md')) as f:
            readme = f.read()
        start = readme.index('roslaunch robot_ai cartpole_gym.launch sims:=')
        sims = int(readme[start:].split('sims:=', 1)[1].split()[0])
        self.assertEqual(sims, 4, 'ros_env.test starts 4 sims: the README\'s block must be sized for those')
        blocks = [b for b in python_blocks() if b.needs_ros == 'cartpole' and not b.missing]
        self.assertIn('SyncVectorEnv', blocks[0].code)
        self.assertEqual(blocks[0].page, 'README.md')
        self.assertGreaterEqual(len(blocks), 3, 'the test finds too few blocks')
        for block in blocks:
            self.assertEqual(run_as_written(block, timeout=120), '')

    def test_every_standard_vectoriser_trains_on_the_sims_bit_for_bit(self):
        """SyncVectorEnv over gymnasium.make (CleanRL), make_vec 'sync' and the package's vector env, in this
        process; AsyncVectorEnv over gymnasium.make and make_vec 'async' in fresh processes (forked workers of a
        process where rospy never ran)."""
        make = [lambda: gymnasium.vector.SyncVectorEnv([lambda: make_ros()] * 4),
                lambda: gymnasium.make_vec('robot_ai/RosCartPole-v1', num_envs=4, vectorization_mode='sync'),
                lambda: gymnasium.make_vec('robot_ai/RosCartPole-v1', num_envs=4)]
        for build in make:
            vector = build()
            self.opened.append(vector)
            self.assert_same_vector_run(vector)
            vector.close()
        for mode in ('async-make', 'make_vec-async'):
            done = subprocess.run([sys.executable, VECTORISERS, mode], capture_output=True, text=True, timeout=300)
            self.assertEqual(done.returncode, 0, done.stderr[-3000:])
            self.assertEqual(done.stdout.strip(), 'same as gymnasium', (mode, done.stdout, done.stderr[-2000:]))

    def assert_same_vector_run(self, vector, seed=5, steps=300):
        ref = gymnasium.make_vec('CartPole-v1', num_envs=4, vectorization_mode='sync')
        rng = np.random.default_rng(seed)
        self.assertTrue(same(vector.reset(seed=seed)[0], ref.reset(seed=seed)[0]))
        for _ in range(steps):
            a = rng.integers(2, size=4)
            for x, y in zip(vector.step(a)[:4], ref.step(a)[:4]):
                self.assertTrue(same(x, y))

    def test_third_parties_never_take_a_step(self):
        """While an env pauses (a PPO update), another node floods cart_force, calls ~reset, ~set_state and ~push
        and publishes joint_states of its own on the sim's topic, and watchers subscribe to the sim's latched
        joint_states (rospy re-sends the latched state to each, bumping its header.seq: issue 40 saw that end a
        50k-step PPO run): the sim refuses and ignores them all, and the env's run equals gymnasium's."""
        env, ref = self.ros('/cartpole_0'), gymnasium.make('CartPole-v1')
        obs, _ = env.reset(seed=21)
        ref.reset(seed=21)
        for _ in range(5):
            for x, y in zip(env.step(good(obs)), ref.step(good(obs))):
                self.assertTrue(same(x, y))
        flood = subprocess.Popen(['rostopic', 'pub', '-r', '200', '/cartpole_0/cart_force', 'std_msgs/Float64',
                                  'data: 10.0'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                 preexec_fn=os.setsid)
        fake = subprocess.Popen(['rostopic', 'pub', '-r', '100', '/cartpole_0/joint_states', 'sensor_msgs/JointState',
                                 '{name: [cart_slider, pole_hinge], position: [0.5, 0.1], velocity: [0, 0]}'],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
        try:
            time.sleep(3.0)          # a pause longer than the sim's 1 s driver silence
            for _ in range(3):       # read-only watchers, each sent the latched state when it subscribes
                echo = subprocess.run(['rostopic', 'echo', '-n', '1', '/cartpole_0/joint_states/position'],
                                      capture_output=True, text=True, timeout=60)
                self.assertIn('---', echo.stdout, echo.stderr)
            for service, args in (('reset', '{}'), ('set_state', '{state: [0, 0, 0.1, 0]}'),
                                  ('push', '{angular_velocity: 1.0}')):
                answer = subprocess.run(['rosservice', 'call', f'/cartpole_0/cartpole_sim/{service}', args],
                                        capture_output=True, text=True, timeout=60).stdout
                self.assertIn('success: False', answer, service)
                self.assertIn('leased to', answer, service)
            obs = env.unwrapped.state.astype(np.float32)
            for t in range(300):
                r1, r2 = env.step(good(obs)), ref.step(good(obs))
                for x, y in zip(r1, r2):
                    self.assertTrue(same(x, y), (t, r1, r2))
                obs = r1[0]
                if r1[2] or r1[3]:
                    break
        finally:
            for p in (flood, fake):
                os.killpg(p.pid, signal.SIGINT)
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:      # rostopic on a loaded machine: SIGINT not yet handled
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait()

    def test_a_set_state_of_millions_of_numbers_costs_the_sim_its_size(self):
        """Issue 40: ~set_state with 20 million numbers cost the sim 1.2 GB (a Python float each) before it refused
        them. Read by numpy, 10 million numbers (80 MB) cost about their size, and the refusal says why."""
        import struct
        from robot_ai.srv import SetCartPoleState, SetCartPoleStateRequest

        class Big(SetCartPoleStateRequest):     # the array's bytes as they are (rospy's numpy writer needs numpy 1)
            def serialize(self, buff):
                buff.write(struct.pack('<I', len(self.state)))
                buff.write(np.ascontiguousarray(self.state, '<f8').tobytes())
        service = type('BigSetState', (), dict(_type=SetCartPoleState._type, _md5sum=SetCartPoleState._md5sum,
                                               _request_class=Big, _response_class=SetCartPoleState._response_class))
        uri = rosgraph.Master('/test').lookupNode('/free/cartpole_sim')
        pid = xmlrpc.client.ServerProxy(uri).getPid('/test')[2]

        def peak_mib():
            with open(f'/proc/{pid}/status') as f:
                return next(int(l.split()[1]) for l in f if l.startswith('VmHWM')) / 1024
        before = peak_mib()
        call = rospy.ServiceProxy('/free/cartpole_sim/set_state', service)
        answer = call(state=np.zeros(10_000_000))
        self.assertFalse(answer.success)
        self.assertIn('a state is 4 numbers', answer.message)
        self.assertLess(peak_mib() - before, 250, f'the sim grew from {before:.0f} to {peak_mib():.0f} MiB')

    def test_a_stopped_env_keeps_its_sim(self):
        """Issue 40: an env whose process was stopped (Ctrl-Z, a debugger; or busy for seconds in C code) lost its sim
        to the next env that asked, and raised at its next step. The lease holds across pauses of any length."""
        code = ("import gymnasium, os, signal, sys, robot_ai.envs; e = gymnasium.make('robot_ai/RosCartPole-v1', "
                "robot_ns='/cartpole_3'); e.reset(seed=0); print('held', flush=True); os.kill(os.getpid(), "
                "signal.SIGSTOP); e.step(1); print('stepped', flush=True); e.close()")
        holder = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, start_new_session=True)
        try:
            self.assertEqual(holder.stdout.readline().strip(), 'held')
            deadline = time.monotonic() + 30
            while open(f'/proc/{holder.pid}/stat').read().rsplit(')', 1)[1].split()[0] != 'T':
                self.assertLess(time.monotonic(), deadline)
                time.sleep(0.05)
            for _ in range(2):
                with self.assertRaises(RosCartPoleError) as caught:
                    self.ros('/cartpole_3', timeout=3.0).reset(seed=0)
                self.assertIn('leased to', str(caught.exception))
            os.kill(holder.pid, signal.SIGCONT)
            out, err = holder.communicate(timeout=60)
            self.assertEqual(holder.returncode, 0, err[-2000:])
            self.assertIn('stepped', out)
        finally:
            if holder.poll() is None:
                os.killpg(holder.pid, signal.SIGKILL)
                holder.wait()

    def test_a_killed_env_frees_its_sim(self):
        code = ("import gymnasium, os, signal, robot_ai.envs; e = gymnasium.make('robot_ai/RosCartPole-v1', "
                "robot_ns='/cartpole_3'); e.reset(seed=0); print('held', flush=True); os.kill(os.getpid(), 9)")
        done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
        self.assertEqual(done.returncode, -signal.SIGKILL, done.stderr[-2000:])
        self.assertIn('held', done.stdout)
        t = time.monotonic()
        env = self.ros('/cartpole_3', timeout=5.0)
        env.reset(seed=0)           # the holder is gone: its lease ends when someone asks
        self.assertLess(time.monotonic() - t, 5.0)

    def test_no_master_is_an_error_within_the_timeout_and_every_call_after_a_failure_is_the_envs_own_error(self):
        code = ("import gymnasium, time, robot_ai.envs\n"
                "env = gymnasium.make('robot_ai/RosCartPole-v1', timeout=2.0)\n"
                "t = time.monotonic()\n"
                "try:\n    env.reset(seed=0)\nexcept robot_ai.envs.RosCartPoleError as e:\n"
                "    print('reset:', e, round(time.monotonic() - t, 1))\n"
                "try:\n    env.step(0)\nexcept robot_ai.envs.RosCartPoleError as e:\n    print('step:', e)\n")
        env = dict(os.environ, ROS_MASTER_URI=f'http://localhost:{free_port()}')
        done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60, env=env)
        self.assertEqual(done.returncode, 0, done.stderr[-2000:])
        lines = done.stdout.splitlines()
        self.assertTrue(lines[0].startswith('reset: no ROS master answers'), done.stdout)
        self.assertLess(float(lines[0].split()[-1]), 2.0 + 3.0)
        self.assertTrue(lines[1].startswith('step: no ROS master answers'), done.stdout)
        self.assertIn('call reset()', lines[1])
        with tempfile.TemporaryDirectory() as folder:
            subprocess.run([sys.executable, '-m', 'robot_ai.cartpole', 'random-search', '--iterations', '3',
                            '--episodes', '3', '--output-dir', folder], check=True, capture_output=True, timeout=120)
            policy = next(os.path.join(folder, f) for f in os.listdir(folder) if f.endswith('.npz'))
            t = time.monotonic()
            cli = subprocess.run([sys.executable, '-m', 'robot_ai.cartpole', 'evaluate', policy, '--ros-env',
                                  '/cartpole_0', '--timeout', '1'], capture_output=True, text=True, timeout=60, env=env)
        self.assertLess(time.monotonic() - t, 30.0)
        self.assertEqual(cli.returncode, 1, cli.stderr)
        self.assertNotIn('Traceback', cli.stderr)
        self.assertIn('no ROS master answers', cli.stderr)

    def test_a_flood_of_invalid_forces_never_stalls_a_free_running_sim(self):
        """Each ignored force still answers its state (the last valid force held): the free sim keeps its 50
        states a second of ROS time. (YAML reads 1e308 as a string: rostopic then published nothing at all, and the
        sim stepped on its clock; 1.0e+308 is the float beyond MAX_FORCE this means.)"""
        counted = []
        sub = rospy.Subscriber('/free/joint_states', JointState, lambda m: counted.append(time.monotonic()))
        flood = subprocess.Popen(['rostopic', 'pub', '-r', '300', '/free/cart_force', 'std_msgs/Float64',
                                  'data: 1.0e+308'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                 preexec_fn=os.setsid)
        try:
            time.sleep(3.0)
            start = len(counted)
            time.sleep(4.0)
            states = len(counted) - start
        finally:
            os.killpg(flood.pid, signal.SIGINT)
            flood.wait(30)
            sub.unregister()
        self.assertGreater(states, 100, states)        # 200 in 4 s; the old sim answered about 4

if __name__ == '__main__':
    rospy.init_node('test_ros_env')
    rostest.rosrun('robot_ai', 'ros_env', TestRosEnv, sys.argv)
