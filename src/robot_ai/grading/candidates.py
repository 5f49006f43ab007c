"""check_fk's candidates as students wrote them (no rospy): how a file is run, a Python 2 file's verdict, the node
in a student's folder, and a verdict's figures for a class's CSV.

A course node starts ``#!/usr/bin/env python`` (which on Debian 12 is no command at all, or pyenv's Python without
ROS's modules) and may still hold Python 2 (``print x``), which ROS Noetic's Python 3 cannot parse: check_fk runs a
Python file with its own interpreter, and turns a file that does not compile into a verdict that names the line.
"""
from __future__ import annotations

import errno
import os
import re
import stat
from dataclasses import dataclass

from robot_ai.policies.files import read_fd

MAX_SOURCE = 4 * 1024 * 1024    # bytes of a candidate file read to classify it
MAX_FILES = 5000                # names of a student's folder looked at for its node (the sandbox copies at most as
                                # many: robot_ai.grading.sandbox.MAX_COPY_FILES)

# what Python 3.11 says of Python 2 code -> (the construct, what to write instead)
PYTHON2 = (
    ("Missing parentheses in call to 'print'", 'print statement', 'write print(...)'),
    ("Missing parentheses in call to 'exec'", 'exec statement', 'write exec(...)'),
    ('multiple exception types must be parenthesized', 'except X, e', 'write except X as e'),
    ('leading zeros in decimal integer literals', 'octal literal 0NNN', 'write 0oNNN'),
    ('inconsistent use of tabs and spaces', 'tabs mixed with spaces', 'indent with spaces only'),
)
PRINT_TO_FILE = re.compile(r'^\s*print\s*>>\s*[\w.]+\s*,')
PYTHON2_LINES = (
    (re.compile(r'^\s*raise\s+[\w.]+\s*,'), 'raise E, message', 'write raise E(message)'),
    (re.compile(r'`[^`]*`'), 'backquotes', 'write repr(...)'),
    (re.compile(r'<>'), '<> operator', 'write !='),
    (re.compile(r'\b(?:ur|UR|Ur|uR)["\']'), "ur'' string", "write r''"),
    (re.compile(r'^\s*print\s*>>'), 'print >>file', 'write print(..., file=f)'),
    (re.compile(r'\b\d+[lL]\b'), 'long literal 10L', 'write 10'),
)


def read_head(path: str, size: int = MAX_SOURCE) -> bytes:
    """The first size bytes of a regular file, opened without blocking; OSError for anything else (a FIFO, a device
    such as /proc/kmsg, a folder), which is never waited on."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, 'not a regular file', path)
        return read_fd(fd, size)
    finally:
        os.close(fd)


def is_python(path: str) -> bool:
    """A file with a Python #! line (python, python2, python3, through env or not), or a .py file without one."""
    try:
        first = read_head(path, 256).split(b'\n', 1)[0]
    except OSError:
        return False
    if first.startswith(b'#!'):
        return b'python' in first
    return path.endswith('.py')


def command(path: str, python: str) -> list[str]:
    """How check_fk starts a candidate file: a Python file with `python` (the package's), whatever its #! line
    names; anything else as it is (its own #! line or binary)."""
    return [python, path] if is_python(path) else [path]


def syntax_verdict(path: str) -> str | None:
    """None if the Python file compiles; else the verdict: a Python 2 construct named with its line and what to
    write instead, or the SyntaxError's own words with the file and line."""
    name = os.path.basename(path)
    try:
        source = read_head(path)
    except OSError as e:
        return f'FAIL: cannot read {path}: {e.strerror or e}'
    try:
        compile(source, path, 'exec', dont_inherit=True)
        # `print >>f, x` parses in Python 3 too (a tuple), and fails only when it runs: Python 2 all the same
        for number, text in enumerate(source.decode('utf-8', errors='replace').splitlines(), 1):
            if PRINT_TO_FILE.match(text):
                return (f'FAIL: {name} line {number} is Python 2 (print >>file): ROS Noetic runs Python 3; write '
                        f'print(..., file=f){_quoted(text)}')
        return None
    except SyntaxError as e:
        line, message = e.lineno or 0, str(e.msg or e)
        text = (e.text or '').rstrip('\n')
        if not text and line:
            lines = source.decode('utf-8', errors='replace').splitlines()
            text = lines[line - 1] if 0 < line <= len(lines) else ''
    except (ValueError, UnicodeDecodeError) as e:    # NUL bytes, an undecodable file
        return f'FAIL: {name} is not a Python source file Python 3 can read ({e})'
    for words, construct, instead in PYTHON2:
        if words in message:
            return (f'FAIL: {name} line {line} is Python 2 ({construct}): ROS Noetic runs Python 3; {instead}'
                    f'{_quoted(text)}')
    for pattern, construct, instead in PYTHON2_LINES:
        if pattern.search(text):
            return (f'FAIL: {name} line {line} is Python 2 ({construct}): ROS Noetic runs Python 3; {instead}'
                    f'{_quoted(text)}')
    return f'FAIL: {name} line {line}: SyntaxError: {message}: the node cannot start{_quoted(text)}'


def _quoted(text: str) -> str:
    text = ' '.join(text.split())
    return f' (line: {text[:120]})' if text else ''


def find_node(folder: str, max_files: int = MAX_FILES) -> str | None:
    """The FK node in a student's folder (searched down 3 levels): among its Python files, the ones that start a
    node (rospy.init_node), preferring those that read joint_states; ties go to the shortest path, then by name.
    Regular files only: a symbolic link (in the folder or out of it), a FIFO or a device is never opened, a folder
    link never followed; at most max_files names are looked at."""
    found = []
    seen = 0
    top = folder.rstrip(os.sep).count(os.sep)
    for root, dirs, files in os.walk(folder):
        if seen > max_files:
            break
        dirs[:] = sorted(d for d in dirs if not d.startswith('.') and root.count(os.sep) - top < 3)
        for f in sorted(files):
            seen += 1
            if seen > max_files:
                break
            path = os.path.join(root, f)
            try:
                regular = stat.S_ISREG(os.lstat(path).st_mode)
            except OSError:
                continue
            if not regular or not is_python(path):
                continue
            try:
                text = read_head(path).decode('utf-8', errors='replace')
            except OSError:
                continue
            if 'init_node' in text:
                found.append((0 if 'joint_states' in text else 1, path.count(os.sep), path))
    return min(found)[2] if found else None


GRADE_LINE = re.compile(r'grade: (\d{1,3}(?:\.\d+)?) ')     # robot_ai.grading.gradebook.grade_line
WRONG_LINK_AT = ('publish a transform for ', '')     # where a verdict names its link: 'FAIL: <link>, ...', ...


def first_wrong_link(verdict: str, links: list[str]) -> str:
    """The URDF link a FAIL verdict says to fix first ('FAIL: forearm, rotation off', 'FAIL: publish a transform for
    tool0', 'FAIL: tool0 was not published in ...'), or '' for a verdict about something else (a node that died, frames
    the URDF does not have: those may name the root only to say where the tree starts)."""
    if not verdict.startswith('FAIL: '):
        return ''
    rest = verdict[len('FAIL: '):]
    for prefix in WRONG_LINK_AT:
        if rest.startswith(prefix):
            word = re.split(r'[,\s]', rest[len(prefix):], maxsplit=1)[0]
            if word in set(links):
                return word
    return ''


@dataclass(frozen=True)
class Result:
    """A graded student: one row of the class's CSV."""
    student: str
    verdict: str          # PASS, FAIL: ..., or why nothing could be graded
    score: str            # "5/7 links, 18/20 configurations", or ''
    first_wrong_link: str
    seconds: float        # the one duration of its grading: its judge's, or the class run's where none ran
    grade: float | None = None    # 0-100 (robot_ai.grading.gradebook.grade_of); None: not graded
    source: str = ''      # the node's file name, as the student named it

    @classmethod
    def of(cls, student: str, output: str, seconds: float, links: list[str]) -> Result:
        """From check_fk's output: its last PASS/FAIL line, its score line, the first URDF link the verdict
        names."""
        lines = output.strip().splitlines()
        verdicts = [line for line in lines if line.startswith(('PASS', 'FAIL'))]
        verdict = verdicts[-1] if verdicts else (lines[-1] if lines else 'no verdict')
        score = next((line[len('score: '):] for line in reversed(lines) if line.startswith('score: ')), '')
        found = next((m for m in map(GRADE_LINE.match, reversed(lines)) if m), None)
        grade = float(found[1]) if found and float(found[1]) <= 100.0 else None
        return cls(student, verdict, score, first_wrong_link(verdict, links), seconds, grade)

    def line(self) -> str:
        score = f' [{self.score}]' if self.score else ''
        return f'{self.student}: {self.verdict}{score} ({self.seconds:.1f} s)'
