"""Policy files: a search's or a training's policy saved to disk and loaded again by any node, the CLI or the
controller, as stable-baselines3's ``model.save()`` / ``load()`` do. No rospy.

One ``.npz`` file, read with ``numpy.load(..., allow_pickle=False)``: the arrays the policy needs and ``metadata``,
a JSON string (``format`` "robot_ai-policy/1", ``kind``, ``env_id``, ``seed`` (the policy's own), ``created``,
``settings``, ``figures``, ``source``). Arrays: a linear policy's ``weights`` (4,); a Q-learning agent's
``feature_weights`` (4, D), ``feature_offsets`` (D,) (the scaler folded in), ``amplitude`` (0-d) and
``q_weights`` (2, D): everything it needs to act, nothing re-drawn from a seed.

Kind ``ars_linear`` is ARS's linear policy for any env with a Box(-1, 1) action (the reach task): ``weights``
(act, obs), ``obs_mean`` and ``obs_std`` (obs,), an optional ``bias`` (act,); its action is
``clip(weights @ ((x - obs_mean) / obs_std) + bias, -1, 1)`` for x the flattened observation. Its metadata names the
env it acts in: ``env_id`` (any), ``env_kwargs`` (the env's settings), and for a reach policy ``joints``, ``robot``,
``model`` and ``model_sha256`` (robot_ai.reach.learn checks them against the arm it is asked to drive).

    path = save('/tmp/best.npz', LinearPolicy(np.array([0.1, 0.2, 0.9, 0.5])), env_id='CartPole-v1', seed=0)
    policy = load(path)                # a Policy; anything else raises PolicyError with one line
    policy.act(state), policy.kind, policy.metadata['figures']
    policy.evaluate(CartPoleDynamics.of(policy.env_id), 100, 500, seed=0)
"""
import datetime
import io
import json
import os
import stat
import zipfile
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from robot_ai import ars
from robot_ai.cartpole.artifacts import write_whole
from robot_ai.cartpole.dynamics import SUPPORTED_ENVS, CartPoleDynamics
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.cartpole.q_learning import Agent

if TYPE_CHECKING:
    from robot_ai.onnx_policy import OnnxPolicy

FORMAT = 'robot_ai-policy/1'
KINDS = ('linear', 'q_learning', 'ars_linear')
CARTPOLE_KINDS = ('linear', 'q_learning')
MAX_ARS_ACTIONS = 64                     # an arm's joints (joint control) or a tip's 3 coordinates
MAX_ARS_INPUTS = 1024                    # an arm's joints + 9
MAX_LIST = 256                           # items of a list in env_kwargs or joints
EXTENSION = '.npz'
MAX_FILE_BYTES = 16 * 1024 * 1024        # a 10,000-component agent is 1.1 MB; anything far larger is not a policy
MAX_DIMENSIONS = 4 * 10000               # q_learning.MAX_COMPONENTS banks of 4
MAX_ELEMENTS = 4 * MAX_DIMENSIONS        # the largest array a policy holds (feature_weights, 4 x D)
MAX_HEADER_BYTES = 4096                  # of an .npy header (numpy writes about 128)
MAX_METADATA_CHARS = 65536               # a policy's metadata is about 1,000 characters
MAX_TEXT = 1000                          # characters of a source, a created date, a setting's or figure's text
AVERAGE_FIGURES = ('best_avg_length', 'final_avg_length', 'last100_average', 'greedy_average')


class PolicyError(ValueError):
    """A file that is not a policy this package can use; the message is one line that says what is wrong."""


@dataclass(frozen=True, eq=False)
class Policy:
    """A policy and where it came from. actor: a linear_search.LinearPolicy or a q_learning.Agent."""
    actor: LinearPolicy | Agent | ars.LinearPolicy
    metadata: dict
    path: str = ''

    @property
    def kind(self) -> str:
        return self.actor.kind

    @property
    def env_id(self) -> str:
        return self.metadata['env_id']

    @property
    def seed(self) -> int:
        return self.metadata['seed']

    def act(self, state):
        """The policy's action for one state: 0 or 1 for a CartPole state (x, x_dot, theta, theta_dot); an array
        in [-1, 1] for an ars_linear policy's flattened observation."""
        return self.actor.act(state)

    def push_right(self, observations: np.ndarray) -> np.ndarray:
        """Batched: observations (4, n) float32 -> (n,) bool, for CartPoleDynamics.episode_lengths."""
        return self.actor.push_right(observations)

    def evaluate(self, dynamics, episodes: int, max_steps: int, seed: int) -> np.ndarray:
        """Lengths (episodes,) of episodes played with the policy, start states from rng_for(seed)."""
        return self.actor.evaluate(dynamics, episodes, max_steps, seed)

    def describe(self) -> str:
        """One line: kind, env, seed, figures, and the file it came from."""
        m = self.metadata
        figures = ', '.join(f'{k} {v:.2f}' if isinstance(v, float) else f'{k} {v}'
                            for k, v in (m.get('figures') or {}).items())
        where = f' from {self.path}' if self.path else ''
        source = f', {m["source"]}' if m.get('source') else ''
        return f'{m["kind"]} policy{where} ({m["env_id"]}, seed {m["seed"]}{source}{"; " + figures if figures else ""})'


def arrays_of(actor: LinearPolicy | Agent | ars.LinearPolicy) -> dict:
    """The arrays a policy file holds for actor."""
    if isinstance(actor, LinearPolicy):
        return dict(weights=np.asarray(actor.weights, dtype=np.float64).reshape(4))
    if isinstance(actor, ars.LinearPolicy):
        arrays = dict(weights=actor.weights, obs_mean=actor.obs_mean, obs_std=actor.obs_std)
        if actor.bias is not None:
            arrays['bias'] = actor.bias
        return {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
    return dict(feature_weights=actor.feature_weights, feature_offsets=actor.feature_offsets,
                amplitude=np.array(actor.amplitude, dtype=np.float64), q_weights=actor.q_weights)


def save(path: str, actor: LinearPolicy | Agent | ars.LinearPolicy, env_id: str, seed: int,
         settings: dict | None = None, figures: dict | None = None, source: str = '', **extra) -> str:
    """Write actor as a policy file at path, whole or not at all (a temporary file renamed into place); return path.

    seed: the policy's own (a learner's, not its batch's); settings: what made it; figures: how good it is;
    source: a few words on where it came from ("search", "training, learner 3"); extra: more metadata (an
    ars_linear policy's env_kwargs, joints, robot, model, model_sha256)."""
    metadata = dict(format=FORMAT, kind=actor.kind, env_id=env_id, seed=int(seed),
                    created=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
                    settings=settings or {}, figures=figures or {}, source=source, **extra)
    arrays = arrays_of(actor)
    _check_arrays(actor.kind, arrays)  # never write a file that load() would refuse
    text = json.dumps(metadata, allow_nan=False)
    _check_figures(_metadata(np.array(text)))
    return write_whole(path, lambda f: np.savez(f, metadata=np.array(text), **arrays))


def load(path: str) -> Policy:
    """The policy in a file written by save(); PolicyError (one line) for anything else: a missing or unreadable
    file, not an npz, pickled objects, another format or kind, missing or extra arrays, wrong shapes or types,
    numbers that are not finite (or subnormal) in the type the policy computes in, figures its env cannot give.

    Nothing is inflated before it is known to be what it should be: the archive's directory and each member's .npy
    header (name, dtype, shape, size) are checked first, so a file that would inflate to gigabytes is refused
    having read a few hundred bytes of it. The file is opened without blocking (a FIFO is refused, not waited on).
    """
    if not str(path).strip():
        raise PolicyError('the path is empty: give a policy file (.npz), absolute or ~/...')
    path = os.path.abspath(os.path.expanduser(str(path)))
    if path.lower().endswith('.onnx'):
        raise PolicyError(f'{path} is an ONNX model, not a policy file (.npz): ONNX policies drive the controllers '
                          f'and are evaluated by `evaluate`; searches and trainings start from .npz files only')
    data = read_regular_file(path)
    try:
        metadata, arrays = _read_archive(data)
        metadata = _metadata(metadata)
        kind = metadata['kind']
        _check_arrays(kind, arrays)
        _check_figures(metadata)
    except PolicyError as e:
        raise PolicyError(f'{path}: {e}') from None
    if kind == 'linear':
        actor = LinearPolicy(arrays['weights'])
    elif kind == 'ars_linear':
        a = arrays['weights'].shape[0]
        actor = ars.LinearPolicy(arrays['weights'], arrays['obs_mean'], arrays['obs_std'], arrays.get('bias'),
                                 low=-np.ones(a), high=np.ones(a))
    else:
        actor = Agent(arrays['feature_weights'], arrays['feature_offsets'], float(arrays['amplitude']),
                      arrays['q_weights'])
    return Policy(actor, metadata, path)


def load_any(path: str, env_id: str = '') -> 'Policy | OnnxPolicy':
    """A cart-pole policy of either format: a policy file (.npz, load) or an ONNX model (.onnx, exported from
    another library: robot_ai.onnx_policy.load_cartpole, env_id naming its CartPole when its metadata does not).
    Both act(state), push_right(observations), evaluate(...) and describe()."""
    if str(path).strip().lower().endswith('.onnx'):
        from robot_ai.onnx_policy import load_cartpole
        return load_cartpole(path, env_id)
    return load(path)


def _size(n: int) -> str:
    return f'{n / (1024 * 1024):.1f} MiB' if n >= 1024 * 1024 else f'{n:,} bytes'


def _a(what: str) -> str:
    return ('an ' if what[:1].lower() in 'aeio' or what.startswith('ONNX') else 'a ') + what


def read_regular_file(path: str, max_bytes: int = MAX_FILE_BYTES, what: str = 'policy file') -> bytes:
    """The bytes of a regular file of at most max_bytes, opened without blocking and checked once open (a path
    swapped for a FIFO or a device between a check and the open is refused, never waited on)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise PolicyError(f'no {what} at {path}') from None
    except OSError as e:
        raise PolicyError(f'{path}: cannot open it: {e.strerror}') from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise PolicyError(f'{path} is not a file' if stat.S_ISDIR(st.st_mode) else
                              f'{path} is not a regular file (a FIFO, a device or a socket)')
        if st.st_size > max_bytes:
            raise PolicyError(f'{path} is {_size(st.st_size)}: too large for {_a(what)} (at most {_size(max_bytes)})')
        chunks, left = [], max_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
        if left <= 0:
            raise PolicyError(f'{path} is too large for {_a(what)} (at most {_size(max_bytes)})')
        return b''.join(chunks)
    except OSError as e:
        raise PolicyError(f'{path}: cannot read it: {e.strerror}') from None
    finally:
        os.close(fd)


def _read_archive(data: bytes) -> tuple[np.ndarray, dict]:
    """(the metadata array, {name: array}) of an .npz's bytes, every member's header checked before its data is
    read (see _check_header)."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
        members = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, OSError):
        raise PolicyError('not a policy file (not an .npz archive)') from None
    names = [m.filename for m in members]
    if len(names) > 16:
        raise PolicyError(f'an archive of {len(names)} members: a policy holds at most 4 arrays and its metadata')
    if len(set(names)) != len(names):
        raise PolicyError('an archive that holds a member twice')
    not_npy = [n for n in names if not n.endswith('.npy')]
    if not_npy:
        raise PolicyError(f'not a policy file: {len(not_npy)} member(s) are not .npy arrays')
    by_name = {n[:-4]: m for n, m in zip(names, members)}
    if 'metadata' not in by_name:
        raise PolicyError('no metadata: not a robot_ai policy file')
    with archive:
        metadata = _read_member(archive, by_name['metadata'], 'metadata')
        kind = _peek_kind(metadata)
        want = _wanted_shapes(kind, archive, by_name)
        missing = sorted(set(want) - set(by_name))
        extra = sorted(set(by_name) - set(want) - {'metadata'})
        if missing or extra:
            raise PolicyError(f'a {kind} policy holds the arrays {", ".join(sorted(want))}; '
                              + '; '.join(p for p in (f'missing {", ".join(missing)}' if missing else '',
                                                      f'unexpected {", ".join(_shown(n) for n in extra)}'
                                                      if extra else '') if p))
        arrays = {name: _read_member(archive, by_name[name], name, shape) for name, shape in want.items()}
    return metadata, arrays


def _peek_kind(metadata: np.ndarray) -> str:
    """The kind a metadata array names (fully checked later by _metadata); PolicyError if it names none."""
    kind = _metadata_json(metadata).get('kind')
    if kind not in KINDS:
        raise PolicyError(f'kind is {_shown(kind)}, not one of {", ".join(KINDS)}')
    return kind


def _wanted_shapes(kind: str, archive: zipfile.ZipFile, by_name: dict) -> dict:
    """{array name: shape} a policy of kind holds; a Q-learning agent's D is read from feature_offsets' header, an
    ars_linear policy's sizes from its weights'."""
    if kind == 'linear':
        return {'weights': (4,)}
    if kind == 'ars_linear':
        if 'weights' not in by_name:
            raise PolicyError('an ars_linear policy holds weights (actions, observations): this file does not')
        with archive.open(by_name['weights']) as f:
            shape, _, _ = _check_header(f, by_name['weights'], 'weights')
        if len(shape) != 2 or not (1 <= shape[0] <= MAX_ARS_ACTIONS and 1 <= shape[1] <= MAX_ARS_INPUTS):
            raise PolicyError(f'weights must have shape (actions, observations), at most ({MAX_ARS_ACTIONS}, '
                              f'{MAX_ARS_INPUTS}), got {_shown(shape)}')
        a, d = shape
        want = {'weights': (a, d), 'obs_mean': (d,), 'obs_std': (d,)}
        if 'bias' in by_name:
            want['bias'] = (a,)
        return want
    if 'feature_offsets' not in by_name:
        raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}: a q_learning '
                          'policy holds it, this file does not')
    with archive.open(by_name['feature_offsets']) as f:
        shape, _, _ = _check_header(f, by_name['feature_offsets'], 'feature_offsets')
    if len(shape) != 1 or not 1 <= shape[0] <= MAX_DIMENSIONS:
        raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}, got '
                          f'{_shown(shape)}')
    d = shape[0]
    return {'feature_weights': (4, d), 'feature_offsets': (d,), 'amplitude': (), 'q_weights': (2, d)}


def _check_header(f, member: zipfile.ZipInfo, name: str) -> tuple[tuple, np.dtype, int]:
    """(shape, dtype, data bytes) from a member's .npy header, checked: real numbers of at most 8 bytes (metadata:
    a unicode string of at most MAX_METADATA_CHARS), and a member exactly as large as the header says."""
    try:
        version = np.lib.format.read_magic(f)
        read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                       (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read_header is None:
            raise ValueError
        shape, _, dtype = read_header(f, max_header_size=MAX_HEADER_BYTES)
        header_bytes = f.tell()
    except Exception:    # numpy's own messages quote the header's bytes: say what is wrong, not what it holds
        raise PolicyError(f'{name} is not a readable .npy array (its header is not numpy\'s)') from None
    if not (isinstance(shape, tuple) and len(shape) <= 2
            and all(isinstance(n, int) and 0 <= n <= MAX_ELEMENTS for n in shape)):
        raise PolicyError(f'{name} has a shape no policy array has')
    if name == 'metadata':
        if dtype.kind != 'U' or shape != ():
            raise PolicyError('metadata is not a JSON string')
        if dtype.itemsize // 4 > MAX_METADATA_CHARS:
            raise PolicyError(f'metadata of {dtype.itemsize // 4} characters: at most {MAX_METADATA_CHARS}')
    elif dtype.kind not in 'fiu' or dtype.itemsize > 8 or dtype.hasobject or dtype.fields is not None:
        raise PolicyError(f'{name} must hold real numbers of at most 64 bits, got dtype {_shown(str(dtype))}')
    elements = int(np.prod(shape, dtype=np.int64))
    if elements > MAX_ELEMENTS:
        raise PolicyError(f'{name} has {elements} numbers: more than any policy array')
    size = elements * dtype.itemsize
    if member.file_size != header_bytes + size:
        raise PolicyError(f'{name} is {member.file_size} bytes where its header says {header_bytes + size}')
    return shape, dtype, size


def _read_member(archive: zipfile.ZipFile, member: zipfile.ZipInfo, name: str, shape: tuple | None = None):
    """A member's array, its header checked (and its shape, when given) before any of its data is read."""
    try:
        with archive.open(member) as f:
            got, dtype, size = _check_header(f, member, name)
            if shape is not None and got != shape:
                raise PolicyError(f'{name} must have shape {shape}, got {_shown(got)}')
            raw = f.read(size + 1)
    except PolicyError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, RuntimeError, NotImplementedError):
        raise PolicyError(f'{name} cannot be read: the archive is damaged or uses an unknown compression') from None
    if len(raw) != size:
        raise PolicyError(f'{name} is cut short')
    return np.frombuffer(raw, dtype=dtype).reshape(got).copy()


def _metadata_json(raw: np.ndarray) -> dict:
    if raw.shape != () or raw.dtype.kind != 'U':
        raise PolicyError('metadata is not a JSON string')
    try:
        metadata = json.loads(str(raw))
    except RecursionError:
        raise PolicyError('metadata is not JSON a policy holds: nested too deep') from None
    except ValueError:
        raise PolicyError('metadata is not JSON') from None
    if not isinstance(metadata, dict):
        raise PolicyError('metadata is not a JSON object')
    return metadata


def _shown(value) -> str:
    """A value from a file, for a message: short, never its bytes at length (a plain short name as it is)."""
    if isinstance(value, str) and len(value) <= 40 and value.replace('_', '').isalnum() and value.isascii():
        return value
    text = ascii(value)
    return text if len(text) <= 40 else text[:37] + '...'


def _metadata(raw: np.ndarray) -> dict:
    metadata = _metadata_json(raw)
    if metadata.get('format') != FORMAT:
        raise PolicyError(f'format is {_shown(metadata.get("format"))}, this version reads {FORMAT!r}')
    if metadata.get('kind') not in KINDS:
        raise PolicyError(f'kind is {_shown(metadata.get("kind"))}, not one of {", ".join(KINDS)}')
    if metadata['kind'] in CARTPOLE_KINDS and metadata.get('env_id') not in SUPPORTED_ENVS:
        raise PolicyError(f'env_id is {_shown(metadata.get("env_id"))}, not one of {", ".join(SUPPORTED_ENVS)}')
    if metadata['kind'] == 'ars_linear':
        _check_ars_metadata(metadata)
    if not isinstance(metadata.get('seed'), int) or isinstance(metadata.get('seed'), bool):
        raise PolicyError(f'seed is {_shown(metadata.get("seed"))}, not a whole number')
    for name in ('settings', 'figures'):
        value = metadata.setdefault(name, {})
        if not isinstance(value, dict):
            raise PolicyError(f'{name} is not a JSON object')
        for key, v in value.items():
            if len(key) > MAX_TEXT or not (v is None or isinstance(v, (bool, int, float))
                                           or isinstance(v, str) and len(v) <= MAX_TEXT):
                raise PolicyError(f'{name} must map short names to numbers, text of at most {MAX_TEXT} characters, '
                                  'true/false or null')
    for name in ('created', 'source'):
        value = metadata.setdefault(name, '')
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            raise PolicyError(f'{name} must be text of at most {MAX_TEXT} characters')
    return metadata


def _plain(value, depth: int = 0) -> bool:
    """A short JSON value an env's settings hold: a number, a short text, true/false, null, or a short list of
    them (or of such lists, one level down)."""
    if value is None or isinstance(value, (bool, int, float)):
        return True
    if isinstance(value, str):
        return len(value) <= MAX_TEXT
    if isinstance(value, list) and depth < 2:
        return len(value) <= MAX_LIST and all(_plain(v, depth + 1) for v in value)
    return False


def _check_ars_metadata(metadata: dict) -> None:
    """An ars_linear policy's env: env_id a short text, env_kwargs short names to plain values, joints names."""
    env_id = metadata.get('env_id')
    if not isinstance(env_id, str) or not 0 < len(env_id) <= 200:
        raise PolicyError(f'env_id is {_shown(env_id)}, not the id of an env')
    kwargs = metadata.setdefault('env_kwargs', {})
    if not isinstance(kwargs, dict) or not all(isinstance(k, str) and len(k) <= 100 and _plain(v)
                                               for k, v in kwargs.items()):
        raise PolicyError('env_kwargs must map short names to numbers, short texts, true/false, null or lists of them')
    joints = metadata.setdefault('joints', [])
    if not isinstance(joints, list) or len(joints) > MAX_LIST or not all(isinstance(j, str) and len(j) <= MAX_TEXT
                                                                         for j in joints):
        raise PolicyError('joints must be a list of joint names')
    for name in ('robot', 'model', 'model_sha256'):
        value = metadata.setdefault(name, '')
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            raise PolicyError(f'{name} must be text of at most {MAX_TEXT} characters')


def _check_figures(metadata: dict) -> None:
    """A file's claimed figures are within what its env can give: an average length or reward from 0 to the env's
    step limit (CartPole-v1: 500). A node never compares with a figure nobody could have measured."""
    if metadata['kind'] not in CARTPOLE_KINDS:
        return
    limit = CartPoleDynamics.of(metadata['env_id']).max_episode_steps
    for key in AVERAGE_FIGURES:
        if key not in metadata['figures']:
            continue
        v = metadata['figures'][key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= limit:
            raise PolicyError(f'figures.{key} is {_shown(v)}: {metadata["env_id"]} gives 0 to {limit}')


def _check_arrays(kind: str, arrays: dict) -> None:
    """PolicyError unless arrays are exactly what a policy of kind needs: names, shapes, real numbers that are finite
    and not subnormal in the type the policy computes in (a Q-learning agent: float32; a linear policy: float64).
    Converts them to that type, in place."""
    if kind == 'linear':
        want = {'weights': ((4,), np.float64)}
    elif kind == 'ars_linear':
        shape = np.shape(arrays.get('weights', np.zeros(0)))
        if len(shape) != 2 or not (1 <= shape[0] <= MAX_ARS_ACTIONS and 1 <= shape[1] <= MAX_ARS_INPUTS):
            raise PolicyError(f'weights must have shape (actions, observations), at most ({MAX_ARS_ACTIONS}, '
                              f'{MAX_ARS_INPUTS}), got {_shown(shape)}')
        a, d = shape
        want = {'weights': ((a, d), np.float64), 'obs_mean': ((d,), np.float64), 'obs_std': ((d,), np.float64)}
        if 'bias' in arrays:
            want['bias'] = ((a,), np.float64)
    else:
        d = arrays.get('feature_offsets', np.zeros(0)).shape
        dimensions = d[0] if len(d) == 1 else -1
        if not 1 <= dimensions <= MAX_DIMENSIONS:
            raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}, got {d}')
        want = {'feature_weights': ((4, dimensions), np.float32), 'feature_offsets': ((dimensions,), np.float32),
                'amplitude': ((), np.float64), 'q_weights': ((2, dimensions), np.float32)}
    missing = sorted(set(want) - set(arrays))
    extra = sorted(set(arrays) - set(want))
    if missing or extra:
        raise PolicyError(f'a {kind} policy holds the arrays {", ".join(sorted(want))}; '
                          + '; '.join(p for p in (f'missing {", ".join(missing)}' if missing else '',
                                                  f'unexpected {", ".join(extra)}' if extra else '') if p))
    for name, (shape, compute) in want.items():
        a = np.asarray(arrays[name])
        if a.dtype.kind not in 'fiu' or a.dtype.itemsize > 8:
            raise PolicyError(f'{name} must hold real numbers of at most 64 bits, got dtype {_shown(str(a.dtype))}')
        if a.shape != shape:
            raise PolicyError(f'{name} must have shape {shape}, got {_shown(a.shape)}')
        with np.errstate(over='ignore', invalid='ignore'):
            converted = a.astype(compute)
        bad = ~np.isfinite(converted)
        if bad.any():
            raise PolicyError(f'{name} holds {int(bad.sum())} NaN or infinite number(s) in {np.dtype(compute).name}, '
                              'the type the policy computes in')
        subnormal = (converted != 0) & (np.abs(converted) < np.finfo(compute).smallest_normal)
        if subnormal.any():
            raise PolicyError(f'{name} holds {int(subnormal.sum())} subnormal number(s) (below '
                              f'{np.finfo(compute).smallest_normal:.3g} in {np.dtype(compute).name})')
        arrays[name] = converted
    if kind == 'ars_linear' and not (arrays['obs_std'] > 0).all():
        raise PolicyError('obs_std must hold positive numbers: a policy divides by them')
    if kind == 'q_learning':
        amplitude = float(arrays['amplitude'])
        if not amplitude > 0:
            raise PolicyError(f'amplitude must be positive, got {amplitude:g}')
        with np.errstate(over='ignore', invalid='ignore'):     # the agent computes in float32 (rbf_transform)
            bound = np.float32(amplitude) * np.abs(arrays['q_weights']).sum(axis=1, dtype=np.float32)
        if not np.isfinite(bound).all():
            raise PolicyError('amplitude x q_weights exceed float32: the Q-values would be infinite')
