"""Reach-v0 with velocity_scale (issue 39): the env moves the arm as reach_controller's safety layer and a
joint_trajectory_controller do, one control period per step, so that what a policy learns is what the arm does
through ROS. No roscore."""
import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import robot_ai.reach  # noqa: F401 (registers robot_ai/Reach-v0)
from fk_helpers import robot_path
from robot_ai import ars
from robot_ai.reach import ReachError, ReachSetup, ReachVectorEnv, learn, policy_files
from robot_ai.reach.env import ReachEnv, Recovery
from robot_ai.reach.safety import SafetyLayer, violations
from robot_ai.reach.trajectory import Follower
from test_reach import assert_same, make_sync

KUKA = robot_path('kuka_lwr_arm.urdf')
UR5 = robot_path('ur5.urdf')


def through_the_layer(setup: ReachSetup, env: ReachEnv, policy, seed: int, steps: int):
    """The env's episode beside reach_controller's loop run in-process on the same goal: every control period the
    policy acts on where the arm is (its target after the limit recovery, as the node's), the safety layer plans
    (two periods ahead), the plan goes to a Follower (what arm_sim and a joint_trajectory_controller run). (the
    env's joints, the loop's joints, the loop's times) per step."""
    act = lambda o: policy.act_batch(ars.flatten_batch(setup.observation_space,     # noqa: E731
                                                       {k: np.asarray(v)[None] for k, v in o.items()}))[0]
    obs, _ = env.reset(seed=seed)
    goal = obs['desired_goal'].tolist()
    period = setup.control_period
    layer = SafetyLayer(setup.limits, period)
    arm = Follower(np.array(env.joint_positions))
    env_q, loop_q, times = [], [], []
    recovery = Recovery()                  # the goal's limit recovery, as reach_controller keeps it
    for k in range(steps):
        t = k * period
        q = arm.state_at(t)[0]
        env_q.append(np.array(env.joint_positions))
        loop_q.append(q)
        times.append(t)
        tip, jac = setup.place_one(q.tolist())
        a = setup.check_action_one(act(setup.observation_one(q.tolist(), tip, goal)))
        target, recovery = setup.recover_one(q.tolist(), tip, setup.move_one(q.tolist(), jac, a), a, goal, recovery)
        plan = layer.plan(t, target, q, measured_at=t)
        assert not plan.held, plan.held
        arm.take(t, plan.start, *plan.points(period))
        obs = env.step(np.asarray(act(obs), dtype=np.float32))[0]
    return np.array(env_q), np.array(loop_q), np.array(times)


@pytest.mark.parametrize('robot, scale', [(KUKA, 0.5), (UR5, 1.0), (robot_path('panda.urdf'), 0.25)])
def test_the_env_moves_the_arm_as_the_safety_layer_and_a_trajectory_controller_do(robot, scale):
    """The P-controller's episodes in the env and in the loop reach_controller runs (layer, then follower) go
    through the same joints to 1e-6 rad; the motion passes no limit and would pass them without the layer (the
    actions ask for more than a period allows)."""
    setup = ReachSetup(robot, velocity_scale=scale)
    env = ReachEnv(robot, velocity_scale=scale)
    policy = learn.p_controller(setup)
    asked = []
    for seed in range(3):
        env_q, loop_q, times = through_the_layer(setup, env, policy, seed, setup.episode_steps)
        np.testing.assert_allclose(env_q, loop_q, atol=1e-6, rtol=0)     # float rounding of the Hermite
        found = violations(times, env_q, setup.limits)
        assert found.total == 0, found
        asked.append(np.abs(np.diff(env_q, axis=0)).max() / setup.control_period / setup.limits.velocity.max())
    assert max(asked) > 0.3, 'the arm hardly moved'


def test_a_step_moves_at_most_a_period_at_the_limits_and_the_target_comes_two_periods_later():
    setup = ReachSetup(KUKA, velocity_scale=0.25, control='joints')
    env = ReachEnv(KUKA, velocity_scale=0.25, control='joints')
    env.reset(seed=0)
    q0 = np.array(env.joint_positions)
    for _ in range(2):                     # the targets sent before the first: the arm at rest, held
        env.step(np.ones(setup.arm.n, np.float32))
        np.testing.assert_array_equal(env.joint_positions, q0)
    env.step(np.ones(setup.arm.n, np.float32))
    moved = np.array(env.joint_positions) - q0
    a, dt = setup.limits.acceleration, setup.control_period
    assert (moved > 0).all() and (moved <= 0.5 * a * dt * dt * (1 + 1e-9)).all()   # from rest, at most a t^2 / 2


def test_episodes_are_as_long_in_time_and_bad_settings_are_one_line():
    assert ReachSetup(UR5).episode_steps == 50
    assert ReachSetup(UR5, velocity_scale=1.0).episode_steps == 200
    assert ReachSetup(UR5, velocity_scale=0.25).episode_steps == 800
    assert ReachVectorEnv(2, model=UR5, velocity_scale=0.5).max_episode_steps == 400
    for kwargs, words in [(dict(velocity_scale=0.0), 'velocity_scale'), (dict(velocity_scale=2), 'velocity_scale'),
                          (dict(joint_limits={'joint_limits': {}}, acceleration_scale=0.5), 'give velocity_scale'),
                          (dict(velocity_scale=0.5, control_period=0), 'control_period'),
                          (dict(velocity_scale=0.5, joint_limits='joint_limits: 3'), 'joint_limits')]:
        with pytest.raises(ReachError, match=words):
            ReachSetup(UR5, **kwargs)


def test_joint_limits_yaml_narrows_the_motion_as_it_narrows_the_layer():
    fast = ReachSetup(UR5, velocity_scale=1.0)
    names = fast.arm.joints
    yaml = {'joint_limits': {n: {'has_velocity_limits': True, 'max_velocity': 0.1} for n in names}}
    slow = ReachSetup(UR5, velocity_scale=1.0, joint_limits=yaml)
    np.testing.assert_allclose(slow.limits.velocity, np.minimum(fast.limits.velocity, 0.1))
    env = ReachEnv(UR5, velocity_scale=1.0, joint_limits=yaml, control='joints')
    env.reset(seed=0)
    qs = [np.array(env.joint_positions)]
    for _ in range(40):
        env.step(np.ones(fast.arm.n, np.float32))
        qs.append(np.array(env.joint_positions))
    speed = np.abs(np.diff(qs, axis=0)).max() / fast.control_period
    assert 0.09 < speed <= 0.1 * (1 + 1e-9)


@pytest.mark.parametrize('kwargs, n', [(dict(model=KUKA, start='chained', velocity_scale=1.0), 3),
                                       (dict(model=UR5, start='random', velocity_scale=0.5), 2),
                                       (dict(model=KUKA, goal='pose', velocity_scale=1.0), 2),
                                       (dict(model=KUKA, velocity_scale=1.0,
                                             obstacles=[{'box': [2, 2, 0.1], 'position': [0, 0, -0.06]},
                                                        {'sphere': 0.15, 'position': [0.35, 0.0, 0.6]}]), 3)])
def test_vector_env_with_the_layer_equals_sync_vector_env_bit_for_bit(kwargs, n):
    kwargs = dict(reward_type='dense', max_episode_steps=100, **kwargs)      # TimeLimit's and the vector env's
    sync, vec = make_sync(n, **kwargs), gymnasium.make_vec('robot_ai/Reach-v0', num_envs=n, **kwargs)
    rng = np.random.default_rng(3)
    o1, i1 = sync.reset(seed=5)
    o2, i2 = vec.reset(seed=5)
    assert_same(o1, o2)
    for t in range(230):                  # past two autoresets
        a = rng.uniform(-1.5, 1.5, size=vec.action_space.shape).astype(np.float32)
        r1, r2 = sync.step(a), vec.step(a)
        for x, y in zip(r1, r2):
            assert_same(x, y)


def test_the_env_checker_passes_and_a_policy_file_keeps_the_layer(tmp_path):
    env = gymnasium.make('robot_ai/Reach-v0', model=KUKA, velocity_scale=0.5, max_episode_steps=400).unwrapped
    check_env(env)
    training = learn.train(dict(model=KUKA, velocity_scale=0.5), seed=0, evaluate_episodes=100,
                           settings=learn.replace(learn.default_settings(ReachSetup(KUKA)), iterations=3))
    path = policy_files.save(training, str(tmp_path / 'kuka.npz'))
    policy, setup, _ = policy_files.load(path)
    assert setup.limits is not None and setup.limits.velocity_scale == 0.5 and setup.episode_steps == 400


def test_through_gives_the_setup_velocity_scale_makes_without_loading_the_model_again():
    """What reach_controller predicts with (its layer's limits on its setup) is the env velocity_scale makes."""
    made = ReachSetup(KUKA, velocity_scale=0.5, control_period=0.04)
    plain = ReachSetup(KUKA)
    through = plain.through(made.limits, 0.04)
    assert plain.limits is None and plain.episode_steps == 50          # the setup it came from is unchanged
    assert through.episode_steps == made.episode_steps == 400 and through.control_period == 0.04
    policy = learn.p_controller(plain)
    a = learn.evaluate(policy, through, 50)
    b = learn.evaluate(policy, made, 50)
    np.testing.assert_array_equal(a.distances, b.distances)
