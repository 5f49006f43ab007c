"""Helper processes (the learners of a training, the plot process) that are safe to start from a threaded node and
never outlive it. No rospy.

- **Never forked from the caller**: ``spawn`` starts a fresh interpreter with subprocess, which on Linux uses
  vfork + exec here (no ``preexec_fn``): the caller's atfork handlers do not run, so a thread of the caller that is
  inside OpenBLAS (an ``~evaluate`` call) cannot deadlock the start (OpenBLAS's fork handler waits for its threads
  with the GIL held). Nothing of the caller is inherited but the environment: no sockets (the node's ports), no
  pipes of other children (``close_fds``).
- **Never outlive the parent**: the child calls ``die_with_parent`` first thing: the kernel sends it a signal
  when the parent ends, however it ends (SIGKILL included), and a parent that ended before the call is noticed too.
- **Never see a Ctrl-C meant for others**: each child leads a process group of its own, so a terminal's Ctrl-C
  (or roslaunch's SIGINT to a node's group) reaches the parent only, and the parent ends its children; a child
  never prints a KeyboardInterrupt traceback while it is still importing its modules.

Frames (``write_frame`` / ``FrameReader``): length-prefixed pickles between a parent and the child it spawned
(both this package's code); a frame cut short by a dying child is never taken for a message.

    proc = spawn('robot_ai.cartpole.learner_worker')     # in the child's main: die_with_parent(signal.SIGKILL)
"""
import ctypes
import os
import pickle
import signal
import struct
import subprocess
import sys
from dataclasses import dataclass
from typing import BinaryIO, ClassVar

PARENT_PID_ENV = 'ROBOT_AI_PARENT_PID'
PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36     # orphans below this process become its children (launch_guard, check_fk)
_HEADER = struct.Struct('<Q')


def spawn(module: str, *args: str, text: bool = False, stderr=None) -> subprocess.Popen:
    """`python -m module args` with the caller's interpreter and import path, pipes on stdin and stdout, in a
    process group of its own; the child learns its parent's pid (for die_with_parent)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p), **{PARENT_PID_ENV: str(os.getpid())})
    return subprocess.Popen([sys.executable, '-m', module, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=stderr, env=env, close_fds=True, process_group=0, text=text,
                            bufsize=1 if text else -1)


def die_with_parent(signum: int = signal.SIGTERM) -> None:
    """In a child started by spawn: get signum when the parent ends (Linux's PR_SET_PDEATHSIG); end at once if it
    has already ended. Elsewhere (not Linux, or not started by spawn) the parent check is skipped."""
    parent = os.environ.get(PARENT_PID_ENV)
    if not sys.platform.startswith('linux'):
        return
    prctl(PR_SET_PDEATHSIG, int(signum))
    if parent and os.getppid() != int(parent):  # the parent ended before prctl: no signal will come
        os._exit(1)


def alive(pid: int) -> bool:
    """Whether a process of that pid exists (one of another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def prctl(option: int, value: int) -> bool:
    """Linux's prctl(option, value); whether it succeeded."""
    return ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0


@dataclass(frozen=True)
class ProcessStat:
    """What /proc/<pid>/stat says of a process: its state letter ('R', 'S', 'T' stopped, 'Z' zombie, ...) and its
    parent's pid."""
    state: str
    ppid: int

    _WORDS: ClassVar[dict[str, str]] = {'R': 'running', 'S': 'sleeping', 'D': 'waiting on the disk', 'T': 'stopped',
                                        't': 'stopped', 'Z': 'ended'}

    @property
    def stopped(self) -> bool:
        """Stopped (SIGSTOP, a Ctrl-Z, a debugger): it will not do anything before it is continued."""
        return self.state in ('T', 't')

    @property
    def in_words(self) -> str:
        """The state for a message: 'running', 'stopped', ..."""
        return self._WORDS.get(self.state, f'state {self.state}')


def process_stat(pid: int) -> ProcessStat | None:
    """/proc/<pid>/stat's state and parent; None if there is no such process. (The name, in parentheses, may hold
    spaces and parentheses: the fields are read after its last ')'.)"""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return ProcessStat(fields[0], int(fields[1]))
    except (OSError, IndexError, ValueError):
        return None


def descendants(pid: int) -> list[int]:
    """Every live process below pid (children first), from /proc."""
    children: dict[int, list[int]] = {}
    for entry in filter(str.isdigit, os.listdir('/proc')):
        stat = process_stat(int(entry))
        if stat is not None and stat.state != 'Z':
            children.setdefault(stat.ppid, []).append(int(entry))
    found, todo = [], list(children.get(pid, []))
    while todo:
        p = todo.pop(0)
        found.append(p)
        todo.extend(children.get(p, []))
    return found


def reap() -> None:
    """Collect the exit status of every ended child (a subreaper's orphans become its children)."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def write_frame(stream: BinaryIO, message) -> None:
    """One message on a binary stream: its pickle's length, then the pickle."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def read_frame(stream: BinaryIO):
    """The next message of a blocking binary stream; None at its end (or at a frame cut short)."""
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        return None
    size = _HEADER.unpack(header)[0]
    data = stream.read(size)
    return pickle.loads(data) if len(data) == size else None


class FrameReader:
    """Messages out of the bytes of a non-blocking read, as they come: feed(chunk) -> the messages it completed."""

    def __init__(self):
        self._buffer = bytearray()

    def feed(self, chunk: bytes) -> list:
        self._buffer += chunk
        messages = []
        while len(self._buffer) >= _HEADER.size:
            size = _HEADER.unpack_from(self._buffer)[0]
            end = _HEADER.size + size
            if len(self._buffer) < end:
                break
            messages.append(pickle.loads(bytes(self._buffer[_HEADER.size:end])))
            del self._buffer[:end]
        return messages

    @property
    def partial(self) -> bool:
        """Whether bytes of an unfinished frame are waiting."""
        return bool(self._buffer)
