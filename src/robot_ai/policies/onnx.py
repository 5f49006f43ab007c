"""Policies exported by other libraries (.onnx), run with onnxruntime on the CPU. No rospy; nothing here knows a robot
or an env (robot_ai.policies.envs describes them).

stable-baselines3 trains with torch, which a robot's computer should not need; ONNX is how its policy travels
(stable-baselines3's export guide: opset 14 or later; for SAC, the actor only). Here such a file drives the package's
robots wherever a policy file is taken:

    policy = build(read('ppo_cartpole.onnx'), target_of('CartPole-v1'))   # robot_ai.policies.load does this
    policy = build(read('sac_reach.onnx'), target_of('robot_ai/Reach-v0', {'control': 'joints'}))
    policy.act(observation)          # one observation as the env gives it -> the action the env takes
    policy.act_batch(flat)           # (M, obs) flattened observations -> (M,) integers or (M, act) floats

The model: one float32 input of shape (batch, obs), the env's observation flattened as gymnasium.spaces.flatten does
(a Dict in its key order: achieved_goal, desired_goal, observation); its first output is the action: for a Discrete
env an integer (batch,) or (batch, 1), or one score per action (batch, n) whose argmax is taken; for a Box env
(batch, act) floats, clipped to the action space. The env comes from the model's metadata (metadata_props key
``robot_ai_env``: JSON ``{"env_id": ..., "env_kwargs": {...}}``) or from the caller, who wins.

Checked before anything runs, each refusal a PolicyError of one line that says what is wrong: a regular file of at
most MAX_BYTES; an ONNX model (protobuf); no tensor anywhere in it (initializers, attributes, subgraphs) stored as
external data (a path written in a model file is never opened: the model is given to onnxruntime as bytes); operators
of the standard domains only (ai.onnx, ai.onnx.ml), no local functions; onnx's checker; one input and outputs that
fit the env's spaces (naming both shapes); a trial run on zero and random observations that neither fails nor answers
NaN, infinities or actions outside the space. onnxruntime then runs it with one intra-op and one inter-op thread and
no spinning, so that a controller never takes a core.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces

from robot_ai.policies.envs import Target, flatten_batch as _flatten
from robot_ai.policies.files import PolicyError, read_regular_file
from robot_ai.text import percent

MAX_BYTES = 64 * 1024 * 1024
STANDARD_DOMAINS = ('', 'ai.onnx', 'ai.onnx.ml')
METADATA_KEY = 'robot_ai_env'
TRIAL_OBSERVATIONS = 16
EXTENSION = '.onnx'


class ActionError(PolicyError):
    """A model's answer that is no action of its env: out of range, the wrong number of scores, NaN or infinite."""


@dataclass(eq=False)
class OnnxPolicy:
    """A checked ONNX model and the env it acts in (see the module's docstring)."""
    path: str
    env_id: str
    env_kwargs: dict
    observation_space: spaces.Space
    action_space: spaces.Space
    session: object
    input_name: str
    output_name: str
    scores: bool                        # Discrete: the output is one score per action (argmax), not an integer
    metadata: dict = field(default_factory=dict)
    note: str = ''                      # what loading it for an env found worth saying (robot_ai.policies.load)
    target: object = None               # that env (a robot_ai.policies.Target)

    kind = 'onnx'

    @property
    def actor(self) -> OnnxPolicy:
        """The object that acts (as a robot_ai policy file's Policy.actor)."""
        return self

    @property
    def seed(self) -> int:
        return int(self.metadata.get('seed', 0))

    def _run(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.session.run([self.output_name], {self.input_name: x})[0])

    def act_batch(self, x) -> np.ndarray:
        """Actions of flattened observations x (M, obs): (M,) int64 for a Discrete env, (M, act) float64 clipped to a
        Box env's bounds. Every answer is checked (actions): ActionError, one line, for one that is no action."""
        x = np.ascontiguousarray(x, dtype=np.float32)
        return self.actions(self._run(x), len(x))

    def actions(self, out: np.ndarray, m: int, of: str = 'observations') -> np.ndarray:
        """The env's actions of the model's output for m observations, checked: one answer per observation, finite,
        as many scores or numbers as the env's actions, integers within a Discrete env's range; ActionError (one line)
        otherwise. A model may pass the checks at load and answer otherwise on real states."""
        if len(out) != m:
            raise ActionError(f'{self.path} answers {len(out)} actions for {m} observations: its first dimension must '
                              f'be the batch')
        rows = out.reshape(m, -1)
        if out.dtype.kind == 'f':
            bad = int((~np.isfinite(rows)).any(axis=1).sum())
            if bad:
                raise ActionError(f'{self.path} answers NaN or infinite actions (on {bad} of {m} {of})')
        space = self.action_space
        if isinstance(space, spaces.Discrete):
            n, start = int(space.n), int(space.start)
            if self.scores:
                if rows.shape[1] != n:
                    raise ActionError(f'{self.path} answers {rows.shape[1]} scores for an observation; the env has '
                                      f'{n} actions, one score each')
                return np.argmax(rows, axis=1) + start
            if rows.shape[1] != 1:
                raise ActionError(f'{self.path} answers {rows.shape[1]} numbers for an observation; one integer action '
                                  f'is wanted')
            a = rows[:, 0].astype(np.int64) + start
            outside = (a < start) | (a >= start + n)
            if outside.any():
                raise ActionError(f'{self.path} answers actions outside {start} to {start + n - 1}: '
                                  f'{sorted(set(a[outside].tolist()))[:5]} (on {int(outside.sum())} of {m} {of})')
            return a
        size = int(np.prod(space.shape))
        if rows.shape[1] != size:
            raise ActionError(f'{self.path} answers {rows.shape[1]} numbers for an observation; the env\'s action is '
                              f'{size}')
        return np.minimum(np.maximum(rows.astype(np.float64), space.low.reshape(-1)), space.high.reshape(-1))

    def act(self, observation):
        """The action of one observation as the env gives it (a Dict env's dict, or an array)."""
        flat = spaces.flatten(self.observation_space, observation) if isinstance(self.observation_space, spaces.Dict) \
            else np.asarray(observation, dtype=np.float32).reshape(-1)
        a = self.act_batch(flat.reshape(1, -1))[0]
        return int(a) if isinstance(self.action_space, spaces.Discrete) else a

    # the CartPole agents' interface (robot_ai.cartpole.policy_kinds)
    def push_right(self, observations: np.ndarray) -> np.ndarray:
        """observations (4, n) float32 -> (n,) bool: the policy pushes right (action 1)."""
        return self.act_batch(np.ascontiguousarray(observations.T)) == 1

    def describe(self) -> str:
        m = self.metadata
        parts = [self.env_id + (f' as {m["exported_for"]}' if m.get('exported_for') else '')]
        if m.get('producer'):
            parts.append(f'made by {m["producer"]}')
        if isinstance(m.get('success_rate'), (int, float)):
            parts.append(f'success rate {percent(m["success_rate"])}')
        if isinstance(m.get('mean_length'), (int, float)):
            parts.append(f'average length {m["mean_length"]:.1f}')
        return f'ONNX policy from {self.path} ({"; ".join(parts)})'


# ------------------------------------------------------------------------------------------------------ checks
def _tensors(graph):
    """Every TensorProto of a graph and its subgraphs: initializers, sparse initializers, attributes' tensors."""
    for t in graph.initializer:
        yield t
    for sparse in graph.sparse_initializer:
        yield sparse.values
        yield sparse.indices
    for node in graph.node:
        for attribute in node.attribute:
            if attribute.HasField('t'):
                yield attribute.t
            yield from attribute.tensors
            if attribute.HasField('sparse_tensor'):
                yield attribute.sparse_tensor.values
                yield attribute.sparse_tensor.indices
            for sub in ([attribute.g] if attribute.HasField('g') else []) + list(attribute.graphs):
                yield from _tensors(sub)


def _nodes(graph):
    for node in graph.node:
        yield node
        for attribute in node.attribute:
            for sub in ([attribute.g] if attribute.HasField('g') else []) + list(attribute.graphs):
                yield from _nodes(sub)


def _dims(value_info) -> tuple[int, list]:
    """(element type, dims: int or None for a symbolic one) of a graph input or output; (0, []) without a tensor
    type."""
    t = value_info.type
    if not t.HasField('tensor_type'):
        return 0, []
    shape = [d.dim_value if d.HasField('dim_value') else None for d in t.tensor_type.shape.dim]
    return t.tensor_type.elem_type, shape


def _shown(shape: list, names: list | None = None) -> str:
    """A shape as messages and `show` print it: numbers, and a symbolic dimension by its own name (the model's
    'n' is n, not batch; an unnamed one is 'batch' first and '?' after)."""
    names = names or [None] * len(shape)
    words = [str(d) if d is not None else (name or ('batch' if i == 0 else '?'))
             for i, (d, name) in enumerate(zip(shape, names))]
    return '(' + ', '.join(words) + (',)' if len(shape) == 1 else ')')


def _dim_names(value_info) -> list:
    """The symbolic names (dim_param) of a graph input's or output's dimensions, None where a dimension has none."""
    t = value_info.type
    if not t.HasField('tensor_type'):
        return []
    return [d.dim_param if d.HasField('dim_param') and d.dim_param else None for d in t.tensor_type.shape.dim]


def _parse(data: bytes, where: str):
    """The checked ModelProto of data (see the module's docstring), before onnxruntime sees it."""
    import onnx
    from google.protobuf.message import DecodeError
    try:
        model = onnx.ModelProto()
        model.ParseFromString(data)
    except (DecodeError, ValueError, RuntimeError):
        raise PolicyError(f'{where} is not an ONNX model (not a protobuf ModelProto)') from None
    if model.ir_version <= 0 or not model.opset_import or not model.graph.node:
        raise PolicyError(f'{where} is not an ONNX model (no IR version, opset or graph)')
    for tensor in _tensors(model.graph):
        if tensor.data_location == onnx.TensorProto.EXTERNAL or len(tensor.external_data):
            location = next((e.value for e in tensor.external_data if e.key == 'location'), '?')
            raise PolicyError(f'{where} keeps tensor {tensor.name!r} in external data ({location!r}): a path written '
                              f'in a model file is never opened; export it as one file')
    domains = sorted({o.domain for o in model.opset_import} | {n.domain for n in _nodes(model.graph)})
    unknown = [d for d in domains if d not in STANDARD_DOMAINS]
    if unknown:
        raise PolicyError(f'{where} uses operators outside the standard domains: {", ".join(unknown)} (only '
                          f'ai.onnx and ai.onnx.ml run here)')
    if len(model.functions):
        raise PolicyError(f'{where} defines local functions ({model.functions[0].name}): only standard operators '
                          f'run here')
    try:
        onnx.checker.check_model(model)
    except Exception as e:       # onnx.checker.ValidationError, and whatever a malformed graph raises
        raise PolicyError(f'{where} is not a valid ONNX model: {str(e).strip().splitlines()[0][:300]}') from None
    return model


def env_of(model) -> dict:
    """The model's metadata robot_ai_env as a dict ({} without it): env_id, env_kwargs and whatever else the
    exporter wrote there (robot, joints, success_rate, ...)."""
    props = {p.key: p.value for p in model.metadata_props}
    if METADATA_KEY not in props:
        return {}
    try:
        value = json.loads(props[METADATA_KEY])
        if not isinstance(value, dict) or not isinstance(value.get('env_id', ''), str) or \
                not isinstance(value.get('env_kwargs') or {}, dict):
            raise TypeError
    except (ValueError, TypeError):
        raise PolicyError(f'its metadata {METADATA_KEY} is not JSON {{"env_id": ..., "env_kwargs": {{...}}}}') \
            from None
    value['env_kwargs'] = value.get('env_kwargs') or {}
    return value


def _fit(model, where: str, observation_space, action_space) -> tuple[str, str, bool]:
    """(input name, output name, whether a Discrete env's output is scores) once the model's input and first output
    fit the spaces; PolicyError naming both shapes otherwise."""
    import onnx
    initializers = {t.name for t in model.graph.initializer}
    inputs = [i for i in model.graph.input if i.name not in initializers]
    d = int(spaces.flatdim(observation_space))
    if len(inputs) != 1:
        raise PolicyError(f'{where} has {len(inputs)} inputs ({", ".join(i.name for i in inputs)}); one is wanted: the '
                          f'flattened observation, (batch, {d})')
    elem, shape = _dims(inputs[0])
    if elem != onnx.TensorProto.FLOAT or len(shape) != 2 or shape[1] not in (None, d):
        kind = onnx.TensorProto.DataType.Name(elem) if elem else 'no tensor'
        raise PolicyError(f'{where} takes {kind} {_shown(shape)} as {inputs[0].name!r}; the env\'s flattened '
                          f'observation is float32 (batch, {d})')
    output = model.graph.output[0]
    elem, shape = _dims(output)
    integer = elem in (onnx.TensorProto.INT64, onnx.TensorProto.INT32)
    floating = elem in (onnx.TensorProto.FLOAT, onnx.TensorProto.DOUBLE)
    if isinstance(action_space, spaces.Discrete):
        n = int(action_space.n)
        wanted = f'an integer action (batch,) or one score per action (batch, {n})'
        fits = (integer and (len(shape) == 1 or (len(shape) == 2 and shape[1] in (None, 1)))) or \
            (floating and len(shape) == 2 and shape[1] in (None, n))
        scores = floating
    elif isinstance(action_space, spaces.Box):
        a = int(np.prod(action_space.shape))
        wanted = f'float actions (batch, {a})'
        fits = floating and len(shape) == 2 and shape[1] in (None, a)
        scores = False
    else:
        raise PolicyError(f'the env\'s action space {action_space} is neither Discrete nor Box')
    if not fits:
        kind = onnx.TensorProto.DataType.Name(elem) if elem else 'no tensor'
        raise PolicyError(f'{where}\'s first output {output.name!r} is {kind} {_shown(shape)}; the env takes {wanted}')
    return inputs[0].name, output.name, scores


def session_of(data: bytes):
    """An onnxruntime session of the model's bytes on the CPU: one intra-op and one inter-op thread, no spinning."""
    import onnxruntime
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = onnxruntime.ExecutionMode.ORT_SEQUENTIAL
    options.add_session_config_entry('session.intra_op.allow_spinning', '0')
    options.add_session_config_entry('session.inter_op.allow_spinning', '0')
    options.log_severity_level = 3
    return onnxruntime.InferenceSession(data, options, providers=['CPUExecutionProvider'])


def trial_observations(observation_space) -> np.ndarray:
    """The trial's observations: zeros, and TRIAL_OBSERVATIONS - 1 standard normal ones (seeded)."""
    d = int(spaces.flatdim(observation_space))
    rng = np.random.default_rng(0)
    return np.concatenate((np.zeros((1, d)), rng.normal(size=(TRIAL_OBSERVATIONS - 1, d)))).astype(np.float32)


TRIAL_SECONDS = 20.0              # wall seconds the bounded trial (a session, one run) may take in its child
TRIAL_MEMORY = 2 * 1024 ** 3      # bytes of address space it may use
TRIAL_CHILD = '''
import resource, sys
import numpy as np
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
resource.setrlimit(resource.RLIMIT_CPU, (int(sys.argv[2]), int(sys.argv[2])))
from robot_ai.policies.onnx import session_of
raw = sys.stdin.buffer.read()
n = int.from_bytes(raw[:8], 'little')
data, x = raw[8:8 + n], np.frombuffer(raw[8 + n:], dtype=np.float32).reshape(int(sys.argv[3]), -1)
session_of(data).run([sys.argv[5]], {sys.argv[4]: x})
print('ok', flush=True)
'''


def bounded_trial(data: bytes, input_name: str, output_name: str, x: np.ndarray, where: str) -> None:
    """The model's session and one run of the trial's observations, first in a child process bounded in time
    (TRIAL_SECONDS) and memory (TRIAL_MEMORY): a Loop of 2**40 iterations, or a 459-byte file that expands one number
    to gigabytes, is refused here in one line before this process builds anything of it. Ctrl-C ends the child."""
    import subprocess
    import sys
    command = [sys.executable, '-c', TRIAL_CHILD, str(TRIAL_MEMORY), str(int(TRIAL_SECONDS) + 1), str(len(x)),
               input_name, output_name]
    child = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        out, err = child.communicate(len(data).to_bytes(8, 'little') + data + x.tobytes(), timeout=TRIAL_SECONDS)
    except subprocess.TimeoutExpired:
        raise PolicyError(f'{where} takes more than {TRIAL_SECONDS:g} s to answer {len(x)} observations: refused '
                          f'(a policy answers in milliseconds)') from None
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    if child.returncode != 0 or out.strip() != b'ok':
        said = err.decode(errors='replace').strip().splitlines()
        cause = said[-1][:300] if said else f'it ended with status {child.returncode}'
        if child.returncode == -9 or 'MemoryError' in cause or 'bad_alloc' in cause or 'allocat' in cause.lower():
            raise PolicyError(f'{where} needs more than {TRIAL_MEMORY / 1024 ** 3:g} GiB to answer {len(x)} '
                              f'observations: refused ({cause})')
        raise PolicyError(f'{where} fails on a {x.shape[1]}-number observation: {cause}')


def _trial(policy: OnnxPolicy, where: str) -> None:
    """Run the model on zero and random observations: it must answer finite actions within the space."""
    x = trial_observations(policy.observation_space)
    d = x.shape[1]
    try:
        out = policy._run(x)
    except Exception as e:       # onnxruntime's errors: a model that fails on a well-formed observation
        raise PolicyError(f'{where} fails on a {d}-number observation: {str(e).strip().splitlines()[0][:300]}') \
            from None
    policy.actions(out, len(x), 'trial observations')


@dataclass(eq=False)
class OnnxFile:
    """A checked ONNX model file before it meets an env: its path, bytes, ModelProto and metadata (env_of)."""
    path: str
    data: bytes
    model: object
    info: dict

    kind = 'onnx'

    @property
    def metadata(self) -> dict:
        return self.info

    @property
    def env_id(self) -> str:
        return self.info.get('env_id', '')

    @property
    def env_kwargs(self) -> dict:
        return dict(self.info.get('env_kwargs', {}))

    def action_size(self) -> int | None:
        """The size of the first output's last dimension when fixed (a Box env's action size), else None."""
        _, shape = _dims(self.model.graph.output[0])
        return shape[-1] if len(shape) == 2 else None


def read(path: str) -> OnnxFile:
    """A checked ONNX model (the module's docstring: everything but the fit to an env and the trial run)."""
    import os
    if not str(path).strip():
        raise PolicyError('the path is empty: give an ONNX file (.onnx), absolute or ~/...')
    where = os.path.abspath(os.path.expanduser(str(path)))
    data = read_regular_file(where, MAX_BYTES, 'ONNX file')
    model = _parse(data, where)
    try:
        info = env_of(model)
    except PolicyError as e:
        raise PolicyError(f'{where}: {e}') from None
    return OnnxFile(where, data, model, info)


def build(file: OnnxFile, target: Target) -> OnnxPolicy:
    """The policy of a read file acting in the target's env: its input and output fit the env's spaces, onnxruntime
    takes it, and its trial run answers actions of the space."""
    where, model = file.path, file.model
    env_id, env_kwargs = target.env_id, target.env_kwargs
    observation_space, action_space = target.observation_space, target.action_space
    input_name, output_name, scores = _fit(model, where, observation_space, action_space)
    bounded_trial(file.data, input_name, output_name, trial_observations(observation_space), where)
    try:
        session = session_of(file.data)
    except Exception as e:       # onnxruntime refusing what onnx's checker let through
        raise PolicyError(f'{where}: onnxruntime cannot run it: {str(e).strip().splitlines()[0][:300]}') from None
    metadata = {p.key: p.value for p in model.metadata_props if p.key != METADATA_KEY}
    metadata.update(file.info)
    metadata.update(target.metadata)
    metadata.update(env_id=env_id, env_kwargs=dict(env_kwargs), producer=' '.join(
        v for v in (model.producer_name, model.producer_version) if v), opset=max(
        (o.version for o in model.opset_import if o.domain in ('', 'ai.onnx')), default=0))
    policy = OnnxPolicy(where, env_id, dict(env_kwargs), observation_space, action_space, session, input_name,
                        output_name, scores, metadata)
    _trial(policy, where)
    return policy


def summary(file: OnnxFile) -> dict:
    """What `show` prints of an ONNX file: its metadata, producer, opset, inputs and outputs."""
    import onnx
    model = file.model

    def tensors(values):
        initializers = {t.name for t in model.graph.initializer}
        out = {}
        for v in values:
            if v.name in initializers:
                continue
            elem, shape = _dims(v)
            out[v.name] = f'{onnx.TensorProto.DataType.Name(elem) if elem else "?"} {_shown(shape, _dim_names(v))}'
        return out
    return dict(path=file.path, producer=' '.join(v for v in (model.producer_name, model.producer_version) if v),
                opset={o.domain or 'ai.onnx': o.version for o in model.opset_import}, ir_version=model.ir_version,
                metadata={**{p.key: p.value for p in model.metadata_props if p.key != METADATA_KEY}, **file.info},
                inputs=tensors(model.graph.input), outputs=tensors(model.graph.output),
                operators=sorted({n.op_type for n in _nodes(model.graph)}))


def flatten_batch(observation_space, observations) -> np.ndarray:
    """A batch of observations as the model takes them (float32 (M, obs)): gymnasium.spaces.flatten's order."""
    return _flatten(observation_space, observations).astype(np.float32)
