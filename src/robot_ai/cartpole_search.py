"""Random search of a linear CartPole policy, batched over every candidate and episode at once. No rospy.

The course's exercise: draw weight vectors w uniformly in [-1, 1]^4, play episodes with the policy
``action = 1 if obs.dot(w) > 0 else 0``, keep the best average episode length (the first best wins ties),
then evaluate the best on final episodes. Here every (candidate, episode) pair is stepped together with
gymnasium's own CartPole equations in numpy, and episodes that have ended are dropped from the batch, so a
100 x 100 search takes a fraction of a second instead of the course loop's seconds.

Given the same start state and weights, an episode here has the length gymnasium's ``gym.make(env_id)``
gives (tested on hundreds of pairs). The same seed gives the same result bit for bit: weights, start states
and the random-action baseline all come from ``numpy.random.default_rng(seed)`` in a fixed order, and the
batching does not change which numbers are drawn.

    python -m robot_ai.cartpole_search --iterations 100 --episodes 100 --seed 0 --video
"""
import argparse
import math
import os
import time

import numpy as np

SUPPORTED_ENVS = ('CartPole-v0', 'CartPole-v1')
MAX_ITERATIONS = 100000
MAX_EPISODES = 10000
MAX_WORK = 20000000            # iterations * episodes (+ final episodes): about a minute or two on 2 cores
BATCH_ENVS = 131072            # episodes stepped together: bounds memory (~40 MiB of state) whatever the size


class SearchError(ValueError):
    """A request outside what the search allows; the message says what is allowed."""


class CartPoleModel(object):
    """gymnasium's CartPole constants, read from gymnasium's own environment, and its step limit."""

    def __init__(self, env_id='CartPole-v1'):
        import gymnasium as gym
        if env_id not in SUPPORTED_ENVS:
            try:
                gym.spec(env_id)
                known = True
            except Exception:
                known = False
            raise SearchError('env_id %r is %s; allowed: %s' % (
                env_id, 'not a CartPole environment' if known else 'unknown', ', '.join(SUPPORTED_ENVS)))
        spec = gym.spec(env_id)
        env = gym.make(env_id).unwrapped
        if getattr(env, 'kinematics_integrator', 'euler') != 'euler' or getattr(env, '_sutton_barto_reward', False):
            raise SearchError('%s is configured differently from the course (euler, reward 1 a step)' % env_id)
        self.env_id = env_id
        self.max_episode_steps = int(spec.max_episode_steps)
        for name in ('gravity', 'masspole', 'total_mass', 'length', 'polemass_length', 'force_mag', 'tau',
                     'theta_threshold_radians', 'x_threshold'):
            setattr(self, name, float(getattr(env, name)))
        env.close()

    def episode_lengths(self, weights, starts, max_steps, rng=None):
        """Lengths (C, E) of the episodes started at starts (C, E, 4) with weights (C, 4).

        weights None: random actions drawn from rng (the course's random-action baseline)."""
        starts = np.asarray(starts, dtype=np.float64)
        c, e = starts.shape[:2]
        n = c * e
        s = starts.reshape(n, 4).T.copy()                      # rows x, x_dot, theta, theta_dot
        w = None if weights is None else np.repeat(np.asarray(weights, np.float64), e, axis=0).T.copy()
        alive = np.arange(n)
        lengths = np.full(n, max_steps, dtype=np.int64)
        g, mp, tm, ln, pml = self.gravity, self.masspole, self.total_mass, self.length, self.polemass_length
        fm, tau, tt, xt = self.force_mag, self.tau, self.theta_threshold_radians, self.x_threshold
        for t in range(1, max_steps + 1):
            if w is None:
                push = rng.random(len(alive)) < 0.5
            else:
                # the policy sees gymnasium's float32 observation, promoted exactly to float64 in the dot
                push = np.einsum('ij,ij->j', s.astype(np.float32), w) > 0
            x, x_dot, theta, theta_dot = s
            force = np.where(push, fm, -fm)
            cos, sin = np.cos(theta), np.sin(theta)
            # the same operations, in the same order, as gymnasium's CartPoleEnv.step
            temp = (force + pml * np.square(theta_dot) * sin) / tm
            theta_acc = (g * sin - cos * temp) / (ln * (4.0 / 3.0 - mp * np.square(cos) / tm))
            x_acc = temp - pml * theta_acc * cos / tm
            s = np.stack((x + tau * x_dot, x_dot + tau * x_acc, theta + tau * theta_dot, theta_dot + tau * theta_acc))
            done = (np.abs(s[0]) > xt) | (np.abs(s[2]) > tt)  # |x| > t is gymnasium's x < -t or x > t
            if done.any():
                lengths[alive[done]] = t
                keep = ~done
                alive, s = alive[keep], s[:, keep]
                if w is not None:
                    w = w[:, keep]
                if not len(alive):
                    break
        return lengths.reshape(c, e)


def resolve(env_id='', iterations=0, episodes=0, max_steps=0, final_episodes=0, defaults=None):
    """Fill zero/empty fields with defaults and check every value; raise SearchError saying what is allowed."""
    d = dict(env_id='CartPole-v1', iterations=100, episodes=100, final_episodes=100)
    d.update(defaults or {})
    env_id = env_id or d['env_id']
    model = CartPoleModel(env_id)
    iterations = int(iterations or d['iterations'])
    episodes = int(episodes or d['episodes'])
    final_episodes = int(final_episodes or d['final_episodes'])
    limit = model.max_episode_steps
    max_steps = int(max_steps or limit)
    if not 1 <= iterations <= MAX_ITERATIONS:
        raise SearchError('iterations must be 1 to %d (0 = %d), got %d' % (MAX_ITERATIONS, d['iterations'], iterations))
    for name, value in (('episodes', episodes), ('final_episodes', final_episodes)):
        if not 1 <= value <= MAX_EPISODES:
            raise SearchError('%s must be 1 to %d (0 = %d), got %d' % (name, MAX_EPISODES, d[name], value))
    if not 1 <= max_steps <= limit:
        raise SearchError('max_steps must be 1 to %s\'s limit %d (0 = %d), got %d' % (env_id, limit, limit, max_steps))
    if iterations * episodes + final_episodes > MAX_WORK:
        raise SearchError('iterations x episodes = %d episodes is more than the limit of %d; use fewer iterations '
                          'or episodes' % (iterations * episodes, MAX_WORK))
    return model, iterations, episodes, max_steps, final_episodes


def check_weights(weights):
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (4,):
        raise SearchError('weights must be 4 numbers (x, x_dot, theta, theta_dot), got %d' % w.size)
    if not np.isfinite(w).all():
        raise SearchError('weights must be finite numbers, got %s' % list(w))
    return w


def act(weights, state):
    """The course's policy: 1 (push right) if state.w > 0, else 0."""
    s = np.asarray(state, dtype=np.float64).reshape(-1)
    if s.shape != (4,):
        raise SearchError('state must be 4 numbers (x, x_dot, theta, theta_dot), got %d' % s.size)
    if not np.isfinite(s).all():
        raise SearchError('state must be finite numbers, got %s' % list(s))
    return 1 if float(np.dot(s, weights)) > 0 else 0


def start_states(rng, count, episodes):
    """gymnasium's reset distribution: each of the 4 state variables uniform in [-0.05, 0.05)."""
    return rng.uniform(-0.05, 0.05, size=(count, episodes, 4))


def evaluate(model, weights, episodes, max_steps, seed):
    """Lengths of `episodes` episodes of one policy, start states from default_rng(seed)."""
    rng = np.random.default_rng(seed)
    w = check_weights(weights)
    return model.episode_lengths(w[None, :], start_states(rng, 1, episodes), max_steps)[0]


class SearchResult(object):
    __slots__ = ('env_id', 'seed', 'iterations', 'episodes', 'max_steps', 'weights', 'avg_lengths',
                 'best_index', 'best_weights', 'best_avg_length', 'final_lengths', 'final_avg_length',
                 'baseline_avg_length', 'elapsed', 'cancelled')

    def __init__(self, **kw):
        for k in self.__slots__:
            setattr(self, k, kw.get(k))


def random_search(model, iterations=100, episodes=100, max_steps=None, seed=0, final_episodes=100,
                  progress=None, should_stop=None, batch_envs=BATCH_ENVS):
    """The course's random search, batched.

    progress(i, avg, best, elapsed) is called for every candidate i (1-based) in order; should_stop() is
    asked between batches, and a search it stops returns the candidates evaluated so far (cancelled=True).
    """
    t0 = time.time()
    max_steps = max_steps or model.max_episode_steps
    rng = np.random.default_rng(seed)
    weights = rng.uniform(-1.0, 1.0, size=(iterations, 4))
    per_batch = max(1, batch_envs // episodes)
    avgs = np.empty(iterations)
    best_index, best, done, cancelled = -1, -math.inf, 0, False
    while done < iterations:
        if should_stop is not None and should_stop():
            cancelled = True
            break
        k = min(per_batch, iterations - done)
        lengths = model.episode_lengths(weights[done:done + k], start_states(rng, k, episodes), max_steps)
        batch_avgs = lengths.mean(axis=1)
        avgs[done:done + k] = batch_avgs
        for j, avg in enumerate(batch_avgs):
            if avg > best:  # strictly better, as the course: the first of equal candidates stays the best
                best, best_index = avg, done + j
            if progress is not None:
                progress(done + j + 1, float(avg), float(best), time.time() - t0)
        done += k
    avgs = avgs[:done]
    final = np.zeros(0, np.int64)
    baseline = float('nan')
    if best_index >= 0 and not cancelled:
        final = model.episode_lengths(weights[best_index][None, :], start_states(rng, 1, final_episodes),
                                      max_steps)[0]
        baseline = float(model.episode_lengths(None, start_states(rng, 1, episodes), max_steps, rng).mean())
    return SearchResult(env_id=model.env_id, seed=seed, iterations=iterations, episodes=episodes,
                        max_steps=max_steps, weights=weights[:done], avg_lengths=avgs, best_index=best_index,
                        best_weights=weights[best_index] if best_index >= 0 else np.zeros(4),
                        best_avg_length=float(best) if best_index >= 0 else 0.0, final_lengths=final,
                        final_avg_length=float(final.mean()) if len(final) else 0.0,
                        baseline_avg_length=baseline, elapsed=time.time() - t0, cancelled=cancelled)


# ------------------------------------------------------------------------------------------ artifacts
def artifact_stem(output_dir, result):
    os.makedirs(output_dir, exist_ok=True)
    stamp = time.strftime('%Y%m%d-%H%M%S')
    base = os.path.join(output_dir, 'search_%s_%s_seed%d' % (stamp, result.env_id, result.seed))
    stem, n = base, 1
    while os.path.exists(stem + '.png'):
        n += 1
        stem = '%s_%d' % (base, n)
    return stem


def plot_learning_curve(result, path):
    """PNG: every candidate's average length, the best so far, the random-action baseline, the step limit."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    x = np.arange(1, len(result.avg_lengths) + 1)
    ax.plot(x, result.avg_lengths, '.', ms=4, color='tab:blue', label='candidate average length')
    ax.plot(x, np.maximum.accumulate(result.avg_lengths), '-', color='tab:orange', lw=2, label='best so far')
    if math.isfinite(result.baseline_avg_length):
        ax.axhline(result.baseline_avg_length, ls='--', color='tab:gray',
                   label='random actions (%.1f)' % result.baseline_avg_length)
    ax.axhline(result.max_steps, ls=':', color='tab:red', label='step limit (%d)' % result.max_steps)
    ax.set_xlabel('candidate (iteration)')
    ax.set_ylabel('average episode length over %d episodes' % result.episodes)
    ax.set_title('%s random search, seed %d: best %.1f, final %.1f' % (
        result.env_id, result.seed, result.best_avg_length, result.final_avg_length))
    ax.set_ylim(0, result.max_steps * 1.08)
    ax.legend(loc='center right', fontsize=8, framealpha=0.9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def record_video(env_id, weights, max_steps, seed, path):
    """mp4 of one episode of the policy, rendered by gymnasium (rgb_array) and written by RecordVideo."""
    os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    os.environ.setdefault('SDL_AUDIODRIVER', 'dummy')
    import shutil
    import tempfile

    import gymnasium as gym
    from gymnasium.wrappers import RecordVideo
    work = tempfile.mkdtemp(prefix='video_', dir=os.path.dirname(path))
    folder = os.path.join(work, 'frames')  # a folder RecordVideo creates itself
    env = RecordVideo(gym.make(env_id, render_mode='rgb_array', max_episode_steps=max_steps), folder,
                      episode_trigger=lambda i: i == 0, name_prefix='best', disable_logger=True)
    try:
        obs, _ = env.reset(seed=int(seed) % (2 ** 32))
        steps, done = 0, False
        while not done:
            obs, _, terminated, truncated, _ = env.step(act(weights, obs))
            steps += 1
            done = terminated or truncated
    finally:
        env.close()
    videos = [f for f in os.listdir(folder) if f.endswith('.mp4')] if os.path.isdir(folder) else []
    if videos:
        shutil.move(os.path.join(folder, videos[0]), path)
    shutil.rmtree(work, ignore_errors=True)
    if not videos:
        raise RuntimeError('RecordVideo wrote no video')
    return path, steps


def main(argv=None):
    p = argparse.ArgumentParser(description='The course\'s CartPole random search, without ROS.')
    p.add_argument('--env-id', default='CartPole-v1', choices=SUPPORTED_ENVS)
    p.add_argument('--iterations', type=int, default=100)
    p.add_argument('--episodes', type=int, default=100)
    p.add_argument('--max-steps', type=int, default=0, help='0 = the environment\'s own limit')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--final-episodes', type=int, default=100)
    p.add_argument('--video', action='store_true', help='record an mp4 of one episode of the best policy')
    p.add_argument('--output-dir', default=os.path.join(os.path.expanduser('~'), '.ros', 'robot_ai'))
    a = p.parse_args(argv)
    try:
        model, iterations, episodes, max_steps, final_episodes = resolve(
            a.env_id, a.iterations, a.episodes, a.max_steps, a.final_episodes)
    except SearchError as e:
        p.error(str(e))
    from tqdm import tqdm
    bar = tqdm(total=iterations, unit='candidate')

    def progress(i, avg, best, elapsed):
        bar.update(1)
        if i % 10 == 0 or i == iterations:
            bar.set_postfix(best='%.1f' % best)
    result = random_search(model, iterations, episodes, max_steps, a.seed, final_episodes, progress=progress)
    bar.close()
    stem = artifact_stem(a.output_dir, result)
    print('best weights      %s' % np.array2string(result.best_weights, precision=4))
    print('best average      %.2f (candidate %d of %d)' % (result.best_avg_length, result.best_index + 1, iterations))
    print('final average     %.2f over %d episodes' % (result.final_avg_length, final_episodes))
    print('random actions    %.2f' % result.baseline_avg_length)
    print('search time       %.3f s' % result.elapsed)
    print('plot              %s' % plot_learning_curve(result, stem + '.png'))
    if a.video:
        print('video             %s' % record_video(result.env_id, result.best_weights, max_steps, a.seed,
                                                    stem + '.mp4')[0])
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
