"""Reach without ROS: ``python -m robot_ai.reach <command> [options]`` (see --help).

    python -m robot_ai.reach train --model /path/arm.urdf.xacro --xacro-args "hand:=true" --tip tool0 --video
    python -m robot_ai.reach evaluate ~/.ros/robot_ai/reach_..._seed0.npz --start chained --video
    python -m robot_ai.reach show ~/.ros/robot_ai/reach_..._seed0.npz

train runs ARS (robot_ai.ars) on the arm's reach task, a line per iteration, and writes the policy file (.npz), its
CSV log and its learning curve side by side; it ends with the success rate over 1000 fresh goals, beside the plain
P-controller's on the same goals. A first Ctrl-C stops after the iteration under way and keeps the best policy so
far; a second ends the run.
"""
from __future__ import annotations

import argparse
import re
import signal
import sys
from dataclasses import replace

import numpy as np

from robot_ai import ars, artifacts
from robot_ai import policies
from robot_ai.cli import (add_ray, command_parser, connect_ray, fraction, fraction_above_0, output_folder,
                          positive_number, refuse, run_command, show_policy, whole_number, write_or_say)
from robot_ai.reach import learn, policy_files
from robot_ai.reach.arm import ReachError
from robot_ai.motion.planner import DEFAULT_TIME_LIMIT
from robot_ai.reach.env import CONTROLS, STARTS, ReachSetup
from robot_ai.reach.safety import DEFAULT_MARGIN, DEFAULT_VELOCITY_SCALE
from robot_ai.reach.task import ANGLE_THRESHOLD, GOALS
from robot_ai.text import percent


def add_robot(p: argparse.ArgumentParser, required_default: str) -> None:
    p.add_argument('--model', default=None, metavar='FILE',
                   help=f'a URDF or xacro file ($(find pkg) through ROS_PACKAGE_PATH); {required_default}')
    p.add_argument('--xacro-args', default='', metavar='ARGS',
                   help='the xacro file\'s arguments: "name:=value name2:=value2" (name=value too)')


def train_parser(sub) -> None:
    d = learn.SETTINGS
    p = sub.add_parser('train', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='ARS learns the arm\'s reach task: policy file, CSV log, plot, held-out success rate',
                       description='Augmented Random Search (Mania et al. 2018) of a linear policy on the reach task '
                       'of any arm (robot_ai/Reach-v0), then the success rate over 1000 fresh goals beside the plain '
                       'P-controller\'s.')
    add_robot(p, 'default: the package\'s UR5')
    p.add_argument('--tip', default=None, help='the link that reaches; default: the arm\'s end (tool0, a TCP, a '
                   'flange, ...; not a finger)')
    p.add_argument('--control', default='ee', choices=CONTROLS,
                   help='ee: tip displacements (damped least squares); joints: joint displacements')
    p.add_argument('--start', default='home', choices=STARTS, help='where each episode starts: home (mid-range), '
                   'random configurations, or chained (where the last episode left the arm)')
    p.add_argument('--goal', default='position', choices=GOALS, help='position: the tip\'s position; pose: its '
                   'position and orientation (within --angle-threshold too)')
    p.add_argument('--angle-threshold', type=positive_number, default=ANGLE_THRESHOLD,
                   help='pose goals: radians within which the orientation is reached')
    add_world(p)
    add_home(p, '; default: the middle of every joint\'s range')
    add_layer(p)
    p.add_argument('--seed', type=int, default=0, help='random seed; the same seed gives the same policy')
    p.add_argument('--iterations', type=whole_number(1, 100000), default=None,
                   help=f'ARS iterations; default {d.iterations} x (ee_step / 0.05 m) ** 0.3, at least {d.iterations} '
                   '(a large arm needs finer weights)')
    p.add_argument('--directions', type=whole_number(1, 4096), default=d.directions,
                   help='N: directions per iteration')
    p.add_argument('--top-directions', type=whole_number(1, 4096), default=d.top_directions,
                   help='b: the best directions kept (at most N)')
    p.add_argument('--step-size', type=positive_number, default=d.step_size, help='alpha')
    p.add_argument('--noise', type=positive_number, default=d.noise, help='nu')
    p.add_argument('--episodes', type=whole_number(1, 4096), default=d.episodes,
                   help='goals per direction and sign in an iteration (the same for every direction)')
    p.add_argument('--target-success', type=fraction, default=None,
                   help='stop once an iteration\'s evaluation (256 goals) reaches this success rate')
    p.add_argument('--video', action='store_true', help='also write an mp4 of the arm reaching 3 fresh goals')
    p.add_argument('--output-dir', default=artifacts.default_output_dir(),
                   help='where the policy, the CSV log, the plot and the video go')
    add_ray(p, 'the rollouts of every iteration, in --chunks envs kept by actors,')
    p.add_argument('--chunks', type=whole_number(0, 4096), default=0,
                   help='envs the rollouts are split into (0: one here, one per CPU of the cluster with --ray); from '
                   'home or random starts any chunks give the same numbers')
    p.set_defaults(run=run_train)


def add_world(p: argparse.ArgumentParser, default: str = '') -> None:
    p.add_argument('--obstacles', default=None, metavar='FILE',
                   help='a YAML file of obstacles in the arm\'s base frame ({box: [sx, sy, sz], position: [x, y, z], '
                   'rpy: [r, p, y]} or {sphere: r, position: [x, y, z]} each); the arm\'s body is checked against '
                   'them and itself' + default)
    p.add_argument('--collision', action='store_true', default=None,
                   help='check the arm\'s body (its URDF <collision> geometry) against itself, without obstacles too')


def add_home(p: argparse.ArgumentParser, default: str = '') -> None:
    p.add_argument('--home', nargs='+', default=None, metavar='Q',
                   help='the arm\'s home: a joint position per joint in the arm\'s order, or name=value pairs (the '
                   'others mid-range); a home in contact with the arm\'s body or the obstacles is refused' + default)


def home(a, parser) -> dict:
    """--home as an env kwarg (joint_positions'); none given: none."""
    return {} if a.home is None else {'home': joint_positions(a.home, '--home', parser)}


def joint_positions(tokens: list[str], flag: str, parser) -> list[float] | dict[str, float]:
    """A configuration given on the command line: numbers in the arm's order, or name=value pairs ({joint: value})."""
    try:
        if all('=' in token for token in tokens):
            return {name: float(value) for name, _, value in (t.partition('=') for t in tokens)}
        return [float(token) for token in tokens]
    except ValueError:
        refuse(parser, f'{flag} must be numbers, or name=value pairs, got {" ".join(tokens)}')


def add_layer(p: argparse.ArgumentParser, default: str = '') -> None:
    p.add_argument('--velocity-scale', type=fraction_above_0, default=None, metavar='SCALE',
                   help='the arm moves as reach_controller\'s safety layer moves it at this ~velocity_scale, one '
                   'control period (0.05 s) per step, and episodes are as long in time (200 steps / SCALE); '
                   'without it, each step\'s joints are reached at once' + default)
    p.add_argument('--joint-limits', default=None, metavar='FILE',
                   help='with --velocity-scale: a MoveIt joint_limits.yaml that narrows the URDF\'s velocities and '
                   'gives the accelerations, as reach_controller\'s ~joint_limits')


def layer(a) -> dict:
    """--velocity-scale and --joint-limits as env kwargs (none given: none, so that a policy file's own stand)."""
    out = {}
    if a.velocity_scale is not None:
        out['velocity_scale'] = a.velocity_scale
    if a.joint_limits is not None:
        out['joint_limits'] = a.joint_limits
    return out


def describe_layer(setup: ReachSetup) -> str:
    return (f'through reach_controller\'s safety layer: {setup.limits.describe()}, a step of '
            f'{setup.control_period:g} s, {setup.episode_steps} steps an episode')


def describe_world(setup: ReachSetup) -> str:
    body = setup.body
    names = ', '.join(o.name for o in setup.obstacles[:8]) or 'no obstacles'
    if len(setup.obstacles) > 8:
        names += f' and {len(setup.obstacles) - 8} more'
    text = (f'{names}; the arm\'s body: {len(body.radii)} spheres on {len(body.links)} links, {len(body.link_pairs)} '
            f'link pairs checked')
    if body.stand_ins:
        text += (f' ({len(body.missing)} collision meshes not on this machine: {", ".join(body.stand_ins)} stood in '
                 f'for by capsules)')
    if body.beyond:
        text += f'; {body.beyond} obstacles beyond the arm\'s reach ({body.reach():.2f} m) left out of the checks'
    return text


def world(a) -> dict:
    """--obstacles and --collision as env kwargs (none given: none, so that a policy file's own stand)."""
    out = {}
    if a.obstacles is not None:
        out['obstacles'] = a.obstacles
    if a.collision:
        out['collision'] = True
    return out


def played_as(setup: ReachSetup, named: dict) -> str:
    """How the env plays the policy beyond its own actions (the limit-avoidance term, the recovery from joint limits
    and blocked steps), and where that comes from: a file whose metadata names neither (an ONNX model exported by
    another library, a file from before them) is played without them, which this says (issue 57: a SAC model reached
    1.6 % from random starts beside the P-controller's 88 %, with nothing saying why)."""
    text = (f'control {setup.control}, limit avoidance {setup.limit_avoidance:g}, recovery from joint limits and '
            f'blocked steps {"on" if setup.limit_recovery else "off"}')
    unnamed = [k for k in ('limit_avoidance', 'limit_recovery') if k not in named]
    if unnamed:
        text += (f' (the policy\'s metadata names no {" nor ".join(unnamed)}: played without, as it was presumably '
                 f'trained; a model that learned with them: give them in its robot_ai_env metadata\'s env_kwargs)')
    return text


def within(setup: ReachSetup) -> str:
    """The task's thresholds in words: '0.05 m', or '0.05 m and 0.1 rad' for pose goals."""
    task = setup.task
    return f'{task.distance_threshold:g} m' + (f' and {task.angle_threshold:g} rad' if setup.pose else '')


def stem_name(setup: ReachSetup) -> str:
    """The robot's name as a file name's part."""
    return 'reach-' + (re.sub(r'[^A-Za-z0-9_.-]+', '_', setup.model.tree.name or 'robot')[:60] or 'robot')


def run_train(a, parser) -> int:
    if a.top_directions > a.directions:
        parser.error(f'--top-directions ({a.top_directions}) must be at most --directions ({a.directions})')
    connect_ray(parser, a.ray)
    kwargs = dict(model=a.model, xacro_args=a.xacro_args or None, tip=a.tip, control=a.control, start=a.start,
                  **world(a), **home(a, parser), **layer(a))
    if a.goal == 'pose':          # position goals: no such settings (a file as before)
        kwargs.update(goal='pose', angle_threshold=a.angle_threshold)
    try:
        setup = ReachSetup(**kwargs)
    except ReachError as e:
        refuse(parser, str(e))
    for warning in setup.arm.warnings:
        print(f'warning: {warning}', file=sys.stderr)
    folder = output_folder(a, parser)
    settings = replace(learn.default_settings(setup), directions=a.directions,
                       top_directions=a.top_directions, step_size=a.step_size, noise=a.noise, episodes=a.episodes)
    if a.iterations:
        settings = replace(settings, iterations=a.iterations)
    print(f'robot             {setup.arm.describe()}')
    if setup.body is not None:
        print(f'world             {describe_world(setup)}')
    where = dict(home='home', random='random starts', chained='where the last goal left the arm')[a.start]
    print(f'task              reach within {within(setup)} in {setup.episode_steps} steps from {where}, control '
          f'{a.control} (ee_step {setup.ee_step:.3f} m)')
    if setup.limits is not None:
        print(f'motion            {describe_layer(setup)}')
    print(f'ARS               {settings.directions} directions, top {settings.top_directions}, step '
          f'{settings.step_size:g}, noise {settings.noise:g}, {settings.episodes} goals each, seed {a.seed}')
    stop = {'asked': False}

    def on_sigint(signum, frame):
        if stop['asked']:
            raise KeyboardInterrupt
        stop['asked'] = True
        print('\nstopping after this iteration (Ctrl-C again to end now): the best policy so far is kept',
              file=sys.stderr)

    def progress(s: ars.IterationStats) -> None:
        print(f'iteration {s.iteration:4d}/{settings.iterations}  success {percent(s.success_rate):>7s}  final '
              f'distance {s.final_metric:.3f} m  steps {s.steps:11,d}  {s.elapsed:6.1f} s', flush=True)
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        training = learn.train(kwargs, settings, a.seed, progress=progress, should_stop=lambda: stop['asked'],
                               target_success=a.target_success, chunks=a.chunks, ray_address=a.ray)
    finally:
        signal.signal(signal.SIGINT, previous)
    result, held = training.result, training.held_out
    print(f'held-out          {percent(held.success_rate)} of {len(held.distances)} fresh goals within '
          f'{within(setup)} (mean final distance {held.mean_distance:.3f} m), the policy of '
          f'iteration {result.best_iteration}')
    if training.p_controller is not None:
        print(f'P-controller      {percent(training.p_controller.success_rate)} of the same goals (the plain '
              f'P-controller on the tip error)')
    print(f'training          {len(result.history)} iterations, {result.steps:,} steps, {result.elapsed:.1f} s'
          f'{" (stopped early: best so far kept)" if result.cancelled else ""}')
    stem = artifacts.artifact_stem(folder, stem_name(setup), 'Reach-v0', a.seed)
    write_or_say('policy', lambda: policy_files.save(training, stem + '.npz'))
    write_or_say('log', lambda: artifacts.write_csv(stem + '.csv', *ars.history_log(result, settings)))
    write_or_say('plot', lambda: artifacts.write_plot(plot_job(training), stem + '.png'))
    if a.video:
        write_or_say('video', lambda: learn.record_video(result.policy, setup, stem + '.mp4'))
    return 0 if not result.cancelled else 1


def plot_job(training: learn.Training) -> dict:
    """The learning curve: each iteration's success rate on its 256 evaluation goals, the held-out rate, the
    P-controller's."""
    result, setup = training.result, training.setup
    x = [h.steps / 1e6 for h in result.history]
    hlines = [dict(y=95.0, label='95 %', color='tab:gray', ls=':')]
    if training.p_controller is not None:
        hlines.append(dict(y=100 * training.p_controller.success_rate, color='tab:green', ls='--',
                           label=f'P-controller, {"pose" if setup.pose else "tip"} error '
                                 f'({percent(training.p_controller.success_rate)})'))
    if training.held_out is not None:
        hlines.append(dict(y=100 * training.held_out.success_rate, color='tab:red', ls='--',
                           label=f'ARS held-out, {len(training.held_out.distances)} goals '
                                 f'({percent(training.held_out.success_rate)})'))
    layer = '' if setup.limits is None else f' through the safety layer x{setup.limits.velocity_scale:g}'
    world = f' among {len(setup.obstacles)} obstacle{"s" if len(setup.obstacles) > 1 else ""}' if setup.obstacles \
        else ''
    return dict(title=f'Reach with ARS: {setup.model.tree.name} ({setup.model.name}), tip {setup.arm.tip}, '
                      f'{setup.control} control{layer}{world}, seed {result.seed}: {result.elapsed:.1f} s',
                xlabel='training steps (millions)', ylabel='goals reached within '
                f'{within(setup)} (%)',
                series=[dict(x=x, y=[100 * h.success_rate for h in result.history], style='line', color='tab:blue',
                             lw=2, label='each iteration, 256 fresh goals'
                             + (', no recovery' if setup.limit_recovery else ''))],
                hlines=hlines, ylim=[0, 105])


def evaluate_parser(sub) -> None:
    p = sub.add_parser('evaluate', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the success rate of a reach policy file over fresh goals',
                       description='Play a reach policy file on fresh goals of the arm it learned on (or of --model, '
                       'the same robot) and print its success rate beside the P-controller\'s.')
    p.add_argument('policy', help='a reach policy file (.npz), or an ONNX model (.onnx) exported from another library '
                   '(examples/sb3_sac_her_reach_onnx.py)')
    add_robot(p, 'default: the file the policy learned on')
    p.add_argument('--episodes', type=whole_number(1, 10 ** 6), default=learn.HELD_OUT_EPISODES, help='fresh goals')
    p.add_argument('--seed', type=int, default=learn.HELD_OUT_SEED, help='seed of the first goal (goal i: seed + i)')
    p.add_argument('--start', choices=STARTS, action='append', default=None,
                   help='where each episode starts: home, random configurations, or chained (where the last goal left '
                   'the arm, as clicks in rviz come); repeat for several; default: all three')
    p.add_argument('--video', action='store_true', help='also write an mp4 of the arm reaching 3 of the goals')
    p.add_argument('--output-dir', default=artifacts.default_output_dir(), help='where the video goes')
    add_world(p, ' (default: the world the policy learned in)')
    add_home(p, ' (default: the policy\'s)')
    add_layer(p, ' (default: as the policy learned)')
    p.set_defaults(run=run_evaluate)


def run_evaluate(a, parser) -> int:
    try:
        policy, setup, note = policy_files.load(a.policy, model=a.model or None, xacro_args=a.xacro_args or None,
                                                **world(a), **home(a, parser), **layer(a))
    except (policies.PolicyError, ReachError) as e:
        refuse(parser, str(e))
    if note:
        print(note, file=sys.stderr)
    folder = output_folder(a, parser) if a.video else ''
    starts = list(dict.fromkeys(a.start or STARTS))
    results = {}
    for start in starts:         # played first: a model that answers no action is one line, before any figure
        try:
            results[start] = learn.evaluate(policy.actor, setup, a.episodes, a.seed, start=start)
        except (policies.PolicyError, ValueError) as e:     # a model that answers no action on a real state
            print(f'evaluate: {e}', file=sys.stderr)
            return 1
    print(policy.describe())
    print(f'robot             {setup.arm.describe()}')
    if setup.body is not None:
        print(f'world             {describe_world(setup)}')
    if setup.limits is not None:
        print(f'motion            {describe_layer(setup)}')
    print(f'goals             {a.episodes} fresh goals within {within(setup)} in {setup.episode_steps} steps (seed '
          f'{a.seed}); the policy learned from {setup.start}')
    print(f'played as         {played_as(setup, policy.target.env_kwargs)}')
    for start in starts:
        result = results[start]
        misses = result.misses_text()
        planned = (f'; {percent(result.planned)} of those reached by a planned way round (the planner\'s share)'
                   if setup.body is not None else '')
        print(f'from {start:<12s} {percent(result.success_rate):>7s} (mean final distance '
              f'{result.mean_distance:.3f} m){"; missed: " + misses if misses else ""}{planned}')
        if setup.control == 'ee':
            p = learn.evaluate(learn.p_controller(setup), setup, a.episodes, a.seed, start=start)
            planned = f' ({percent(p.planned)} by a planned way)' if setup.body is not None else ''
            print(f'  P-controller    {percent(p.success_rate):>7s} of the same goals from the same starts{planned}')
    if a.video:
        stem = artifacts.artifact_stem(folder, 'evaluate-' + stem_name(setup), 'Reach-v0', a.seed)
        write_or_say('video', lambda: learn.record_video(policy.actor, setup, stem + '.mp4', seed=a.seed))
    return 0


def plan_parser(sub) -> None:
    p = sub.add_parser('plan', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='a collision-free, timed motion to one goal (OMPL RRT-Connect, TOPP-RA)',
                       description='Plan the arm\'s motion from --from (default: home) to a goal with its body among '
                       'the obstacles: configurations that reach the goal clear by --margin, a path to one of them '
                       '(OMPL\'s RRT-Connect), timed within the joint limits (TOPP-RA). Prints the plan, or why there '
                       'is none (exit status 1); --trajectory writes it as a trajectory_msgs/JointTrajectory YAML '
                       '(rostopic pub -f takes it).')
    add_robot(p, 'default: the package\'s UR5')
    p.add_argument('--tip', default=None, help='the link that reaches; default: the arm\'s end')
    p.add_argument('--goal', nargs='+', type=float, required=True, metavar='X',
                   help='x y z (metres, in the arm\'s base frame), or x y z qx qy qz qw for a pose')
    p.add_argument('--from', dest='start_q', nargs='+', default=None, metavar='Q',
                   help='where the arm stands: joint positions in the arm\'s order, or name=value pairs')
    add_world(p)
    add_home(p, '; default: the middle of every joint\'s range')
    p.add_argument('--margin', type=float, default=DEFAULT_MARGIN, help='metres kept from every contact')
    p.add_argument('--velocity-scale', type=fraction_above_0, default=DEFAULT_VELOCITY_SCALE, metavar='SCALE',
                   help='of the URDF\'s (and --joint-limits\') velocities and accelerations, as reach_controller')
    p.add_argument('--joint-limits', default=None, metavar='FILE', help='a MoveIt joint_limits.yaml')
    p.add_argument('--time-limit', type=positive_number, default=DEFAULT_TIME_LIMIT,
                   help='seconds the path search may take')
    p.add_argument('--trajectory', default=None, metavar='FILE', help='write the timed plan there (YAML)')
    p.add_argument('--period', type=positive_number, default=0.05, help='seconds between the trajectory\'s points')
    p.set_defaults(run=run_plan)


def run_plan(a, parser) -> int:
    from robot_ai.reach.planning import ReachPlanner
    kwargs = dict(model=a.model, xacro_args=a.xacro_args or None, tip=a.tip,
                  goal='pose' if len(a.goal) == 7 else 'position', **world(a), **home(a, parser))
    kwargs['collision'] = True              # a plan is of the arm's body, obstacles or not
    if len(a.goal) not in (3, 7):
        refuse(parser, f'--goal must be x y z, or x y z qx qy qz qw, got {len(a.goal)} numbers')
    try:
        setup = ReachSetup(**kwargs)
        planner = ReachPlanner(setup, margin=a.margin, velocity_scale=a.velocity_scale, joint_limits=a.joint_limits,
                               time_limit=a.time_limit)
        start = setup.home
        if a.start_q is not None:
            start = setup.configuration(joint_positions(a.start_q, '--from', parser), '--from', setup.home)
    except ReachError as e:
        refuse(parser, str(e))
    print(f'robot             {setup.arm.describe()}')
    print(f'world             {describe_world(setup)}')
    print(f'limits            {planner.limits.describe()}, {a.margin:g} m from every contact')
    plan = planner.plan(start, a.goal)
    if not plan.found:
        print(f'not planned: {plan.reason} ({plan.seconds * 1000:.0f} ms)')
        return 1
    path, timed = plan.path, plan.timed
    print(f'planned           in {plan.seconds * 1000:.0f} ms: {path.how}, {len(path.waypoints)} waypoints, '
          f'{path.length():.2f} rad of joint motion, {path.motions} motions and {path.states} configurations '
          f'checked; {plan.configurations} clear configurations reach the goal')
    print(f'timed             {timed.duration:.2f} s ({timed.how})')
    end = setup.goals_of(timed.end[:, None])[:, 0]
    print(f'reaches           {np.round(end[:3], 4).tolist()} ({np.linalg.norm(end[:3] - np.array(a.goal[:3])):.4f} m '
          f'from the goal) at {np.round(timed.end, 4).tolist()}')
    if a.trajectory:
        write_or_say('trajectory', lambda: _write_trajectory(a.trajectory, setup.arm.joints, timed, a.period))
    return 0


def _write_trajectory(path: str, joints: list[str], timed, period: float) -> str:
    import yaml
    times, positions, velocities = timed.sample(period)
    points = [{'positions': p.tolist(), 'velocities': v.tolist(),
               'time_from_start': {'secs': int(t), 'nsecs': int(round((t - int(t)) * 1e9))}}
              for t, p, v in zip(times.tolist(), positions, velocities)]
    text = yaml.safe_dump({'joint_names': list(joints), 'points': points}, sort_keys=False)
    return artifacts.write_whole(path, lambda f: f.write(text.encode()))


def show_parser(sub) -> None:
    p = sub.add_parser('show', help='print a reach policy file\'s metadata and arrays',
                       description='Print the metadata of a policy file (JSON) and the shapes of its arrays.')
    p.add_argument('policy', help='a policy file (.npz) or an ONNX model (.onnx)')
    p.set_defaults(run=run_show)


def run_show(a, parser) -> int:
    return show_policy(a.policy, parser)


def build_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    """The command line's parser and its commands' (test_docs parses every command the docs show)."""
    parser, sub = command_parser('python -m robot_ai.reach', 'Any arm learns to reach (ARS), without ROS.')
    train_parser(sub)
    evaluate_parser(sub)
    plan_parser(sub)
    show_parser(sub)
    return parser, sub


def main(argv=None) -> int:
    parser, sub = build_parser()
    return run_command(parser, sub, argv)


if __name__ == '__main__':
    sys.exit(main())
