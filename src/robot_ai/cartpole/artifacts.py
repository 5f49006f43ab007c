"""Where the agents' files go, what they are called, and how they are drawn: plots and videos. No rospy.

A plot is described by a job, a plain dict that crosses a pipe as JSON (the nodes hand plots to
``robot_ai.plot_worker``, a process of its own) and is drawn by ``write_plot``::

    job = {'title': ..., 'xlabel': ..., 'ylabel': ...,
           'series': [{'y': [...], 'x': [...] (default 1..n), 'label': ..., 'style': 'line' | 'points' | 'step',
                       'color': ..., 'lw': ..., 'alpha': ...}, ...],
           'hlines': [{'y': ..., 'label': ..., 'color': ..., 'ls': ...}, ...],
           'ylim': [low, high] (optional), 'integer_x': true, 'xscale': 'log' (optional)}
    write_plot(search_plot_job(result), stem + '.png')

Plots, videos, policy files and CSV logs are written whole or not at all: into a hidden temporary file beside them,
named after the writing process (so that ``remove_leftovers`` can tell a dead writer's leftovers), then renamed into
place.
"""
import csv
import io
import os
import tempfile
import threading
import time

import numpy as np

FIGSIZE_INCHES, DPI = (10.0, 5.6), 100   # 1000 x 560 pixels: reads well in a README
TEMP_PREFIX = '.robot_ai_tmp_'          # + <pid>_...: files being written; see remove_leftovers
EXTENSIONS = ('.png', '.mp4', '.npz', '.csv')   # one run's files: plot, video, policy, log
_reserved = set()                       # stems handed out by this process whose files may not exist yet
_reserved_lock = threading.Lock()


def default_output_dir() -> str:
    """$ROS_HOME/robot_ai, or ~/.ros/robot_ai when ROS_HOME is unset: where every agent's files go."""
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(ros_home, 'robot_ai')


def artifact_stem(output_dir: str, kind: str, env_id: str, seed: int) -> str:
    """A path without extension for one run's files, new in output_dir: <kind>_<time>_<env>_seed<seed>[_n].

    The seed is written as given (seed-1 for -1). Stems handed out earlier by this process are not handed out
    again, even before their files exist."""
    os.makedirs(output_dir, exist_ok=True)
    base = os.path.join(output_dir, f'{kind}_{time.strftime("%Y%m%d-%H%M%S")}_{env_id}_seed{int(seed)}')
    with _reserved_lock:
        stem, n = base, 1
        while stem in _reserved or any(os.path.lexists(stem + ext) for ext in EXTENSIONS):
            n += 1
            stem = f'{base}_{n}'
        _reserved.add(stem)
    return stem


def search_plot_job(result) -> dict:
    """The learning curve of a linear_search.SearchResult: every candidate's average length, the best so far,
    the random-action baseline and the step limit."""
    avgs = [float(v) for v in result.avg_lengths]
    hlines = []
    if np.isfinite(result.baseline_avg_length):
        hlines.append(dict(y=result.baseline_avg_length, label=f'random actions ({result.baseline_avg_length:.1f})',
                           color='tab:gray', ls='--'))
    hlines.append(dict(y=result.max_steps, label=f'step limit ({result.max_steps})', color='tab:red', ls=':'))
    return dict(
        title=f'{result.env_id} random search, seed {result.seed}: best {result.best_avg_length:.1f}, '
              f'final {result.final_avg_length:.1f}',
        xlabel='candidate (iteration)', ylabel=f'average episode length over {result.episodes} episodes',
        series=[dict(y=avgs, label='candidate average length', style='points', color='tab:blue'),
                dict(y=[float(v) for v in np.maximum.accumulate(avgs)] if avgs else [], label='best so far',
                     style='step', color='tab:orange', lw=2)],
        hlines=hlines, ylim=[0, result.max_steps * 1.05], integer_x=True)


def ars_plot_job(result, settings, search, env_id: str, final_average: float) -> dict:
    """ARS's learning curve beside the course's random search, against the episodes each played (log scale): ARS's
    average length of its perturbed policies per iteration, the random search's best candidate so far."""
    per_iteration = 2 * settings.directions * settings.episodes
    ars_x = [per_iteration * (i + 1) for i in range(len(result.history))]
    search_x = [search.episodes * (i + 1) for i in range(len(search.avg_lengths))]
    return dict(
        title=f'{env_id}: ARS (final average {final_average:.1f}) and the course\'s random search (final average '
              f'{search.final_avg_length:.1f}), seed {result.seed}',
        xlabel='episodes played (log scale)', ylabel='average episode length', xscale='log',
        series=[dict(x=ars_x, y=[float(h.rollout_return) for h in result.history], style='line', color='tab:orange',
                     lw=2, label=f'ARS: its perturbed policies ({settings.directions} directions x 2)'),
                dict(x=search_x, y=[float(v) for v in np.maximum.accumulate(search.avg_lengths)], style='step',
                     color='tab:blue', lw=2, label=f'random search: best so far ({search.episodes} episodes each)')],
        hlines=[dict(y=search.max_steps, label=f'step limit ({search.max_steps})', color='tab:red', ls=':')],
        ylim=[0, search.max_steps * 1.05])


def ars_log(result, settings) -> tuple[list, list]:
    """(header, rows) of an ARS run's CSV log: one row per iteration."""
    header = ['iteration', 'steps', 'episodes', 'seconds', 'rollout_return', 'eval_return', 'success_rate',
              'final_metric']
    per_iteration = 2 * settings.directions * settings.episodes + settings.eval_episodes
    return header, [[h.iteration, h.steps, h.iteration * per_iteration, f'{h.elapsed:.3f}', repr(h.rollout_return),
                     repr(h.eval_return), repr(h.success_rate), repr(h.final_metric)] for h in result.history]


def q_learning_plot_job(result) -> dict:
    """The learning curves of a q_learning.TrainingResult: learner 0's total reward per episode and its running
    average of 100, every other learner's running average as a faint line, the random-action baseline."""
    from robot_ai.cartpole.q_learning import running_average, RBF_GAMMAS
    t = result.training
    rewards = [np.asarray(r, dtype=np.float64) for r in result.total_rewards]
    others = f'learners 1-{len(rewards) - 1}' if len(rewards) > 2 else 'learner 1'
    series = [dict(y=[float(v) for v in running_average(r)], style='line', color='tab:blue', alpha=0.3, lw=1,
                   label=f'{others}: running average of 100' if j == 1 else None)
              for j, r in enumerate(rewards) if j > 0]
    series += [dict(y=[float(v) for v in rewards[0]], style='points', color='tab:gray', ms=3,
                    label='learner 0: total reward per episode'),
               dict(y=[float(v) for v in running_average(rewards[0])], style='line', color='tab:orange', lw=2.5,
                    label='learner 0: running average of 100')]
    best = t.max_steps if t.bootstrap_at_time_limit else t.max_steps - 1
    spread = (f'{len(result.last100_averages)} learners, last-100 average {result.mean_last100:.1f} '
              f'$\\pm$ {result.ci95_last100:.1f}' if len(result.last100_averages) > 1   # mathtext: a real +-
              else f'last-100 average {result.mean_last100:.1f}')
    if len(result.greedy_averages):
        greedy = result.greedy_averages
        spread += (f'; final greedy agents: {greedy.min():.1f} to {greedy.max():.1f} steps' if len(greedy) > 1
                   else f'; final greedy agent: {greedy[0]:.1f} steps')
        from robot_ai.cartpole.q_learning import collapsed_learners
        bad = collapsed_learners(result)
        if bad:   # a line of its own, short enough for the plot's width
            spread += (f'\ncollapsed at the end of training: {"learners" if len(bad) > 1 else "learner"} '
                       f'{", ".join(map(str, bad))} (greedy far below last-100)')
    if result.failed:   # their curves stop where their processes did
        spread += (f'\n{"learners" if len(result.failed) > 1 else "learner"} {", ".join(map(str, result.failed))} '
                   'failed: the curve stops where the process did')
    return dict(
        title=f'{result.env_id} Q-learning, {t.regressor} regressor, {len(RBF_GAMMAS)} x {t.components} RBF features, '
              f'seed {result.seed}\n{spread}',
        xlabel='episode', ylabel='total reward (+1 steps)', series=series,
        hlines=[dict(y=result.baseline_total_reward, label=f'random actions ({result.baseline_total_reward:.1f})',
                     color='tab:gray', ls='--'),
                dict(y=best, label=f'the most an episode can total ({best})', color='tab:red', ls=':')],
        ylim=[0, t.max_steps * 1.05], integer_x=True)


def write_plot(job: dict, path: str) -> str:
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
        if job.get('xscale'):
            ax.set_xscale(job['xscale'])
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
            fig.legend(*zip(*keep), loc='outside lower center', ncols=min(3 if len(keep) > 4 else 4, len(keep)),
                       fontsize=9, frameon=False)
        write_whole(path, lambda f: fig.savefig(f, format='png'))
    finally:
        plt.close(fig)
    return path


def write_whole(path: str, write) -> str:
    """Write a file whole or not at all: write(f) fills a hidden temporary binary file beside path, named after
    this process, which is then renamed into place; return path."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=f'{TEMP_PREFIX}{os.getpid()}_', suffix=os.path.splitext(path)[1], dir=folder)
    try:
        with os.fdopen(fd, 'wb') as f:
            write(f)
        readable(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_csv(path: str, header: list, rows) -> str:
    """A CSV file with a header row, whole or not at all; return path."""
    def write(f):
        text = io.TextIOWrapper(f, encoding='utf-8', newline='')
        out = csv.writer(text)
        out.writerow(header)
        out.writerows(rows)
        text.flush()
        text.detach()
    return write_whole(path, write)


def search_log(result) -> tuple[list, list]:
    """(header, rows) of a search's CSV log: one row per candidate evaluated."""
    header = ['candidate', 'w_x', 'w_x_dot', 'w_theta', 'w_theta_dot', 'avg_length']
    return header, [[i + 1] + [repr(float(v)) for v in w] + [repr(float(a))]
                    for i, (w, a) in enumerate(zip(result.weights, result.avg_lengths))]


def q_learning_log(result) -> tuple[list, list]:
    """(header, rows) of a training's CSV log: one row per episode per learner, learners in order."""
    from robot_ai.cartpole.q_learning import epsilon
    header = ['learner', 'seed', 'episode', 'total_reward', 'epsilon']
    return header, [[j, result.seed + j, n + 1, int(total), repr(epsilon(n))]
                    for j, totals in enumerate(result.total_rewards) for n, total in enumerate(totals)]


def write_video(path: str, frames, fps: float) -> str:
    """An mp4 of frames (an iterable of (H, W, 3) uint8 arrays, all one size), written whole or not at all; return
    path. Frames are streamed to ffmpeg one at a time (memory stays flat however long the video) into a hidden
    temporary file beside path, named after this process, and renamed into place when complete."""
    import imageio_ffmpeg
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=f'{TEMP_PREFIX}{os.getpid()}_', suffix='.mp4', dir=folder)
    os.close(fd)
    writer = None
    try:
        for frame in frames:
            if writer is None:
                writer = imageio_ffmpeg.write_frames(tmp, (frame.shape[1], frame.shape[0]), fps=fps,
                                                     macro_block_size=1, output_params=['-y'])
                writer.send(None)  # start ffmpeg
            writer.send(np.ascontiguousarray(frame))
        if writer is None:
            raise RuntimeError('no frame to write')
        writer.close()
        writer = None
        if os.path.getsize(tmp) == 0:
            raise RuntimeError('ffmpeg wrote an empty video')
        readable(tmp)
        os.replace(tmp, path)
    except BaseException:
        if writer is not None:
            writer.close()
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def record_video(env_id: str, policy, max_steps: int, seed: int, path: str) -> tuple[str, int]:
    """mp4 of one episode rendered by gymnasium (rgb_array), written whole or not at all (write_video); returns
    (path, steps). policy(observation) -> action (0 or 1); the start state comes from gymnasium's reset(seed)."""
    os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    os.environ.setdefault('SDL_AUDIODRIVER', 'dummy')
    from robot_ai.cartpole.dynamics import make_env
    env = make_env(env_id, render_mode='rgb_array', max_episode_steps=max_steps)
    steps = 0

    def frames():
        nonlocal steps
        obs, _ = env.reset(seed=int(seed) % (2 ** 32))
        yield env.render()
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            steps += 1
            done = terminated or truncated
            yield env.render()
    try:
        write_video(path, frames(), env.metadata['render_fps'])
    finally:
        env.close()
    return path, steps


MIN_FREE_BYTES = 32 * 1024 * 1024   # a plot is ~60 KB, a video ~100 KB: below this, a disk is as good as full


def unwritable_reason(output_dir: str, min_free: int = MIN_FREE_BYTES) -> str:
    """Why files cannot be written in output_dir (not writable, or a nearly full disk), or '' if they can."""
    if not os.access(output_dir, os.W_OK | os.X_OK):
        return f'{output_dir} is not writable'
    try:
        st = os.statvfs(output_dir)
    except OSError as e:
        return f'cannot tell the free space where {output_dir} is: {e}'
    free = st.f_bavail * st.f_frsize
    if free < min_free:
        return (f'the disk where {output_dir} is is full: {free // 1024} KiB free '
                f'(at least {min_free // (1024 * 1024)} MiB wanted)')
    return ''


def remove_leftovers(output_dir: str) -> list[str]:
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


def readable(path: str) -> None:
    """The permissions a file created the ordinary way would have (mkstemp makes it 0600)."""
    umask = 0o022
    try:
        with open('/proc/self/status') as f:
            umask = next(int(l.split()[1], 8) for l in f if l.startswith('Umask:'))
    except (OSError, StopIteration, ValueError):
        pass
    os.chmod(path, 0o666 & ~umask)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
