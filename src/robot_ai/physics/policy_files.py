"""The manipulation envs' policy files: the learner's MLP (kind 'mlp') saved with the robot and task it learned on,
loaded for that robot only, and exported as ONNX (the same numbers through onnxruntime). No rospy.

    path = save(training, 'push.npz')                 # training: physics.learn.Training
    onnx_path = export_onnx(training, 'push.onnx')
    policy = robot_ai.policies.load('push.npz', 'robot_ai/Push-v0')      # or the .onnx: its env from its metadata

A file's metadata names the env (env_id, env_kwargs: the task's model, xacro_args, tip and sizes), the robot and its
URDF's SHA-256; loading it for another robot is refused in one line naming both. ``import robot_ai.physics``
registers Push-v0 and PickAndPlace-v0 as envs a policy acts in, so that an ONNX model naming them (from here or from
another library) is fitted to their spaces.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np

from robot_ai import policies
from robot_ai.artifacts import write_whole
from robot_ai.physics.mlp import KIND, Mlp
from robot_ai.policies import Kind, PolicyError, Target, register_env, register_kind
from robot_ai.policies.npz import MAX_TEXT, plain, shown
from robot_ai.policies.onnx import METADATA_KEY

ENV_IDS = {'push': 'robot_ai/Push-v0', 'pick_and_place': 'robot_ai/PickAndPlace-v0'}
ENV_SETTINGS = ('model', 'urdf', 'xacro_args', 'tip', 'object_size', 'object_mass', 'distance_threshold', 'reward_type',
                'obj_range', 'goal_range', 'goal_height', 'step_time')
MAX_WIDTH = 4096
MAX_INPUTS = 1024
OPSET = 17


# ------------------------------------------------------------------------------------------- the kind 'mlp'
def _shapes(key_shape, names: set) -> dict:
    if key_shape is None or any(s is None for s in key_shape):
        raise PolicyError('an mlp policy holds layer0, layer1, layer2 (each its weights and a bias row) and norm')
    first, second, third = key_shape
    if not all(len(s) == 2 for s in key_shape):
        raise PolicyError(f'the layers must be matrices, got shapes {shown(key_shape)}')
    d, h1, h2, a = first[0] - 1, first[1], second[1], third[1]
    if not (1 <= d <= MAX_INPUTS and 1 <= h1 <= MAX_WIDTH and 1 <= h2 <= MAX_WIDTH and 1 <= a <= 64):
        raise PolicyError(f'the layers\' shapes {shown(key_shape)} are not those of a policy (at most {MAX_INPUTS} '
                          f'inputs, layers of {MAX_WIDTH})')
    return {'layer0': ((d + 1, h1), np.float64), 'layer1': ((h1 + 1, h2), np.float64),
            'layer2': ((h2 + 1, a), np.float64), 'norm': ((2, d), np.float64)}


def _check_metadata(metadata: dict) -> None:
    env_id = metadata.get('env_id')
    if env_id not in ENV_IDS.values():
        raise PolicyError(f'env_id is {shown(env_id)}, not one of {", ".join(ENV_IDS.values())}')
    kwargs = metadata.setdefault('env_kwargs', {})
    if not isinstance(kwargs, dict) or not all(isinstance(k, str) and len(k) <= 100 and plain(v)
                                               for k, v in kwargs.items()):
        raise PolicyError('env_kwargs must map short names to numbers, short texts, true/false, null or lists of them')
    for name in ('robot', 'model_sha256'):
        value = metadata.setdefault(name, '')
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            raise PolicyError(f'{name} must be text of at most {MAX_TEXT} characters')


def _check_values(arrays: dict) -> None:
    if not (arrays['norm'][1] > 0).all():
        raise PolicyError('norm\'s second row (the inputs\' scale) must hold positive numbers: a policy divides by it')


register_kind(Kind(KIND, ('layer0', 'layer1', 'layer2'), _shapes, Mlp.from_arrays, lambda net: net.arrays(),
                   check_metadata=_check_metadata, check_values=_check_values))


# ------------------------------------------------------------------------------------------------- the envs
def _target(env_id: str, env_kwargs: dict) -> Target:
    from robot_ai.physics.env import ManipulationSetup
    task = next(t for t, i in ENV_IDS.items() if i == env_id)
    try:
        setup = ManipulationSetup(task, **{k: v for k, v in env_kwargs.items() if k in ENV_SETTINGS})
    except ValueError as e:          # ReachError, PhysicsError: a robot that cannot do the task
        raise PolicyError(f'its env {env_id}: {e}') from None
    return Target(env_id, env_kwargs, setup.observation_space, setup.action_space, (KIND,),
                  check=lambda policy: check_fits(policy, setup), context=setup)


register_env(tuple(ENV_IDS.values()), _target)


def check_fits(policy, setup) -> str:
    """PolicyError (one line naming both) unless a policy learned on setup's robot; a note when the URDF's text
    differs but the robot's name does not, or when the file names no robot."""
    robot = policy.metadata.get('robot', '')
    if not robot:
        return f'{getattr(policy, "path", "the policy")} names no robot: it drives {setup.robot.tree.name} as given'
    if robot != setup.robot.tree.name:
        raise PolicyError(f'{policy.path} learned on {robot}; this env\'s robot is {setup.robot.tree.name}')
    if (policy.metadata.get('model_sha256') or '') not in ('', setup.robot.sha256):
        return f'{policy.path}: the robot {robot}\'s URDF differs from the one it learned on'
    return ''


def env_kwargs_of(setup) -> dict:
    """The env kwargs that make setup again (ManipulationEnv's)."""
    return {'model': setup.robot.path or setup.robot.name, 'xacro_args': dict(setup.robot.xacro_args) or None,
            'tip': setup.arm.tip, 'object_size': setup.object_size, 'distance_threshold': setup.distance_threshold,
            'reward_type': setup.reward_type, 'obj_range': setup.obj_range, 'goal_range': setup.goal_range,
            'goal_height': setup.goal_height, 'step_time': setup.step_time}


def save(training, path: str, held_out=None) -> str:
    """A physics.learn.Training's network as a policy file at path; held_out: (success rate, mean distance,
    episodes) of its own check on fresh goals, when it was made."""
    setup = training.setup
    figures = dict(eval_success_rate=training.best_success, best_round=training.best_round,
                   rounds=len(training.history), train_seconds=round(training.elapsed, 3),
                   env_steps=int(training.steps))
    if held_out is not None:
        figures.update(success_rate=held_out[0], mean_final_distance=held_out[1], held_out_episodes=held_out[2])
    settings = {k: ' x '.join(map(str, v)) if isinstance(v, tuple) else v      # hidden: '256 x 256'
                for k, v in dataclasses.asdict(training.settings).items()}
    return policies.save(path, training.net, ENV_IDS[setup.task], training.seed, settings=settings, figures=figures,
                         source='DAgger of the scripted expert (python -m robot_ai.physics train)',
                         env_kwargs=env_kwargs_of(setup), robot=setup.robot.tree.name,
                         model_sha256=setup.robot.sha256)


def load(path: str, **overrides):
    """(the policy in a file (.npz or .onnx), the ManipulationSetup it acts in): the env and robot the file names,
    with overrides (another model file for the same robot, say); PolicyError of one line for anything else."""
    from robot_ai.policies.envs import target_of

    def choose(file) -> Target:
        if file.env_id not in ENV_IDS.values():
            raise PolicyError(f'{file.path} acts in {file.env_id or "no env it names"}, not in '
                              f'{" or ".join(ENV_IDS.values())}')
        kwargs = {**file.env_kwargs, **{k: v for k, v in overrides.items() if v is not None}}
        robot = (getattr(file, 'metadata', None) or {}).get('robot', '')
        if overrides.get('model') and robot:
            from robot_ai.reach.model import load_model
            try:
                name = load_model(kwargs['model'], kwargs.get('xacro_args')).tree.name
            except ValueError as e:
                raise PolicyError(str(e)) from None
            if name != robot:
                raise PolicyError(f'{file.path} learned on {robot}; {kwargs["model"]} is {name}')
        return target_of(file.env_id, kwargs)
    policy = policies.load(path, choose)
    return policy, policy.target.context


def export_onnx(net: Mlp, path: str, env_id: str, env_kwargs: dict, info: dict | None = None) -> str:
    """net as an ONNX model at path (opset OPSET): input 'observation' float32 (batch, inputs), the flattened
    observation; output 'action' float32 (batch, outputs); metadata robot_ai_env names the env (and info: the
    robot, its success rate). Whole or not at all."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    def constant(name: str, value: np.ndarray):
        return numpy_helper.from_array(np.asarray(value, dtype=np.float32), name)

    initializers = [constant('mean', net.mean), constant('scale', net.scale)]
    nodes = [helper.make_node('Sub', ['observation', 'mean'], ['centred']),
             helper.make_node('Div', ['centred', 'scale'], ['h0'])]
    for k, (w, b) in enumerate(zip(net.weights, net.biases)):
        initializers += [constant(f'w{k}', w), constant(f'b{k}', b)]
        last = k == len(net.weights) - 1
        nodes += [helper.make_node('Gemm', [f'h{k}', f'w{k}', f'b{k}'], [f'z{k}']),
                  helper.make_node('Tanh' if last else 'Relu', [f'z{k}'], ['action' if last else f'h{k + 1}'])]
    graph = helper.make_graph(nodes, 'robot_ai_mlp', [
        helper.make_tensor_value_info('observation', TensorProto.FLOAT, ['batch', net.inputs])],
        [helper.make_tensor_value_info('action', TensorProto.FLOAT, ['batch', net.outputs])], initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', OPSET)],
                              producer_name='robot_ai', doc_string='robot_ai physics.learn policy')
    model.ir_version = 8
    helper.set_model_props(model, {METADATA_KEY: json.dumps({'env_id': env_id, 'env_kwargs': env_kwargs,
                                                             **(info or {})})})
    onnx.checker.check_model(model)
    data = model.SerializeToString()
    return write_whole(path, lambda f: f.write(data))
