"""Push and pick-and-place without ROS: ``python -m robot_ai.physics <command> [options]`` (see --help).

    python -m robot_ai.physics train --task push --model /path/panda.urdf --minutes 10
    python -m robot_ai.physics evaluate ~/.ros/robot_ai/push-panda_..._seed0.npz      # or its .onnx
    python -m robot_ai.physics show ~/.ros/robot_ai/push-panda_..._seed0.onnx

train learns the task on the arm (robot_ai.physics.learn: DAgger of the scripted expert into a small network, many
MuJoCo worlds at once), a line per measured round, and writes the policy file (.npz), the same network as ONNX and
its CSV log side by side; it ends with the success rate over 200 fresh goals, beside the expert's on the same goals.
A first Ctrl-C stops after the round under way and keeps the best network so far; a second ends the run.
"""
from __future__ import annotations

import argparse
import re
import signal
import sys
import warnings

from robot_ai import artifacts
from robot_ai.cli import (command_parser, output_folder, positive_number, refuse, run_command, show_policy,
                          whole_number, write_or_say)
from robot_ai.physics import PhysicsError, policy_files
from robot_ai.physics.env import TASKS, ManipulationSetup, ManipulationVectorEnv
from robot_ai.physics.learn import FINAL_SEED, LearnSettings, Round, evaluate, expert_policy, learn
from robot_ai.policies import PolicyError
from robot_ai.reach.arm import ReachError
from robot_ai.text import percent

HELD_OUT = 200


def stem_name(setup: ManipulationSetup) -> str:
    robot = re.sub(r'[^A-Za-z0-9_.-]+', '_', setup.robot.tree.name or 'robot')[:60] or 'robot'
    return f'{setup.task.replace("_", "-")}-{robot}'


def train_parser(sub) -> None:
    d = LearnSettings()
    p = sub.add_parser('train', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='learn push or pick-and-place on an arm with a gripper: policy file, ONNX, CSV log',
                       description='DAgger of the scripted expert into a small network (robot_ai.physics.learn) on '
                       'robot_ai/Push-v0 or robot_ai/PickAndPlace-v0, then the success rate over '
                       f'{HELD_OUT} fresh goals beside the expert\'s.')
    p.add_argument('--task', default='push', choices=TASKS)
    p.add_argument('--model', required=True, metavar='FILE',
                   help='the arm with a gripper: a URDF or xacro file ($(find pkg) through ROS_PACKAGE_PATH)')
    p.add_argument('--xacro-args', default='', metavar='ARGS', help='the xacro file\'s arguments: "name:=value ..."')
    p.add_argument('--tip', default=None, help='the link the gripper hangs from; default: the arm\'s end')
    p.add_argument('--minutes', type=positive_number, default=d.minutes, help='the wall-clock budget')
    p.add_argument('--target', type=float, default=d.target,
                   help='stop once the held-out success rate reaches this (1 or more: use the whole budget)')
    p.add_argument('--worlds', type=whole_number(1, 4096), default=d.worlds, help='MuJoCo worlds stepped at once')
    p.add_argument('--seed', type=int, default=0, help='random seed; the same seed gives the same network')
    p.add_argument('--output-dir', default=artifacts.default_output_dir())
    p.set_defaults(run=run_train)


def noted(build):
    """build()'s result, the warnings it gave (a setup's notes: what of the task the arm cannot do) printed to
    stderr as 'note: ...' lines, without the warning's source line."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', UserWarning)
        made = build()
    for w in caught:
        if issubclass(w.category, UserWarning):
            print(f'note: {w.message}', file=sys.stderr)
        else:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return made


def run_train(a, parser) -> int:
    try:
        setup = noted(lambda: ManipulationSetup(a.task, model=a.model, xacro_args=a.xacro_args or None, tip=a.tip))
    except (ReachError, PhysicsError, ValueError) as e:
        refuse(parser, str(e))
    folder = output_folder(a, parser)
    settings = LearnSettings(minutes=a.minutes, worlds=a.worlds, target=a.target if a.target < 1 else None)
    space = setup.space
    print(f'robot             {setup.robot.tree.name}: {setup.arm.n} joints to {setup.arm.tip}, gripper '
          f'{", ".join(setup.gripper)}')
    print(f'task              {policy_files.ENV_IDS[setup.task]}: a {setup.object_size:g} m cube on a table at '
          f'z {space.table_top:.3f}, within {setup.distance_threshold:g} m of the goal in 50 steps')
    print(f'DAgger            {settings.worlds} worlds, a {" x ".join(map(str, settings.hidden))} network, '
          f'{settings.minutes:g} minutes at most, seed {a.seed}')
    stop = {'asked': False}

    def on_sigint(signum, frame):
        if stop['asked']:
            raise KeyboardInterrupt
        stop['asked'] = True
        print('\nstopping after this round (Ctrl-C again to end now): the best network so far is kept',
              file=sys.stderr)

    def progress(r: Round) -> None:
        if r.eval_success is not None:
            print(f'round {r.round:5d}  held-out success {percent(r.eval_success):>7s}  samples {r.samples:9,d}  '
                  f'loss {r.loss:.4f}  {r.seconds:7.1f} s', flush=True)
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        training = learn(setup, settings, a.seed, on_round=progress, should_stop=lambda: stop['asked'])
    finally:
        signal.signal(signal.SIGINT, previous)
    env = ManipulationVectorEnv(settings.worlds, setup.task, setup=setup)
    held = evaluate(training.net.act_batch, env, HELD_OUT, FINAL_SEED)
    expert = evaluate(expert_policy(setup), env, HELD_OUT, FINAL_SEED)
    print(f'held-out          {percent(held[0])} of {HELD_OUT} fresh goals (mean final distance {held[1]:.3f} m), '
          f'the network of round {training.best_round}')
    print(f'expert            {percent(expert[0])} of the same goals (the scripted expert it learned from)')
    print(f'training          {len(training.history)} rounds, {training.steps:,} steps, {training.elapsed:.1f} s'
          f'{" (stopped early: best so far kept)" if stop["asked"] else ""}')
    stem = artifacts.artifact_stem(folder, stem_name(setup), policy_files.ENV_IDS[setup.task].split('/')[-1], a.seed)
    write_or_say('policy', lambda: policy_files.save(training, stem + '.npz', held_out=(*held, HELD_OUT)))
    write_or_say('onnx', lambda: policy_files.export_onnx(
        training.net, stem + '.onnx', policy_files.ENV_IDS[setup.task], policy_files.env_kwargs_of(setup),
        {'robot': setup.robot.tree.name, 'model_sha256': setup.robot.sha256, 'success_rate': held[0]}))
    write_or_say('log', lambda: artifacts.write_csv(stem + '.csv', list(Round.__dataclass_fields__), [
        [r.round, f'{r.seconds:.3f}', r.samples, repr(r.loss), repr(r.rollout_success),
         '' if r.eval_success is None else repr(r.eval_success)] for r in training.history]))
    return 0 if not stop['asked'] else 1


def evaluate_parser(sub) -> None:
    p = sub.add_parser('evaluate', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='a policy file or ONNX model on fresh goals: its success rate, beside the expert\'s')
    p.add_argument('policy', help='a policy file (.npz) from train, or an ONNX model naming Push-v0 or '
                   'PickAndPlace-v0 in its metadata')
    p.add_argument('--model', default=None, metavar='FILE', help='the robot file (default: the one the policy names)')
    p.add_argument('--episodes', type=whole_number(1, 100000), default=HELD_OUT)
    p.add_argument('--seed', type=int, default=FINAL_SEED, help='seed of the first goal (goal i: seed + i)')
    p.set_defaults(run=run_evaluate)


def run_evaluate(a, parser) -> int:
    try:
        policy, setup = noted(lambda: policy_files.load(a.policy, model=a.model))
    except PolicyError as e:
        refuse(parser, str(e))
    if policy.note:
        print(f'note: {policy.note}', file=sys.stderr)
    env = ManipulationVectorEnv(min(32, a.episodes), setup.task, setup=setup)
    success, distance = evaluate(policy.act_batch, env, a.episodes, a.seed)
    expert = evaluate(expert_policy(setup), env, a.episodes, a.seed)
    print(f'policy            {a.policy}')
    print(f'success           {percent(success)} of {a.episodes} goals (mean final distance {distance:.3f} m)')
    print(f'expert            {percent(expert[0])} of the same goals')
    return 0


def show_parser(sub) -> None:
    p = sub.add_parser('show', help='a policy file\'s metadata and arrays, or an ONNX model\'s summary')
    p.add_argument('policy')
    p.set_defaults(run=lambda a, parser: show_policy(a.policy, parser))


def world_parser(sub) -> None:
    p = sub.add_parser('world', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the pick-and-place task\'s table, cubes and ready configuration as YAML, for arm_sim and '
                       'pick_place (pick.launch world:=)',
                       description='The table the task lays out under the arm (robot_ai.physics.workspace), cubes on '
                       'it and the ready configuration (home: arm_sim\'s start), one YAML that arm_sim\'s and '
                       'pick_place\'s ~obstacles, ~objects and ~home take (rosparam load).')
    p.add_argument('--model', required=True, metavar='FILE',
                   help='the arm with a gripper: a URDF or xacro file ($(find pkg) through ROS_PACKAGE_PATH)')
    p.add_argument('--xacro-args', default='', metavar='ARGS', help='the xacro file\'s arguments: "name:=value ..."')
    p.add_argument('--tip', default=None, help='the link the gripper hangs from; default: the arm\'s end')
    p.add_argument('--cubes', type=whole_number(0, 20), default=2, help='cubes on the table')
    p.add_argument('--seed', type=int, default=0, help='where the cubes lie')
    p.add_argument('--output', default='', metavar='FILE', help='write it there (default: print it)')
    p.set_defaults(run=run_world)


def run_world(a, parser) -> int:
    import yaml
    from robot_ai.physics.pick import PickError, PickPlace, world
    try:
        setup = noted(lambda: ManipulationSetup('pick_and_place', model=a.model, xacro_args=a.xacro_args or None,
                                                tip=a.tip))
        ready = PickPlace(setup, obstacles=[setup.table()]).ready      # clear of the safety layer's body
        made = world(setup, a.cubes, a.seed, ready)
    except (ReachError, PhysicsError, PickError) as e:
        refuse(parser, str(e))
    text = (f'# python -m robot_ai.physics world --model {a.model}: the pick-and-place task of '
            f'{setup.robot.tree.name} (tip {setup.arm.tip})\n' + yaml.safe_dump(made, sort_keys=False,
                                                                               default_flow_style=None))
    if not a.output:
        print(text, end='')
        return 0
    artifacts.write_whole(a.output, lambda f: f.write(text.encode()))
    print(a.output)
    return 0


def build_parser():
    parser, sub = command_parser('python -m robot_ai.physics', 'Push and pick-and-place in MuJoCo on any arm with '
                                 'a gripper, learned in minutes (robot_ai/Push-v0, robot_ai/PickAndPlace-v0).')
    train_parser(sub)
    evaluate_parser(sub)
    show_parser(sub)
    world_parser(sub)
    return parser, sub


def main(argv=None) -> int:
    parser, sub = build_parser()
    return run_command(parser, sub, argv)


if __name__ == '__main__':
    sys.exit(main())
