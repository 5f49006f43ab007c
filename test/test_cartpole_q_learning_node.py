#!/usr/bin/env python3
"""cartpole_q_learning node: train, evaluate, act, the action with feedback and cancel, bad input, artifacts."""
import math
import os
import subprocess
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus

from robot_ai import policies

from robot_ai.cartpole import q_learning
from robot_ai.cartpole.dynamics import CartPoleDynamics
from robot_ai.msg import QLearningAction, QLearningGoal, QLearningProgress
from robot_ai.srv import Act, EvaluateAgent, LoadPolicy, QLearning

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from ros_helpers import action_client, on_this_master, wait_file  # noqa: E402

NS = '/cartpole_q_learning/'


class TestCartPoleQLearningNode(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        for name in ('train', 'evaluate', 'act'):
            rospy.wait_for_service(NS + name, 60)
        cls.train = rospy.ServiceProxy(NS + 'train', QLearning)
        cls.evaluate = rospy.ServiceProxy(NS + 'evaluate', EvaluateAgent)
        cls.act = rospy.ServiceProxy(NS + 'act', Act)
        cls.progress = []
        cls.sub = rospy.Subscriber(NS + 'progress', QLearningProgress, cls.progress.append, queue_size=10000)
        cls.output_dir = os.path.abspath(rospy.get_param(NS + 'output_dir'))

    def test_0_before_any_training(self):
        self.assertFalse(self.act(state=[0, 0, 0, 0]).success)
        res = self.evaluate(episodes=3)
        self.assertFalse(res.success)
        self.assertIn('train one first', res.message)

    def test_1_course_experiment_with_defaults(self):
        res = self.train()  # every field zero/empty: the course's 500 episodes of CartPole-v0, tf, seed 0
        self.assertTrue(res.success, res.message)
        self.assertIn('avg reward for last 100 episodes: %.2f' % res.mean_last100, res.message)
        self.assertEqual(len(res.total_rewards), 500)
        self.assertEqual(len(res.last100_averages), 1)
        self.assertEqual(res.ci95_last100, 0.0)
        # the same training without ROS gives the same numbers, bit for bit
        local = q_learning.train(q_learning.resolve(), 0)
        self.assertEqual(list(res.total_rewards), list(local.total_rewards[0]))
        self.assertEqual(res.mean_last100, local.mean_last100)
        self.assertGreater(res.mean_last100, 190)
        self.assertTrue(res.plot_path.startswith(self.output_dir) and res.plot_path.endswith('.png'))
        self.assertTrue(wait_file(res.plot_path), res.plot_path)
        with open(res.plot_path, 'rb') as f:
            self.assertEqual(f.read(8), b'\x89PNG\r\n\x1a\n')
        self.assertEqual(res.video_path, '')
        deadline = time.time() + 5
        while not any(p.learner == 0 and p.episode == 500 for p in self.progress) and time.time() < deadline:
            time.sleep(0.05)
        self.assertTrue(any(p.learner == 0 and p.episode == 500 and p.episodes == 500 for p in self.progress))
        # learner 0 becomes the node's agent: greedy episodes and actions as the library's agent gives them
        ev = self.evaluate(episodes=20, seed=5)
        self.assertTrue(ev.success, ev.message)
        want = local.agents[0].evaluate(CartPoleDynamics.of('CartPole-v0'), 20, 200, 5)
        self.assertEqual(list(ev.lengths), [int(v) for v in want])
        self.assertAlmostEqual(ev.avg_length, float(np.mean(want)))
        self.assertGreater(ev.avg_length, 190)
        for state in ([0, 0, 0.05, 0], [0, 0, -0.05, 0], [0.1, -0.4, 0.01, 0.3]):
            a = self.act(state=state)
            self.assertTrue(a.success, a.message)
            self.assertEqual(a.action, local.agents[0].act(state))

    def test_1b_train_on_from_a_policy_file(self):
        """Issue 27: ~train takes an initial policy file and continues its agent for more episodes (as
        stable-baselines3's load() then learn()); the new file names the file it started from."""
        first = self.train(episodes=60, components=50, seed=2)
        self.assertTrue(first.success, first.message)
        on = self.train(episodes=40, seed=3, initial_policy=first.policy_path)
        self.assertTrue(on.success, on.message)
        self.assertEqual(len(on.total_rewards), 40)
        from robot_ai import policies
        start, kept = policies.load(first.policy_path), policies.load(on.policy_path)
        self.assertEqual(kept.metadata['settings']['started_from'], first.policy_path)
        self.assertEqual(kept.metadata['settings']['start_episode'], 60)
        self.assertEqual(kept.metadata['settings']['components'], 50)
        self.assertEqual(kept.actor.feature_weights.tobytes(), start.actor.feature_weights.tobytes())
        local = q_learning.train(q_learning.resolve(episodes=40, start=start.actor,
                                                    start_settings=start.metadata['settings']), 3)
        self.assertEqual(list(on.total_rewards), list(local.total_rewards[0]))
        for bad, message in (('/nonexistent.npz', 'initial_policy: no policy file at'),
                             (first.log_path, 'initial_policy:')):
            res = self.train(episodes=5, initial_policy=bad)
            self.assertFalse(res.success)
            self.assertIn(message, res.message)

    def test_2_learners_video_and_v1(self):
        res = self.train(env_id='CartPole-v1', episodes=150, components=200, learners=3, seed=-2, regressor='sgd',
                         gamma=0.95, bootstrap_at_time_limit=True, record_video=True)
        self.assertTrue(res.success, res.message)
        self.assertEqual(len(res.last100_averages), 3)
        self.assertAlmostEqual(res.mean_last100, float(np.mean(res.last100_averages)))
        self.assertGreater(res.ci95_last100, 0.0)
        self.assertIn(' +/- ', res.message)
        self.assertTrue(res.message.isascii(), res.message)   # rosservice call shows anything else as \xB1
        training = q_learning.resolve('CartPole-v1', 150, 0.95, 'sgd', 200, 1, True)
        single, _ = q_learning.train_one(training, -2 + 2)  # learner 2 is the single run with seed -2 + 2
        self.assertEqual(res.last100_averages[2], single[-100:].mean())
        self.assertIn('_CartPole-v1_seed-2', res.video_path)
        self.assertTrue(res.video_path.startswith(self.output_dir) and os.path.getsize(res.video_path) > 1000)
        self.assertTrue(wait_file(res.plot_path))

    def test_3_bad_input_gets_a_message_fast_and_the_node_keeps_serving(self):
        cases = [
            (self.train, dict(regressor='adam'), 'regressor must be one of sgd, tf'),
            (self.train, dict(env_id='MountainCar-v0'), 'not a CartPole'),
            (self.train, dict(env_id='NoSuchEnv-v3'), 'unknown'),
            (self.train, dict(gamma=float('nan')), 'gamma must be in (0, 1]'),
            (self.train, dict(gamma=2.0), 'gamma must be in (0, 1]'),
            (self.train, dict(components=10 ** 6), 'components must be 1 to'),
            (self.train, dict(learners=64, episodes=10000), 'more than the limit'),
            (self.evaluate, dict(episodes=10 ** 6), 'episodes must be 1 to'),
            (self.evaluate, dict(max_steps=1000), 'max_steps must be 1 to'),
            (self.act, dict(state=[0.0, 1.0]), 'state must be 4 numbers'),
            (self.act, dict(state=[0.0, float('inf'), 0, 0]), 'finite'),
        ]
        for call, kwargs, message in cases:
            t = time.time()
            res = call(**kwargs)
            self.assertFalse(res.success, kwargs)
            self.assertIn(message, res.message)
            self.assertLess(time.time() - t, 1.0, 'a bad request must be answered within a second')
        self.assertTrue(self.train(episodes=5, components=10).success)

    def test_4_action_feedback_and_cancel(self):
        client = action_client(NS + 'training', QLearningAction)
        self.assertIsNotNone(client, 'no action server with connected topics within 30 s')
        feedback = []
        client.send_goal(QLearningGoal(episodes=120, components=100, seed=11),
                         feedback_cb=lambda fb: feedback.append(fb))
        self.assertTrue(client.wait_for_result(rospy.Duration(60)))
        self.assertEqual(client.get_state(), GoalStatus.SUCCEEDED)
        result = client.get_result()
        self.assertTrue(result.success, result.message)
        self.assertEqual(len(result.total_rewards), 120)
        deadline = time.time() + 5
        while len(feedback) < 120 and time.time() < deadline:
            time.sleep(0.05)
        self.assertEqual([fb.episode for fb in feedback], list(range(1, 121)))
        self.assertEqual([fb.total_reward for fb in feedback], list(result.total_rewards))
        self.assertEqual([fb.epsilon for fb in feedback], [1 / math.sqrt(n + 1) for n in range(120)])
        self.assertAlmostEqual(feedback[-1].running_average, float(np.mean(result.total_rewards[-100:])))

        # a long batch (16 learners x 4,000 episodes) is cancelled after its first feedback
        feedback[:] = []
        client.send_goal(QLearningGoal(episodes=4000, learners=16, seed=1), feedback_cb=lambda fb: feedback.append(fb))
        deadline = time.time() + 60
        while not feedback and time.time() < deadline:
            time.sleep(0.05)
        self.assertTrue(feedback, 'no feedback from a long training')
        t = time.time()
        client.cancel_goal()
        self.assertTrue(client.wait_for_result(rospy.Duration(30)))
        self.assertEqual(client.get_state(), GoalStatus.PREEMPTED)
        self.assertLess(time.time() - t, 10)
        self.assertIn('cancelled', client.get_result().message)
        self.assertTrue(self.train(episodes=5, components=10).success)  # serving again


    def test_5_concurrent_evaluations_stay_within_memory(self):
        """8 concurrent ~evaluate calls of 1,000 episodes on an agent with 40,000 features peaked at 1.34 GB: now
        one evaluation runs at a time and its features are computed 16 MiB at a time."""
        training = q_learning.resolve(episodes=10, components=10000)
        _, agent = q_learning.train_one(training, 0)
        path = policies.save(os.path.join(self.output_dir, 'big_agent.npz'), agent, 'CartPole-v0', 0)
        load = rospy.ServiceProxy(NS + 'load_policy', LoadPolicy)
        self.assertTrue(load(path=path).success)
        pid = node_pid('cartpole_q_learning')
        before = peak_mib(pid)
        answers = []
        def call():
            answers.append(self.evaluate(episodes=1000, seed=3, env_id='CartPole-v1'))
        calls = [threading.Thread(target=call) for _ in range(8)]
        for c in calls:
            c.start()
        deadline = time.monotonic() + 900            # one at a time: on a loaded machine minutes, not a failure
        for c in calls:
            c.join(max(1.0, deadline - time.monotonic()))
        self.assertEqual(len(answers), 8)
        self.assertTrue(all(a.success and list(a.lengths) == list(answers[0].lengths) for a in answers))
        peak = peak_mib(pid)
        print(f'node peak memory {before:.0f} MiB before, {peak:.0f} MiB after 8 concurrent evaluations')
        self.assertLess(peak, max(before, 150) + 150)


def node_pid(name):
    table = [l.split(None, 1) for l in subprocess.run(['ps', '-eo', 'pid=,args='], capture_output=True,
                                                      text=True).stdout.splitlines()]
    pids = [int(pid) for pid, args in table if f'__name:={name}' in args.split() and on_this_master(pid)]
    assert len(pids) == 1, pids
    return pids[0]


def peak_mib(pid):
    with open(f'/proc/{pid}/status') as f:
        return next(int(l.split()[1]) for l in f if l.startswith('VmHWM:')) / 1024.0


if __name__ == '__main__':
    rospy.init_node('test_cartpole_q_learning_node')
    rostest.rosrun('robot_ai', 'test_cartpole_q_learning_node', TestCartPoleQLearningNode)
