"""A long-lived process that draws learning curves, fed one JSON job per line on stdin. No rospy.

The cartpole_search node hands plots to it instead of a thread: matplotlib holds the GIL for tens of
milliseconds, which a thread in the node would take from the service answering the search.

    job = {"path": ..., "env_id": ..., "seed": ..., "episodes": ..., "max_steps": ...,
           "avg_lengths": [...], "best_avg_length": ..., "final_avg_length": ..., "baseline_avg_length": ...}
"""
import json
import sys

import numpy as np

from robot_ai.cartpole_search import SearchResult, plot_learning_curve

FIELDS = ('env_id', 'seed', 'episodes', 'max_steps', 'best_avg_length', 'final_avg_length',
          'baseline_avg_length')


def job_of(result, path):
    """The JSON line of one plot job for a SearchResult."""
    job = {k: getattr(result, k) for k in FIELDS}
    job['avg_lengths'] = [float(v) for v in result.avg_lengths]
    job['path'] = path
    return json.dumps(job) + '\n'


def main():
    for line in sys.stdin:
        try:
            job = json.loads(line)
            result = SearchResult(avg_lengths=np.array(job['avg_lengths']), **{k: job[k] for k in FIELDS})
            plot_learning_curve(result, job['path'])
            print('written %s' % job['path'], flush=True)
        except Exception as e:  # one bad job must not stop the next ones
            print('failed %s' % e, file=sys.stderr, flush=True)


if __name__ == '__main__':
    main()
