"""Policy files of every kind, read safely, for every part of the package. No rospy; nothing here imports
robot_ai.cartpole, robot_ai.reach or robot_ai.nodes: each registers what it needs (its .npz kinds with
``register_kind``, its envs with ``register_env``).

- ``files``: reading a file a user names, bounded and without blocking; ``PolicyError``, one line.
- ``npz``: the package's own ``.npz`` policy files (save, load) and the kinds registered for them.
- ``onnx``: models exported by other libraries, checked, run with onnxruntime on one thread.
- ``envs``: the env a policy is loaded to act in (``Target``), and observations flattened as a policy takes them.

One loader for every node and CLI::

    policy = load('best.npz')                              # as the file is
    policy = load('ppo.onnx')                              # an ONNX model: its env from its metadata
    policy = load(path, 'CartPole-v1')                     # for an env: its spaces, kinds and checks
    policy = load(path, choose)                            # choose(file) -> Target: the env chosen from what the
                                                           # file names (file.env_id, .env_kwargs, .metadata)
    policy.act(observation), policy.note, policy.target
"""
from __future__ import annotations

from typing import Callable

from robot_ai.policies.envs import Target, register_env, target_of
from robot_ai.policies.files import PolicyError, read_regular_file
from robot_ai.policies.npz import Kind, Policy, arrays_of, register_kind, save
from robot_ai.policies import npz, onnx

__all__ = ['Kind', 'Policy', 'PolicyError', 'Target', 'arrays_of', 'is_onnx_path', 'load',
           'read_regular_file', 'register_env', 'register_kind', 'save', 'target_of']


def is_onnx_path(path) -> bool:
    return str(path).strip().lower().endswith(onnx.EXTENSION)


def load(path: str, env: str | Target | Callable[[object], Target] | None = None):
    """The policy in a file: a .npz policy file (a Policy) or an ONNX model (an OnnxPolicy), checked; PolicyError of
    one line for anything else.

    env: None (a .npz as it is; an ONNX model acts in the env its metadata names), an env id (that env, registered
    or made), a Target, or a function of the file read (a Policy or an onnx.OnnxFile: its path, kind, env_id,
    env_kwargs and metadata) -> Target. With an env,
    a .npz of a kind that does not act there is refused, and the target's check(policy) runs: its note is the
    policy's ``note``, the target its ``target``."""
    if is_onnx_path(path):
        file = onnx.read(path)
        target = _target(env, file)
        if target is None:
            if not file.env_id:
                raise PolicyError(f'{file.path} names no env (its metadata has no {onnx.METADATA_KEY}): give one '
                                  f'(--env-id)')
            target = target_of(file.env_id, file.env_kwargs)
        policy = onnx.build(file, target)
    else:
        policy = npz.load(path)
        target = _target(env, policy)
        if target is not None and target.kinds and policy.kind not in target.kinds:
            raise PolicyError(f'{policy.path} is a {policy.kind} policy for {policy.env_id}; {target.env_id} takes '
                              f'{" or ".join(target.kinds)} policies')
    if target is not None:
        policy.target = target
        policy.note = target.check(policy) if target.check is not None else ''
    return policy


def _target(env, file) -> Target | None:
    if env is None or isinstance(env, Target):
        return env
    if isinstance(env, str):
        return target_of(env, {}) if env else None
    return env(file)
