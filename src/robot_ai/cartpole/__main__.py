"""The CartPole agents without ROS: ``python -m robot_ai.cartpole <agent> [options]`` (see --help).

    python -m robot_ai.cartpole random-search --iterations 100 --episodes 100 --seed 0 --video
"""
import argparse
import sys

import numpy as np

from robot_ai.cartpole import artifacts, linear_search
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


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m robot_ai.cartpole',
                                     description='The course\'s CartPole agents, without ROS.')
    sub = parser.add_subparsers(dest='agent', required=True, metavar='AGENT')
    random_search_parser(sub)
    a = parser.parse_args(argv)
    try:
        return a.run(a, sub.choices[a.agent])
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
