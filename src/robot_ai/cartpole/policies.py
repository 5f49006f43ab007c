"""Policy files: a search's or a training's policy saved to disk and loaded again by any node, the CLI or the
controller, as stable-baselines3's ``model.save()`` / ``load()`` do. No rospy.

One ``.npz`` file, read with ``numpy.load(..., allow_pickle=False)``: the arrays the policy needs and ``metadata``,
a JSON string (``format`` "robot_ai-policy/1", ``kind``, ``env_id``, ``seed`` (the policy's own), ``created``,
``settings``, ``figures``, ``source``). Arrays: a linear policy's ``weights`` (4,); a Q-learning agent's
``feature_weights`` (4, D), ``feature_offsets`` (D,) (the scaler folded in), ``amplitude`` (0-d) and
``q_weights`` (2, D): everything it needs to act, nothing re-drawn from a seed.

    path = save('/tmp/best.npz', LinearPolicy(np.array([0.1, 0.2, 0.9, 0.5])), env_id='CartPole-v1', seed=0)
    policy = load(path)                # a Policy; anything else raises PolicyError with one line
    policy.act(state), policy.kind, policy.metadata['figures']
    policy.evaluate(CartPoleDynamics.of(policy.env_id), 100, 500, seed=0)
"""
import datetime
import json
import math
import os
import zipfile
from dataclasses import dataclass

import numpy as np

from robot_ai.cartpole.artifacts import write_whole
from robot_ai.cartpole.dynamics import SUPPORTED_ENVS
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.cartpole.q_learning import Agent

FORMAT = 'robot_ai-policy/1'
KINDS = ('linear', 'q_learning')
EXTENSION = '.npz'
MAX_FILE_BYTES = 64 * 1024 * 1024        # a 10,000-component agent is 1.1 MB; anything far larger is not a policy
MAX_DIMENSIONS = 4 * 10000               # q_learning.MAX_COMPONENTS banks of 4


class PolicyError(ValueError):
    """A file that is not a policy this package can use; the message is one line that says what is wrong."""


@dataclass(frozen=True, eq=False)
class Policy:
    """A policy and where it came from. actor: a linear_search.LinearPolicy or a q_learning.Agent."""
    actor: LinearPolicy | Agent
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

    def act(self, state) -> int:
        """The policy's action (0 or 1) for one state (x, x_dot, theta, theta_dot)."""
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


def arrays_of(actor: LinearPolicy | Agent) -> dict:
    """The arrays a policy file holds for actor."""
    if isinstance(actor, LinearPolicy):
        return dict(weights=np.asarray(actor.weights, dtype=np.float64).reshape(4))
    return dict(feature_weights=actor.feature_weights, feature_offsets=actor.feature_offsets,
                amplitude=np.array(actor.amplitude, dtype=np.float64), q_weights=actor.q_weights)


def save(path: str, actor: LinearPolicy | Agent, env_id: str, seed: int, settings: dict | None = None,
         figures: dict | None = None, source: str = '') -> str:
    """Write actor as a policy file at path, whole or not at all (a temporary file renamed into place); return path.

    seed: the policy's own (a learner's, not its batch's); settings: what made it; figures: how good it is;
    source: a few words on where it came from ("search", "training, learner 3")."""
    metadata = dict(format=FORMAT, kind=actor.kind, env_id=env_id, seed=int(seed),
                    created=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
                    settings=settings or {}, figures=figures or {}, source=source)
    arrays = arrays_of(actor)
    _check_arrays(actor.kind, arrays)  # never write a file that load() would refuse
    text = json.dumps(metadata, allow_nan=False)
    return write_whole(path, lambda f: np.savez(f, metadata=np.array(text), **arrays))


def load(path: str) -> Policy:
    """The policy in a file written by save(); PolicyError (one line) for anything else: a missing or unreadable
    file, not an npz, pickled objects, another format or kind, missing or extra arrays, wrong shapes or types,
    non-finite numbers."""
    path = os.path.abspath(os.path.expanduser(str(path)))
    if not os.path.exists(path):
        raise PolicyError(f'no policy file at {path}')
    if not os.path.isfile(path):
        raise PolicyError(f'{path} is not a file')
    size = os.path.getsize(path)
    if size > MAX_FILE_BYTES:
        raise PolicyError(f'{path} is {size // (1024 * 1024)} MiB: too large for a policy file')
    if not zipfile.is_zipfile(path):
        raise PolicyError(f'{path} is not a policy file (not an .npz archive)')
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise PolicyError(f'{path} is not a policy file: {_one_line(e)}')
    try:
        metadata = _metadata(arrays.pop('metadata', None))
        kind = metadata['kind']
        _check_arrays(kind, arrays)
    except PolicyError as e:
        raise PolicyError(f'{path}: {e}')
    if kind == 'linear':
        actor = LinearPolicy(arrays['weights'].astype(np.float64))
    else:
        actor = Agent(arrays['feature_weights'], arrays['feature_offsets'], float(arrays['amplitude']),
                      arrays['q_weights'])
    return Policy(actor, metadata, path)


def _one_line(e: BaseException) -> str:
    return ' '.join(str(e).split()) or type(e).__name__


def _metadata(raw) -> dict:
    if raw is None:
        raise PolicyError('no metadata: not a robot_ai policy file')
    if raw.shape != () or raw.dtype.kind != 'U':
        raise PolicyError('metadata is not a JSON string')
    try:
        metadata = json.loads(str(raw))
    except ValueError as e:
        raise PolicyError(f'metadata is not JSON: {_one_line(e)}')
    if not isinstance(metadata, dict):
        raise PolicyError('metadata is not a JSON object')
    if metadata.get('format') != FORMAT:
        raise PolicyError(f'format is {metadata.get("format")!r}, this version reads {FORMAT!r}')
    if metadata.get('kind') not in KINDS:
        raise PolicyError(f'kind is {metadata.get("kind")!r}, not one of {", ".join(KINDS)}')
    if metadata.get('env_id') not in SUPPORTED_ENVS:
        raise PolicyError(f'env_id is {metadata.get("env_id")!r}, not one of {", ".join(SUPPORTED_ENVS)}')
    if not isinstance(metadata.get('seed'), int) or isinstance(metadata.get('seed'), bool):
        raise PolicyError(f'seed is {metadata.get("seed")!r}, not a whole number')
    for name in ('settings', 'figures'):
        if not isinstance(metadata.setdefault(name, {}), dict):
            raise PolicyError(f'{name} is not a JSON object')
    metadata.setdefault('created', '')
    metadata.setdefault('source', '')
    return metadata


def _check_arrays(kind: str, arrays: dict) -> None:
    """PolicyError unless arrays are exactly what a policy of kind needs: names, shapes, real finite numbers."""
    if kind == 'linear':
        want = {'weights': (4,)}
    else:
        d = arrays.get('feature_offsets', np.zeros(0)).shape
        dimensions = d[0] if len(d) == 1 else -1
        if not 1 <= dimensions <= MAX_DIMENSIONS:
            raise PolicyError(f'feature_offsets must have shape (D,) with D from 1 to {MAX_DIMENSIONS}, got {d}')
        want = {'feature_weights': (4, dimensions), 'feature_offsets': (dimensions,), 'amplitude': (),
                'q_weights': (2, dimensions)}
    missing = sorted(set(want) - set(arrays))
    extra = sorted(set(arrays) - set(want))
    if missing or extra:
        raise PolicyError(f'a {kind} policy holds the arrays {", ".join(sorted(want))}; '
                          + '; '.join(p for p in (f'missing {", ".join(missing)}' if missing else '',
                                                  f'unexpected {", ".join(extra)}' if extra else '') if p))
    for name, shape in want.items():
        a = arrays[name]
        if a.dtype.kind not in 'fiu':
            raise PolicyError(f'{name} must hold real numbers, got dtype {a.dtype}')
        if a.shape != shape:
            raise PolicyError(f'{name} must have shape {shape}, got {a.shape}')
        if not np.isfinite(a).all():
            raise PolicyError(f'{name} holds {int((~np.isfinite(a)).sum())} NaN or infinite numbers')
        if kind == 'q_learning' and name != 'amplitude':
            arrays[name] = a.astype(np.float32, copy=False)  # what the agent computes in
    if kind == 'q_learning' and not (0 < float(arrays['amplitude']) < math.inf):
        raise PolicyError(f'amplitude must be positive, got {float(arrays["amplitude"])}')
