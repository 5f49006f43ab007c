"""Small ONNX models for the tests, built with onnx.helper (no torch): linear policies whose actions a numpy line
reproduces, and broken or hostile files the loader must refuse."""
from __future__ import annotations

import json

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def model(nodes, inputs, outputs, initializers=(), env: dict | None = None, opset=OPSET, domains=()) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, 'policy', inputs, outputs, list(initializers))
    opsets = [helper.make_opsetid('', opset)] + [helper.make_opsetid(d, 1) for d in domains]
    m = helper.make_model(graph, opset_imports=opsets, producer_name='robot_ai tests')
    m.ir_version = 8
    if env is not None:
        helper.set_model_props(m, {'robot_ai_env': json.dumps(env)})
    return m


def tensor(name, elem, shape):
    return helper.make_tensor_value_info(name, elem, shape)


def cartpole_scores(weights: np.ndarray, env=None) -> onnx.ModelProto:
    """Scores (batch, 2) = (0, observation . weights): argmax pushes right exactly when the course's linear policy
    does (weights . state > 0)."""
    w = np.zeros((4, 2), np.float32)
    w[:, 1] = weights
    return model([helper.make_node('MatMul', ['obs', 'W'], ['scores'])],
                 [tensor('obs', TensorProto.FLOAT, ['batch', 4])], [tensor('scores', TensorProto.FLOAT, ['batch', 2])],
                 [numpy_helper.from_array(w, 'W')], env if env is not None else {'env_id': 'CartPole-v1'})


def cartpole_integer(weights: np.ndarray, env=None) -> onnx.ModelProto:
    """The same policy as an integer action (batch,) int64, as stable-baselines3's PPO exports it."""
    w = np.zeros((4, 2), np.float32)
    w[:, 1] = weights
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['scores']),
             helper.make_node('ArgMax', ['scores'], ['action'], axis=1, keepdims=0)]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                 [tensor('action', TensorProto.INT64, ['batch'])], [numpy_helper.from_array(w, 'W')],
                 env if env is not None else {'env_id': 'CartPole-v1'})


def linear_tanh(weights: np.ndarray, bias: np.ndarray, env=None) -> onnx.ModelProto:
    """Box actions tanh(observation @ weights + bias): (batch, in) -> (batch, out)."""
    n_in, n_out = weights.shape
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['xw']), helper.make_node('Add', ['xw', 'b'], ['z']),
             helper.make_node('Tanh', ['z'], ['action'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', n_in])],
                 [tensor('action', TensorProto.FLOAT, ['batch', n_out])],
                 [numpy_helper.from_array(weights.astype(np.float32), 'W'),
                  numpy_helper.from_array(bias.astype(np.float32), 'b')], env)


def save(m: onnx.ModelProto, path: str) -> str:
    with open(path, 'wb') as f:
        f.write(m.SerializeToString())
    return path


def linear_clip(weights: np.ndarray, env=None) -> onnx.ModelProto:
    """Box actions clip(observation @ weights, -1, 1): (batch, in) -> (batch, out)."""
    n_in, n_out = weights.shape
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['z']), helper.make_node('Clip', ['z', 'lo', 'hi'], ['action'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', n_in])],
                 [tensor('action', TensorProto.FLOAT, ['batch', n_out])],
                 [numpy_helper.from_array(weights.astype(np.float32), 'W'),
                  numpy_helper.from_array(np.array(-1, np.float32), 'lo'),
                  numpy_helper.from_array(np.array(1, np.float32), 'hi')], env)


def linear_nan_past(weights: np.ndarray, bound: float, env=None) -> onnx.ModelProto:
    """linear_clip's actions, NaN for observations whose squared norm is over bound: a reach arm from random starts
    (its joints anywhere in their ranges), and none of the loader's trial observations when bound is well over their
    dimension (standard normal numbers). A model that passes the checks at load and answers NaN for some goals."""
    n_in, n_out = weights.shape
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['z']), helper.make_node('Clip', ['z', 'lo', 'hi'], ['clipped']),
             helper.make_node('ReduceSumSquare', ['obs'], ['norm'], keepdims=1, axes=[1]),
             helper.make_node('Sub', ['bound', 'norm'], ['room']), helper.make_node('Sqrt', ['room'], ['root']),
             helper.make_node('Mul', ['root', 'zero'], ['nan_or_zero']),
             helper.make_node('Add', ['clipped', 'nan_or_zero'], ['action'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', n_in])],
                 [tensor('action', TensorProto.FLOAT, ['batch', n_out])],
                 [numpy_helper.from_array(weights.astype(np.float32), 'W'),
                  numpy_helper.from_array(np.array(-1, np.float32), 'lo'),
                  numpy_helper.from_array(np.array(1, np.float32), 'hi'),
                  numpy_helper.from_array(np.array(bound, np.float32), 'bound'),
                  numpy_helper.from_array(np.array(0, np.float32), 'zero')], env)


def reach_nan_where_x_is_positive(weights: np.ndarray, env=None) -> onnx.ModelProto:
    """A reach policy (achieved goal, desired goal, joints and tip, flattened: the tip again at 13:16) with
    linear_clip's actions, NaN for every real state whose goal has x > 0.01 and for no trial observation: NaN where
    sqrt(|achieved_x - tip_x| + 1000 relu(0.01 - goal_x) - 1e-3) is, and the achieved goal is the tip only in a real
    state (the loader's trial observations are zeros, where goal_x is 0, and independent normal numbers)."""
    n_in, n_out = weights.shape

    def column(name, k):
        return helper.make_node('Slice', ['obs', f's{k}', f'e{k}', 'axis'], [name])

    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['z']), helper.make_node('Clip', ['z', 'lo', 'hi'], ['clipped']),
             column('achieved_x', 0), column('tip_x', 13), column('goal_x', 3),
             helper.make_node('Sub', ['achieved_x', 'tip_x'], ['d']), helper.make_node('Abs', ['d'], ['gap']),
             helper.make_node('Sub', ['east', 'goal_x'], ['minus_x']), helper.make_node('Relu', ['minus_x'], ['west']),
             helper.make_node('Mul', ['west', 'big'], ['far']), helper.make_node('Add', ['gap', 'far'], ['room']),
             helper.make_node('Sub', ['room', 'eps'], ['signed']), helper.make_node('Sqrt', ['signed'], ['root']),
             helper.make_node('Mul', ['root', 'zero'], ['nan_or_zero']),
             helper.make_node('Add', ['clipped', 'nan_or_zero'], ['action'])]
    constants = [numpy_helper.from_array(np.array([k], np.int64), f's{k}') for k in (0, 3, 13)]
    constants += [numpy_helper.from_array(np.array([k + 1], np.int64), f'e{k}') for k in (0, 3, 13)]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', n_in])],
                 [tensor('action', TensorProto.FLOAT, ['batch', n_out])],
                 [numpy_helper.from_array(weights.astype(np.float32), 'W'),
                  numpy_helper.from_array(np.array(-1, np.float32), 'lo'),
                  numpy_helper.from_array(np.array(1, np.float32), 'hi'),
                  numpy_helper.from_array(np.array([1], np.int64), 'axis'),
                  numpy_helper.from_array(np.array(1000, np.float32), 'big'),
                  numpy_helper.from_array(np.array(0.01, np.float32), 'east'),
                  numpy_helper.from_array(np.array(1e-3, np.float32), 'eps'),
                  numpy_helper.from_array(np.array(0, np.float32), 'zero')] + constants, env)


def cartpole_seven_on_real_states(weights: np.ndarray) -> onnx.ModelProto:
    """The course's policy as an integer action (cartpole_integer), except action 7 for states whose every number is
    in (-0.1, 0.1) and not 0: every CartPole start state, and none of the loader's trial observations (zeros, and
    standard normal numbers). A model that passes the checks at load and acts wrongly on every real state."""
    w = np.zeros((4, 2), np.float32)
    w[:, 1] = weights
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['scores']),
             helper.make_node('ArgMax', ['scores'], ['good'], axis=1, keepdims=0),
             helper.make_node('Abs', ['obs'], ['size']),
             helper.make_node('Less', ['size', 'small'], ['below']),
             helper.make_node('Greater', ['size', 'zero'], ['above']),
             helper.make_node('And', ['below', 'above'], ['inside']),
             helper.make_node('Cast', ['inside'], ['inside_f'], to=TensorProto.FLOAT),
             helper.make_node('ReduceMin', ['inside_f'], ['all_inside'], axes=[1], keepdims=0),
             helper.make_node('Cast', ['all_inside'], ['real'], to=TensorProto.BOOL),
             helper.make_node('Where', ['real', 'seven', 'good'], ['action'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                 [tensor('action', TensorProto.INT64, ['batch'])],
                 [numpy_helper.from_array(w, 'W'), numpy_helper.from_array(np.array(0.1, np.float32), 'small'),
                  numpy_helper.from_array(np.array(0.0, np.float32), 'zero'),
                  numpy_helper.from_array(np.array(7, np.int64), 'seven')], {'env_id': 'CartPole-v1'})


def cartpole_three_scores(weights: np.ndarray) -> onnx.ModelProto:
    """Scores declared (batch, 2) that come out as (batch, 3): (0, observation . weights, 1000), whose argmax would
    always be action 2."""
    w = np.zeros((4, 3), np.float32)
    w[:, 1] = weights
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['raw']), helper.make_node('Add', ['raw', 'shift'], ['scores'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                 [tensor('scores', TensorProto.FLOAT, ['batch', 2])],
                 [numpy_helper.from_array(w, 'W'), numpy_helper.from_array(np.array([0, 0, 1000], np.float32),
                                                                            'shift')], {'env_id': 'CartPole-v1'})


def cartpole_endless_loop(weights: np.ndarray) -> onnx.ModelProto:
    """The course's scores through a Loop of 2**40 iterations that pass them on unchanged: days to answer."""
    w = np.zeros((4, 2), np.float32)
    w[:, 1] = weights
    body = helper.make_graph([helper.make_node('Identity', ['cond_in'], ['cond_out']),
                              helper.make_node('Identity', ['v_in'], ['v_out'])], 'body',
                             [tensor('i', TensorProto.INT64, []), tensor('cond_in', TensorProto.BOOL, []),
                              tensor('v_in', TensorProto.FLOAT, ['batch', 2])],
                             [tensor('cond_out', TensorProto.BOOL, []),
                              tensor('v_out', TensorProto.FLOAT, ['batch', 2])])
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['raw']),
             helper.make_node('Loop', ['trips', 'go', 'raw'], ['scores'], body=body)]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                 [tensor('scores', TensorProto.FLOAT, ['batch', 2])],
                 [numpy_helper.from_array(w, 'W'), numpy_helper.from_array(np.array(2 ** 40, np.int64), 'trips'),
                  numpy_helper.from_array(np.array(True), 'go')], {'env_id': 'CartPole-v1'})


def cartpole_gigabytes(weights: np.ndarray) -> onnx.ModelProto:
    """The course's scores plus the sum of one zero expanded to 800 million numbers: a small file, 3.2 GB to run."""
    w = np.zeros((4, 2), np.float32)
    w[:, 1] = weights
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['raw']),
             helper.make_node('Expand', ['nothing', 'many'], ['big']),
             helper.make_node('ReduceSum', ['big'], ['sum'], keepdims=0),
             helper.make_node('Add', ['raw', 'sum'], ['scores'])]
    return model(nodes, [tensor('obs', TensorProto.FLOAT, ['batch', 4])],
                 [tensor('scores', TensorProto.FLOAT, ['batch', 2])],
                 [numpy_helper.from_array(w, 'W'), numpy_helper.from_array(np.array(0.0, np.float32), 'nothing'),
                  numpy_helper.from_array(np.array([800_000_000], np.int64), 'many')], {'env_id': 'CartPole-v1'})
