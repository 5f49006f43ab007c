"""What the CartPole agent nodes share: parameters, the plot process, and how requests and goals are answered.

Plots are drawn by ``robot_ai.plot_worker`` in a process of its own, so that a response never waits for
matplotlib nor shares the GIL with it. The response therefore arrives before its plot: ``plot_path`` names
the file the plot process is drawing, which appears whole (it is renamed into place once written), usually
within a second; the response's message says so.
"""
import os
import queue
import subprocess
import sys
import threading
import time

import rospy

from robot_ai.cartpole.artifacts import artifact_stem, default_output_dir, remove_leftovers, unwritable_reason
from robot_ai.cartpole.dynamics import RequestError
from robot_ai.plot_worker import job_line


def agent_settings(module, what):
    """(defaults, output_dir) of an agent node whose pure module has DEFAULTS and resolve(defaults=...): read
    from the ~ parameters, checked at start (a bad one raises, with a message), the folder prepared."""
    defaults = defaults_from_params(module.DEFAULTS)
    output_dir = output_dir_param()
    problem = prepare_output_dir(output_dir)
    if problem:
        rospy.logwarn('%s: %s will answer without plots and videos', problem, what)
    module.resolve(defaults=defaults)  # a bad default is a clear error at start, not at the first request
    return defaults, output_dir


def defaults_from_params(defaults):
    """The node's defaults for zero/empty request fields: each ~<name> parameter, where it is set and not
    zero or empty, else the pure module's default. A value of the wrong kind is a ValueError naming it."""
    out = {}
    for name, default in defaults.items():
        value = rospy.get_param('~' + name, '')
        if value in ('', 0, None):
            out[name] = default
            continue
        try:
            out[name] = type(default)(value)
        except (TypeError, ValueError):
            raise ValueError('~%s must be %s (like %r), got %r' % (name, type(default).__name__, default, value))
    return out


def output_dir_param():
    """~output_dir, expanded; empty or unset: $ROS_HOME/robot_ai (~/.ros/robot_ai when ROS_HOME is unset)."""
    value = rospy.get_param('~output_dir', '')
    if not isinstance(value, str):
        raise ValueError('~output_dir must be a folder path, got %r' % (value,))
    return os.path.abspath(os.path.expanduser(value or default_output_dir()))


class PlotProcess(object):
    """The node's plot process, fed by a thread of its own: draw() never waits for it.

    A job waits in a queue of PENDING; a writer thread hands it to the plot process (restarted if it died). A
    plot process that hangs only stalls that thread: once PENDING jobs wait, draw() says no and the plot is
    skipped, never a search or a training."""
    PENDING = 8

    def __init__(self):
        self.jobs = queue.Queue(maxsize=self.PENDING)
        self.proc = None
        self._start()
        threading.Thread(target=self._hand_over, name='plot jobs', daemon=True).start()
        rospy.on_shutdown(self.close)

    def _start(self):
        self.proc = subprocess.Popen([sys.executable, '-m', 'robot_ai.plot_worker'], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, bufsize=1)
        threading.Thread(target=self._log, args=(self.proc,), name='plots', daemon=True).start()

    @staticmethod
    def _log(proc):
        for line in proc.stdout:
            rospy.loginfo('plot %s', line.strip())

    def draw(self, job, path):
        """Queue a plot job; '' if queued, else why the plot is skipped."""
        try:
            self.jobs.put_nowait((job, path))
            return ''
        except queue.Full:
            rospy.logwarn_throttle(10.0, 'plot skipped: the plot process is behind (%d plots waiting)' % self.PENDING)
            return 'the plot process is behind (%d plots waiting)' % self.PENDING

    def _hand_over(self):
        while True:
            item = self.jobs.get()
            if item is None:
                return
            job, path = item
            for _ in range(2):
                if self.proc.poll() is not None:
                    rospy.logwarn('the plot process ended (status %s); starting another', self.proc.returncode)
                    self._start()
                try:
                    self.proc.stdin.write(job_line(job, path))
                    self.proc.stdin.flush()
                    break
                except (BrokenPipeError, OSError, ValueError) as e:
                    rospy.logwarn('could not hand the plot %s to the plot process: %s', path, e)
            else:
                rospy.logerr('plot not written: %s', path)

    def close(self):
        """End of input once the queued plots are handed over: the plot process draws them and ends (bounded)."""
        try:
            self.jobs.put(None, timeout=2.0)
        except queue.Full:
            pass
        deadline = time.time() + 10
        while not self.jobs.empty() and time.time() < deadline:
            time.sleep(0.05)
        try:
            self.proc.stdin.close()
            self.proc.wait(max(0.1, deadline - time.time()))
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()


def prepare_output_dir(output_dir):
    """Create output_dir and remove what writers killed earlier left in it; a reason string if it is not
    writable or its disk is full (the agents then answer without files), else ''."""
    try:
        os.makedirs(output_dir, exist_ok=True)
    except OSError as e:
        return 'cannot create %s: %s' % (output_dir, e.strerror or e)
    removed = remove_leftovers(output_dir)
    if removed:
        rospy.loginfo('removed %d temporary files that killed writers left in %s', len(removed), output_dir)
    return unwritable_reason(output_dir)


def write_files(plots, output_dir, kind, env_id, seed, plot_job, video=None):
    """A response's files: (plot_path, video_path, a note for its message). Never raises: the numbers are worth
    returning whatever happens to the files; a path is '' unless its file is written (the video) or queued
    for drawing (the plot), and the note says what failed and why.

    video: None, or a function of the mp4 path that writes it."""
    problem = prepare_output_dir(output_dir)
    if problem:
        return '', '', 'no files written: %s' % problem
    try:
        stem = artifact_stem(output_dir, kind, env_id, seed)
    except OSError as e:
        return '', '', 'no files written: %s' % e
    skipped = plots.draw(plot_job, stem + '.png')
    notes = ['learning curve skipped: %s' % skipped if skipped else 'learning curve being drawn to plot_path']
    video_path = ''
    if video is not None:
        try:
            video_path = video(stem + '.mp4')
        except Exception as e:  # ffmpeg, a full disk, a read-only folder: the search's numbers still go back
            rospy.logerr('video not written: %s', e)
            notes.append('video not written: %s' % e)
    return '' if skipped else stem + '.png', video_path, '; '.join(notes)


def answer(work, response_class, what):
    """A service's response: work() returns (the response's fields, result), fields None if the node's shutdown
    stopped the work; a RequestError or any other
    failure becomes success: false with the reason, and the node keeps serving."""
    try:
        fields, _ = work()
        if fields is None:
            return response_class(success=False, message='cancelled: the node is shutting down')
        return response_class(**fields)
    except RequestError as e:
        return response_class(success=False, message=str(e))
    except Exception as e:
        rospy.logerr('%s failed: %s', what, e)
        return response_class(success=False, message='%s failed: %s' % (what, e))


def answer_goal(server, work, result_class, what, cancelled):
    """An action goal's end: work() returns (fields, result), fields None if the goal was cancelled (or the node
    shut down), when
    cancelled(result) gives (message, the partial result's fields)."""
    try:
        fields, result = work()
    except RequestError as e:
        server.set_aborted(result_class(success=False, message=str(e)), str(e))
        return
    except Exception as e:
        rospy.logerr('%s failed: %s', what, e)
        server.set_aborted(result_class(success=False, message='%s failed: %s' % (what, e)))
        return
    if fields is None:
        message, partial = cancelled(result)
        server.set_preempted(result_class(success=False, message=message, **partial), message)
        return
    server.set_succeeded(result_class(**fields), fields['message'])
