"""Where the agents' files go, what they are called, and how they are drawn: plots and videos. No rospy.

A plot is described by a job, a plain dict that crosses a pipe as JSON (the nodes hand plots to
``robot_ai.plot_worker``, a process of its own) and is drawn by ``write_plot``::

    job = {'title': ..., 'xlabel': ..., 'ylabel': ...,
           'series': [{'y': [...], 'x': [...] (default 1..n), 'label': ..., 'style': 'line' | 'points' | 'step',
                       'color': ..., 'lw': ..., 'alpha': ...}, ...],
           'hlines': [{'y': ..., 'label': ..., 'color': ..., 'ls': ...}, ...],
           'ylim': [low, high] (optional), 'integer_x': true}
    write_plot(search_plot_job(result), stem + '.png')

Plot and video files are written whole or not at all: into a hidden temporary file beside them, named after the
writing process (so that ``remove_leftovers`` can tell a dead writer's leftovers), then renamed into place.
"""
import os
import tempfile
import threading
import time

import numpy as np

FIGSIZE_INCHES, DPI = (10.0, 5.6), 100   # 1000 x 560 pixels: reads well in a README
TEMP_PREFIX = '.robot_ai_tmp_'          # + <pid>_...: files being written; see remove_leftovers
_reserved = set()                       # stems handed out by this process whose files may not exist yet
_reserved_lock = threading.Lock()


def default_output_dir():
    """$ROS_HOME/robot_ai, or ~/.ros/robot_ai when ROS_HOME is unset: where every agent's files go."""
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(ros_home, 'robot_ai')


def artifact_stem(output_dir, kind, env_id, seed):
    """A path without extension for one run's files, new in output_dir: <kind>_<time>_<env>_seed<seed>[_n].

    The seed is written as given (seed-1 for -1). Stems handed out earlier by this process are not handed out
    again, even before their files exist."""
    os.makedirs(output_dir, exist_ok=True)
    base = os.path.join(output_dir, '%s_%s_%s_seed%d' % (kind, time.strftime('%Y%m%d-%H%M%S'), env_id, int(seed)))
    with _reserved_lock:
        stem, n = base, 1
        while stem in _reserved or any(os.path.lexists(stem + ext) for ext in ('.png', '.mp4')):
            n += 1
            stem = '%s_%d' % (base, n)
        _reserved.add(stem)
    return stem


def search_plot_job(result):
    """The learning curve of a linear_search.SearchResult: every candidate's average length, the best so far,
    the random-action baseline and the step limit."""
    avgs = [float(v) for v in result.avg_lengths]
    hlines = []
    if np.isfinite(result.baseline_avg_length):
        hlines.append(dict(y=result.baseline_avg_length, label='random actions (%.1f)' % result.baseline_avg_length,
                           color='tab:gray', ls='--'))
    hlines.append(dict(y=result.max_steps, label='step limit (%d)' % result.max_steps, color='tab:red', ls=':'))
    return dict(
        title='%s random search, seed %d: best %.1f, final %.1f' % (
            result.env_id, result.seed, result.best_avg_length, result.final_avg_length),
        xlabel='candidate (iteration)', ylabel='average episode length over %d episodes' % result.episodes,
        series=[dict(y=avgs, label='candidate average length', style='points', color='tab:blue'),
                dict(y=[float(v) for v in np.maximum.accumulate(avgs)] if avgs else [], label='best so far',
                     style='step', color='tab:orange', lw=2)],
        hlines=hlines, ylim=[0, result.max_steps * 1.05], integer_x=True)


def q_learning_plot_job(result):
    """The learning curves of a q_learning.TrainingResult: learner 0's total reward per episode and its running
    average of 100, every other learner's running average as a faint line, the random-action baseline."""
    from robot_ai.cartpole.q_learning import running_average, RBF_GAMMAS
    t = result.training
    rewards = [np.asarray(r, dtype=np.float64) for r in result.total_rewards]
    series = [dict(y=[float(v) for v in running_average(r)], style='line', color='tab:blue', alpha=0.3, lw=1,
                   label='learners 1-%d: running average of 100' % (len(rewards) - 1) if j == 1 else None)
              for j, r in enumerate(rewards) if j > 0]
    series += [dict(y=[float(v) for v in rewards[0]], style='points', color='tab:gray', ms=3,
                    label='learner 0: total reward per episode'),
               dict(y=[float(v) for v in running_average(rewards[0])], style='line', color='tab:orange', lw=2.5,
                    label='learner 0: running average of 100')]
    best = t.max_steps if t.bootstrap_at_time_limit else t.max_steps - 1
    spread = ('%d learners, last-100 average %.1f ± %.1f' % (len(result.last100_averages), result.mean_last100,
                                                              result.ci95_last100)
              if len(result.last100_averages) > 1 else 'last-100 average %.1f' % result.mean_last100)
    return dict(
        title='%s Q-learning, %s regressor, %d x %d RBF features, seed %d: %s' % (
            result.env_id, t.regressor, len(RBF_GAMMAS), t.components, result.seed, spread),
        xlabel='episode', ylabel='total reward (+1 steps)', series=series,
        hlines=[dict(y=result.baseline_total_reward, label='random actions (%.1f)' % result.baseline_total_reward,
                     color='tab:gray', ls='--'),
                dict(y=best, label='most an episode totals (%d)' % best, color='tab:red', ls=':')],
        ylim=[0, t.max_steps * 1.05], integer_x=True)


def write_plot(job, path):
    """Draw a plot job into the PNG file path (1000 x 560), whole or not at all; return path."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator
    fig, ax = plt.subplots(figsize=FIGSIZE_INCHES, dpi=DPI, layout='constrained')
    try:
        for s in job.get('series', []):
            y = np.asarray(s['y'], dtype=np.float64)
            x = np.asarray(s['x'], dtype=np.float64) if s.get('x') is not None else np.arange(1, len(y) + 1)
            style = s.get('style', 'line')
            kw = dict(color=s.get('color'), label=s.get('label'), alpha=s.get('alpha', 1.0))
            if style == 'points':
                ax.plot(x, y, '.', ms=s.get('ms', 4), **kw)
            else:
                ax.plot(x, y, '-', lw=s.get('lw', 1.5), drawstyle='steps-post' if style == 'step' else 'default', **kw)
        for h in job.get('hlines', []):
            ax.axhline(h['y'], color=h.get('color', 'tab:gray'), ls=h.get('ls', '--'), lw=1.2, label=h.get('label'))
        if job.get('integer_x'):
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        if job.get('ylim'):
            ax.set_ylim(*job['ylim'])
        ax.set_xlabel(job.get('xlabel', ''))
        ax.set_ylabel(job.get('ylabel', ''))
        ax.set_title(job.get('title', ''))
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        keep = [(h, l) for h, l in zip(handles, labels) if l and not l.startswith('_')]
        if keep:  # below the axes, never over the data
            fig.legend(*zip(*keep), loc='outside lower center', ncols=min(3 if len(keep) > 4 else 4, len(keep)), fontsize=9,
                       frameon=False)
        folder = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix='%s%d_' % (TEMP_PREFIX, os.getpid()), suffix='.png', dir=folder)
        try:
            with os.fdopen(fd, 'wb') as f:
                fig.savefig(f, format='png')
            _readable(tmp)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    finally:
        plt.close(fig)
    return path


def record_video(env_id, policy, max_steps, seed, path):
    """mp4 of one episode rendered by gymnasium (rgb_array), written whole or not at all; returns (path, steps).

    policy(observation) -> action (0 or 1); the start state comes from gymnasium's reset(seed). Frames are
    streamed to ffmpeg one at a time (memory stays flat however long the episode) into a hidden temporary file
    beside path, named after this process, and renamed into place when complete."""
    os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    os.environ.setdefault('SDL_AUDIODRIVER', 'dummy')
    import gymnasium as gym
    import imageio_ffmpeg
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix='%s%d_' % (TEMP_PREFIX, os.getpid()), suffix='.mp4', dir=folder)
    os.close(fd)
    env = gym.make(env_id, render_mode='rgb_array', max_episode_steps=max_steps)
    writer = None
    try:
        obs, _ = env.reset(seed=int(seed) % (2 ** 32))
        frame = env.render()
        writer = imageio_ffmpeg.write_frames(tmp, (frame.shape[1], frame.shape[0]), fps=env.metadata['render_fps'],
                                             macro_block_size=1, output_params=['-y'])
        writer.send(None)  # start ffmpeg
        writer.send(frame)
        steps, done = 0, False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            steps += 1
            done = terminated or truncated
            writer.send(env.render())
        writer.close()
        writer = None
        if os.path.getsize(tmp) == 0:
            raise RuntimeError('ffmpeg wrote an empty video')
        _readable(tmp)
        os.replace(tmp, path)
    except BaseException:
        if writer is not None:
            writer.close()
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    finally:
        env.close()
    return path, steps


MIN_FREE_BYTES = 32 * 1024 * 1024   # a plot is ~60 KB, a video ~100 KB: below this, a disk is as good as full


def unwritable_reason(output_dir, min_free=MIN_FREE_BYTES):
    """Why files cannot be written in output_dir (not writable, or a nearly full disk), or '' if they can."""
    if not os.access(output_dir, os.W_OK | os.X_OK):
        return '%s is not writable' % output_dir
    try:
        st = os.statvfs(output_dir)
    except OSError as e:
        return 'cannot tell the free space where %s is: %s' % (output_dir, e)
    free = st.f_bavail * st.f_frsize
    if free < min_free:
        return 'the disk where %s is is full: %d KiB free (at least %d MiB wanted)' % (
            output_dir, free // 1024, min_free // (1024 * 1024))
    return ''


def remove_leftovers(output_dir):
    """Delete the temporary files (videos and plots being written) that processes which no longer run left in
    output_dir, after a kill -9 say; return their names. Files of running processes are left alone."""
    removed = []
    try:
        names = os.listdir(output_dir)
    except OSError:
        return removed
    for name in names:
        if not name.startswith(TEMP_PREFIX):
            continue
        try:
            pid = int(name[len(TEMP_PREFIX):].split('_')[0])
        except ValueError:
            continue
        if _running(pid):
            continue
        try:
            os.unlink(os.path.join(output_dir, name))
            removed.append(name)
        except OSError:
            pass
    return removed


def _readable(path):
    """The permissions a file created the ordinary way would have (mkstemp makes it 0600)."""
    umask = 0o022
    try:
        with open('/proc/self/status') as f:
            umask = next(int(l.split()[1], 8) for l in f if l.startswith('Umask:'))
    except (OSError, StopIteration, ValueError):
        pass
    os.chmod(path, 0o666 & ~umask)


def _running(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
