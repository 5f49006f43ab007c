"""robot_ai.reach without ROS: the arm's tip and Jacobian against KinematicTree.link_poses and finite differences on
every robot in ../shared/robots and a xacro arm; ReachVectorEnv against gymnasium's SyncVectorEnv bit for bit;
gymnasium's env checker; the goal-env reward; the refusals; policy files; the command line."""
import glob
import os
import subprocess
import sys
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import robot_ai.reach  # registers robot_ai/Reach-v0
from fk_helpers import robot_path
from robot_ai import ars
from robot_ai import policies
from robot_ai.reach import Arm, ReachEnv, ReachError, ReachSetup, ReachVectorEnv, goal_distance, learn, policy_files

HERE = os.path.dirname(os.path.realpath(__file__))
XACRO_ARM = os.path.join(HERE, '..', 'urdf', 'reach_arm7.urdf.xacro')
PACKAGE_UR5 = os.path.join(HERE, '..', '..', 'urdf', 'ur5_arm.urdf')
SHARED_ROBOTS = sorted(glob.glob(os.path.join(os.path.dirname(robot_path('ur5.urdf')), '**', '*.urdf'),
                              recursive=True))


def tree_of(path, xacro_args=None):
    return robot_ai.reach.load_model(path, xacro_args).tree


def arms_of(tree, most=12):
    """Arms of every tip that can be one (the deepest first, at most `most`), and the tips that cannot."""
    tips = Arm.candidate_tips(tree)[:most]
    arms, refused = [], []
    for tip in tips:
        try:
            arms.append(Arm(tree, tip))
        except ReachError as e:
            refused.append((tip, str(e)))
    return arms, refused


def test_the_shared_robots_are_all_there():
    names = {os.path.basename(p) for p in SHARED_ROBOTS}
    assert {'ur5.urdf', 'panda.urdf', 'kuka_lwr_arm.urdf', 'pr2.urdf', 'one_link.urdf'} <= names


@pytest.mark.parametrize('path, xacro_args', [(p, None) for p in SHARED_ROBOTS] + [(PACKAGE_UR5, None),
                         (XACRO_ARM, None), (XACRO_ARM, 'scale:=2.5 tool:=true')],
                         ids=lambda v: os.path.basename(v) if isinstance(v, str) and '/' in v else str(v))
def test_tip_equals_link_poses_and_jacobian_equals_finite_differences(path, xacro_args):
    tree = tree_of(path, xacro_args)
    arms, refused = arms_of(tree)
    for tip, message in refused:     # a tip on its joint's axis (a fixture's second link): refused in one line
        assert '\n' not in message and tip in message
    if not Arm.candidate_tips(tree):
        with pytest.raises(ReachError, match='no moving joint|does not move'):
            Arm(tree)
        return
    if not arms:     # robot_state_publisher's fixture: one joint whose child sits on its axis
        assert os.path.basename(path) == 'two_links_moving_joint.urdf', refused
        assert all('does not move' in m for _, m in refused)
        return
    rng = np.random.default_rng(0)
    for arm in arms:
        q = rng.uniform(arm.lower, arm.upper, size=(25, arm.n))
        tips = arm.tip_positions(q)
        base = arm.base if arm.base != tree.root else None
        for i in range(len(q)):
            poses = tree.link_poses(tree.resolve_positions(arm.positions(q[i])), base=base)
            np.testing.assert_allclose(tips[i], poses[arm.tip][:3, 3], atol=1e-12, err_msg=f'{path} {arm.tip}')
            assert np.linalg.norm(tips[i]) <= arm.radius + 1e-9
        jac, eps = arm.jacobian(q), 1e-6
        for k in range(arm.n):
            dq = np.zeros(arm.n)
            dq[k] = eps
            fd = (arm.tip_positions(q + dq) - arm.tip_positions(q - dq)) / (2 * eps)
            np.testing.assert_allclose(jac[:, :, k], fd, atol=1e-8, err_msg=f'{path} {arm.tip} {arm.joints[k]}')
        np.testing.assert_array_equal(arm.tip_positions(q[3]), tips[3])          # one configuration alone
        # the orientation (pose goals' groundwork): against link_poses, and its angular Jacobian against finite
        # differences of the rotation, omega = vee(dR R^T)
        rotations = arm.tip_rotations(q)
        for i in range(0, len(q), 5):
            poses = tree.link_poses(tree.resolve_positions(arm.positions(q[i])), base=base)
            np.testing.assert_allclose(rotations[i], poses[arm.tip][:3, :3], atol=1e-12, err_msg=f'{path} {arm.tip}')
        angular = arm.angular_jacobian(q)
        for k in range(arm.n):
            dq = np.zeros(arm.n)
            dq[k] = eps
            d = (arm.tip_rotations(q + dq) - arm.tip_rotations(q - dq)) / (2 * eps) @ rotations.transpose(0, 2, 1)
            omega = np.stack((d[:, 2, 1], d[:, 0, 2], d[:, 1, 0]), axis=1)
            np.testing.assert_allclose(angular[:, :, k], omega, atol=1e-8, err_msg=f'{path} {arm.tip} {arm.joints[k]}')


def test_mimic_joints_follow_their_source_even_off_the_chain():
    tree = tree_of(robot_path('panda.urdf'))
    right = Arm(tree, 'panda_rightfinger')     # panda_finger_joint2 mimics panda_finger_joint1, off this chain
    assert right.joints[-1] == 'panda_finger_joint1' and 'panda_finger_joint2' not in right.joints


def test_limits_home_and_velocities_come_from_the_urdf():
    arm = Arm(tree_of(robot_path('ur5.urdf')), 'tool0')
    np.testing.assert_allclose(arm.lower, [-2 * np.pi, -2 * np.pi, -np.pi, -2 * np.pi, -2 * np.pi, -2 * np.pi])
    np.testing.assert_allclose(arm.home, 0.0)
    np.testing.assert_allclose(arm.velocity, np.pi)
    pr2 = Arm(tree_of(robot_path('pr2.urdf')))
    continuous = [i for i, n in enumerate(pr2.joints) if pr2.tree.joints[n].type == 'continuous']
    assert continuous and all(pr2.lower[i] == -np.pi and pr2.upper[i] == np.pi for i in continuous)


def test_damped_least_squares_is_the_textbook_formula_and_clamping_keeps_the_limits():
    arm = Arm(tree_of(robot_path('panda.urdf')))
    rng = np.random.default_rng(1)
    q = rng.uniform(arm.lower, arm.upper, size=(40, arm.n))
    jac = arm.jacobian(q)
    dx = rng.normal(size=(40, 3)) * 0.05
    dq = arm.damped_least_squares(jac.transpose(1, 2, 0), dx.T, 0.03).T
    for i in range(40):
        j = jac[i]
        expected = j.T @ np.linalg.solve(j @ j.T + 0.03 ** 2 * np.eye(3), dx[i])
        np.testing.assert_allclose(dq[i], expected, rtol=1e-9, atol=1e-12)
    moved = arm.move_tip(q, dx * 20, 0.03)
    assert (moved >= arm.lower - 1e-12).all() and (moved <= arm.upper + 1e-12).all()


def make_sync(n, **kwargs):
    return gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make('robot_ai/Reach-v0', **kwargs) for _ in range(n)])


def assert_same(a, b):
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            assert_same(a[k], b[k])
        return
    assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
    assert np.array_equal(a, b), (a, b)


@pytest.mark.parametrize('model, control, start, n, extra', [
    (None, 'ee', 'home', 5, {}), (None, 'joints', 'random', 3, {}), (robot_path('panda.urdf'), 'ee', 'random', 4, {}),
    (robot_path('pr2.urdf'), 'ee', 'home', 3, {}), (XACRO_ARM, 'joints', 'home', 2, {}),
    (XACRO_ARM, 'ee', 'random', 6, {}), (robot_path('kuka_lwr_arm.urdf'), 'ee', 'chained', 4, {'limit_avoidance': 0.3}),
    (None, 'joints', 'chained', 3, {}), (robot_path('panda.urdf'), 'ee', 'random', 3, {'limit_avoidance': 1.0})])
def test_vector_env_equals_sync_vector_env_bit_for_bit(model, control, start, n, extra):
    kwargs = dict(model=model, control=control, start=start, reward_type='dense', **extra)
    sync, vec = make_sync(n, **kwargs), gymnasium.make_vec('robot_ai/Reach-v0', num_envs=n, **kwargs)
    assert isinstance(vec.unwrapped, ReachVectorEnv)
    rng = np.random.default_rng(7)
    for first in (11, [3, None, 5] + [None] * (n - 3)):   # an int seed, then a list with unseeded envs
        seeds = first if isinstance(first, int) else first[:n]   # None: the env goes on with its generator
        o1, i1 = sync.reset(seed=seeds)
        o2, i2 = vec.reset(seed=seeds)
        assert_same(o1, o2)
        assert_same(i1, i2)
        ee_step = vec.unwrapped.setup.ee_step
        for t in range(120):     # two autoresets of the 50-step episodes
            if control == 'ee' and t % 3:   # a P-controller most steps: the arm reaches, clamps, settles
                a = np.clip((o1['desired_goal'] - o1['achieved_goal']) / ee_step, -1, 1).astype(np.float32)
            else:
                a = rng.uniform(-1.5, 1.5, size=vec.action_space.shape).astype(np.float32)
            r1, r2 = sync.step(a), vec.step(a)
            for x, y in zip(r1, r2):      # observations, rewards, terminations, truncations, infos
                assert_same(x, y)
            o1 = r1[0]
    mask = np.array([i % 2 == 0 for i in range(n)])
    assert_same(sync.reset(seed=99, options={'reset_mask': mask})[1],
                vec.reset(seed=99, options={'reset_mask': mask})[1])
    assert_same(sync.step(np.zeros(vec.action_space.shape, np.float32))[0],
                vec.step(np.zeros(vec.action_space.shape, np.float32))[0])


def test_reach_env_passes_gymnasiums_checker_and_follows_the_goal_env_convention():
    for control in ('ee', 'joints'):
        env = gymnasium.make('robot_ai/Reach-v0', control=control, render_mode='rgb_array').unwrapped
        assert isinstance(env, ReachEnv)
        check_env(env)     # raises on a failure
        obs, info = env.reset(seed=0)
        assert set(obs) == {'achieved_goal', 'desired_goal', 'observation'} and 'is_success' in info
        assert obs['observation'].shape == (env.arm.n + 3,) and obs['observation'].dtype == np.float64
        np.testing.assert_array_equal(obs['observation'][-3:], obs['achieved_goal'])
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        # stable-baselines3's HER calls compute_reward on batches of relabelled goals
        batch_a = np.stack([obs['achieved_goal']] * 5)
        batch_d = np.stack([obs['desired_goal'], obs['achieved_goal'], obs['achieved_goal'] + [0.06, 0, 0],
                            obs['achieved_goal'] + [0, 0.04, 0], obs['desired_goal']])
        rewards = env.compute_reward(batch_a, batch_d, [info] * 5)
        assert rewards.shape == (5,) and rewards[0] == reward and rewards[1] == 0.0
        assert rewards[2] == -1.0 and rewards[3] == 0.0      # 0.06 m is outside 0.05 m, 0.04 m inside
        frame = env.render()
        assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8 and frame.std() > 0
        env.close()


def test_dense_reward_is_minus_the_distance_and_success_is_within_the_threshold():
    env = gymnasium.make('robot_ai/Reach-v0', reward_type='dense', distance_threshold=0.1)
    obs, _ = env.reset(seed=3)
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        d = float(goal_distance(obs['achieved_goal'], obs['desired_goal']))
        assert reward == -d and info['is_success'] == (d < 0.1) and not terminated
    assert truncated     # 50 steps, as FetchReach and PandaReach


@pytest.mark.parametrize('kwargs, words', [
    (dict(tip='no_such_link'), ['no_such_link', 'is not a link', 'tool0']),
    (dict(tip='base_link'), ['base_link', 'no moving joint']),
    (dict(model='/nonexistent/arm.urdf'), ['/nonexistent/arm.urdf']),
    (dict(model=robot_path('fixtures/one_link.urdf')), ['no moving joint']),
    (dict(model=XACRO_ARM, xacro_args='scale'), ['name:=value']),
    (dict(control='torque'), ['control must be one of']),
    (dict(home=[0.0] * 3), ['home must be 6 joint positions']),
    (dict(home={'elbow_joint': 9.0}), ['elbow_joint 9 not in']),
])
def test_refusals_are_one_line_that_says_what_is_wrong(kwargs, words):
    with pytest.raises(ReachError) as e:
        ReachSetup(**kwargs)
    message = str(e.value)
    assert '\n' not in message and all(w in message for w in words), message


def test_a_model_that_does_not_load_is_one_line(tmp_path):
    bad = tmp_path / 'bad.urdf.xacro'
    bad.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:nope/></robot>')
    with pytest.raises(ReachError) as e:
        ReachSetup(model=str(bad))
    assert '\n' not in str(e.value) and 'bad.urdf.xacro' in str(e.value) and 'nope' in str(e.value)


def test_actions_that_are_not_numbers_are_refused_and_the_env_goes_on():
    env = gymnasium.make('robot_ai/Reach-v0')
    env.reset(seed=0)
    with pytest.raises(ValueError, match='finite'):
        env.step(np.array([np.nan, 0, 0], np.float32))
    with pytest.raises(ValueError, match='3 numbers'):
        env.step(np.zeros(6, np.float32))
    env.step(np.zeros(3, np.float32))


def test_p_controller_reaches_from_home_and_a_random_policy_does_not():
    setup = ReachSetup()
    p = learn.evaluate(learn.p_controller(setup), setup, 400)
    assert p.success_rate >= 0.98
    random_policy = ars.LinearPolicy(np.random.default_rng(0).normal(size=(3, 15)), np.zeros(15), np.ones(15),
                                     np.zeros(3), -np.ones(3), np.ones(3))
    assert learn.evaluate(random_policy, setup, 400).success_rate < 0.1


def test_a_short_ars_run_learns_to_reach_is_reproducible_and_its_file_drives_the_same_arm(tmp_path):
    settings = replace(learn.SETTINGS, iterations=40)
    first = learn.train(dict(model=XACRO_ARM), settings, seed=3, evaluate_episodes=300)
    again = learn.train(dict(model=XACRO_ARM), settings, seed=3, evaluate_episodes=0)
    np.testing.assert_array_equal(first.policy.weights, again.policy.weights)
    assert first.held_out.success_rate >= 0.5          # a random policy: below 0.1 (above)
    path = policy_files.save(first, str(tmp_path / 'arm7.npz'))
    policy, setup, note = policy_files.load(path)
    assert note == '' and setup.arm.joints == first.setup.arm.joints
    x = np.random.default_rng(0).normal(size=(10, 9 + setup.arm.n))
    np.testing.assert_array_equal(policy.actor.act_batch(x), first.policy.act_batch(x))
    assert policy.metadata['training_steps'] == first.result.steps and policy.metadata['joints'] == setup.arm.joints
    # the same robot with other xacro arguments is another tip; another robot is refused, naming both
    with pytest.raises(policies.PolicyError) as e:
        policy_files.load(path, ReachSetup(model=XACRO_ARM, xacro_args='tool:=true', tip='tool'))
    assert 'reach_arm7' in str(e.value) and 'tip flange' in str(e.value) and 'tip tool' in str(e.value)
    with pytest.raises(policies.PolicyError) as e:
        policy_files.load(path, ReachSetup())
    assert 'reach_arm7' in str(e.value) and 'robot_ai_ur5_arm' in str(e.value) and '\n' not in str(e.value)


@pytest.mark.parametrize('goal', ['position', 'pose'])
def test_the_learned_action_depends_on_the_error_not_on_where_the_goal_is(goal):
    """The weights of the achieved goal, the desired goal and the tip (x, y and z apart) sum to zero in every row, all
    through training: moving goal and tip together does not change the action. Free, their sum random-walked, and
    a 2.7 m KUKA KR210's policy stopped 5-13 cm short of goals (ARS 97.9 % from random starts; 100 % so)."""
    training = learn.train(dict(model=XACRO_ARM, goal=goal), replace(learn.SETTINGS, iterations=5), seed=1,
                           evaluate_episodes=0)
    n = training.setup.arm.n
    policy = training.policy
    for i in range(3):
        group = [i, 3 + i] if goal == 'pose' else [i, 3 + i, 6 + n + i]
        sums = (policy.weights[:, group] / policy.obs_std[group]).sum(axis=1)
        assert np.abs(sums).max() < 1e-9 * np.abs(policy.weights).max(), sums
    env = ReachVectorEnv(20, model=XACRO_ARM, goal=goal)
    obs = env.reset(seed=0)[0]
    shifted = {k: v.copy() for k, v in obs.items()}
    for key in ('achieved_goal', 'desired_goal'):
        shifted[key][:, :3] += [0.3, -0.2, 0.1]
    if goal == 'position':
        shifted['observation'][:, n:] += [0.3, -0.2, 0.1]
    flat = [ars.flatten_batch(env.single_observation_space, o) for o in (obs, shifted)]
    assert not np.allclose(flat[0], flat[1])
    np.testing.assert_allclose(training.policy.act_batch(flat[1]), training.policy.act_batch(flat[0]), atol=1e-12)


def test_ars_cancel_keeps_the_best_policy_so_far():
    calls = []
    settings = ars.ARSSettings(iterations=50, directions=8, top_directions=4, step_size=0.1, noise=0.1, episodes=2,
                               eval_episodes=32)
    result = learn.train({}, settings, seed=0, progress=calls.append, should_stop=lambda: len(calls) >= 6,
                         evaluate_episodes=0)
    assert result.result.cancelled and len(result.result.history) == 6
    best = max(range(6), key=lambda i: (calls[i].success_rate, calls[i].eval_return))
    assert result.result.best_iteration == best       # the policy evaluated in iteration best + 1


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, '-m', 'robot_ai.reach', *args], capture_output=True, text=True,
                          timeout=600, cwd=cwd)


@pytest.mark.parametrize('args, words', [
    (['train', '--tip', 'nowhere'], ['nowhere', 'is not a link']),
    (['train', '--model', '/no/such/arm.xacro'], ['/no/such/arm.xacro']),
    (['train', '--tip', 'base_link'], ['no moving joint']),
    (['train', '--top-directions', '9', '--directions', '4'], ['--top-directions']),
    (['evaluate', '/no/such/policy.npz'], ['no policy file']),
])
def test_command_line_refusals_are_one_line_and_exit_2(args, words):
    done = run_cli(*args)
    assert done.returncode == 2 and 'Traceback' not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert all(w in last for w in words), done.stderr
    if '--top-directions' not in args:   # issue 40: a file or robot refused is one line, without argparse's usage
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_command_line_trains_evaluates_and_shows(tmp_path):
    done = run_cli('train', '--model', XACRO_ARM, '--iterations', '20', '--output-dir', str(tmp_path), '--video')
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert sum(line.startswith('iteration') for line in lines) == 20
    held = next(line for line in lines if line.startswith('held-out'))
    assert 'of 1000 fresh goals' in held
    files = {os.path.splitext(f)[1]: f for f in os.listdir(tmp_path)}
    assert set(files) == {'.npz', '.csv', '.png', '.mp4'}, files
    assert os.path.getsize(tmp_path / files['.png']) > 10000 and os.path.getsize(tmp_path / files['.mp4']) > 10000
    with open(tmp_path / files['.csv']) as f:
        assert len(f.read().splitlines()) == 21
    done = run_cli('evaluate', str(tmp_path / files['.npz']), '--episodes', '200')
    assert done.returncode == 0, done.stderr
    rates = [line for line in done.stdout.splitlines() if line.startswith('from ')]
    assert [line.split()[1] for line in rates] == ['home', 'random', 'chained'], done.stdout
    assert done.stdout.count('P-controller') == 3
    done = run_cli('evaluate', str(tmp_path / files['.npz']), '--episodes', '100', '--start', 'chained')
    assert done.returncode == 0 and [line.split()[1] for line in done.stdout.splitlines()
                                     if line.startswith('from ')] == ['chained'], done.stdout
    done = run_cli('show', str(tmp_path / files['.npz']))
    assert done.returncode == 0 and '"kind": "ars_linear"' in done.stdout and 'weights: float64 (3, 16)' in done.stdout
    done = run_cli('evaluate', str(tmp_path / files['.npz']), '--model', PACKAGE_UR5)
    assert done.returncode == 2 and 'reach_arm7' in done.stderr and 'Traceback' not in done.stderr


def test_reset_options_set_the_goal_and_the_start_and_keep_the_random_stream():
    """Issue 41: a clicked point that fails in rviz is tried in-process with reset(options={'goal': ..., 'q': ...})."""
    env = ReachEnv(model=PACKAGE_UR5)
    plain, _ = env.reset(seed=3)
    goal, q = [0.3, -0.2, 0.4], (env.arm.lower + env.arm.upper) / 3
    obs, info = env.reset(seed=3, options={'goal': goal, 'q': q.tolist()})
    assert obs['desired_goal'].tolist() == goal
    np.testing.assert_array_equal(env.joint_positions, q)
    np.testing.assert_allclose(obs['achieved_goal'], env.arm.tip_positions(q[None, :])[0], atol=1e-12)
    assert info['is_success'] == (goal_distance(obs['achieved_goal'], np.array(goal)) < 0.05)
    by_name, _ = env.reset(seed=3, options={'q': dict(zip(env.arm.joints, q.tolist()))})
    np.testing.assert_array_equal(by_name['desired_goal'], plain['desired_goal'])   # the draws are made either way
    np.testing.assert_array_equal(env.joint_positions, q)
    for options, said in (({'goal': [0, 0]}, 'goal must be 3 finite numbers'),
                          ({'goal': [0, 0, float('nan')]}, 'goal must be 3 finite numbers'),
                          ({'q': [0.0]}, f'q must be {env.arm.n} joint positions'),
                          ({'q': (env.arm.upper + 1).tolist()}, 'q outside the joint limits'),
                          ({'q': {'nope': 1.0}}, 'q names joints the arm does not have'),
                          ({'start': 1}, 'reset options are goal')):
        with pytest.raises(ReachError, match=said):
            env.reset(seed=3, options=options)
    obs, _ = env.reset(seed=3)           # the env goes on after a refused option
    np.testing.assert_array_equal(obs['desired_goal'], plain['desired_goal'])


# ------------------------------------------------------------------------------- issue 38: reach from anywhere
@pytest.mark.parametrize('path', [robot_path('ur5.urdf'), robot_path('kuka_lwr_arm.urdf'), robot_path('panda.urdf'),
                                  robot_path('pr2.urdf')])
def test_the_null_space_term_leaves_the_tip_where_it_is_and_moves_the_joints_off_their_limits(path):
    """J N g = 0 (the Jacobian identity, up to the projection's small damping), and a step with the term takes
    the tip where the step without it does, with the joints farther from their limits."""
    arm = Arm(tree_of(path))
    rng = np.random.default_rng(3)
    middle, half = (arm.lower + arm.upper) / 2, (arm.upper - arm.lower) / 2
    q = middle + half * rng.uniform(-0.95, 0.95, (200, arm.n))           # anywhere, near the limits too
    q_t = np.ascontiguousarray(q.T)
    tip, axes, origins = arm.forward(q_t)
    jac_t = arm.jacobian_t(tip, axes, origins)
    g_t = arm.limit_gradient_t(q_t, 0.3)
    projected = arm.null_space_t(jac_t, g_t, 1e-6)
    moved_tip = np.einsum('ikn,kn->in', jac_t, projected)
    scale = np.linalg.norm(np.einsum('ikn,kn->in', jac_t, g_t), axis=0)
    assert (np.linalg.norm(moved_tip, axis=0) <= 1e-6 * scale + 1e-12).all()
    assert (np.linalg.norm(projected, axis=0) <= np.linalg.norm(g_t, axis=0) + 1e-12).all()   # a projection
    setup = ReachSetup(model=path, limit_avoidance=1.0)
    dx = rng.uniform(-1, 1, (3, 200)) * setup.ee_step * 0.2
    plain = arm.move_t(q_t, jac_t, dx, setup.damping)
    kept = arm.move_t(q_t, jac_t, dx, setup.damping, limit_gain=setup.limit_gain)
    free = ((plain > arm.lower[:, None]) & (plain < arm.upper[:, None])).all(axis=0)   # no joint clamped
    t_plain, t_kept = arm.forward(plain, with_axes=False)[0], arm.forward(kept, with_axes=False)[0]
    # the same tip up to second order in the step (the term is linear), a small part of what the unprojected
    # step would move it
    felt = np.linalg.norm(np.einsum('ikn,kn->in', jac_t, arm.limit_gradient_t(q_t, setup.limit_gain)), axis=0)
    assert np.median((np.linalg.norm(t_plain - t_kept, axis=0) / felt)[free]) < 0.05
    # Liegeois' criterion whose gradient the term follows, sum |u|^3 (u: the joint's place in its range, -1 to 1)
    h_plain = (np.abs((plain - middle[:, None]) / half[:, None]) ** 3).sum(axis=0)
    h_kept = (np.abs((kept - middle[:, None]) / half[:, None]) ** 3).sum(axis=0)
    assert (h_kept[free] <= h_plain[free] + 1e-9).mean() > 0.95 and h_kept[free].sum() < h_plain[free].sum()


@pytest.mark.parametrize('path, tip', [(robot_path('pr2.urdf'), 'r_gripper_tool_frame'),
                                       (robot_path('panda.urdf'), None)])
def test_through_a_layer_a_slow_joint_is_asked_for_its_share_one_arm_as_the_batch(path, tip):
    """Weighted least squares (through a safety layer, each joint by its velocity limit over the fastest): the PR2's
    torso (0.013 m/s beside 2 rad/s) is asked for a fraction of what plain least squares asks, the tip still moves
    by the step asked (to first order); one arm's numbers are the batch's bit for bit, near limits and with the
    null-space term; weights of 1 are plain least squares to the bit."""
    setup = ReachSetup(model=path, tip=tip, velocity_scale=0.25)
    arm, w = setup.arm, setup.joint_weights
    assert w.max() == 1.0 and (w > 0).all()
    rng = np.random.default_rng(4)
    middle, half = (arm.lower + arm.upper) / 2, (arm.upper - arm.lower) / 2
    q = middle + half * rng.uniform(-0.99, 0.99, (100, arm.n))
    q_t = np.ascontiguousarray(q.T)
    tip_t, axes, origins = arm.forward(q_t)
    jac_t = arm.jacobian_t(tip_t, axes, origins)
    dx = rng.uniform(-1, 1, (3, 100)) * setup.ee_step
    plain = arm.move_t(q_t, jac_t, dx, setup.damping, limit_gain=setup.limit_gain)
    weighted = arm.move_t(q_t, jac_t, dx, setup.damping, limit_gain=setup.limit_gain, weights=w)
    np.testing.assert_array_equal(arm.move_t(q_t, jac_t, dx, setup.damping, limit_gain=setup.limit_gain,
                                             weights=np.ones(arm.n)), plain)
    clamped = 0
    for i in range(100):
        jac = jac_t[:, :, i].tolist()
        one = arm.move_one(q[i].tolist(), jac, dx[:, i].tolist(), setup.damping, limit_gain=setup.limit_gain,
                           weights=w.tolist())
        assert one == weighted[:, i].tolist(), i
        clamped += bool(((weighted[:, i] <= arm.lower) | (weighted[:, i] >= arm.upper)).any())
    assert clamped > 0                                             # the clamping passes were met too
    slow = int(w.argmin())
    small = 0.01 * setup.ee_step
    tiny_plain = arm.move_t(q_t, jac_t, dx * 0.01, setup.damping)
    tiny = arm.move_t(q_t, jac_t, dx * 0.01, setup.damping, weights=w)
    free = ((tiny > arm.lower[:, None]) & (tiny < arm.upper[:, None])).all(axis=0)
    moved = arm.forward(tiny, with_axes=False)[0] - tip_t
    assert np.median(np.linalg.norm(moved - dx * 0.01, axis=0)[free] / small) < 0.1     # the step asked
    if w[slow] < 0.1:                                              # the PR2's torso
        asked = np.abs(tiny - q_t)[slow][free] / w[slow]
        asked_plain = np.abs(tiny_plain - q_t)[slow][free] / w[slow]
        assert np.median(asked) < 0.2 * np.median(asked_plain)     # in time, a fraction of what it was asked


def test_a_chained_start_is_where_the_last_episode_left_the_arm():
    env = ReachEnv(model=PACKAGE_UR5, start='chained')
    obs, _ = env.reset(seed=5)
    np.testing.assert_array_equal(env.joint_positions, env.setup.home)       # the first episode: home
    for _ in range(10):
        obs, *_ = env.step(np.clip((obs['desired_goal'] - obs['achieved_goal']) / env.setup.ee_step, -1, 1))
    left, goal = env.joint_positions, obs['desired_goal']
    obs, _ = env.reset()
    np.testing.assert_array_equal(env.joint_positions, left)
    assert not np.array_equal(obs['desired_goal'], goal)
    home = ReachEnv(model=PACKAGE_UR5)                                      # the same goals as from home
    assert np.array_equal(home.reset(seed=5)[0]['desired_goal'], ReachEnv(model=PACKAGE_UR5, start='chained').reset(
        seed=5)[0]['desired_goal'])


def test_an_unreached_goal_says_why_truthfully():
    from robot_ai.reach.task import why_unreached
    arm = Arm(tree_of(PACKAGE_UR5))
    kind, line = why_unreached(arm, [3.0, 0.0, 0.2], arm.home, 2.1)
    assert kind == 'beyond' and '3.007 m from base_link' in line and f'{arm.radius:.3f} m' in line
    q = arm.home.copy()
    q[0], q[2] = arm.upper[0], arm.lower[2]
    kind, line = why_unreached(arm, [0.3, 0.2, 0.4], q, 0.25)
    assert kind == 'limits' and 'shoulder_pan_joint, elbow_joint at their limits' in line and '0.250 m' in line
    kind, line = why_unreached(arm, [0.3, 0.2, 0.4], arm.home, 0.25)
    assert kind == 'other' and 'no joint at a limit' in line


def test_evaluation_from_random_and_chained_starts_counts_the_misses_by_reason():
    """Without the limit recovery, the P-controller from home reaches nearly every goal; from random starts and
    chained it misses some, each with a reason (joint limits); chained evaluation is reproducible and each arm goes
    through its goals one after another."""
    setup = ReachSetup(model=robot_path('kuka_lwr_arm.urdf'), limit_recovery=False)
    p = learn.p_controller(setup)
    rates = {}
    for start in ('home', 'random', 'chained'):
        e = learn.evaluate(p, setup, 300, start=start)
        assert e.start == start and len(e.distances) == 300
        assert sum(e.misses.values()) == round((1 - e.success_rate) * 300)
        rates[start] = e.success_rate
    assert rates['home'] > 0.97 and rates['random'] < rates['home'] and rates['chained'] < rates['home']
    again = learn.evaluate(p, setup, 300, start='chained')
    assert again.success_rate == rates['chained'] and again.misses['limits'] > 0
    assert setup.start == 'home'                 # the setup given is left as it was
