"""robot_ai.cartpole.policies: the file format, save/load round trips that act and evaluate exactly as the policy
that was saved, and one-line refusals of everything else."""
import io
import json
import os
import zipfile

import numpy as np
import pytest

from robot_ai.cartpole import linear_search as ls, policies, q_learning as ql
from robot_ai.cartpole.dynamics import CartPoleDynamics


@pytest.fixture(scope='module')
def agent():
    training = ql.resolve(episodes=40, components=30)
    return ql.train_one(training, 7)[1], training


def states(n=300, seed=0):
    """Random states like an episode's, as float64 (what a ROS service or joint_states carries)."""
    return np.random.default_rng(seed).uniform([-2.4, -3, -0.21, -3.5], [2.4, 3, 0.21, 3.5], (n, 4))


def test_linear_round_trip_is_exact(tmp_path):
    w = np.array([0.1, -0.25, 0.93, 0.47])
    path = policies.save(str(tmp_path / 'lin.npz'), ls.LinearPolicy(w), 'CartPole-v1', -3,
                         settings={'iterations': 100}, figures={'final_avg_length': 492.37}, source='search 1')
    with np.load(path, allow_pickle=False) as data:           # the format, read as any numpy user would
        assert sorted(data.files) == ['metadata', 'weights'] and data['weights'].shape == (4,)
        meta = json.loads(str(data['metadata']))
    assert meta['format'] == 'robot_ai-policy/1' and meta['kind'] == 'linear' and meta['env_id'] == 'CartPole-v1'
    assert meta['seed'] == -3 and meta['settings'] == {'iterations': 100} and 'T' in meta['created']
    policy = policies.load(path)
    assert policy.kind == 'linear' and policy.path == path and policy.metadata['figures']['final_avg_length'] == 492.37
    assert policy.actor.weights.tobytes() == w.tobytes()
    for s in states():
        assert policy.act(s) == ls.act(w, s)
    dyn = CartPoleDynamics.of('CartPole-v1')
    assert list(policy.evaluate(dyn, 50, 500, 4)) == list(ls.evaluate(dyn, w, 50, 500, 4))
    assert 'linear policy from' in policy.describe() and 'search 1' in policy.describe()


def test_q_learning_round_trip_acts_and_evaluates_as_the_agent(tmp_path, agent):
    agent, training = agent
    path = policies.save(str(tmp_path / 'q.npz'), agent, 'CartPole-v0', 7, training.settings(), {'x': 1.5})
    with np.load(path, allow_pickle=False) as data:
        d = agent.q_weights.shape[1]
        assert {k: data[k].shape for k in data.files if k != 'metadata'} == {
            'feature_weights': (4, d), 'feature_offsets': (d,), 'amplitude': (), 'q_weights': (2, d)}
    policy = policies.load(path)
    assert policy.kind == 'q_learning' and policy.seed == 7 and policy.metadata['settings']['components'] == 30
    for s in states():
        assert policy.act(s) == agent.act(s)
    obs = states(200, 1).T.astype(np.float32)
    assert (policy.push_right(obs) == agent.push_right(obs)).all()
    dyn = CartPoleDynamics.of('CartPole-v0')
    assert list(policy.evaluate(dyn, 40, 200, 2)) == list(agent.evaluate(dyn, 40, 200, 2))


def test_save_is_whole_or_absent(tmp_path):
    with pytest.raises(policies.PolicyError, match='NaN'):
        policies.save(str(tmp_path / 'nan.npz'), ls.LinearPolicy(np.array([0.0, np.nan, 0, 0])), 'CartPole-v1', 0)
    assert os.listdir(tmp_path) == []        # nothing written, no temporary file left


def rewrite(tmp_path, source, name='bad.npz', drop=(), **changes):
    """A copy of the policy file `source` with arrays dropped or changed (metadata as a dict is dumped to JSON)."""
    with np.load(source, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k not in drop}
    for k, v in changes.items():
        arrays[k] = np.array(json.dumps(v)) if k == 'metadata' and isinstance(v, dict) else v
    path = str(tmp_path / name)
    np.savez(path, **arrays)
    return path


def refusals(tmp_path, agent):
    lin = policies.save(str(tmp_path / 'lin.npz'), ls.LinearPolicy(np.ones(4)), 'CartPole-v1', 0)
    q = policies.save(str(tmp_path / 'q.npz'), agent, 'CartPole-v0', 0)
    meta = policies.load(lin).metadata
    (tmp_path / 'text.npz').write_text('weights: 1 2 3 4\n')
    (tmp_path / 'random.npz').write_bytes(np.random.default_rng(0).bytes(3000))
    with zipfile.ZipFile(tmp_path / 'zip.npz', 'w') as z:
        z.writestr('readme.txt', 'hello')
    buf = io.BytesIO()
    np.save(buf, np.array([{'a': 1}], dtype=object), allow_pickle=True)
    with zipfile.ZipFile(tmp_path / 'pickle.npz', 'w') as z:
        z.writestr('weights.npy', buf.getvalue())
    return [
        (str(tmp_path / 'missing.npz'), 'no policy file at'),
        (str(tmp_path), 'is not a file'),
        (str(tmp_path / 'text.npz'), 'not an .npz archive'),
        (str(tmp_path / 'random.npz'), 'not an .npz archive'),
        (str(tmp_path / 'zip.npz'), 'no metadata'),
        (str(tmp_path / 'pickle.npz'), 'not a policy file'),
        (rewrite(tmp_path, lin, 'nan.npz', weights=np.array([0.1, np.nan, 0, 0])), 'weights holds 1 NaN or infinite'),
        (rewrite(tmp_path, lin, 'inf.npz', weights=np.array([0.1, np.inf, 0, 0])), 'NaN or infinite'),
        (rewrite(tmp_path, lin, 'shape.npz', weights=np.ones(5)), 'weights must have shape (4,)'),
        (rewrite(tmp_path, lin, 'str.npz', weights=np.array(['a', 'b', 'c', 'd'])), 'real numbers'),
        (rewrite(tmp_path, lin, 'extra.npz', q_weights=np.ones((2, 3))), 'unexpected q_weights'),
        (rewrite(tmp_path, lin, 'nometa.npz', drop=('metadata',)), 'no metadata'),
        (rewrite(tmp_path, lin, 'badjson.npz', metadata=np.array('{not json')), 'metadata is not JSON'),
        (rewrite(tmp_path, lin, 'format.npz', metadata=dict(meta, format='robot_ai-policy/9')), 'format is'),
        (rewrite(tmp_path, lin, 'kind.npz', metadata=dict(meta, kind='dqn')), 'kind is'),
        (rewrite(tmp_path, lin, 'env.npz', metadata=dict(meta, env_id='MountainCar-v0')), 'env_id is'),
        (rewrite(tmp_path, lin, 'seed.npz', metadata=dict(meta, seed='zero')), 'seed is'),
        (rewrite(tmp_path, lin, 'askind.npz', metadata=dict(meta, kind='q_learning')), 'feature_offsets must have'),
        (rewrite(tmp_path, q, 'qmissing.npz', drop=('q_weights',)), 'missing q_weights'),
        (rewrite(tmp_path, q, 'qshape.npz', q_weights=np.ones((3, agent.q_weights.shape[1]))), 'q_weights must have'),
        (rewrite(tmp_path, q, 'qamp.npz', amplitude=np.array(-1.0)), 'amplitude must be positive'),
    ]


def test_load_refuses_anything_else_with_one_line(tmp_path, agent):
    for path, message in refusals(tmp_path, agent[0]):
        with pytest.raises(policies.PolicyError) as e:
            policies.load(path)
        text = str(e.value)
        assert message in text, (path, text)
        assert '\n' not in text and len(text) < 400, text
