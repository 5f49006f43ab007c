"""A reach task's policy files: ARS's policies saved and loaded for an arm, and ONNX models that act on one. No rospy.

    path = save(training, '/tmp/reach.npz')
    policy, setup, note = load(path)                              # the arm and tip the file names
    policy, setup, note = load(path, ReachSetup(model=...))       # this arm: another robot or tip is refused
    policy, setup, note = load('sac.onnx', model='/path/arm.urdf') # an ONNX model, on the arm given

A policy file is the package's .npz of kind ars_linear (robot_ai.ars); its metadata names the env (env_id,
env_kwargs), the robot, its file's SHA-256, the tip and the joints in order: loading it for another robot or tip is
refused in one line naming both. ``import robot_ai.reach`` registers Reach-v0 and RosReach-v0 as envs a policy acts
in (robot_ai.policies.envs), so an ONNX model naming them is fitted to their spaces.
"""
from __future__ import annotations

import os

import numpy as np
from gymnasium import spaces

from robot_ai import policies
from robot_ai.policies import PolicyError, Target, register_env
from robot_ai.reach.arm import ReachError
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.learn import with_features

ENV_ID = 'robot_ai/Reach-v0'
REACH_ENVS = (ENV_ID, 'robot_ai/RosReach-v0')
ENV_SETTINGS = ('model', 'xacro_args', 'tip', 'control', 'start', 'distance_threshold', 'ee_step', 'damping', 'home',
                'limit_avoidance', 'obstacles', 'collision', 'goal', 'angle_threshold', 'angle_step', 'velocity_scale',
                'acceleration_scale', 'joint_limits', 'control_period', 'limit_recovery')


def save(training, path: str) -> str:
    """A learn.Training's best policy as a policy file at path, with its figures and the arm it learned on."""
    setup, result = training.setup, training.result
    figures = dict(training_steps=int(result.steps), iterations=len(result.history),
                   best_iteration=int(result.best_iteration), train_seconds=round(result.elapsed, 3))
    if training.held_out is not None:
        figures.update(success_rate=training.held_out.success_rate,
                       mean_final_distance=training.held_out.mean_distance, held_out_episodes=len(
                           training.held_out.distances))
    if training.p_controller is not None:
        figures['p_controller_success_rate'] = training.p_controller.success_rate
    return policies.save(path, training.policy, ENV_ID, training.seed, settings=result.settings.as_dict(),
                         figures=figures, source='ARS (python -m robot_ai.reach train)',
                         env_kwargs=training.env_kwargs, joints=list(setup.arm.joints),
                         robot=setup.model.tree.name, model=setup.model.name, model_sha256=setup.model.sha256,
                         training_steps=int(result.steps),
                         success_rate=training.held_out.success_rate if training.held_out else None)


def setup_of(policy, **overrides) -> ReachSetup:
    """The reach setup a policy file names (its env_kwargs), with overrides (another model file, say)."""
    given = {k: v for k, v in overrides.items() if v is not None}
    return _setup_of_kwargs(policy.metadata.get('env_kwargs', {}), given, policy.metadata.get('robot', ''))


def target(setup: ReachSetup, env_id: str = ENV_ID, env_kwargs: dict | None = None) -> Target:
    """setup's reach task as the env a policy acts in: its spaces, ARS's kind, and check_fits as the check."""
    return Target(env_id, dict(env_kwargs or {}), setup.observation_space, setup.action_space, ('ars_linear',),
                  check=lambda policy: check_fits(policy, setup), context=setup)


def _registered(env_id: str, env_kwargs: dict) -> Target:
    """Reach-v0 and RosReach-v0 by id (an ONNX model naming them): the arm of their model, tip and control."""
    keep = ('model', 'xacro_args', 'tip', 'control', 'urdf', 'goal', 'angle_threshold', 'angle_step')
    try:
        setup = ReachSetup(**{k: v for k, v in env_kwargs.items() if k in keep})
    except ReachError as e:
        raise PolicyError(f'its env {env_id}: {e}') from None
    return Target(env_id, env_kwargs, setup.observation_space, setup.action_space, ('ars_linear',), context=setup)


register_env(REACH_ENVS, _registered)


def check_fits(policy, setup: ReachSetup) -> str:
    """PolicyError (one line naming both) unless policy (a policy file's, or an ONNX model's) is a reach policy for
    setup's robot, tip, joints and spaces; returns a note ('' or a warning to show) when only the URDF's text
    differs, or when an ONNX model names no robot (its spaces fit, so it drives)."""
    m = policy.metadata
    where = policy.path or 'the policy'
    onnx = policy.kind == 'onnx'
    if (onnx and m.get('env_id') not in REACH_ENVS) or (not onnx and (policy.kind != 'ars_linear'
                                                                      or m.get('env_id') != ENV_ID)):
        raise PolicyError(f'{where} is a {policy.kind} policy for {m.get("env_id")}, not a reach policy ({ENV_ID})')
    arm = setup.arm
    robot = setup.model.tree.name
    kwargs = m.get('env_kwargs', {})
    learned = f'{m.get("robot") or "?"} ({m.get("model") or kwargs.get("model") or "?"}), tip {kwargs.get("tip")}'
    here = f'{robot} ({setup.model.name}), tip {arm.tip}'
    differs = [k for k, mine in (('robot', robot), ('joints', arm.joints)) if (k in m or not onnx) and m.get(k) != mine]
    if (kwargs.get('tip') or not onnx) and kwargs.get('tip') != arm.tip:
        differs.append('tip')
    if differs:
        raise PolicyError(f'{where} learned to reach with {learned} (joints {", ".join(m.get("joints", []))});'
                          f' this arm is {here} (joints {", ".join(arm.joints)})')
    control = kwargs.get('control', 'ee')
    if control != setup.control:
        raise PolicyError(f'{where} acts with control={control}; this env has control={setup.control}')
    goal = kwargs.get('goal', 'position')
    if goal != setup.task.goal:
        raise PolicyError(f'{where} learned {goal} goals; this env has goal={setup.task.goal} (a policy learns one '
                          f'kind: train another with goal={setup.task.goal})')
    inputs, actions = policy_sizes(policy)
    # an ONNX model takes the flattened observation; ARS's linear map takes it, or for pose goals its features
    # (learn.PoseFeatures): 9 + n either way
    want = int(spaces.flatdim(setup.observation_space)) if onnx else 9 + arm.n
    if inputs != want or actions != setup.action_space.shape[0]:
        raise PolicyError(f'{where} maps {inputs} observations to {actions} actions; this env has '
                          f'{want} and {setup.action_space.shape[0]}')
    if m.get('model_sha256') and m['model_sha256'] != setup.model.sha256:
        return (f'note: {setup.model.name} is not the URDF text {where} learned on ({m.get("model")}); same robot, '
                f'tip and joints, so it drives it')
    if onnx and 'robot' not in m:
        return (f'note: {where} names no robot (its metadata robot_ai_env has none); its input and output fit '
                f'{robot}\'s with tip {arm.tip}, so it drives it')
    return ''


def policy_sizes(policy) -> tuple[int, int]:
    """(observation size, action size) a reach policy takes and gives."""
    if policy.kind == 'onnx':
        return int(spaces.flatdim(policy.observation_space)), int(np.prod(policy.action_space.shape))
    actions, inputs = policy.actor.weights.shape
    return inputs, actions


def load(path: str, setup: ReachSetup | None = None, **overrides):
    """(the policy, its setup, a note) of a reach policy file (.npz) or ONNX model (.onnx): for setup's arm when
    given (refused in one line if it is another robot or tip), else for the env its metadata names with overrides
    (model=, xacro_args=, urdf=, tip=: setup_of). PolicyError or ReachError: one line."""
    given = {k: v for k, v in overrides.items() if v is not None}

    def choose(file) -> Target:
        if file.kind == 'onnx':
            return _onnx_target(file, setup, given)
        if file.kind != 'ars_linear':
            raise PolicyError(f'{file.path} is a {file.kind} policy for {file.env_id}, not a reach policy')
        chosen = setup
        if chosen is None:
            _require_model(file, file.env_kwargs, given)
            chosen = setup_of(file, **given)
        return target(chosen, ENV_ID, file.env_kwargs)

    policy = policies.load(path, choose)
    setup = policy.target.context
    if policy.kind == 'ars_linear':          # pose goals: the features its linear map acts on (learn.PoseFeatures)
        policy.actor = with_features(policy.actor, setup)
    return policy, setup, policy.note


def _onnx_target(file, setup: ReachSetup | None, given: dict) -> Target:
    """The target of an ONNX model: its metadata's env (Reach-v0 when it names none; without a model, the env's default
    robot, as gymnasium.make would make it), control from its metadata or else from its action size (3, or 6 for
    pose goals: ee, otherwise joints)."""
    env_id = file.env_id or ENV_ID
    if env_id not in REACH_ENVS:
        raise PolicyError(f'{file.path} acts in {env_id}, not a reach env ({", ".join(REACH_ENVS)})')
    kwargs = file.env_kwargs
    if 'control' not in kwargs and file.action_size() is not None:
        kwargs['control'] = 'ee' if file.action_size() == (6 if kwargs.get('goal') == 'pose' else 3) else 'joints'
    if setup is None:
        _require_model(file, kwargs, given)
        setup = _setup_of_kwargs(kwargs, given, file.info.get('robot', ''))
    elif kwargs.get('control', 'ee') != setup.control:
        raise PolicyError(f'{file.path} acts with control={kwargs.get("control", "ee")}; this env has '
                          f'control={setup.control}')
    return target(setup, env_id, kwargs)


def _require_model(file, kwargs: dict, given: dict) -> None:
    """PolicyError when the robot file a policy learned on is gone and the caller names no other."""
    model = kwargs.get('model')
    if model and not os.path.exists(model) and not any(given.get(k) for k in ('model', 'urdf')):
        raise PolicyError(f'{file.path} learned on {model}, which is not there any more: give the robot file with '
                          f'--model')


def _setup_of_kwargs(env_kwargs: dict, given: dict, learned_on: str = '') -> ReachSetup:
    """The setup of a policy's env kwargs with the caller's overrides; a robot file without the policy's tip is a
    PolicyError naming the robot the policy learned on (learned_on)."""
    kwargs = {k: v for k, v in env_kwargs.items() if k in ENV_SETTINGS}
    kwargs.setdefault('limit_avoidance', 0.0)     # a file from before the term learned without it
    kwargs.setdefault('limit_recovery', False)    # a file from before the recovery learned without it
    other_file = 'model' in given or 'urdf' in given
    if other_file:      # another robot file (or text): its own limits and sizes
        kwargs = {k: v for k, v in kwargs.items() if k not in ('model', 'xacro_args', 'home', 'ee_step', 'damping')}
    kwargs.update(given)
    try:
        return ReachSetup(**kwargs)
    except ReachError as e:
        if other_file and learned_on and 'tip' in kwargs and 'tip' not in given and 'is not a link' in str(e):
            raise PolicyError(f'the policy learned to reach with {learned_on}, tip {kwargs["tip"]}, a link '
                              f'this robot does not have ({e})') from None
        raise
