"""Where a run's files go, what they are called, and how they are written: output folders, CSV logs, plots, videos
and whole-file writes, for every part of the package (the cart-pole's agents, reach, the grader). No rospy.

A plot is described by a job, a plain dict that crosses a pipe as JSON (the nodes hand plots to
``robot_ai.plot_worker``, a process of its own) and is drawn by ``write_plot``::

    job = {'title': ..., 'xlabel': ..., 'ylabel': ...,
           'series': [{'y': [...], 'x': [...] (default 1..n), 'label': ..., 'style': 'line' | 'points' | 'step',
                       'color': ..., 'lw': ..., 'alpha': ...}, ...],
           'hlines': [{'y': ..., 'label': ..., 'color': ..., 'ls': ...}, ...],
           'ylim': [low, high] (optional), 'integer_x': true, 'xscale': 'log' (optional)}
    write_plot(job, artifact_stem(default_output_dir(), 'search', 'CartPole-v1', 0) + '.png')

What a job holds for each run is its part's business (``robot_ai.cartpole.outputs``, ``robot_ai.reach``'s CLI).

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

from robot_ai.child_process import alive

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
        if alive(pid):
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
