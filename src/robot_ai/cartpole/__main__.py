"""The CartPole agents without ROS: ``python -m robot_ai.cartpole <command> [options]`` (see --help).

    python -m robot_ai.cartpole random-search --iterations 100 --episodes 100 --seed 0 --video
    python -m robot_ai.cartpole q-learning --episodes 500 --seed 0 --learners 8
    python -m robot_ai.cartpole evaluate ~/.ros/robot_ai/qlearning_..._seed0.npz --episodes 100
    python -m robot_ai.cartpole show ~/.ros/robot_ai/search_..._seed0.npz

random-search and q-learning write the run's policy file (.npz), its CSV log and its plot side by side, and print
their paths; evaluate and show take any policy file, of either kind.
"""
import argparse
import sys
from dataclasses import replace

import numpy as np

from robot_ai import ars, artifacts

from robot_ai import policies

from robot_ai.cartpole import linear_search, outputs, policy_kinds, q_learning
from robot_ai.cartpole.dynamics import SUPPORTED_ENVS, CartPoleDynamics, RequestError
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.cli import (add_ray, command_parser, connect_ray, fraction_above_0, output_folder, positive_number,
                          refuse, run_command, show_policy, whole_number, write_or_say)
from robot_ai.text import counted


def progress_bar(total: int, unit: str):
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, file=sys.stderr, dynamic_ncols=True)


def add_common(p: argparse.ArgumentParser, default_env: str) -> None:
    p.add_argument('--env-id', default=default_env, choices=SUPPORTED_ENVS, help='the CartPole environment')
    p.add_argument('--seed', type=int, default=0, help='random seed; the same seed gives the same result')
    p.add_argument('--video', action='store_true', help='also record an mp4 of one episode of the result')
    p.add_argument('--output-dir', default=artifacts.default_output_dir(),
                   help='where the policy, the CSV log, the plot and the video go ($ROS_HOME/robot_ai, or '
                   '~/.ros/robot_ai)')


def random_search_parser(sub) -> None:
    d = linear_search.DEFAULTS
    p = sub.add_parser('random-search', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the course\'s random search of a linear policy',
                       description='The course\'s random search: draw linear policies w in [-1, 1]^4, keep the '
                       'best average episode length, evaluate it on final episodes.')
    add_common(p, d['env_id'])
    p.add_argument('--iterations', type=whole_number(1, linear_search.MAX_ITERATIONS), default=d['iterations'],
                   help=f'candidate policies to try (1 to {linear_search.MAX_ITERATIONS})')
    p.add_argument('--episodes', type=whole_number(1, linear_search.MAX_EPISODES), default=d['episodes'],
                   help=f'episodes per candidate (1 to {linear_search.MAX_EPISODES})')
    p.add_argument('--max-steps', type=int, default=0, help='step limit of an episode; 0 = the environment\'s own')
    p.add_argument('--final-episodes', type=whole_number(1, linear_search.MAX_EPISODES), default=d['final_episodes'],
                   help=f'episodes of the final evaluation of the best policy (1 to {linear_search.MAX_EPISODES})')
    p.set_defaults(run=run_random_search)


def run_random_search(a, parser) -> int:
    try:
        search = linear_search.resolve(a.env_id, a.iterations, a.episodes, a.max_steps, a.final_episodes)
    except RequestError as e:
        parser.error(str(e))
    folder = output_folder(a, parser)
    bar = progress_bar(search.iterations, 'candidate')

    def progress(i, avg, best, elapsed):
        bar.update(1)
        if i % 10 == 0 or i == search.iterations:
            bar.set_postfix(best=f'{best:.1f}')
    try:
        result = linear_search.random_search(search.dynamics, search.iterations, search.episodes, search.max_steps,
                                             a.seed, search.final_episodes, progress=progress)
    finally:  # an interrupted run's message goes on a line of its own
        bar.close()
    print(f'best weights      {np.array2string(result.best_weights, precision=4)}')
    print(f'best average      {result.best_avg_length:.2f} (candidate {result.best_index + 1} of {search.iterations})')
    print(f'final average     {result.final_avg_length:.2f} over {counted(search.final_episodes, "episode")}')
    print(f'random actions    {result.baseline_avg_length:.2f}')
    print(f'search time       {result.elapsed:.3f} s')
    stem = artifacts.artifact_stem(folder, 'search', result.env_id, a.seed)
    weights = result.best_weights
    write_or_say('policy', lambda: policies.save(stem + '.npz', LinearPolicy(weights), result.env_id, a.seed,
                                                 result.settings(), result.figures(), 'random-search (CLI)'))
    write_or_say('log', lambda: artifacts.write_csv(stem + '.csv', *outputs.search_log(result)))
    write_or_say('plot', lambda: artifacts.write_plot(outputs.search_plot_job(result), stem + '.png'))
    if a.video:
        write_or_say('video', lambda: outputs.record_video(
            result.env_id, lambda obs: linear_search.act(weights, obs), search.max_steps, a.seed, stem + '.mp4')[0])
    return 0


def ars_parser(sub) -> None:
    d = linear_search.ARS_SETTINGS
    p = sub.add_parser('ars', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='Augmented Random Search of the course\'s linear policy, beside the course\'s random '
                            'search',
                       description='ARS (Mania, Guy and Recht 2018, V1): the course\'s random search grown into a '
                       'walk: perturb the 4 weights along random directions, step toward the better ones. Prints its '
                       'figures beside the course\'s random search (100 x 100) from the same seed: which needs fewer '
                       'episodes?')
    add_common(p, 'CartPole-v1')
    p.add_argument('--directions', type=whole_number(1, 1000), default=d.directions,
                   help='N: directions per iteration (each played with + and -)')
    p.add_argument('--top-directions', type=whole_number(1, 1000), default=d.top_directions,
                   help='b: the best directions kept for the step (at most N)')
    p.add_argument('--step-size', type=positive_number, default=d.step_size, help='alpha')
    p.add_argument('--noise', type=positive_number, default=d.noise, help='nu: the perturbations\' size')
    p.add_argument('--max-steps', type=whole_number(1, 10 ** 9), default=d.max_steps,
                   help='training steps the run may take (rl-baselines3-zoo trains CartPole for 50,000)')
    p.add_argument('--final-episodes', type=whole_number(1, linear_search.MAX_EPISODES), default=100,
                   help='episodes of the final evaluation (gymnasium\'s equations, start states from the seed)')
    add_ray(p, 'the rollouts of every iteration, in --chunks envs kept by actors,')
    p.add_argument('--chunks', type=whole_number(0, 1000), default=0,
                   help='envs the rollouts are split into (0: one here, one per CPU of the cluster with --ray); '
                   'gymnasium\'s CartPole vector env draws every start from one generator, so other chunks give '
                   'other numbers (the same chunks the same, here and on Ray)')
    p.set_defaults(run=run_ars)


def run_ars(a, parser) -> int:
    if a.top_directions > a.directions:
        parser.error(f'--top-directions ({a.top_directions}) must be at most --directions ({a.directions})')
    connect_ray(parser, a.ray)
    dynamics = CartPoleDynamics.of(a.env_id)
    settings = replace(linear_search.ARS_SETTINGS, directions=a.directions, top_directions=a.top_directions,
                       step_size=a.step_size, noise=a.noise, max_steps=a.max_steps)
    folder = output_folder(a, parser)
    print(f'ARS on {a.env_id}, seed {a.seed}: {settings.directions} directions, top {settings.top_directions}, step '
          f'{settings.step_size:g}, noise {settings.noise:g}, at most {settings.max_steps:,} steps')

    def progress(stats):
        print(f'iteration {stats.iteration:3d}  average length of the perturbed policies {stats.rollout_return:6.1f}  '
              f'steps {stats.steps:7,d}  {stats.elapsed:5.2f} s', flush=True)
    result = linear_search.ars_search(a.env_id, a.seed, settings, progress=progress, chunks=a.chunks,
                                      ray_address=a.ray)
    weights = result.policy.weights[0].copy()
    final = linear_search.evaluate(dynamics, weights, a.final_episodes, dynamics.max_episode_steps, a.seed)
    ars_episodes = 2 * settings.directions * settings.episodes * len(result.history)
    search = linear_search.random_search(dynamics, seed=a.seed, final_episodes=a.final_episodes)
    search_episodes, search_steps = linear_search.episodes_used(search)
    print(f'weights           {np.array2string(weights, precision=4)}')
    print(f'ARS               average {final.mean():.2f} over {counted(a.final_episodes, "episode")} after '
          f'{len(result.history)} iterations: {ars_episodes:,} episodes, {result.steps:,} steps, '
          f'{result.elapsed:.2f} s')
    print(f'random search     average {search.final_avg_length:.2f} over {counted(a.final_episodes, "episode")} '
          f'(the course\'s, {search.iterations} x {search.episodes}): {search_episodes:,} episodes, '
          f'{search_steps:,} steps, {search.elapsed:.2f} s')
    fewer = 'ARS' if ars_episodes < search_episodes else 'the random search'
    least, most = min(ars_episodes, search_episodes), max(ars_episodes, search_episodes)
    print(f'fewer episodes    {fewer}: {least:,} against {most:,} ({most / max(1, least):.0f} times fewer)')
    stem = artifacts.artifact_stem(folder, 'ars', a.env_id, a.seed)
    figures = dict(final_avg_length=float(final.mean()), training_steps=int(result.steps), episodes=ars_episodes,
                   iterations=len(result.history))
    write_or_say('policy', lambda: policies.save(stem + '.npz', LinearPolicy(weights), a.env_id, a.seed,
                                                 settings.as_dict(), figures, 'ARS (CLI)'))
    write_or_say('log', lambda: artifacts.write_csv(stem + '.csv', *ars.history_log(result, settings)))
    write_or_say('plot', lambda: artifacts.write_plot(outputs.ars_plot_job(result, settings, search, a.env_id,
                                                                             float(final.mean())), stem + '.png'))
    if a.video:
        write_or_say('video', lambda: outputs.record_video(
            a.env_id, lambda obs: linear_search.act(weights, obs), dynamics.max_episode_steps, a.seed,
            stem + '.mp4')[0])
    return 0


def q_learning_parser(sub) -> None:
    d = q_learning.DEFAULTS
    p = sub.add_parser('q-learning', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the course\'s Q-learning agent with RBF features (its "TensorFlow warm-up")',
                       description='The course\'s Q-learning with RBF features: epsilon-greedy (1/sqrt(n+1)), '
                       'r = -200 on the last step, one linear regressor per action. Ends by printing the '
                       'average total reward of the last 100 episodes (the mean over learners if several). '
                       'The best learner (greedy average over 100 episodes, then last-100 average) is saved.')
    add_common(p, d['env_id'])
    p.add_argument('--episodes', type=whole_number(1, q_learning.MAX_EPISODES), default=d['episodes'],
                   help=f'episodes per learner (1 to {q_learning.MAX_EPISODES})')
    p.add_argument('--gamma', type=fraction_above_0, default=d['gamma'], help='discount, in (0, 1]')
    p.add_argument('--regressor', default=None, choices=sorted(q_learning.REGRESSORS),
                   help='tf: the warm-up\'s (w ~ N(0, 1), w += 0.2 (G - x.w) x); sgd: q_learning.py\'s '
                   f'(w ~ N(0, 1)/sqrt(D), w += 0.1 (G - x.w) x); default {d["regressor"]}, or the initial '
                   'policy\'s')
    p.add_argument('--components', type=whole_number(1, q_learning.MAX_COMPONENTS), default=None,
                   help=f'random Fourier features per RBF bank (4 banks; 1 to {q_learning.MAX_COMPONENTS}); default '
                   f'{d["components"]}, or the initial policy\'s')
    p.add_argument('--learners', type=whole_number(1, q_learning.MAX_LEARNERS), default=d['learners'],
                   help=f'independent learners, seeds seed, seed+1, ... (1 to {q_learning.MAX_LEARNERS}), spread over '
                   'the cores')
    p.add_argument('--bootstrap-at-time-limit', action='store_true',
                   help='a time-limit truncation is not a failure: no -200, bootstrap from s\' (the course: off)')
    p.add_argument('--initial-policy', default='', metavar='FILE',
                   help='train on from a q_learning policy file, as stable-baselines3\'s load() then learn(): its '
                   'features and weights start every learner, epsilon goes on from its episodes')
    add_ray(p, 'every learner a task')
    p.set_defaults(run=run_q_learning)


def run_q_learning(a, parser) -> int:
    start = None
    try:
        if a.initial_policy:
            start = policies.npz.load(a.initial_policy)
            if start.kind != 'q_learning':
                raise RequestError(f'--initial-policy: {start.path} holds a {start.kind} policy, not a q_learning one')
        training = q_learning.resolve(a.env_id, a.episodes, a.gamma, a.regressor or '', a.components or 0, a.learners,
                                      a.bootstrap_at_time_limit, start=start.actor if start else None,
                                      start_settings=start.metadata['settings'] if start else None,
                                      started_from=start.path if start else '')
    except (RequestError, policies.PolicyError) as e:
        refuse(parser, str(e))
    connect_ray(parser, a.ray)
    folder = output_folder(a, parser)
    bar = progress_bar(training.episodes * training.learners, 'episode')
    recent = []

    def progress(learner, episode, total, eps):
        bar.update(1)
        if learner == 0:
            recent.append(total)
            if episode % 10 == 0:
                bar.set_postfix(learner0_avg100=f'{np.mean(recent[-100:]):.1f}', eps=f'{eps:.3f}')
    try:
        result = q_learning.train(training, a.seed, progress=progress, ray_address=a.ray)
    finally:  # an interrupted run's message goes on a line of its own
        bar.close()
    for j, why in result.failed.items():
        print(f'learner {j} failed: {why}', file=sys.stderr)
    if result.cancelled or result.failed:
        print(f'training ended early: {len(result.finished)} of {training.learners} learners finished',
              file=sys.stderr)
    best = result.best_learner()
    print('last-100 average: the exploring agent\'s total reward over its last 100 training episodes; greedy '
          f'average: the final agent, greedy, over {q_learning.GREEDY_EPISODES} episodes (far below the other: '
          'the agent collapsed at the end of its training)')
    for i, j in enumerate(result.finished):
        print(f'learner {j:2d} (seed {a.seed + j})  last-100 average {result.last100_averages[i]:.2f}, greedy '
              f'average {result.greedy_averages[i]:.2f}{"  <- best" if j == best else ""}')
    collapsed = q_learning.collapse_note(result)
    if collapsed:
        print(collapsed)
    if len(result.last100_averages) > 1:
        print(f'mean of {len(result.last100_averages)} learners    {result.mean_last100:.2f} +/- '
              f'{result.ci95_last100:.2f} (95% interval of the mean)')
    print(f'random actions         {result.baseline_total_reward:.2f}')
    print(f'training time          {result.elapsed:.1f} s')
    stem = artifacts.artifact_stem(folder, 'qlearning', result.env_id, a.seed)
    if best >= 0:
        agent = result.agents[best]
        write_or_say('policy', lambda: policies.save(
            stem + '.npz', agent, result.env_id, a.seed + best, training.settings(), result.figures_of(best),
            f'q-learning (CLI), learner {best}' + training.origin()))
    write_or_say('log', lambda: artifacts.write_csv(stem + '.csv', *outputs.q_learning_log(result)))
    write_or_say('plot', lambda: artifacts.write_plot(outputs.q_learning_plot_job(result), stem + '.png'))
    if a.video and best >= 0:
        write_or_say(f'video (learner {best})', lambda: outputs.record_video(
            result.env_id, agent.act, training.max_steps, a.seed + best, stem + '.mp4')[0])
    print(f'avg reward for last {min(100, training.episodes)} episodes: {result.mean_last100:.2f}')
    return 0 if not (result.cancelled or result.failed) else 1


def evaluate_parser(sub) -> None:
    p = sub.add_parser('evaluate', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='play greedy episodes of a policy file and print the average',
                       description='Play episodes with the policy of a file (either kind, or an ONNX model '
                       'exported from another library), start states from the seed, and print the average episode '
                       'length.')
    p.add_argument('policy', help='a policy file (.npz) or an ONNX model (.onnx)')
    p.add_argument('--episodes', type=whole_number(1, q_learning.MAX_EVAL_EPISODES), default=100,
                   help=f'episodes (1 to {q_learning.MAX_EVAL_EPISODES})')
    p.add_argument('--seed', type=int, default=0, help='seed of the start states')
    p.add_argument('--env-id', default='', choices=('',) + SUPPORTED_ENVS,
                   help='"" = the policy\'s own env (an ONNX model\'s metadata robot_ai_env)')
    p.add_argument('--max-steps', type=int, default=0, help='step limit of an episode; 0 = the environment\'s own')
    p.add_argument('--video', action='store_true', help='also write an mp4 of one episode (its start state from '
                   'gymnasium\'s reset(seed)), as the searches do')
    p.add_argument('--output-dir', default=artifacts.default_output_dir(), help='where the video goes')
    p.add_argument('--ros-env', metavar='NAMESPACE', default=None,
                   help='play the episodes on the ROS cart-pole in NAMESPACE (a lockstep cartpole_sim, e.g. '
                   '/cartpole_0 of cartpole_gym.launch) through robot_ai.envs, instead of in this process')
    p.add_argument('--timeout', type=float, default=5.0, help='with --ros-env: seconds any wait for the sim lasts')
    p.set_defaults(run=run_evaluate)


def run_evaluate(a, parser) -> int:
    try:
        policy = policy_kinds.load(a.policy, a.env_id)
        dynamics = CartPoleDynamics.of(a.env_id or policy.env_id)
        max_steps = dynamics.resolve_max_steps(a.max_steps)
    except (policies.PolicyError, RequestError) as e:
        refuse(parser, str(e))
    folder = output_folder(a, parser) if a.video else ''
    if a.ros_env is None:
        try:
            lengths = policy_kinds.evaluate(policy, dynamics, a.episodes, max_steps, a.seed)
        except policies.PolicyError as e:         # an ONNX model that answers no action on a real state
            print(f'evaluate: {e}', file=sys.stderr)
            return 1
    else:
        try:
            from robot_ai.envs.ros_cartpole import RosCartPoleError, episode_lengths   # rospy: only when asked
        except ImportError as e:
            print(f'evaluate: --ros-env needs ROS and robot_ai\'s messages ({e}): source the workspace first '
                  f'(source .catkin_ws/devel/setup.bash, or your own devel/setup.bash)', file=sys.stderr)
            return 1
        if not 0 < a.timeout <= 3600:
            parser.error(f'--timeout must be in (0, 3600] seconds, got {a.timeout:g}')
        try:
            lengths = episode_lengths(policy.push_right, a.ros_env, dynamics.env_id, a.episodes, max_steps, a.seed,
                                      a.timeout)
        except (RosCartPoleError, policies.PolicyError) as e:
            print(f'evaluate: {e}', file=sys.stderr)
            return 1
    print(policy.describe())
    where = f' on the ROS cart-pole {a.ros_env}' if a.ros_env is not None else ''
    print(f'{counted(a.episodes, "episode")} of {dynamics.env_id}{where} (seed {a.seed}): lengths from '
          f'{lengths.min()} to {lengths.max()}')
    print(f'average length: {lengths.mean():.2f}')
    if a.video:
        stem = artifacts.artifact_stem(folder, 'evaluate', dynamics.env_id, a.seed)
        write_or_say('video', lambda: outputs.record_video(dynamics.env_id, policy.act, max_steps, a.seed,
                                                             stem + '.mp4')[0])
    return 0


def show_parser(sub) -> None:
    p = sub.add_parser('show', help='print a policy file\'s metadata and arrays',
                       description='Print the metadata of a policy file (JSON) and the shapes of its arrays; of an '
                       'ONNX model, its metadata, inputs, outputs and operators.')
    p.add_argument('policy', help='a policy file (.npz) or an ONNX model (.onnx)')
    p.set_defaults(run=run_show)


def run_show(a, parser) -> int:
    return show_policy(a.policy, parser)


def build_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    """The command line's parser and its commands' (test_docs parses every command the docs show)."""
    parser, sub = command_parser('python -m robot_ai.cartpole',
                                 'The course\'s CartPole agents, and their policy files, without ROS.')
    random_search_parser(sub)
    q_learning_parser(sub)
    ars_parser(sub)
    evaluate_parser(sub)
    show_parser(sub)
    return parser, sub


def main(argv=None) -> int:
    parser, sub = build_parser()
    return run_command(parser, sub, argv)


if __name__ == '__main__':
    sys.exit(main())
