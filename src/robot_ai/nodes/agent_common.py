"""What the CartPole agent nodes share: parameters, the plot process, and how requests and goals are answered.

Every successful search or training writes its policy file and a CSV log beside its plot (write_files), and
both nodes take a policy file at start (~policy) and at any time (~load_policy). Plots are drawn by
``robot_ai.plot_worker`` in a process of its own, so that a response never waits for matplotlib nor shares the GIL
with it. The response therefore arrives before its plot: ``plot_path`` names
the file the plot process is drawing, which appears whole (it is renamed into place once written), usually
within a second; the response's message says so.
"""
import os
import queue
import subprocess
import threading
import time
from dataclasses import dataclass
from typing import Callable

import rospy

from robot_ai import policies

from robot_ai.cartpole import policy_kinds
from robot_ai.artifacts import (artifact_stem, default_output_dir, remove_leftovers, unwritable_reason,
                                         write_csv)
from robot_ai.cartpole.dynamics import RequestError
from robot_ai.policies import Policy, PolicyError
from robot_ai.child_process import process_stat, spawn
from robot_ai.plot_worker import job_line
from robot_ai.srv import LoadPolicyResponse


def agent_settings(module, what: str) -> tuple[dict, str]:
    """(defaults, output_dir) of an agent node whose pure module has DEFAULTS and resolve(defaults=...): read
    from the ~ parameters, checked at start (a bad one raises, with a message), the folder prepared."""
    defaults = defaults_from_params(module.DEFAULTS)
    for name, value in defaults.items():  # each on its own: the message shows the package's default, not the value
        try:
            module.resolve(**{name: value})
        except RequestError as e:
            raise ValueError(f'~{name}: {e}')
    output_dir = output_dir_param()
    problem = prepare_output_dir(output_dir)
    if problem:
        rospy.logwarn(f'{problem}: {what} will answer without files (plots, videos, policies, logs)')
    module.resolve(defaults=defaults)  # a bad default is a clear error at start, not at the first request
    return defaults, output_dir


def defaults_from_params(defaults: dict) -> dict:
    """The node's defaults for zero/empty request fields: each ~<name> parameter, where it is set and not
    zero or empty, else the pure module's default. A value of the wrong kind is a ValueError naming it: nothing is
    converted silently (2.7 is not a whole number, true is not a number)."""
    out = {}
    for name, default in defaults.items():
        value = rospy.get_param('~' + name, '')
        if not isinstance(value, bool) and value in ('', 0, None):   # False == 0, but is no number here
            out[name] = default
            continue
        if isinstance(value, bool):
            ok = False
        elif isinstance(default, str):
            ok = isinstance(value, str)
        elif isinstance(default, int):
            ok = isinstance(value, int) or isinstance(value, float) and value.is_integer()
        else:
            ok = isinstance(value, (int, float))
        if not ok:
            raise ValueError(f'~{name} must be {type(default).__name__} (like {default!r}), got {value!r}')
        out[name] = type(default)(value)
    return out


def output_dir_param() -> str:
    """~output_dir, expanded; empty or unset: $ROS_HOME/robot_ai (~/.ros/robot_ai when ROS_HOME is unset)."""
    value = rospy.get_param('~output_dir', '')
    if not isinstance(value, str):
        raise ValueError(f'~output_dir must be a folder path, got {value!r}')
    return os.path.abspath(os.path.expanduser(value or default_output_dir()))


class PlotProcess:
    """The node's plot process, fed by a thread of its own: draw() never waits for it.

    A job waits in a queue of PENDING; a writer thread hands it to the plot process (restarted if it died), which
    acknowledges every plot (written or failed). A plot process that hangs only stalls that thread: once PENDING
    jobs wait, or plots wait and none was acknowledged for ACK_SECONDS, draw() says the plot process is behind
    and the plot is skipped, never a search or a training; a plot process silent twice that long is killed (its
    plots logged as lost) and the next plot starts another. The plot process (robot_ai.child_process.spawn)
    ends with the node however the node ends, and a Ctrl-C meant for the node never reaches it."""
    PENDING = 8
    ACK_SECONDS = 15.0

    def __init__(self):
        self.jobs = queue.Queue(maxsize=self.PENDING)
        self.lock = threading.Lock()
        self.handed: dict[str, float] = {}  # path -> when it was handed to the plot process, until acknowledged
        self.last_ack = time.monotonic()     # the plot process's last `written` or `failed`
        self.proc = None
        self._start()
        threading.Thread(target=self._hand_over, name='plot jobs', daemon=True).start()
        rospy.on_shutdown(self.close)

    def _start(self):
        self.proc = spawn('robot_ai.plot_worker', text=True, stderr=subprocess.PIPE)
        for stream in (self.proc.stdout, self.proc.stderr):
            threading.Thread(target=self._log, args=(stream,), name='plots', daemon=True).start()

    def _log(self, stream):
        """Log the plot process's lines; `written <path>` and `failed <path>: <why>` acknowledge a plot."""
        for line in stream:
            line = line.rstrip()
            status, _, rest = line.partition(' ')
            if status in ('written', 'failed'):
                with self.lock:
                    self.handed.pop(rest.split(': ', 1)[0] if status == 'failed' else rest, None)
                    self.last_ack = time.monotonic()
                (rospy.loginfo if status == 'written' else rospy.logerr)(f'plot {line}')
            elif line:
                rospy.logwarn(f'plot process: {line}')

    def overdue(self, seconds: float | None = None) -> str:
        """Why the plot process is behind ('' if it is not): plots wait for it and it has acknowledged none for
        `seconds` (ACK_SECONDS) since the oldest was handed over. A backlog it works through is not behind."""
        with self.lock:
            if not self.handed:
                return ''
            path, since = min(self.handed.items(), key=lambda item: item[1])
            silent = time.monotonic() - max(since, self.last_ack)
        if silent < (self.ACK_SECONDS if seconds is None else seconds):
            return ''
        return (f'the plot process is behind ({os.path.basename(path)} not written, nothing acknowledged for '
                f'{silent:.0f} s)')

    def draw(self, job: dict, path: str) -> str:
        """Queue a plot job; '' if queued, else why the plot is skipped."""
        behind = self.overdue()
        if not behind:
            try:
                self.jobs.put_nowait((job, path))
                return ''
            except queue.Full:
                behind = f'the plot process is behind ({self.PENDING} plots waiting)'
        rospy.logwarn(f'plot skipped: {behind}')
        return behind

    def _hand_over(self):
        while True:
            try:
                item = self.jobs.get(timeout=1.0)
            except queue.Empty:
                self._restart_if_silent()
                continue
            if item is None:
                return
            self._restart_if_silent()
            job, path = item
            for _ in range(2):
                if self.proc.poll() is not None:
                    rospy.logwarn(f'the plot process ended (status {self.proc.returncode}); starting another')
                    with self.lock:
                        self.handed.clear()
                    self._start()
                try:
                    with self.lock:
                        self.handed[path] = time.monotonic()
                    self.proc.stdin.write(job_line(job, path))
                    self.proc.stdin.flush()
                    break
                except (BrokenPipeError, OSError, ValueError) as e:
                    rospy.logwarn(f'could not hand the plot {path} to the plot process: {e}')
            else:
                rospy.logerr(f'plot not written: {path}')

    def _restart_if_silent(self) -> None:
        """Kill a plot process that has not acknowledged a plot for twice ACK_SECONDS (stopped, hung): the next
        plot starts another."""
        behind = self.overdue(2 * self.ACK_SECONDS)
        if not behind or self.proc.poll() is not None:
            return
        with self.lock:
            lost = sorted(self.handed)
            self.handed.clear()
        rospy.logerr(f'{behind}: killed it, a new one draws the next plot; plots not written: {", ".join(lost)}')
        self.proc.kill()
        self.proc.wait()

    def close(self) -> None:
        """End of input once the queued plots are handed over: the plot process draws them and ends (bounded; at
        once if it is behind)."""
        try:
            self.jobs.put(None, timeout=2.0)
        except queue.Full:
            pass
        deadline = time.time() + 10
        while not self.jobs.empty() and time.time() < deadline and not self.overdue():
            time.sleep(0.05)
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        while self.proc.poll() is None and time.time() < deadline and not self.overdue() and not stopped(self.proc):
            time.sleep(0.05)
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def stopped(proc: subprocess.Popen) -> bool:
    """Whether a child is stopped (SIGSTOP, a Ctrl-Z): it will not finish anything before it is continued."""
    stat = process_stat(proc.pid)
    return stat is not None and stat.stopped


def prepare_output_dir(output_dir: str) -> str:
    """Create output_dir and remove what writers killed earlier left in it; a reason string if it is not
    writable or its disk is full (the agents then answer without files), else ''."""
    try:
        os.makedirs(output_dir, exist_ok=True)
    except OSError as e:
        return f'cannot create {output_dir}: {e.strerror or e}'
    removed = remove_leftovers(output_dir)
    if removed:
        rospy.loginfo(f'removed {len(removed)} temporary files that killed writers left in {output_dir}')
    return unwritable_reason(output_dir)


@dataclass
class CancelledRun:
    """What a cancelled goal kept: its result so far, the seconds it ran, and the files of its best so far (None:
    nothing had finished)."""
    result: object
    elapsed: float
    files: 'Files | None' = None

    def fields(self) -> dict:
        return dict(elapsed=self.elapsed, **(self.files.fields() if self.files is not None else {}))

    def note(self) -> str:
        return f'; {self.files.note}' if self.files is not None else '; no files: nothing had finished'


@dataclass
class Files:
    """The files of one search or training: each path '' unless written (the plot: queued for drawing)."""
    plot_path: str = ''
    video_path: str = ''
    policy_path: str = ''
    log_path: str = ''
    note: str = ''

    def fields(self) -> dict:
        return dict(plot_path=self.plot_path, video_path=self.video_path, policy_path=self.policy_path,
                    log_path=self.log_path)


def write_files(plots: 'PlotProcess', output_dir: str, kind: str, env_id: str, seed: int, plot_job: dict,
                policy: Callable[[str], str] | None = None, log: tuple | None = None,
                video: Callable[[str], str] | None = None) -> Files:
    """A run's files beside each other (<stem>.npz, .csv, .png, .mp4). Never raises: the numbers are worth
    returning whatever happens to the files; a path is '' unless its file is written (or, the plot, queued for
    drawing), and the note says what failed and why.

    policy: a function of the .npz path that saves the run's policy; log: (header, rows) of its CSV;
    video: a function of the .mp4 path that writes it."""
    problem = prepare_output_dir(output_dir)
    if problem:
        return Files(note=f'no files written: {problem}')
    try:
        stem = artifact_stem(output_dir, kind, env_id, seed)
    except OSError as e:
        return Files(note=f'no files written: {e}')
    files, notes = Files(), []
    for name, what, write in (('policy_path', 'policy file', policy),
                              ('log_path', 'CSV log', None if log is None else lambda p: write_csv(p, *log)),
                              ('video_path', 'video', video)):
        if write is None:
            continue
        path = stem + {'policy_path': '.npz', 'log_path': '.csv', 'video_path': '.mp4'}[name]
        try:
            setattr(files, name, write(path))
        except Exception as e:  # a full disk, a read-only folder, ffmpeg: the numbers still go back
            rospy.logerr(f'{what} not written: {e}')
            notes.append(f'{what} not written: {e}')
    skipped = plots.draw(plot_job, stem + '.png')
    files.plot_path = '' if skipped else stem + '.png'
    notes.insert(0, f'learning curve skipped: {skipped}' if skipped else 'learning curve being drawn to plot_path')
    if policy is not None and files.policy_path:
        notes.append(f'policy saved to {files.policy_path}')
    if video is None:
        notes.append('no video asked for (record_video: false)')
    files.note = '; '.join(notes)
    return files


def policy_param(kind: str) -> Policy | None:
    """The policy file named by ~policy, loaded at start; None if unset or empty. A bad file, or a policy of
    another kind than this node serves, raises PolicyError (a ValueError) with one line."""
    path = rospy.get_param('~policy', '')
    if not isinstance(path, str):
        raise PolicyError(f'~policy must be a file path, got {path!r}')
    if not path:
        return None
    try:
        policy = load_of_kind(path, kind)
    except PolicyError as e:
        raise PolicyError(f'~policy: {e}')
    rospy.loginfo(f'loaded {policy.describe()}')
    return policy


def load_of_kind(path: str, kind: str, env_id: str = '') -> Policy:
    """policies.npz.load(path), refusing a policy of another kind than `kind` ('' takes both, and ONNX models:
    policy_kinds.load, env_id naming the CartPole of one whose metadata does not; PolicyError, one line)."""
    if not kind:
        return policy_kinds.load(path, env_id)
    if str(path).strip().lower().endswith('.onnx'):
        raise PolicyError(f'{path} is an ONNX model: this node starts from and serves {kind} policy files (.npz); '
                          f'an ONNX policy drives cartpole_controller (~policy, ~load_policy)')
    policy = policies.npz.load(path)
    if kind and policy.kind != kind:
        other = 'cartpole_search' if policy.kind == 'linear' else 'cartpole_q_learning'
        raise PolicyError(f'{policy.path} holds a {policy.kind} policy; this node serves {kind} policies '
                          f'(load it into {other}, or give it to cartpole_controller, which takes both)')
    return policy


def answer_load(path: str, kind: str, install: Callable[[Policy], str], env_id: str = '') -> LoadPolicyResponse:
    """~load_policy: load the file and install(policy) it as the node's policy; a bad file changes nothing."""
    try:
        policy = load_of_kind(path, kind, env_id)
    except PolicyError as e:
        rospy.logwarn(f'load_policy refused: {e}')
        return LoadPolicyResponse(success=False, message=f'{e}; the node keeps its policy')
    return LoadPolicyResponse(success=True, message=install(policy))


def stopping() -> bool:
    """Whether the node's shutdown has been asked for (from the moment a Ctrl-C comes, before rospy closes its
    services): a service's work ends at once and its caller is answered while it still can be."""
    return rospy.core.is_shutdown_requested() or rospy.is_shutdown()


def answer(work: Callable, response_class, what: str):
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
        if rospy.core.is_shutdown_requested():   # a publish to a topic the shutdown closed (rospy closes them before
            # is_shutdown() turns true): the shutdown's doing, not an error
            return response_class(success=False, message='cancelled: the node is shutting down')
        rospy.logerr(f'{what} failed: {e}')
        return response_class(success=False, message=f'{what} failed: {e}')


def answer_goal(server, work: Callable, result_class, what: str, cancelled: Callable) -> None:
    """An action goal's end: work() returns (fields, result), fields None if the goal was cancelled (or the node
    shut down), when
    cancelled(result) gives (message, the partial result's fields)."""
    try:
        fields, result = work()
    except RequestError as e:
        server.set_aborted(result_class(success=False, message=str(e)), str(e))
        return
    except Exception as e:
        if rospy.core.is_shutdown_requested():   # as in answer(): the goal ends with the node, quietly
            return
        rospy.logerr(f'{what} failed: {e}')
        server.set_aborted(result_class(success=False, message=f'{what} failed: {e}'))
        return
    if fields is None:
        message, partial = cancelled(result)
        server.set_preempted(result_class(success=False, message=message, **partial), message)
        return
    server.set_succeeded(result_class(**fields), fields['message'])
