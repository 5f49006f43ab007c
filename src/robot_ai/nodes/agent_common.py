"""What the CartPole agent nodes share: parameters, the plot process, and how requests and goals are answered.

Plots are drawn by ``robot_ai.plot_worker`` in a process of its own, so that a response never waits for
matplotlib nor shares the GIL with it. The response therefore arrives before its plot: ``plot_path`` names
the file the plot process is drawing, which appears whole (it is renamed into place once written), usually
within a second; the response's message says so.
"""
import os
import subprocess
import sys
import threading

import rospy

from robot_ai.cartpole.artifacts import default_output_dir
from robot_ai.cartpole.dynamics import RequestError
from robot_ai.plot_worker import job_line


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
    return os.path.abspath(os.path.expanduser(rospy.get_param('~output_dir', '') or default_output_dir()))


class PlotProcess(object):
    """The node's plot process: started at once, restarted if it dies, ended with the node."""

    def __init__(self):
        self.lock = threading.Lock()
        self.proc = None
        self._start()
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
        """Hand a plot job to the plot process; False (and a logged reason) if it could not be handed over."""
        with self.lock:
            for _ in range(2):
                if self.proc.poll() is not None:
                    rospy.logwarn('the plot process ended (status %s); starting another', self.proc.returncode)
                    self._start()
                try:
                    self.proc.stdin.write(job_line(job, path))
                    self.proc.stdin.flush()
                    return True
                except (BrokenPipeError, OSError) as e:
                    rospy.logwarn('could not hand the plot %s to the plot process: %s', path, e)
        rospy.logerr('plot not written: %s', path)
        return False

    def close(self):
        """End of input: the plot process finishes the plots it has and ends."""
        try:
            self.proc.stdin.close()
            self.proc.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()


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
