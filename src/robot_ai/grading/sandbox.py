"""A sandbox for untrusted code (a student's node under check_fk), made of the kernel's namespaces through well-kept
tools: util-linux's unshare (a network, PID and mount namespace per grading), bubblewrap (the candidate's view of the
file system, its own PID namespace) and util-linux's setpriv and prlimit (a user of its own, no capabilities, no new
privileges, resource limits). No rospy.

    problem = unavailable()                     # '' when this machine can: root, and the four tools
    judge = judge_prefix() + [python, ...]      # the grading process in a network, PID and mount namespace of its own
    loopback_up()                               # inside it: its loopback interface up (its own master listens there)
    argv, env = candidate_command(command, uid, '/tmp/copy', Limits(), hide=[class_folder])

What the candidate gets (see docs/nodes/check_fk.md for what is isolated and what is not):
- a uid and gid of its own (neither the grader's nor another candidate's: `uid_for`), no supplementary groups, no
  capabilities, no_new_privs;
- its folder at /student (a copy the grader made, read-only), a tmpfs of Limits.tmp_bytes at /tmp that is also its
  HOME and ROS_HOME; the system (/usr, /etc, ...) and the paths ROS and Python need (the venv, the package, the
  workspace: `visible_paths`) read-only; the class folder and anything else given as `hide` covered by an empty tmpfs;
- its own PID namespace (it sees only its processes; when bwrap ends, the kernel ends them all), its own IPC and
  UTS namespaces, a new session (no terminal to inject into);
- the network namespace of the process that starts it (the judge's: loopback and the judge's own master only);
- limits per process: address space, CPU seconds, file size, open files, no core files; per uid: processes.
"""
from __future__ import annotations

import fcntl
import os
import shutil
import socket
import stat
import struct
import sys
import unicodedata
from dataclasses import dataclass

from robot_ai.policies.files import read_fd

TOOLS = ('bwrap', 'unshare', 'setpriv', 'prlimit')
TOOL_DIRS = ('/usr/bin', '/bin', '/usr/sbin', '/sbin', '/usr/local/bin')
UID_BASE = 3_000_000_000            # far above any account's uid; uid_for spreads a run's candidates from here
SYSTEM = ('/usr', '/etc', '/bin', '/sbin', '/lib', '/lib32', '/lib64', '/libx32', '/opt')
ENV_KEPT = ('PYTHONPATH', 'ROS_PACKAGE_PATH', 'ROS_ROOT', 'ROS_ETC_DIR', 'ROS_DISTRO', 'ROS_VERSION',
            'ROS_PYTHON_VERSION', 'CMAKE_PREFIX_PATH', 'LD_LIBRARY_PATH', 'PKG_CONFIG_PATH', 'LANG', 'LC_ALL',
            'ROS_MASTER_URI', 'ROS_HOSTNAME', 'ROS_IP')
MAX_COPY_BYTES = 64 * 1024 * 1024
MAX_COPY_FILES = 5000


class SandboxError(RuntimeError):
    """The sandbox cannot be made (a missing tool, a folder too large to copy); one line."""


@dataclass(frozen=True)
class Limits:
    """What one candidate may use. memory: address space per process; cpu_seconds: per process; processes: for its
    uid (threads count); file_bytes: the largest file it may write; tmp_bytes: its /tmp and HOME."""
    memory_bytes: int = 2 * 1024 ** 3
    cpu_seconds: int = 600
    processes: int = 256
    file_bytes: int = 16 * 1024 ** 2
    open_files: int = 1024
    tmp_bytes: int = 64 * 1024 ** 2

    def describe(self) -> str:
        return (f'{self.memory_bytes / 1024 ** 3:g} GiB of address space and {self.cpu_seconds} CPU seconds per '
                f'process, {self.processes} processes and threads, files of at most '
                f'{self.file_bytes / 1024 ** 2:g} MiB, {self.tmp_bytes / 1024 ** 2:g} MiB of /tmp')


def tool(name: str) -> str:
    """The absolute path of a tool in the system's folders, whatever PATH holds ('' if none)."""
    for folder in TOOL_DIRS:
        path = os.path.join(folder, name)
        if os.access(path, os.X_OK):
            return path
    return ''


def unavailable() -> str:
    """'' when a sandbox can be made here, else why not (one line)."""
    if not sys.platform.startswith('linux'):
        return 'the sandbox needs Linux namespaces'
    if os.geteuid() != 0:
        return ('the sandbox gives each candidate a user of its own, which needs root (run check_fk with sudo, or '
                'give --no-sandbox to run the candidates as yourself)')
    missing = [t for t in TOOLS if not tool(t)]
    if missing:
        return (f'the sandbox needs {", ".join(missing)} (apt-get install bubblewrap util-linux), or give '
                f'--no-sandbox to run the candidates as yourself')
    return ''


def uid_for(run: int, index: int) -> int:
    """A uid for candidate `index` of run `run` (the grader's pid): no account's, no other candidate's."""
    return UID_BASE + (run % 100_000) * 10_000 + index % 10_000


def judge_prefix() -> list[str]:
    """unshare's command that runs what follows in a network, PID and mount namespace of its own (its /proc
    remounted), killed with its namespace when unshare ends."""
    return [tool('unshare'), '--net', '--pid', '--mount', '--fork', '--kill-child', '--mount-proc', '--']


SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1


def loopback_up() -> None:
    """Bring the loopback interface of this network namespace up (a new one starts down)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        request = struct.pack('16sH14x', b'lo', 0)
        flags = struct.unpack('16sH14x', fcntl.ioctl(s.fileno(), SIOCGIFFLAGS, request))[1]
        fcntl.ioctl(s.fileno(), SIOCSIFFLAGS, struct.pack('16sH14x', b'lo', flags | IFF_UP))


JUDGE_LOG_BYTES = 32 * 1024 ** 2     # a judge's ROS_HOME: its master's and rosout's logs (rosout quotes the student)


JUDGE_HOME = 'ROBOT_AI_JUDGE_HOME'   # names the mount point its grader made for a judge's logs (and removes)


def private_ros_home(size: int = JUDGE_LOG_BYTES) -> str:
    """A ROS_HOME of its own for this judge, on a tmpfs of `size` bytes mounted in the judge's own mount namespace:
    whatever the student sends through the judge's rosout fills it, never the grader's ROS_HOME, and it is gone with
    the namespace. ROS_HOME and ROS_LOG_DIR name it for the processes the judge starts; its path (end_private_ros_home
    removes the mount point). The mount point is the folder $ROBOT_AI_JUDGE_HOME names where it is set: the grader
    made it and removes it, so that a judge killed mid-grade leaves no empty folder in /tmp."""
    import subprocess
    import tempfile
    folder = os.environ.get(JUDGE_HOME, '')
    if not folder or not os.path.isdir(folder):
        folder = tempfile.mkdtemp(prefix='check_fk_judge_')
    subprocess.run([tool('mount'), '-t', 'tmpfs', '-o', f'size={size},mode=0700', 'tmpfs', folder], check=True,
                   capture_output=True)
    os.environ['ROS_HOME'] = folder
    os.environ['ROS_LOG_DIR'] = os.path.join(folder, 'log')
    return folder


def end_private_ros_home(folder: str) -> None:
    import subprocess
    subprocess.run([tool('umount'), '-l', folder], capture_output=True)
    try:
        os.rmdir(folder)
    except OSError:
        pass


def copy_folder(source: str, target: str, uid: int, max_bytes: int = MAX_COPY_BYTES,
                max_files: int = MAX_COPY_FILES) -> None:
    """Copy a candidate's folder for its sandbox: regular files and folders, symbolic links as links (inside the
    sandbox they point into its own view), nothing else (FIFOs, devices); owned by uid, read-only. SandboxError when it
    holds more than max_bytes or max_files."""
    _bounded(source, max_bytes, max_files)
    shutil.copytree(source, target, symlinks=True, ignore=_not_regular, dirs_exist_ok=False)
    for root, dirs, names in os.walk(target):
        for name in dirs + names:
            path = os.path.join(root, name)
            os.lchown(path, uid, uid)
            if not os.path.islink(path):
                os.chmod(path, 0o555 if os.path.isdir(path) else (0o555 if os.access(path, os.X_OK) else 0o444))
    os.chown(target, uid, uid)
    os.chmod(target, 0o555)


def _bounded(source: str, max_bytes: int, max_files: int) -> None:
    """SandboxError when the folder holds more than max_files entries (files and links) or max_bytes of files; nothing
    is read or followed."""
    total = files = 0
    for root, dirs, names in os.walk(source, followlinks=False):
        for name in names + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
            st = os.lstat(os.path.join(root, name))
            files += 1
            total += st.st_size if stat.S_ISREG(st.st_mode) else 0
            if files > max_files or total > max_bytes:
                raise SandboxError(f'the folder holds more than {max_files} files or {max_bytes // 1024 ** 2} MiB')


@dataclass(frozen=True)
class Packed:
    """A candidate's folder as data, what a class run ships to the machine that grades it (robot_ai.grading.on_ray):
    what copy_folder copies (files, folders, symbolic links as links), within the same bounds. entries: (relative
    path, kind 'dir' | 'file' | 'link', mode, content: a file's bytes, a link's target, b'' for a folder), each
    folder before what it holds."""
    entries: tuple[tuple[str, str, int, bytes | str], ...]

    @property
    def size(self) -> int:
        return sum(len(e[3]) for e in self.entries)


def pack_folder(source: str, max_bytes: int = MAX_COPY_BYTES, max_files: int = MAX_COPY_FILES) -> Packed:
    """The folder as a Packed: counted first (SandboxError past max_files or max_bytes, as copy_folder), then read
    without following a link; what is neither a file, a folder nor a link is left out, as copy_folder does."""
    _bounded(source, max_bytes, max_files)
    entries, total = [], 0
    for root, dirs, names in os.walk(source, followlinks=False):
        rel_root = os.path.relpath(root, source)
        dirs.sort()
        for name in dirs + sorted(names):
            path = os.path.join(root, name)
            rel = name if rel_root == '.' else os.path.join(rel_root, name)
            st = os.lstat(path)
            if stat.S_ISLNK(st.st_mode):
                entries.append((rel, 'link', 0, os.readlink(path)))
            elif stat.S_ISDIR(st.st_mode):
                entries.append((rel, 'dir', 0o755, b''))
            elif stat.S_ISREG(st.st_mode):
                fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
                try:
                    if not stat.S_ISREG(os.fstat(fd).st_mode):    # swapped for something else since the walk
                        continue
                    data = read_fd(fd, max_bytes - total + 1)
                finally:
                    os.close(fd)
                total += len(data)
                if total > max_bytes:                              # grown since it was counted
                    raise SandboxError(f'the folder holds more than {max_files} files or '
                                       f'{max_bytes // 1024 ** 2} MiB')
                entries.append((rel, 'file', 0o755 if st.st_mode & 0o111 else 0o644, data))
        dirs[:] = [d for d in dirs if not os.path.islink(os.path.join(root, d))]
    return Packed(tuple(entries))


def pack_file(source: str, max_bytes: int = MAX_COPY_BYTES) -> Packed:
    """A student that is one file (an LMS's flat download: one file per student) as a Packed folder holding it alone;
    a link, a FIFO or a device is SandboxError, and so is a file over max_bytes."""
    try:
        fd = os.open(source, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as e:
        raise SandboxError(f'its file cannot be read: {e.strerror}')
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise SandboxError('it is not a regular file')
        data = read_fd(fd, max_bytes + 1)
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise SandboxError(f'the file holds more than {max_bytes // 1024 ** 2} MiB')
    return Packed(((os.path.basename(source), 'file', 0o755 if st.st_mode & 0o111 else 0o644, data),))


def pack(source: str) -> Packed:
    """A student's folder, or its one file, as a Packed (pack_folder, pack_file)."""
    return pack_file(source) if not os.path.isdir(source) else pack_folder(source)


def unpack_folder(packed: Packed, target: str) -> None:
    """Make the folder a Packed describes at target (which must not exist), owned by this process's user. An entry
    whose path is absolute, climbs with '..', or lies below anything but a folder made here is SandboxError: the data
    came over the network, and nothing outside target is written."""
    os.mkdir(target, 0o700)
    made = {''}
    for entry in packed.entries:
        if not (isinstance(entry, tuple) and len(entry) == 4):
            raise SandboxError('a packed folder entry is not (path, kind, mode, content)')
        rel, kind, mode, content = entry
        parts = rel.split('/') if isinstance(rel, str) else []
        if not parts or any(p in ('', '.', '..') or '\0' in p for p in parts) or os.path.dirname(rel) not in made:
            raise SandboxError(f'a packed folder holds a path that leaves it: {printable(str(rel))}')
        path = os.path.join(target, rel)
        if kind == 'dir':
            os.mkdir(path, 0o755)
            made.add(rel)
        elif kind == 'link' and isinstance(content, str):
            os.symlink(content, path)
        elif kind == 'file' and isinstance(content, bytes):
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o755 if mode & 0o111 else 0o644)
            try:
                view = memoryview(content)
                while view:
                    view = view[os.write(fd, view):]
            finally:
                os.close(fd)
        else:
            raise SandboxError(f'a packed folder holds an entry of an unknown kind: {printable(str(kind))}')


def _not_regular(folder: str, names: list[str]) -> set[str]:
    skipped = set()
    for name in names:
        st = os.lstat(os.path.join(folder, name))
        if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode) or stat.S_ISLNK(st.st_mode)):
            skipped.add(name)
    return skipped


def visible_paths(env: dict | None = None) -> list[str]:
    """The paths the candidate sees read-only beside the system's: the interpreter's prefix (the venv), the entries of
    sys.path and of the ROS variables that exist, each once (a path inside another is covered by it)."""
    env = os.environ if env is None else env
    found = [sys.prefix, sys.base_prefix, os.path.dirname(os.path.realpath(sys.executable))]
    found += [p for p in sys.path if p]
    for key in ('PYTHONPATH', 'ROS_PACKAGE_PATH', 'CMAKE_PREFIX_PATH', 'LD_LIBRARY_PATH', 'ROS_ROOT', 'ROS_ETC_DIR'):
        found += [p for p in env.get(key, '').split(os.pathsep) if p]
    for root in env.get('ROS_PACKAGE_PATH', '').split(os.pathsep):    # a workspace of links (the Makefile's):
        found += _link_targets(root)                                      # where they point, too
    out = []
    for p in sorted({os.path.realpath(p) for p in found if os.path.isabs(p) and os.path.exists(p)}, key=len):
        if p == '/' or any(p == q or p.startswith(q.rstrip('/') + '/') for q in out + list(SYSTEM)):
            continue
        out.append(p)
    return out


def _link_targets(root: str, depth: int = 3, most: int = 2000) -> list[str]:
    """The targets of the symbolic links in a package folder (down to depth levels, at most `most` entries seen)."""
    out, seen = [], 0
    if not root or not os.path.isdir(root):
        return out
    top = root.rstrip('/').count('/')
    for folder, dirs, names in os.walk(root):
        for name in dirs + names:
            seen += 1
            path = os.path.join(folder, name)
            if os.path.islink(path):
                out.append(os.path.realpath(path))
        dirs[:] = [d for d in dirs if not os.path.islink(os.path.join(folder, d))
                   and folder.count('/') - top < depth - 1]
        if seen > most:
            break
    return out


def _ancestors(path: str) -> list[str]:
    """path and the folders above it, from the top: /a/b/c -> [/a, /a/b, /a/b/c] ('/' left out)."""
    parts = [p for p in path.split('/') if p]
    return ['/' + '/'.join(parts[:i]) for i in range(1, len(parts) + 1)]


def _under_system(path: str) -> bool:
    return any(path == q or path.startswith(q + '/') for q in SYSTEM)


def candidate_command(command: list[str], uid: int, folder: str, limits: Limits, hide: list[str] = (),
                      env: dict | None = None) -> tuple[list[str], dict]:
    """(argv, environment) that run `command` as the sandboxed candidate (see the module's docstring): folder is
    mounted read-only at /student, which is its working directory; paths in command under folder are the caller's
    to translate (/student/...)."""
    env = os.environ if env is None else env
    # /tmp first, a tmpfs of its own writable by the candidate's uid (bwrap makes it as root), so that the paths
    # bound below stay visible when they lie under /tmp (a checkout in /tmp/ci/...: its venv, its workspace)
    argv = [tool('bwrap'), '--proc', '/proc', '--dev', '/dev', '--size', str(limits.tmp_bytes), '--perms', '1777',
            '--tmpfs', '/tmp']
    for path in SYSTEM:
        if os.path.islink(path):
            argv += ['--symlink', os.readlink(path), path]
        elif os.path.isdir(path):
            argv += ['--ro-bind', path, path]
    made = {'/tmp'}
    for path in visible_paths(env):
        # the folders above it are bwrap's, made 0700 unless asked: the candidate's uid must pass through them
        parent = os.path.dirname(path)
        for above in [p for p in _ancestors(parent) if p not in made and not _under_system(p)]:
            argv += ['--perms', '0755', '--dir', above]
            made.add(above)
        argv += ['--ro-bind', path, path]
    for path in hide:      # the class folder, the grader's files: an empty tmpfs where they were
        real = os.path.realpath(path)
        if os.path.isdir(real) and any(real == p or real.startswith(p.rstrip('/') + '/')
                                       for p in visible_paths(env) + list(SYSTEM)):
            argv += ['--tmpfs', real]
    # HOME and ROS_HOME in /tmp
    argv += ['--perms', '0777', '--dir', '/tmp/home', '--perms', '0777', '--dir', '/tmp/ros',
             '--perms', '0777', '--dir', '/tmp/ros/log',
             '--ro-bind', folder, '/student', '--chdir', '/student',
             '--unshare-pid', '--unshare-ipc', '--unshare-uts', '--unshare-cgroup-try', '--hostname', 'candidate',
             '--die-with-parent', '--new-session', '--',
             tool('prlimit'), f'--as={limits.memory_bytes}', f'--cpu={limits.cpu_seconds}',
             f'--fsize={limits.file_bytes}', f'--nofile={limits.open_files}', f'--nproc={limits.processes}',
             '--core=0', '--',
             tool('setpriv'), f'--reuid={uid}', f'--regid={uid}', '--clear-groups', '--inh-caps=-all',
             '--bounding-set=-all', '--no-new-privs', '--']
    kept = {k: env[k] for k in ENV_KEPT if k in env}
    bin_dir = os.path.dirname(sys.executable)
    kept.update(PATH=os.pathsep.join(dict.fromkeys([bin_dir, '/usr/local/bin', '/usr/bin', '/bin'])),
                HOME='/tmp/home', ROS_HOME='/tmp/ros', ROS_LOG_DIR='/tmp/ros/log', TMPDIR='/tmp',
                PYTHONDONTWRITEBYTECODE='1', PYTHONUNBUFFERED='1', USER='candidate', LOGNAME='candidate')
    return argv + list(command), kept


def printable(text: str, limit: int = 300, backslashes: bool = True) -> str:
    """text as one line a terminal shows as it is: backslashes doubled (unless backslashes is false: text escaped
    once already), every control, format, separator or unassigned character (newlines, carriage returns, escape
    sequences, bidirectional overrides) written as an escape (\\n, \\r, \\t, \\x1b, \\u202e); cut at limit
    characters."""
    out = []
    for ch in str(text):
        if ch == '\\' and backslashes:
            out.append('\\\\')
        elif ch in '\n\r\t':
            out.append({'\n': '\\n', '\r': '\\r', '\t': '\\t'}[ch])
        elif unicodedata.category(ch) in ('Cc', 'Cf', 'Zl', 'Zp', 'Cs', 'Co', 'Cn'):
            code = ord(ch)
            out.append(f'\\x{code:02x}' if code < 0x100 else f'\\u{code:04x}' if code < 0x10000 else f'\\U{code:08x}')
        else:
            out.append(ch)
        if len(out) >= limit:
            out.append('...')
            break
    return ''.join(out)
