"""The processes of one FK check: a roscore of its own, the candidate's output drained into a bounded log, and
everything the candidate leaves behind ended. No rospy.

    core = start_master(); wait_for_master(core)        # None when a master already runs
    output = Output(proc.stdout, log_path('my_fk'))      # output.lines(): its last lines, escaped, for the report
    stop(proc); end_descendants()
"""
import collections
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

from robot_ai.child_process import descendants, reap
from robot_ai.grading import sandbox

TAIL_LINES = 20         # lines of the candidate's output quoted in a verdict
TAIL_CHARS = 300        # characters kept of each of them
EXCEPTION_LINE = re.compile(r'^[A-Za-z_][\w.]*(Error|Exception|Exit|Interrupt)(: |$)')   # a traceback's last line
LOG_BYTES = 10 * 1024 * 1024   # the candidate's log file stops growing here (its output is still drained)
CHUNK = 64 * 1024              # bytes of the candidate's output read at a time


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


MASTER_MEMORY = 2 * 1024 ** 3    # bytes of address space of the roscore a check starts (its master and rosout)


def start_master():
    """The roscore process this starts (robot_ai.grading.master: ROS's master and rosout, its parameters bounded), or
    None when a master already runs (ROS_MASTER_URI). It has MASTER_MEMORY of address space (and rosout, its child,
    too); `core.refused_file` is where it says who it refused a parameter (robot_ai.grading.master.read_refused)."""
    import rosgraph
    if rosgraph.is_master_online():
        return None
    port = free_port()
    os.environ['ROS_MASTER_URI'] = f'http://127.0.0.1:{port}'
    limit = [sandbox.tool('prlimit'), f'--as={MASTER_MEMORY}', '--'] if sandbox.tool('prlimit') else []
    folder = os.path.join(os.environ.get('ROS_HOME') or os.path.expanduser('~/.ros'), 'log')
    os.makedirs(folder, exist_ok=True)
    refused = os.path.join(folder, f'check_fk_master_{os.getpid()}_{port}.json')
    core = subprocess.Popen(limit + [sys.executable, '-m', 'robot_ai.grading.master', str(port), refused],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                            preexec_fn=os.setsid)
    core.refused_file = refused
    return core


def wait_for_master(core) -> None:
    import rosgraph
    deadline = time.time() + 30
    while core is not None and not rosgraph.is_master_online():
        if time.time() > deadline or core.poll() is not None:
            raise RuntimeError(f'could not start a roscore at {os.environ["ROS_MASTER_URI"]}')
        time.sleep(0.2)


def stop(proc, timeout: float = 10) -> None:
    """SIGINT to the process's group (it was started in a session of its own), then SIGKILL to what is left of the
    group: a child that ignores SIGINT, or outlives its parent, does not survive."""
    if proc is None:
        return
    if proc.poll() is None:
        signal_group(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
    signal_group(proc.pid, signal.SIGKILL)
    proc.wait()


def signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Output:
    """A process's stdout and stderr, drained by a thread into a log file (bounded; none where path is ''), its last
    lines kept."""

    def __init__(self, stream, path: str):
        self.path = path
        self.tail = collections.deque(maxlen=TAIL_LINES)
        self.thread = threading.Thread(target=self._drain, args=(stream,), daemon=True)
        self.thread.start()

    def _drain(self, stream):
        """Read the output in pieces of at most CHUNK bytes, whatever it writes (1 GiB without a newline
        included): the log is cut at LOG_BYTES, a line kept for the tail at TAIL_CHARS."""
        written, line = 0, b''
        try:
            log = open(self.path, 'wb') if self.path else None
        except OSError:
            log, self.path = None, ''
        fd = stream.fileno()
        while True:
            try:
                chunk = os.read(fd, CHUNK)
            except OSError:
                break
            if not chunk:
                break
            if log is not None and written < LOG_BYTES:
                log.write(chunk[:LOG_BYTES - written])
                written += len(chunk)
            *complete, rest = chunk.split(b'\n')
            for piece in complete:
                self._keep((line + piece)[:4 * TAIL_CHARS])
                line = b''
            line = (line + rest)[:4 * TAIL_CHARS]
        if line:
            self._keep(line)
        if log is not None:
            log.close()

    def _keep(self, line: bytes) -> None:
        text = line.decode(errors='replace').rstrip()
        if text:    # escaped: a carriage return or an escape sequence in it cannot rewrite a line of the report
            self.tail.append(sandbox.printable(text, TAIL_CHARS))

    def exception(self) -> str:
        """The last line of the last Python traceback in its output (`ValueError: 'tool' is not in list`), or ''."""
        self.thread.join(1.0)
        lines = list(self.tail)
        for i in range(len(lines) - 1, -1, -1):
            if EXCEPTION_LINE.match(lines[i]) and any(l.startswith('Traceback (most recent call last)')
                                                      or l.startswith('  File ') for l in lines[:i]):
                return lines[i]
        return ''

    def lines(self) -> list[str]:
        """The last lines of its output, indented, and where the whole output is; [] if there was none."""
        self.thread.join(1.0)
        if not self.tail:
            return []
        where = [f'  (its whole output: {self.path})'] if self.path else []
        return ['its last output:'] + ['  | ' + l for l in self.tail] + where


def log_path(candidate: str) -> str:
    """Where the candidate's output goes: $ROS_HOME/log/check_fk_<candidate>_<pid>.log."""
    folder = os.path.join(os.environ.get('ROS_HOME') or os.path.expanduser('~/.ros'), 'log')
    os.makedirs(folder, exist_ok=True)
    return os.path.join(folder, f'check_fk_{candidate.replace("/", "_")}_{os.getpid()}.log')


def end_descendants(keep=None) -> None:
    """SIGKILL every process left below this one but keep (a Popen) and its own, and reap them: check_fk is a child
    subreaper, so whatever the candidate started and left behind has become its descendant. It goes on until none is
    left, for up to 10 s of a clock rather than 100 rounds of 10 ms: a killed process is gone only once it is
    scheduled, which a loaded machine may delay past a second."""
    deadline = time.monotonic() + 10.0
    while True:
        spared = set() if keep is None else {keep.pid, *descendants(keep.pid)}
        left = [pid for pid in descendants(os.getpid()) if pid not in spared]
        if not left or time.monotonic() > deadline:
            return
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.01)
        reap()
