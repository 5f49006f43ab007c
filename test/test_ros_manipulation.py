#!/usr/bin/env python3
"""Push-v0 and PickAndPlace-v0 through ROS (robot_ai/RosPush-v0, robot_ai/RosPickAndPlace-v0) on
manipulation_gym.launch's arm_sims with physics: every observation, reward and success equal to the envs over MuJoCo
bit for bit under the scripted expert and under random actions, on the UR5 with a Robotiq and on the Panda with its
real meshes; gymnasium's env checker; make_vec's sync and async vectorisers equal to the package's vector env; a sim
killed mid-episode said within the timeout; the docs' blocks run as written; an env made for
another world refused, naming the sim; arm_sim's set_object_pose refusing what is not an object or a pose."""
import os
import subprocess
import sys
import time
import unittest

import gymnasium
import numpy as np
import rosgraph
import rospy
import rostest
from geometry_msgs.msg import Pose
from gymnasium.utils.env_checker import check_env

import robot_ai.envs  # noqa: F401  (registers the envs over ROS)
import robot_ai.physics  # noqa: F401  (registers the envs over MuJoCo)
from robot_ai.envs.ros_manipulation import RosManipulationError
from robot_ai.srv import SetObjectPose

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from doc_blocks import python_blocks, run_as_written  # noqa: E402

MESHES = os.path.normpath(os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', 'shared', 'robots',
                                      'meshes'))


def description(ns: str) -> str:
    return rosgraph.Master('/test').getParam(f'{ns}/robot_description')


def expert(env, obs) -> np.ndarray:
    return env.unwrapped.setup.expert(obs['observation'][None], obs['desired_goal'][None])[0]


def same_vector_steps(ros, ref, observations, steps: int, seed: int) -> None:
    """Two vector envs stepped with the same random actions from their observations: equal bit for bit."""
    a_obs, b_obs = observations
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        for key in b_obs:
            np.testing.assert_array_equal(a_obs[key], b_obs[key])
        actions = rng.uniform(-1, 1, (2, 4))
        a_obs, a_reward, _, a_cut, _ = ros.step(actions)
        b_obs, b_reward, _, b_cut, _ = ref.step(actions)
        np.testing.assert_array_equal(a_reward, b_reward)
        np.testing.assert_array_equal(a_cut, b_cut)


class TestRosManipulation(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        os.environ['ROS_PACKAGE_PATH'] = f'{os.environ.get("ROS_PACKAGE_PATH", "")}:{MESHES}'
        rospy.wait_for_service('/arm_1/arm_sim/set_object_pose', timeout=180)
        rospy.wait_for_service('/panda/arm_0/arm_sim/set_object_pose', timeout=180)

    def same_episodes(self, name: str, ns: str, seeds, policy):
        """Episodes of robot_ai/Ros<name> on ns and robot_ai/<name> side by side: equal bit for bit; successes."""
        ros = gymnasium.make(f'robot_ai/Ros{name}', robot_ns=ns)
        ref = gymnasium.make(f'robot_ai/{name}', urdf=description(ns))
        successes = 0
        try:
            for seed in seeds:
                rng = np.random.default_rng(seed)
                a_obs, a_info = ros.reset(seed=seed)
                b_obs, b_info = ref.reset(seed=seed)
                self.assertEqual(a_info, b_info)
                done = False
                while not done:
                    for key in b_obs:
                        np.testing.assert_array_equal(a_obs[key], b_obs[key], err_msg=f'{name} seed {seed} {key}')
                    action = policy(ref, b_obs, rng)
                    a_obs, a_reward, a_end, a_cut, a_info = ros.step(action)
                    b_obs, b_reward, b_end, b_cut, b_info = ref.step(action)
                    self.assertEqual((a_reward, a_end, a_cut, a_info), (b_reward, b_end, b_cut, b_info))
                    done = b_end or b_cut
                successes += b_info['is_success']
        finally:
            ros.close()
            ref.close()
        return successes

    def test_push_on_the_ur5_equals_push_v0(self):
        placed = self.same_episodes('Push-v0', '/arm_0', [0, 1], lambda env, obs, rng: expert(env, obs))
        self.assertGreaterEqual(placed, 1)        # the expert pushes: the cube moved as in MuJoCo, not left
        self.same_episodes('Push-v0', '/arm_0', [2], lambda env, obs, rng: rng.uniform(-1, 1, 4))

    def test_pick_and_place_on_the_panda_equals_pick_and_place_v0(self):
        placed = self.same_episodes('PickAndPlace-v0', '/panda/arm_0', [0, 1],
                                    lambda env, obs, rng: expert(env, obs))
        self.assertGreaterEqual(placed, 1)
        self.same_episodes('PickAndPlace-v0', '/panda/arm_0', [3], lambda env, obs, rng: rng.uniform(-1, 1, 4))

    def test_env_checker_and_the_sync_vectoriser(self):
        env = gymnasium.make('robot_ai/RosPush-v0', robot_ns='/arm_1')
        try:
            check_env(env.unwrapped, skip_render_check=True)
        finally:
            env.close()
        ros = gymnasium.make_vec('robot_ai/RosPush-v0', num_envs=2, vectorization_mode='sync')
        ref = gymnasium.make_vec('robot_ai/Push-v0', num_envs=2, urdf=description('/arm_0'))
        try:
            self.assertEqual(sorted(e.unwrapped.sim_namespace or '' for e in ros.envs), ['', ''])   # not yet
            a_obs, _ = ros.reset(seed=5)
            b_obs, _ = ref.reset(seed=5)
            self.assertEqual(sorted(e.unwrapped.sim_namespace for e in ros.envs), ['/arm_0', '/arm_1'])
            same_vector_steps(ros, ref, (a_obs, b_obs), 60, 0)     # past the 50 steps: the autoresets
        finally:
            ros.close()
            ref.close()

    def test_a_sim_that_dies_is_said_within_the_timeout_and_then_every_call_raises(self):
        env = gymnasium.make('robot_ai/RosPush-v0', robot_ns='/doomed/arm_0', timeout=3.0)
        try:
            env.reset(seed=0)
            env.step(env.action_space.sample())
            subprocess.run(['rosnode', 'kill', '/doomed/arm_0/arm_sim'], capture_output=True, timeout=60)
            start = time.monotonic()
            with self.assertRaises(RosManipulationError) as caught:
                for _ in range(3):     # a step already on its way may still be answered
                    env.step(env.action_space.sample())
            self.assertLess(time.monotonic() - start, 30.0)
            self.assertIn('/doomed/arm_0', str(caught.exception))
            with self.assertRaisesRegex(RosManipulationError, r'call reset\(\) to start again'):
                env.step(env.action_space.sample())
        finally:
            env.close()

    def test_the_docs_blocks_run_as_written(self):
        """Issue 57: the python blocks of the docs that lease an arm with physics (docs/envs/RosManipulation.md) run
        as written on manipulation_gym.launch's arms, each in a process of its own."""
        blocks = [b for b in python_blocks() if b.needs_ros == 'manipulation' and not b.missing]
        self.assertGreaterEqual(len(blocks), 2, 'the test finds too few blocks')
        for block in blocks:
            self.assertEqual(run_as_written(block), '')

    def test_the_async_vectoriser(self):
        """make_vec's async vectoriser (each env in a process of its own, leasing its arm) equals the package's
        vector env, past the autoreset."""
        ros = gymnasium.make_vec('robot_ai/RosPickAndPlace-v0', num_envs=2, vectorization_mode='async',
                                 vector_kwargs={'context': 'spawn'})
        ref = gymnasium.make_vec('robot_ai/PickAndPlace-v0', num_envs=2, urdf=description('/arm_0'))
        try:
            same_vector_steps(ros, ref, (ros.reset(seed=9)[0], ref.reset(seed=9)[0]), 55, 1)
        finally:
            ros.close()
            ref.close()

    def test_another_world_is_refused(self):
        env = gymnasium.make('robot_ai/RosPush-v0', robot_ns='/arm_0', object_size=0.05, timeout=10)
        with self.assertRaises(RosManipulationError) as caught:
            env.reset(seed=0)
        self.assertIn('/arm_0: the arm_sim has another world than this env\'s', str(caught.exception))
        env.close()

    def test_set_object_pose_refuses_what_is_not_an_object_or_a_pose(self):
        call = rospy.ServiceProxy('/arm_0/arm_sim/set_object_pose', SetObjectPose)
        pose = Pose()
        pose.orientation.w = 1.0
        answer = call('nothing', pose)
        self.assertFalse(answer.success)
        self.assertIn("no object 'nothing'", answer.message)
        pose.orientation.w = 0.0
        answer = call('object', pose)
        self.assertFalse(answer.success)
        self.assertIn('unit quaternion', answer.message)


if __name__ == '__main__':
    rospy.init_node('test_ros_manipulation', anonymous=True, disable_signals=True)
    rostest.rosrun('robot_ai', 'ros_manipulation', TestRosManipulation)
