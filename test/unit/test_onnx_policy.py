"""robot_ai.policies.onnx without ROS: ONNX models built with onnx.helper act exactly as the numpy policies they encode
(the course's linear CartPole policy, in both of the shapes stable-baselines3 exports; the reach P-controller and a
tanh layer), through policy_kinds.load, policy_files.load and both command lines; the env comes from the metadata or
the caller; a reach model is refused for another robot, tip or control; and every file that is not a usable policy is
refused in one line before onnxruntime runs it (external data, foreign operators, local functions, wrong shapes, NaN
actions, sizes, FIFOs)."""
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from onnx import TensorProto, helper, numpy_helper

import onnx_models
from fk_helpers import robot_path
from robot_ai import policies
from robot_ai.cartpole import linear_search, policy_kinds
from robot_ai.cartpole.dynamics import CartPoleDynamics
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.policies import PolicyError
from robot_ai.policies import onnx as onnx_policy
from robot_ai.reach import ReachSetup, learn, policy_files

HERE = os.path.dirname(os.path.realpath(__file__))
PACKAGE_UR5 = os.path.abspath(os.path.join(HERE, '..', '..', 'urdf', 'ur5_arm.urdf'))
SRC = os.path.abspath(os.path.join(HERE, '..', '..', 'src'))
WEIGHTS = np.array([0.02, 0.35, 1.0, 0.55], np.float32)      # balances CartPole-v1 for 500 steps from most starts


def observations(n=5000, seed=0):
    return (np.random.default_rng(seed).normal(size=(n, 4)) * [1.0, 1.0, 0.1, 1.0]).astype(np.float32)


@pytest.mark.parametrize('build', [onnx_models.cartpole_scores, onnx_models.cartpole_integer])
def test_a_cartpole_model_acts_and_plays_as_the_linear_policy_it_encodes(tmp_path, build):
    path = onnx_models.save(build(WEIGHTS), str(tmp_path / 'linear.onnx'))
    policy = policy_kinds.load(path)
    x = observations()
    np.testing.assert_array_equal(policy.act_batch(x), (x.astype(np.float64) @ WEIGHTS > 0).astype(int))
    assert [policy.act(s) for s in x[:50]] == [linear_search.act(WEIGHTS, s) for s in x[:50]]
    dynamics = CartPoleDynamics.of(policy.env_id)
    lengths = policy_kinds.evaluate(policy, dynamics, 100, 500, 7)
    np.testing.assert_array_equal(lengths, LinearPolicy(WEIGHTS).evaluate(dynamics, 100, 500, 7))
    assert lengths.mean() > 400
    assert policy.session.get_session_options().intra_op_num_threads == 1
    assert policy.describe().startswith(f'ONNX policy from {path} (CartPole-v1')


def test_the_env_comes_from_the_metadata_or_the_caller(tmp_path):
    bare = onnx_models.save(onnx_models.cartpole_scores(WEIGHTS, env={}), str(tmp_path / 'bare.onnx'))
    with pytest.raises(PolicyError, match='names no env .*--env-id'):
        policy_kinds.load(bare)
    assert policy_kinds.load(bare, 'CartPole-v0').env_id == 'CartPole-v0'
    ros = onnx_models.save(onnx_models.cartpole_scores(WEIGHTS, env={'env_id': 'robot_ai/RosCartPole-v1'}),
                           str(tmp_path / 'ros.onnx'))
    policy = policy_kinds.load(ros)
    assert policy.env_id == 'CartPole-v1' and 'as robot_ai/RosCartPole-v1' in policy.describe()
    reach = onnx_models.save(onnx_models.cartpole_scores(WEIGHTS, env={'env_id': 'robot_ai/Reach-v0'}),
                             str(tmp_path / 'reach.onnx'))
    with pytest.raises(PolicyError, match='acts in robot_ai/Reach-v0, not a cart-pole'):
        policy_kinds.load(reach)
    with pytest.raises(PolicyError, match='ONNX model, not a policy file'):
        policies.npz.load(ros)         # the searches' and trainings' loader takes .npz files only


def reach_model(setup, weights, tmp_path, name='reach.onnx', **env):
    meta = dict(env_id='robot_ai/Reach-v0', env_kwargs=dict(model=PACKAGE_UR5, tip=setup.arm.tip, control='ee'),
                robot=setup.model.tree.name, joints=list(setup.arm.joints))
    meta.update(env)
    return onnx_models.save(onnx_models.linear_clip(weights, meta if env.get('env_id', 1) is not None else None),
                            str(tmp_path / name))


def test_a_reach_model_of_the_p_controller_reaches_as_the_p_controller(tmp_path):
    setup = ReachSetup(model=PACKAGE_UR5)
    p = learn.p_controller(setup)
    path = reach_model(setup, p.weights.T, tmp_path)
    policy, loaded, note = policy_files.load(path)
    assert note == '' and loaded.arm.joints == setup.arm.joints and loaded.control == 'ee'
    x = np.random.default_rng(1).uniform(-1, 1, (2000, 9 + setup.arm.n))
    np.testing.assert_allclose(policy.act_batch(x), p.act_batch(x), atol=1e-5)
    # on the setup the file makes (its metadata predate the limit recovery: without it, as a .npz file of then)
    assert not loaded.limit_recovery and setup.limit_recovery
    ours, theirs = learn.evaluate(policy, loaded, 300), learn.evaluate(p, loaded, 300)
    np.testing.assert_allclose(ours.distances, theirs.distances, atol=1e-4)
    assert abs(ours.success_rate - theirs.success_rate) <= 0.01 and ours.success_rate > 0.9


def test_a_tanh_layer_acts_as_numpy_and_the_action_space_bounds_it(tmp_path):
    setup = ReachSetup(model=PACKAGE_UR5, control='joints')
    rng = np.random.default_rng(2)
    w, b = rng.normal(size=(9 + setup.arm.n, setup.arm.n)), rng.normal(size=setup.arm.n)
    meta = dict(env_id='robot_ai/Reach-v0', env_kwargs=dict(model=PACKAGE_UR5, control='joints'))
    path = onnx_models.save(onnx_models.linear_tanh(w, b, meta), str(tmp_path / 'tanh.onnx'))
    policy, loaded, note = policy_files.load(path)
    assert loaded.control == 'joints' and 'names no robot' in note
    x = rng.uniform(-1, 1, (1000, 9 + setup.arm.n))
    np.testing.assert_allclose(policy.act_batch(x), np.tanh(x @ w + b), atol=1e-5)
    obs, _ = loaded.observation_space.sample(), None
    assert policy.act(obs).shape == (setup.arm.n,)


def test_a_reach_model_is_refused_for_another_robot_tip_or_control(tmp_path):
    setup = ReachSetup(model=PACKAGE_UR5)
    w = learn.p_controller(setup).weights.T
    other = reach_model(setup, w, tmp_path, 'other.onnx', robot='not_a_ur5')
    with pytest.raises(PolicyError, match='learned to reach with not_a_ur5 .* this arm is'):
        policy_files.load(other)
    good = reach_model(setup, w, tmp_path)
    with pytest.raises(PolicyError, match='acts with control=ee; this env has control=joints'):
        policy_files.load(good, ReachSetup(model=PACKAGE_UR5, control='joints'))
    tip = setup.arm.links[-2] if hasattr(setup.arm, 'links') else 'wrist_3_link'
    with pytest.raises(PolicyError, match='tip'):
        policy_files.load(good, tip=tip)
    four = reach_model(setup, np.zeros((9 + setup.arm.n, 4)), tmp_path, 'four.onnx')
    with pytest.raises(PolicyError, match="first output 'action' is FLOAT \\(batch, 4\\); the env takes float actions "
                                          "\\(batch, 3\\)"):
        policy_files.load(four)
    bare = onnx_models.save(onnx_models.linear_clip(w), str(tmp_path / 'bare.onnx'))
    # no metadata: Reach-v0 as gymnasium.make makes it, the package's UR5
    policy, loaded, note = policy_files.load(bare)
    assert loaded.arm.joints == setup.arm.joints and loaded.control == 'ee' and 'names no robot' in note
    policy, loaded, note = policy_files.load(bare, model=PACKAGE_UR5)
    assert loaded.control == 'ee' and 'names no robot' in note
    kuka = os.path.join(os.path.dirname(robot_path('ur5.urdf')), 'kuka_lwr_arm.urdf')
    with pytest.raises(PolicyError, match=r'maps 15 observations to 3 actions; this env has 16 and 3|takes FLOAT'):
        policy_files.load(bare, model=kuka)


# ------------------------------------------------------------------------------------------------------ refusals
def _two_inputs():
    m = onnx_models.cartpole_scores(WEIGHTS)
    m.graph.input.append(onnx_models.tensor('extra', TensorProto.FLOAT, ['batch', 1]))
    return m


def _external(in_subgraph=False):
    m = onnx_models.cartpole_scores(WEIGHTS)
    t = m.graph.initializer[0] if not in_subgraph else None
    if in_subgraph:   # an If whose branch holds the weights, stored outside the file
        w = numpy_helper.from_array(np.ones((4, 2), np.float32), 'W2')
        branch = helper.make_graph([helper.make_node('MatMul', ['obs', 'W2'], ['s'])], 'then', [],
                                   [onnx_models.tensor('s', TensorProto.FLOAT, ['batch', 2])], [w])
        m.graph.node.append(helper.make_node('If', ['cond'], ['unused'], then_branch=branch, else_branch=branch))
        t = branch.initializer[0]
        t = m.graph.node[-1].attribute[0].g.initializer[0]
    t.data_location = TensorProto.EXTERNAL
    t.ClearField('raw_data')
    t.ClearField('float_data')
    for k, v in (('location', '/etc/shadow'), ('offset', '0'), ('length', '32')):
        t.external_data.add(key=k, value=v)
    return m


def _custom_domain():
    m = onnx_models.cartpole_scores(WEIGHTS)
    m.graph.node.append(helper.make_node('System', ['obs'], ['out'], domain='com.evil'))
    m.opset_import.append(helper.make_opsetid('com.evil', 1))
    return m


def _local_function():
    m = onnx_models.cartpole_scores(WEIGHTS)
    f = helper.make_function('local', 'Shadow', ['x'], ['y'], [helper.make_node('Identity', ['x'], ['y'])],
                             [helper.make_opsetid('', 17)])
    m.functions.append(f)
    return m


def _nan():
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['s']), helper.make_node('Div', ['s', 'zero'], ['scores'])]
    w = np.zeros((4, 2), np.float32)
    return onnx_models.model(nodes, [onnx_models.tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                             [onnx_models.tensor('scores', TensorProto.FLOAT, ['batch', 2])],
                             [numpy_helper.from_array(w, 'W'),
                              numpy_helper.from_array(np.zeros(2, np.float32), 'zero')],
                             {'env_id': 'CartPole-v1'})


def _out_of_range():
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['s']),
             helper.make_node('ArgMax', ['s'], ['a'], axis=1, keepdims=0),
             helper.make_node('Add', ['a', 'five'], ['action'])]
    return onnx_models.model(nodes, [onnx_models.tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                             [onnx_models.tensor('action', TensorProto.INT64, ['batch'])],
                             [numpy_helper.from_array(np.ones((4, 2), np.float32), 'W'),
                              numpy_helper.from_array(np.array(5, np.int64), 'five')], {'env_id': 'CartPole-v1'})


def _shape(inputs, outputs):
    w = np.zeros((inputs[1] if len(inputs) > 1 and isinstance(inputs[1], int) else 4, 3), np.float32)
    return onnx_models.model([helper.make_node('MatMul', ['obs', 'W'], ['scores'])],
                             [onnx_models.tensor('obs', TensorProto.FLOAT, inputs)],
                             [onnx_models.tensor('scores', TensorProto.FLOAT, outputs)],
                             [numpy_helper.from_array(w, 'W')], {'env_id': 'CartPole-v1'})


def _bad_metadata():
    m = onnx_models.cartpole_scores(WEIGHTS, env={})
    helper.set_model_props(m, {'robot_ai_env': '{"env_id": 3'})
    return m


REFUSED = {
    'random bytes': (lambda: np.random.default_rng(0).bytes(3000), 'is not an ONNX model'),
    'an empty file': (lambda: b'', 'is not an ONNX model'),
    'external weights': (_external, "keeps tensor 'W' in external data \\('/etc/shadow'\\)"),
    'external weights in a subgraph': (lambda: _external(True), "keeps tensor 'W2' in external data"),
    'a foreign operator domain': (_custom_domain, 'outside the standard domains: com.evil'),
    'a local function': (_local_function, 'defines local functions \\(Shadow\\)'),
    'two inputs': (_two_inputs, 'has 2 inputs \\(obs, extra\\); one is wanted'),
    'five observations': (lambda: _shape(['batch', 5], ['batch', 3]),
                          "takes FLOAT \\(batch, 5\\) as 'obs'; the env's flattened observation is float32 "
                          "\\(batch, 4\\)"),
    'three scores': (lambda: _shape(['batch', 4], ['batch', 3]),
                     "first output 'scores' is FLOAT \\(batch, 3\\); the env takes an integer action"),
    'NaN actions': (_nan, 'answers NaN or infinite actions \\(on 16 of 16 trial observations\\)'),
    'actions out of range': (_out_of_range, 'answers actions outside 0 to 1: \\[5\\]'),
    'metadata that is not JSON': (_bad_metadata, 'metadata robot_ai_env is not JSON'),
    'an env that does not exist': (lambda: onnx_models.cartpole_scores(WEIGHTS, env={'env_id': 'NoSuchEnv-v9'}),
                                   'acts in NoSuchEnv-v9, not a cart-pole'),
}


@pytest.mark.parametrize('case', REFUSED)
def test_a_file_that_is_not_a_usable_policy_is_refused_in_one_line(tmp_path, case):
    make, words = REFUSED[case]
    m = make()
    path = str(tmp_path / 'bad.onnx')
    with open(path, 'wb') as f:
        f.write(m if isinstance(m, bytes) else m.SerializeToString())
    with pytest.raises(PolicyError) as e:
        policy_kinds.load(path)
    assert '\n' not in str(e.value)
    assert re.search(words, str(e.value)), str(e.value)


def test_other_envs_are_made_to_learn_their_spaces_and_unknown_ones_are_one_line(tmp_path):
    path = onnx_models.save(onnx_models.cartpole_scores(WEIGHTS, env={'env_id': 'NoSuchEnv-v9'}),
                            str(tmp_path / 'x.onnx'))
    with pytest.raises(PolicyError, match='its env NoSuchEnv-v9 cannot be made'):
        policies.load(path)
    pendulum = onnx_models.save(onnx_models.linear_tanh(np.ones((3, 1)), np.zeros(1), {'env_id': 'Pendulum-v1'}),
                                str(tmp_path / 'pendulum.onnx'))
    policy = policies.load(pendulum)
    x = np.random.default_rng(0).normal(size=(100, 3))
    np.testing.assert_allclose(policy.act_batch(x), np.clip(np.tanh(x.sum(axis=1, keepdims=True)), -2, 2), atol=1e-6)


def test_sizes_directories_and_fifos_are_refused_without_reading_or_waiting(tmp_path, monkeypatch):
    path = onnx_models.save(onnx_models.cartpole_scores(WEIGHTS), str(tmp_path / 'big.onnx'))
    monkeypatch.setattr(onnx_policy, 'MAX_BYTES', 100)
    with pytest.raises(PolicyError,
                       match=r'big.onnx is [\d,]+ bytes: too large for an ONNX file \(at most 100 bytes\)'):
        policy_kinds.load(path)
    monkeypatch.undo()
    with pytest.raises(PolicyError, match='no ONNX file at'):
        policy_kinds.load(str(tmp_path / 'missing.onnx'))
    os.mkdir(tmp_path / 'dir.onnx')
    with pytest.raises(PolicyError):
        policy_kinds.load(str(tmp_path / 'dir.onnx'))
    os.mkfifo(tmp_path / 'fifo.onnx')
    with pytest.raises(PolicyError, match='regular file|not a file'):
        policy_kinds.load(str(tmp_path / 'fifo.onnx'))
    with pytest.raises(PolicyError, match='the path is empty'):
        onnx_policy.read('  ')


# ------------------------------------------------------------------------------------------------- command lines
def run(*args):
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return subprocess.run([sys.executable, '-m', *args], capture_output=True, text=True, timeout=300, env=env)


def test_both_command_lines_evaluate_and_show_an_onnx_file_and_the_searches_refuse_one(tmp_path):
    path = onnx_models.save(onnx_models.cartpole_integer(WEIGHTS), str(tmp_path / 'ppo_like.onnx'))
    r = run('robot_ai.cartpole', 'evaluate', path, '--episodes', '50', '--seed', '3')
    assert r.returncode == 0, r.stderr
    expected = LinearPolicy(WEIGHTS).evaluate(CartPoleDynamics.of('CartPole-v1'), 50, 500, 3).mean()
    assert f'average length: {expected:.2f}' in r.stdout and 'ONNX policy from' in r.stdout
    shown = json.loads(run('robot_ai.cartpole', 'show', path).stdout)
    assert shown['inputs'] == {'obs': 'FLOAT (batch, 4)'} and shown['outputs'] == {'action': 'INT64 (batch,)'}
    named = onnx_models.cartpole_scores(WEIGHTS)      # issue 40: a (batch, n) output was shown as (batch, batch)
    named.graph.output[0].type.tensor_type.shape.dim[1].ClearField('dim_value')
    named.graph.output[0].type.tensor_type.shape.dim[1].dim_param = 'n'
    shown = json.loads(run('robot_ai.cartpole', 'show', onnx_models.save(named, str(tmp_path / 'n.onnx'))).stdout)
    assert shown['outputs'] == {'scores': 'FLOAT (batch, n)'}, shown
    r = run('robot_ai.cartpole', 'q-learning', '--initial-policy', path, '--episodes', '10')
    assert r.returncode == 2 and 'is an ONNX model, not a policy file (.npz)' in r.stderr
    setup = ReachSetup(model=PACKAGE_UR5)
    reach = reach_model(setup, learn.p_controller(setup).weights.T, tmp_path)
    r = run('robot_ai.reach', 'evaluate', reach, '--episodes', '200', '--start', 'random')
    assert r.returncode == 0, r.stderr
    # its metadata names no limit_avoidance nor limit_recovery: it acts as files from before them did, with neither
    old = ReachSetup(model=PACKAGE_UR5, limit_avoidance=0.0, limit_recovery=False)
    rate = learn.evaluate(learn.p_controller(old), old, 200, start='random').success_rate
    lines = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert '200 fresh goals' in r.stdout and lines['from'].split()[:3] == ['from', 'random', f'{100 * rate:.1f}']
    assert lines['P-controller'].split()[1] == f'{100 * rate:.1f}', r.stdout     # the model is the P-controller
    bad = onnx_models.save(_custom_domain(), str(tmp_path / 'custom.onnx'))
    r = run('robot_ai.reach', 'evaluate', bad)
    assert r.returncode == 2 and 'com.evil' in r.stderr and 'Traceback' not in r.stderr


def test_a_reach_model_that_answers_nan_for_some_goals_is_one_line_and_its_play_is_said(tmp_path):
    """Issue 57: a refused ONNX reach policy printed five lines (the figures' heading, then the refusal), and an
    ONNX model whose metadata names no limit_recovery was played without the recovery with no line saying so."""
    setup = ReachSetup(model=PACKAGE_UR5)
    weights = learn.p_controller(setup).weights.T
    meta = dict(env_id='robot_ai/Reach-v0', env_kwargs=dict(model=PACKAGE_UR5, tip=setup.arm.tip, control='ee'),
                robot=setup.model.tree.name, joints=list(setup.arm.joints))
    nan = onnx_models.save(onnx_models.linear_nan_past(weights, 60.0, meta), str(tmp_path / 'nan.onnx'))
    policy_files.load(nan)                                   # the loader's trial sees nothing wrong
    r = run('robot_ai.reach', 'evaluate', nan, '--episodes', '50')
    assert r.returncode == 1 and r.stdout == '', r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and 'answers NaN or infinite actions' in r.stderr, r.stderr
    good = reach_model(setup, weights, tmp_path)
    r = run('robot_ai.reach', 'evaluate', good, '--episodes', '20', '--start', 'home')
    played = next(line for line in r.stdout.splitlines() if line.startswith('played as'))
    assert 'recovery from joint limits and blocked steps off' in played
    assert 'metadata names no limit_avoidance nor limit_recovery' in played
    named = reach_model(setup, weights, tmp_path, 'named.onnx', env_kwargs=dict(
        model=PACKAGE_UR5, tip=setup.arm.tip, control='ee', limit_recovery=True, limit_avoidance=0.0))
    r = run('robot_ai.reach', 'evaluate', named, '--episodes', '20', '--start', 'home')
    played = next(line for line in r.stdout.splitlines() if line.startswith('played as'))
    assert 'blocked steps on' in played and 'names no' not in played, played


def test_every_action_is_checked_not_only_the_trial_ones(tmp_path):
    """Issue 40: a model that answers well on the loader's trial observations and 7 on every real state was accepted,
    and `cartpole evaluate` played 7 as "push left"; a (batch, 2) scores output that returns 3 columns always gave 2.
    The loader still accepts what it cannot see; every action computed after is checked, and a bad one is one line."""
    seven = onnx_models.save(onnx_models.cartpole_seven_on_real_states(WEIGHTS), str(tmp_path / 'seven.onnx'))
    policy = policy_kinds.load(seven)
    assert policy.act(np.zeros(4, np.float32)) in (0, 1)
    with pytest.raises(onnx_policy.ActionError, match=r'answers actions outside 0 to 1: \[7\]'):
        policy.act(np.full(4, 0.02, np.float32))
    done = subprocess.run([sys.executable, '-m', 'robot_ai.cartpole', 'evaluate', seven, '--episodes', '20'],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and 'Traceback' not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and 'outside 0 to 1' in done.stderr, done.stderr
    three = onnx_models.save(onnx_models.cartpole_three_scores(WEIGHTS), str(tmp_path / 'three.onnx'))
    with pytest.raises(PolicyError, match='answers 3 scores for an observation; the env has 2 actions'):
        policy_kinds.load(three)     # the trial sees it: 3 columns where 2 are declared


def test_a_model_that_runs_for_days_or_takes_gigabytes_is_refused_at_load_within_bounds(tmp_path, monkeypatch):
    """Issue 40: a Loop of 2**40 iterations, or a small file that expands one number to 3.2 GB, is refused in one
    line within the trial's bounds of time and memory, in a child process: this one builds nothing of it."""
    import resource
    import time
    monkeypatch.setattr(onnx_policy, 'TRIAL_SECONDS', 5.0)
    endless = onnx_models.save(onnx_models.cartpole_endless_loop(WEIGHTS), str(tmp_path / 'endless.onnx'))
    t = time.monotonic()
    with pytest.raises(PolicyError, match=r'endless.onnx takes more than 5 s to answer 16 observations'):
        policy_kinds.load(endless)
    assert time.monotonic() - t < 30
    big = onnx_models.save(onnx_models.cartpole_gigabytes(WEIGHTS), str(tmp_path / 'big.onnx'))
    assert os.path.getsize(big) < 2000
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(PolicyError, match=r'big.onnx needs more than 2 GiB to answer 16 observations') as caught:
        policy_kinds.load(big)
    assert '\n' not in str(caught.value)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 500 * 1024   # KiB: nothing of it here
