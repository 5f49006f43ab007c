"""The CartPole agents without ROS: ``python -m robot_ai.cartpole <agent> [options]`` (see --help).

    python -m robot_ai.cartpole random-search --iterations 100 --episodes 100 --seed 0 --video
    python -m robot_ai.cartpole q-learning --episodes 500 --seed 0 --learners 8
"""
import argparse
import sys

import numpy as np

from robot_ai.cartpole import artifacts, linear_search, q_learning
from robot_ai.cartpole.dynamics import SUPPORTED_ENVS, RequestError


def progress_bar(total, unit):
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, file=sys.stderr, dynamic_ncols=True)


def add_common(p, default_env):
    p.add_argument('--env-id', default=default_env, choices=SUPPORTED_ENVS, help='the CartPole environment')
    p.add_argument('--seed', type=int, default=0, help='random seed; the same seed gives the same result')
    p.add_argument('--video', action='store_true', help='also record an mp4 of one episode of the result')
    p.add_argument('--output-dir', default=artifacts.default_output_dir(),
                   help='where the plot and the video go ($ROS_HOME/robot_ai, or ~/.ros/robot_ai)')


def random_search_parser(sub):
    d = linear_search.DEFAULTS
    p = sub.add_parser('random-search', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the course\'s random search of a linear policy',
                       description='The course\'s random search: draw linear policies w in [-1, 1]^4, keep the '
                       'best average episode length, evaluate it on final episodes.')
    add_common(p, d['env_id'])
    p.add_argument('--iterations', type=int, default=d['iterations'], help='candidate policies to try (1 to %d)'
                   % linear_search.MAX_ITERATIONS)
    p.add_argument('--episodes', type=int, default=d['episodes'], help='episodes per candidate (1 to %d)'
                   % linear_search.MAX_EPISODES)
    p.add_argument('--max-steps', type=int, default=0, help='step limit of an episode; 0 = the environment\'s own')
    p.add_argument('--final-episodes', type=int, default=d['final_episodes'],
                   help='episodes of the final evaluation of the best policy')
    p.set_defaults(run=run_random_search)


def run_random_search(a, parser):
    try:
        search = linear_search.resolve(a.env_id, a.iterations, a.episodes, a.max_steps, a.final_episodes)
    except RequestError as e:
        parser.error(str(e))
    bar = progress_bar(search.iterations, 'candidate')

    def progress(i, avg, best, elapsed):
        bar.update(1)
        if i % 10 == 0 or i == search.iterations:
            bar.set_postfix(best='%.1f' % best)
    result = linear_search.random_search(search.dynamics, search.iterations, search.episodes, search.max_steps,
                                         a.seed, search.final_episodes, progress=progress)
    bar.close()
    stem = artifacts.artifact_stem(a.output_dir, 'search', result.env_id, a.seed)
    print('best weights      %s' % np.array2string(result.best_weights, precision=4))
    print('best average      %.2f (candidate %d of %d)' % (result.best_avg_length, result.best_index + 1,
                                                            search.iterations))
    print('final average     %.2f over %d episodes' % (result.final_avg_length, search.final_episodes))
    print('random actions    %.2f' % result.baseline_avg_length)
    print('search time       %.3f s' % result.elapsed)
    print('plot              %s' % artifacts.write_plot(artifacts.search_plot_job(result), stem + '.png'))
    if a.video:
        weights = result.best_weights
        path, _ = artifacts.record_video(result.env_id, lambda obs: linear_search.act(weights, obs),
                                         search.max_steps, a.seed, stem + '.mp4')
        print('video             %s' % path)
    return 0


def q_learning_parser(sub):
    d = q_learning.DEFAULTS
    p = sub.add_parser('q-learning', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help='the course\'s Q-learning agent with RBF features (its "TensorFlow warm-up")',
                       description='The course\'s Q-learning with RBF features: epsilon-greedy (1/sqrt(n+1)), '
                       'r = -200 on the last step, one linear regressor per action. Ends by printing the '
                       'average total reward of the last 100 episodes (the mean over learners if several).')
    add_common(p, d['env_id'])
    p.add_argument('--episodes', type=int, default=d['episodes'], help='episodes per learner (1 to %d)'
                   % q_learning.MAX_EPISODES)
    p.add_argument('--gamma', type=float, default=d['gamma'], help='discount, in (0, 1]')
    p.add_argument('--regressor', default=d['regressor'], choices=sorted(q_learning.REGRESSORS),
                   help='tf: the warm-up\'s (w ~ N(0, 1), w += 0.2 (G - x.w) x); sgd: q_learning.py\'s '
                   '(w ~ N(0, 1)/sqrt(D), w += 0.1 (G - x.w) x)')
    p.add_argument('--components', type=int, default=d['components'], help='random Fourier features per RBF bank '
                   '(4 banks; 1 to %d)' % q_learning.MAX_COMPONENTS)
    p.add_argument('--learners', type=int, default=d['learners'], help='independent learners, seeds seed, seed+1, '
                   '... (1 to %d), spread over the cores' % q_learning.MAX_LEARNERS)
    p.add_argument('--bootstrap-at-time-limit', action='store_true',
                   help='a time-limit truncation is not a failure: no -200, bootstrap from s\' (the course: off)')
    p.set_defaults(run=run_q_learning)


def run_q_learning(a, parser):
    try:
        training = q_learning.resolve(a.env_id, a.episodes, a.gamma, a.regressor, a.components, a.learners,
                                      a.bootstrap_at_time_limit)
    except RequestError as e:
        parser.error(str(e))
    bar = progress_bar(training.episodes * training.learners, 'episode')
    recent = []

    def progress(learner, episode, total, eps):
        bar.update(1)
        if learner == 0:
            recent.append(total)
            if episode % 10 == 0:
                bar.set_postfix(learner0_avg100='%.1f' % np.mean(recent[-100:]), eps='%.3f' % eps)
    result = q_learning.train(training, a.seed, progress=progress)
    bar.close()
    stem = artifacts.artifact_stem(a.output_dir, 'qlearning', result.env_id, a.seed)
    for k, avg in enumerate(result.last100_averages):
        print('learner %2d (seed %d)  last-100 average %.2f' % (k, a.seed + k, avg))
    if len(result.last100_averages) > 1:
        print('mean of %d learners    %.2f ± %.2f (95%% interval of the mean)' % (
            len(result.last100_averages), result.mean_last100, result.ci95_last100))
    print('random actions         %.2f' % result.baseline_total_reward)
    print('training time          %.1f s' % result.elapsed)
    print('plot                   %s' % artifacts.write_plot(artifacts.q_learning_plot_job(result), stem + '.png'))
    if a.video:
        path, steps = artifacts.record_video(result.env_id, result.agent.act, training.max_steps, a.seed, stem + '.mp4')
        print('video                  %s (learner 0, greedy, %d steps)' % (path, steps))
    print('avg reward for last 100 episodes: %.2f' % result.mean_last100)
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m robot_ai.cartpole',
                                     description='The course\'s CartPole agents, without ROS.')
    sub = parser.add_subparsers(dest='agent', required=True, metavar='AGENT')
    random_search_parser(sub)
    q_learning_parser(sub)
    a = parser.parse_args(argv)
    try:
        return a.run(a, sub.choices[a.agent])
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
