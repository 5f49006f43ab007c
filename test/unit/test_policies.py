"""robot_ai.policies with the cart-pole's kinds: the file format, save/load round trips that act and evaluate exactly
as the policy that was saved, and one-line refusals of everything else."""
import io
import json
import os
import resource
import threading
import time
import zipfile

import numpy as np
import pytest

from robot_ai import policies

from robot_ai.cartpole import linear_search as ls, q_learning as ql
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
    with zipfile.ZipFile(tmp_path / 'pickle.npz', 'w') as z, zipfile.ZipFile(lin) as good:
        z.writestr('metadata.npy', good.read('metadata.npy'))
        z.writestr('weights.npy', buf.getvalue())
    return [
        (str(tmp_path / 'missing.npz'), 'no policy file at'),
        (str(tmp_path), 'is not a file'),
        (str(tmp_path / 'text.npz'), 'not an .npz archive'),
        (str(tmp_path / 'random.npz'), 'not an .npz archive'),
        (str(tmp_path / 'zip.npz'), 'not .npy arrays'),
        (str(tmp_path / 'pickle.npz'), 'real numbers'),
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


# ------------------------------------------------------------------------------------- hostile files (issue 23)
def npy_bytes(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def npy_header(descr: str, shape: tuple, extra: str = '') -> bytes:
    """An .npy version 1.0 header claiming descr and shape (no data follows)."""
    text = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, {extra}}}".encode()
    text += b' ' * (63 - (len(text) + 10) % 64) + b'\n'
    return b'\x93NUMPY\x01\x00' + len(text).to_bytes(2, 'little') + text


def archive(path, members: dict, compress=zipfile.ZIP_STORED) -> str:
    with zipfile.ZipFile(path, 'w', compress) as z:
        for name, data in members.items():
            if callable(data):
                with z.open(name, 'w', force_zip64=True) as f:
                    data(f)
            else:
                z.writestr(name, data)
    return str(path)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def zeros_into(total: int):
    def write(f):
        chunk = bytes(1 << 24)
        for _ in range(total // len(chunk)):
            f.write(chunk)
    return write


def test_a_file_that_inflates_to_gigabytes_is_refused_before_it_is_inflated(tmp_path, agent):
    """A 2 MB .npz holding a valid policy plus an array inflating to 2 GiB was refused only after it was inflated
    (10-18 s, 2 GB kept under rospy); an array far above the limit likewise, and a metadata string bomb. Each is
    refused from its headers: in well under the time inflating would take, with no memory to give back."""
    lin = policies.save(str(tmp_path / 'lin.npz'), ls.LinearPolicy(np.ones(4)), 'CartPole-v1', 0)
    q = policies.save(str(tmp_path / 'q.npz'), agent[0], 'CartPole-v0', 0)
    with zipfile.ZipFile(lin) as z:
        lin_members = {n: z.read(n) for n in z.namelist()}
    with zipfile.ZipFile(q) as z:
        q_members = {n: z.read(n) for n in z.namelist()}
    gib = 1 << 30     # what the headers claim; 256 MiB of zeros are written behind each (deflated to 256 KB)
    bomb_header = npy_header('<f8', (gib // 8,))
    bombs = {
        'extra': (archive(tmp_path / 'extra.npz', dict(lin_members, **{'bomb.npy': lambda f: (
            f.write(bomb_header), zeros_into(gib // 4)(f))}), zipfile.ZIP_DEFLATED), 'unexpected'),
        'offsets': (archive(tmp_path / 'offsets.npz', dict(q_members, **{'feature_offsets.npy': lambda f: (
            f.write(npy_header('<f4', (gib // 4,))), zeros_into(gib // 4)(f))}), zipfile.ZIP_DEFLATED),
                    'feature_offsets'),
        'metadata': (archive(tmp_path / 'meta.npz', dict(lin_members, **{'metadata.npy': lambda f: (
            f.write(npy_header('<U268435456', ())), zeros_into(gib // 4)(f))}), zipfile.ZIP_DEFLATED), 'characters'),
    }
    for name, (path, message) in bombs.items():
        assert os.path.getsize(path) < 4 * 1024 * 1024, name
        before, t = peak_rss_mb(), time.monotonic()
        with pytest.raises(policies.PolicyError) as e:
            policies.load(path)
        assert message in str(e.value), (name, str(e.value))
        assert time.monotonic() - t < 2.0, name
        assert peak_rss_mb() - before < 64, f'{name}: the peak memory grew by {peak_rss_mb() - before:.0f} MB'


def test_numbers_that_are_not_finite_or_are_subnormal_where_the_policy_computes(tmp_path, agent):
    agent = agent[0]
    lin = policies.save(str(tmp_path / 'lin.npz'), ls.LinearPolicy(np.ones(4)), 'CartPole-v1', 0)
    q = policies.save(str(tmp_path / 'q.npz'), agent, 'CartPole-v0', 0)
    d = agent.q_weights.shape[1]
    cases = [
        (rewrite(tmp_path, q, 'q1e300.npz', q_weights=np.full((2, d), 1e300)), 'infinite number(s) in float32'),
        (rewrite(tmp_path, q, 'w1e300.npz', feature_weights=np.full((4, d), 1e300)), 'infinite number(s) in float32'),
        (rewrite(tmp_path, q, 'qbig.npz', q_weights=np.full((2, d), 3e38, dtype=np.float32)), 'exceed float32'),
        (rewrite(tmp_path, lin, 'long.npz', weights=np.full(4, np.longdouble('1e4000'))), 'at most 64 bits'),
        (rewrite(tmp_path, lin, 'sub.npz', weights=np.array([0.1, 1e-310, 0.2, 0.3])), 'subnormal'),
        (rewrite(tmp_path, q, 'qsub.npz', q_weights=np.full((2, d), 1e-40, dtype=np.float32)), 'subnormal'),
    ]
    for path, message in cases:
        with pytest.raises(policies.PolicyError) as e:
            policies.load(path)
        assert message in str(e.value), (path, str(e.value))


def test_bad_metadata_and_members_are_one_line_never_a_traceback(tmp_path):
    lin = policies.save(str(tmp_path / 'lin.npz'), ls.LinearPolicy(np.ones(4)), 'CartPole-v1', 0)
    meta = policies.load(lin).metadata
    with zipfile.ZipFile(lin) as z:
        members = {n: z.read(n) for n in z.namelist()}
    secret = 'XYZZY_CRAFTED_HEADER'
    cases = [
        (rewrite(tmp_path, lin, 'deep.npz', metadata=np.array('[' * 30000 + ']' * 30000)), 'nested too deep'),
        (archive(tmp_path / 'big.npz', dict(members, **{'metadata.npy': npy_bytes(np.array(json.dumps(
            dict(meta, source='x' * 8 * 2 ** 20))))}), zipfile.ZIP_DEFLATED), 'characters'),
        (rewrite(tmp_path, lin, 'longsrc.npz', metadata=dict(meta, source='x' * 5000)), 'source must be text'),
        (rewrite(tmp_path, lin, 'nested.npz', metadata=dict(meta, figures={'a': {'b': [1] * 100}})), 'figures must'),
        (rewrite(tmp_path, lin, 'claim.npz', metadata=dict(meta, figures={'final_avg_length': 501})), '0 to 500'),
        (rewrite(tmp_path, lin, 'neg.npz', metadata=dict(meta, figures={'best_avg_length': -1})), '0 to 500'),
        (archive(tmp_path / 'notnpy.npz', dict(members, **{'weights.npy': b'just bytes, not an array'})),
         'not a readable .npy'),
        (archive(tmp_path / 'raw.npz', dict(members, **{'notes.txt': b'hello'})), 'not .npy'),
        (archive(tmp_path / 'crafted.npz', dict(members, **{'weights.npy': npy_header('<f8', (4,),
                                                                                     f"'{secret}': 1")
                                                            + bytes(32)})), 'not a readable .npy'),
        (archive(tmp_path / 'short.npz', dict(members, **{'weights.npy': npy_bytes(np.ones(4))[:-8]})), 'bytes'),
    ]
    for path, message in cases:
        with pytest.raises(policies.PolicyError) as e:
            policies.load(path)
        text = str(e.value)
        assert message in text, (path, text)
        assert '\n' not in text and len(text) < 400 and secret not in text, text
    with pytest.raises(policies.PolicyError, match='the path is empty'):
        policies.load('')


def test_a_fifo_is_refused_at_once_not_waited_on(tmp_path):
    """A path swapped for a FIFO while it loads blocked a service thread for ever."""
    fifo = str(tmp_path / 'policy.npz')
    os.mkfifo(fifo)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault('error', pytest.raises(
        policies.PolicyError, policies.load, fifo)), daemon=True)
    thread.start()
    thread.join(5.0)
    assert not thread.is_alive(), 'load() blocked on a FIFO'
    assert 'not a regular file' in str(result['error'].value)
