#!/usr/bin/env python3
"""Speed and result benchmark of the Q-learning agent (CartPole-v0, 4 x 1000 RBF features, tf regressor), in one run:

- the course's loop for reference: its q_learning.py with scikit-learn's StandardScaler and RBFSamplers and the
  warm-up's gradient-descent regressor (in numpy), ported to gymnasium; per environment step, one learner;
- robot_ai.cartpole.q_learning.train_one, the same 500 episodes, per environment step;
- K learners in one call (K = 1, 8, 32), each in a fresh process: wall time, learners per second, peak memory;
- 8 learners in one call against 8 single runs one after another;
- the result: the last-100 averages of 8 seeds, their mean and 95% interval (the course printed 198.79 for one run).

    python bench/q_learning_speed.py [--course-episodes 60]
"""
import argparse
import json
import subprocess
import sys
import time

import numpy as np


def course_loop(episodes, seed=0):
    """The course's q_learning.py with the warm-up's regressor, unchanged but for gymnasium's API; returns
    (seconds, environment steps, total rewards)."""
    import gymnasium as gym
    from sklearn.kernel_approximation import RBFSampler
    from sklearn.pipeline import FeatureUnion
    from sklearn.preprocessing import StandardScaler
    np.random.seed(seed)

    class SGDRegressor:  # the warm-up's TensorFlow regressor: gradient descent, rate 0.1, on the summed squared error
        def __init__(self, D):
            self.w = np.random.randn(D).astype(np.float32)
            self.lr = 0.1

        def partial_fit(self, X, Y):
            self.w += (2 * self.lr * (Y - X.dot(self.w)).dot(X)).astype(np.float32)

        def predict(self, X):
            return X.dot(self.w)

    class FeatureTransformer:
        def __init__(self, n_components=1000):
            observation_examples = np.random.random((20000, 4)) * 2 - 1
            scaler = StandardScaler()
            scaler.fit(observation_examples)
            featurizer = FeatureUnion([
                ("rbf1", RBFSampler(gamma=0.05, n_components=n_components)),
                ("rbf2", RBFSampler(gamma=1.0, n_components=n_components)),
                ("rbf3", RBFSampler(gamma=0.5, n_components=n_components)),
                ("rbf4", RBFSampler(gamma=0.1, n_components=n_components))])
            feature_examples = featurizer.fit_transform(scaler.transform(observation_examples))
            self.dimensions = feature_examples.shape[1]
            self.scaler = scaler
            self.featurizer = featurizer

        def transform(self, observations):
            return self.featurizer.transform(self.scaler.transform(observations))

    class Model:
        def __init__(self, env, feature_transformer):
            self.env = env
            self.models = [SGDRegressor(feature_transformer.dimensions) for _ in range(env.action_space.n)]
            self.feature_transformer = feature_transformer

        def predict(self, s):
            X = self.feature_transformer.transform(np.atleast_2d(s))
            return np.stack([m.predict(X) for m in self.models]).T

        def update(self, s, a, G):
            X = self.feature_transformer.transform(np.atleast_2d(s))
            self.models[a].partial_fit(X, [G])

        def sample_action(self, s, eps):
            if np.random.random() < eps:
                return self.env.action_space.sample()
            return np.argmax(self.predict(s))

    def play_one(env, model, eps, gamma):
        observation, _ = env.reset()
        done, totalreward, iters = False, 0, 0
        while not done and iters < 2000:
            action = model.sample_action(observation, eps)
            prev_observation = observation
            observation, reward, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
            if done:
                reward = -200
            next = model.predict(observation)
            G = reward + gamma * np.max(next[0])
            model.update(prev_observation, action, G)
            if reward == 1:
                totalreward += reward
            iters += 1
        return totalreward, iters

    env = gym.make('CartPole-v0')
    env.reset(seed=seed)
    env.action_space.seed(seed)
    model = Model(env, FeatureTransformer())
    t0, steps, totals = time.time(), 0, []
    for n in range(episodes):
        total, iters = play_one(env, model, 1.0 / np.sqrt(n + 1), 0.99)
        totals.append(total)
        steps += iters
    return time.time() - t0, steps, totals


BATCH = """
import json, resource, sys, time
from robot_ai.cartpole import q_learning
k, seed = int(sys.argv[1]), int(sys.argv[2])
t = time.time()
r = q_learning.train(q_learning.resolve(learners=k), seed)
wall = time.time() - t
# VmHWM, not ru_maxrss: Linux carries ru_maxrss over exec from the parent (the course loop's 1.3 GB)
hwm = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # forked from this small process
print(json.dumps(dict(wall=wall, peak_mib=hwm / 1024.0, worker_peak_mib=workers / 1024.0,
                      workers=q_learning.worker_count(k) if k > 1 else 0,
                      last100=[float(v) for v in r.last100_averages], mean=r.mean_last100, ci95=r.ci95_last100)))
"""


def batch(k, seed=0):
    out = subprocess.run([sys.executable, '-W', 'ignore', '-c', BATCH, str(k), str(seed)], capture_output=True,
                         text=True, check=True).stdout
    return json.loads(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--course-episodes', type=int, default=60, help='episodes of the course loop to time')
    args = ap.parse_args()
    import warnings
    import gymnasium  # noqa: F401  its logger sets its own warning filters at import: override them after
    warnings.filterwarnings('ignore')
    from robot_ai.cartpole import q_learning
    results = {k: batch(k) for k in (1, 8, 32)}  # before the course loop: its 1.3 GB would blur the machine
    singles = sum(batch(1, seed)['wall'] for seed in range(8))

    seconds, steps, _ = course_loop(args.course_episodes)
    course_step = seconds / steps
    print('course loop (scikit-learn + gymnasium)  %6.0f us a step   (%d episodes, %d steps, %.1f s)' % (
        course_step * 1e6, args.course_episodes, steps, seconds))

    training = q_learning.resolve()
    t = time.time()
    totals, _ = q_learning.train_one(training, 0)
    ours = time.time() - t
    our_steps = int(totals.sum() + len(totals))  # the +1 steps and each episode's last step
    print('train_one, 500 episodes                  %6.1f us a step   %5.0fx   '
          '(%d steps, %.2f s, last-100 average %.2f)'
          % (ours / our_steps * 1e6, course_step / (ours / our_steps), our_steps, ours, totals[-100:].mean()))

    print('learners in one call (each a fresh process; wall time, learners per second, peak resident memory):')
    for k in (1, 8, 32):
        r = results[k]
        print('  K = %2d   %6.1f s   %5.2f learners/s   peak %3.0f MiB%s   mean last-100 %.2f +/- %.2f' % (
            k, r['wall'], k / r['wall'], r['peak_mib'],
            ' + %d workers of %3.0f MiB' % (r['workers'], r['worker_peak_mib']) if r['workers'] else ' ' * 22,
            r['mean'], r['ci95']))
    print('8 learners in one call %.1f s, 8 single runs one after another %.1f s: ratio %.2f (target at most 0.6)' % (
        results[8]['wall'], singles, results[8]['wall'] / singles))
    r = results[8]
    print('result, tf regressor, CartPole-v0, seeds 0-7: %s' % ', '.join('%.2f' % v for v in r['last100']))
    print('  mean %.2f, 95%% interval +/- %.2f (%.2f to %.2f); the course printed 198.79 for one run' % (
        r['mean'], r['ci95'], r['mean'] - r['ci95'], r['mean'] + r['ci95']))


if __name__ == '__main__':
    main()
