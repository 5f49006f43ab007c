"""Policy files: a policy saved to disk and loaded again by any node, CLI or controller, as stable-baselines3's
``model.save()`` / ``load()`` do. No rospy; nothing here knows a robot or an env: each kind of policy is registered by
the part of the package that acts with it (``register_kind``).

One ``.npz`` file, read with ``numpy.load``'s format and never unpickled: the arrays the policy needs and
``metadata``, a JSON string (``format`` "robot_ai-policy/1", ``kind``, ``env_id``, ``seed`` (the policy's own),
``created``, ``settings``, ``figures``, ``source``, and whatever its kind adds). The kinds:

- ``linear`` and ``q_learning`` (robot_ai.cartpole.policy_kinds): the course's CartPole policies;
- ``ars_linear`` (robot_ai.ars): ARS's linear policy for any env, ``clip(weights @ ((x - obs_mean) / obs_std) + bias,
  -1, 1)`` of the flattened observation x; a reach policy's metadata names its robot, tip and joints.

    path = save('/tmp/best.npz', actor, env_id='CartPole-v1', seed=0)   # actor.kind names a registered kind
    policy = load(path)                # a Policy; anything else raises PolicyError with one line
    policy.act(state), policy.kind, policy.metadata['figures']
"""
from __future__ import annotations

import datetime
import io
import json
import os
import zipfile
from dataclasses import dataclass
from typing import Callable

import numpy as np

from robot_ai.artifacts import write_whole
from robot_ai.policies.files import PolicyError, read_regular_file, shown
from robot_ai.text import percent

FORMAT = 'robot_ai-policy/1'
EXTENSION = '.npz'
MAX_FILE_BYTES = 16 * 1024 * 1024        # a 10,000-component agent is 1.1 MB; anything far larger is not a policy
MAX_ELEMENTS = 160000                    # the largest array any kind holds (a Q-learning agent's 4 x 40,000)
MAX_MEMBERS = 16
MAX_HEADER_BYTES = 4096                  # of an .npy header (numpy writes about 128)
MAX_METADATA_CHARS = 65536               # a policy's metadata is about 1,000 characters
MAX_TEXT = 1000                          # characters of a source, a created date, a setting's or figure's text
MAX_LIST = 256                           # items of a list in env_kwargs or joints


def _nothing(_) -> None:
    return None


@dataclass(frozen=True)
class Kind:
    """A kind of policy a file may hold, as the part of the package that acts with it registers it.

    key: the array whose shape sizes the others (None when every shape is fixed; a tuple of names: their shapes,
    each None where absent); shapes(key shape or None, the names present) -> {array name: (shape, the dtype the
    policy computes in)}, PolicyError when the key's shape is not one of this kind's; build(arrays) -> the actor;
    arrays(actor) -> the arrays a file holds for it; check_metadata(metadata): the kind's own fields (its env, ...),
    PolicyError; check_figures(metadata): figures nobody could have measured, PolicyError; check_values(arrays):
    after conversion (positive scales, ...)."""
    name: str
    key: str | tuple[str, ...] | None
    shapes: Callable[[tuple | None, set], dict]
    build: Callable[[dict], object]
    arrays: Callable[[object], dict]
    check_metadata: Callable[[dict], None] = _nothing
    check_figures: Callable[[dict], None] = _nothing
    check_values: Callable[[dict], None] = _nothing


_KINDS: dict[str, Kind] = {}


def register_kind(kind: Kind) -> Kind:
    """Make files of this kind loadable and savable (again: replaced)."""
    _KINDS[kind.name] = kind
    return kind


def _kind(name) -> Kind:
    if name not in _KINDS:
        raise PolicyError(f'kind is {shown(name)}, not one of {", ".join(_KINDS)}')
    return _KINDS[name]


@dataclass(eq=False)
class Policy:
    """A policy and where it came from. actor: what acts (a linear_search.LinearPolicy, a q_learning.Agent, an
    ars.LinearPolicy: whatever its kind builds). note: what loading it for an env found worth saying ('' if
    nothing); target: that env (robot_ai.policies.Target), None when it was loaded as it is."""
    actor: object
    metadata: dict
    path: str = ''
    note: str = ''
    target: object = None

    @property
    def kind(self) -> str:
        return self.actor.kind

    @property
    def env_id(self) -> str:
        return self.metadata['env_id']

    @property
    def env_kwargs(self) -> dict:
        return dict(self.metadata.get('env_kwargs') or {})

    @property
    def seed(self) -> int:
        return self.metadata['seed']

    def act(self, state):
        """The policy's action for one state: 0 or 1 for a CartPole state (x, x_dot, theta, theta_dot); an array
        in [-1, 1] for an ars_linear policy's flattened observation."""
        return self.actor.act(state)

    def act_batch(self, x):
        return self.actor.act_batch(x)

    def push_right(self, observations: np.ndarray) -> np.ndarray:
        """Batched: observations (4, n) float32 -> (n,) bool, for CartPoleDynamics.episode_lengths."""
        return self.actor.push_right(observations)

    def evaluate(self, dynamics, episodes: int, max_steps: int, seed: int) -> np.ndarray:
        """Lengths (episodes,) of episodes played with the policy, start states from rng_for(seed)."""
        return self.actor.evaluate(dynamics, episodes, max_steps, seed)

    def describe(self) -> str:
        """One line: kind, env, seed, figures, and the file it came from."""
        m = self.metadata
        figures = ', '.join(_figure(k, v) for k, v in (m.get('figures') or {}).items())
        where = f' from {self.path}' if self.path else ''
        source = f', {m["source"]}' if m.get('source') else ''
        return f'{m["kind"]} policy{where} ({m["env_id"]}, seed {m["seed"]}{source}{"; " + figures if figures else ""})'


def _figure(name: str, value) -> str:
    """A figure as describe() shows it: a rate (a name ending in 'rate') as a percentage with one decimal, other
    numbers with two."""
    if name.endswith('rate') and isinstance(value, (int, float)) and not isinstance(value, bool):
        return f'{name} {percent(value)}'
    return f'{name} {value:.2f}' if isinstance(value, float) else f'{name} {value}'


def arrays_of(actor) -> dict:
    """The arrays a policy file holds for actor."""
    return _kind(actor.kind).arrays(actor)


def save(path: str, actor, env_id: str, seed: int, settings: dict | None = None, figures: dict | None = None,
         source: str = '', **extra) -> str:
    """Write actor as a policy file at path, whole or not at all (a temporary file renamed into place); return path.

    seed: the policy's own (a learner's, not its batch's); settings: what made it; figures: how good it is;
    source: a few words on where it came from ("search", "training, learner 3"); extra: more metadata (an
    ars_linear policy's env_kwargs, joints, robot, model, model_sha256)."""
    kind = _kind(actor.kind)
    metadata = dict(format=FORMAT, kind=kind.name, env_id=env_id, seed=int(seed),
                    created=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
                    settings=settings or {}, figures=figures or {}, source=source, **extra)
    arrays = kind.arrays(actor)
    _check_arrays(kind, arrays)  # never write a file that load() would refuse
    text = json.dumps(metadata, allow_nan=False)
    kind.check_figures(_metadata(np.array(text)))
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
    data = read_regular_file(path, MAX_FILE_BYTES)
    try:
        metadata, arrays = _read_archive(data)
        metadata = _metadata(metadata)
        kind = _kind(metadata['kind'])
        _check_arrays(kind, arrays)
        kind.check_figures(metadata)
    except PolicyError as e:
        raise PolicyError(f'{path}: {e}') from None
    return Policy(kind.build(arrays), metadata, path)


def _read_archive(data: bytes) -> tuple[np.ndarray, dict]:
    """(the metadata array, {name: array}) of an .npz's bytes, every member's header checked before its data is
    read (see _check_header)."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
        members = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, OSError):
        raise PolicyError('not a policy file (not an .npz archive)') from None
    names = [m.filename for m in members]
    if len(names) > MAX_MEMBERS:
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
        kind = _kind(_metadata_json(metadata).get('kind'))
        def header_shape(name: str) -> tuple:
            with archive.open(by_name[name]) as f:
                return _check_header(f, by_name[name], name)[0]
        key_shape = _key_shape(kind, set(by_name), header_shape)
        want = {name: shape for name, (shape, _) in kind.shapes(key_shape, set(by_name)).items()}
        _same_names(kind.name, want, set(by_name) - {'metadata'}, shown)
        arrays = {name: _read_member(archive, by_name[name], name, shape) for name, shape in want.items()}
    return metadata, arrays


def _key_shape(kind: Kind, names: set, shape_of: Callable[[str], tuple]):
    """The shape of kind's key array (None where the file has none), or a tuple of them for a key of several
    names."""
    if kind.key is None:
        return None
    if isinstance(kind.key, tuple):
        return tuple(shape_of(k) if k in names else None for k in kind.key)
    return shape_of(kind.key) if kind.key in names else None


def _same_names(kind: str, want, have: set, show=str) -> None:
    missing = sorted(set(want) - have)
    extra = sorted(have - set(want))
    if missing or extra:
        raise PolicyError(f'a {kind} policy holds the arrays {", ".join(sorted(want))}; '
                          + '; '.join(p for p in (f'missing {", ".join(missing)}' if missing else '',
                                                  f'unexpected {", ".join(show(n) for n in extra)}' if extra else '')
                                      if p))


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
        raise PolicyError(f'{name} must hold real numbers of at most 64 bits, got dtype {shown(str(dtype))}')
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
                raise PolicyError(f'{name} must have shape {shape}, got {shown(got)}')
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


def _metadata(raw: np.ndarray) -> dict:
    metadata = _metadata_json(raw)
    if metadata.get('format') != FORMAT:
        raise PolicyError(f'format is {shown(metadata.get("format"))}, this version reads {FORMAT!r}')
    _kind(metadata.get('kind')).check_metadata(metadata)
    if not isinstance(metadata.get('seed'), int) or isinstance(metadata.get('seed'), bool):
        raise PolicyError(f'seed is {shown(metadata.get("seed"))}, not a whole number')
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


def plain(value, depth: int = 0) -> bool:
    """A short JSON value an env's settings hold: a number, a short text, true/false, null, or a short list of
    them (or of such lists, one level down)."""
    if value is None or isinstance(value, (bool, int, float)):
        return True
    if isinstance(value, str):
        return len(value) <= MAX_TEXT
    if isinstance(value, list) and depth < 2:
        return len(value) <= MAX_LIST and all(plain(v, depth + 1) for v in value)
    return False


def _check_arrays(kind: Kind, arrays: dict) -> None:
    """PolicyError unless arrays are exactly what a policy of kind needs: names, shapes, real numbers that are finite
    and not subnormal in the type the policy computes in. Converts them to that type, in place."""
    key_shape = _key_shape(kind, set(arrays), lambda name: np.shape(arrays[name]))
    want = kind.shapes(key_shape, set(arrays))
    _same_names(kind.name, want, set(arrays))
    for name, (shape, compute) in want.items():
        a = np.asarray(arrays[name])
        if a.dtype.kind not in 'fiu' or a.dtype.itemsize > 8:
            raise PolicyError(f'{name} must hold real numbers of at most 64 bits, got dtype {shown(str(a.dtype))}')
        if a.shape != shape:
            raise PolicyError(f'{name} must have shape {shape}, got {shown(a.shape)}')
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
    kind.check_values(arrays)
