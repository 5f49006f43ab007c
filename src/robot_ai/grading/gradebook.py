"""A class's grades as course staff keep and import them: the grade rule, the students' LMS identifiers, and the CSV,
written as the class goes so that a grader killed mid-class loses no verdict it printed. No rospy.

    grade = grade_of(right=130, links=7, configurations=20)           # 92.8: the share of link poses right, floored
    book = Gradebook('grades.csv', 'moodle', students, id_from='folder')
    book.start()                       # the header, on disk at once
    book.add(result)                   # a row per student as its verdict comes, flushed and synced
    book.finish(results)               # the whole class in the folder's order, students not graded named so

Formats (``--csv-format``):
- ``robot_ai``: student, id, grade, verdict, score, first_wrong_link, seconds.
- ``moodle``: an assignment's offline grading worksheet (Identifier ``Participant N``, Full name, Grade, Maximum
  Grade, Feedback comments), what Moodle's "Upload grading worksheet" reads; N from the folder Moodle's "Download all
  submissions" makes (``Full Name_N_assignsubmission_file_``).
- ``canvas``: Canvas's gradebook import (Student, ID, SIS User ID, SIS Login ID, Section, then the assignment's
  column); ID from the file name Canvas's "Download Submissions" gives (``lastfirst_ID_SUBMISSION_name.py``, ``_LATE``
  after the name when late).
"""
from __future__ import annotations

import csv
import math
import os
import re
import threading
from dataclasses import dataclass

FORMATS = ('robot_ai', 'moodle', 'canvas')
ID_FROM = ('folder', 'file')
MAXIMUM_GRADE = 100
NOT_GRADED = 'not graded (check_fk was stopped)'
FORMULA_STARTS = ('=', '+', '-', '@', '\t', '\r')

MOODLE_NAME = re.compile(r'^(?P<name>.+?)_(?P<id>\d+)_assign(?:submission|feedback)_')
CANVAS_NAME = re.compile(r'^(?P<name>[^_]+?)(?:_LATE)?_(?P<id>\d+)_(?:\d+_)?')


def grade_of(right: int, links: int, configurations: int) -> float:
    """The grade, 0 to 100: the share of link poses right (a graded link in a configuration asked for, published,
    finite and within the tolerance), floored to a tenth, so that only a PASS is 100."""
    total = links * configurations
    if total <= 0 or right <= 0:
        return 0.0
    return math.floor(1000 * min(right, total) / total) / 10


def grade_line(right: int, links: int, configurations: int) -> str:
    """The report line that carries the grade (robot_ai.grading.candidates.Result reads it back)."""
    return (f'grade: {grade_of(right, links, configurations):.1f} ({right} of {links * configurations} link poses '
            f'right: {links} links x {configurations} configurations)')


@dataclass(frozen=True)
class Identity:
    name: str          # the student's name as the LMS's download gives it, or the folder's (file's) name
    id: str            # the LMS's number for the student, or the name where the download has none


def identity(folder: str, source: str = '', id_from: str = 'folder') -> Identity:
    """A student's name and LMS identifier from its folder's name (Moodle's downloads: `Full Name_N_assignsubmission_
    file_`), or with id_from 'file' from its node file's name (Canvas's: `lastfirst_N_SUBMISSION_name.py`)."""
    text = folder if id_from == 'folder' or not source else source
    for pattern in (MOODLE_NAME, CANVAS_NAME):
        m = pattern.match(text)
        if m:
            return Identity(m['name'], m['id'])
    stem = os.path.splitext(text)[0] if id_from == 'file' and source else text
    return Identity(stem, stem)


def spreadsheet_cell(text: str) -> str:
    """A CSV cell no spreadsheet evaluates: text that starts as a formula would (a student folder named `=2+5` or
    `@SUM(9+9)`) gets a leading apostrophe, as OWASP's CSV-injection advice says; other text is as it is."""
    return "'" + text if text.startswith(FORMULA_STARTS) else text


class Gradebook:
    """A class's CSV in one of FORMATS: the header and each verdict on disk as they come (flushed and synced: a grader
    killed with SIGKILL leaves every row it printed), then the whole class in order (written beside and renamed)."""

    def __init__(self, path: str, fmt: str, students: list[str], id_from: str = 'folder',
                 assignment: str = 'check_fk'):
        if fmt not in FORMATS:
            raise ValueError(f'--csv-format must be one of {", ".join(FORMATS)}, got {fmt!r}')
        self.path, self.fmt, self.students, self.id_from, self.assignment = path, fmt, students, id_from, assignment
        self.lock = threading.Lock()
        self.stream = None

    def header(self) -> list[str]:
        if self.fmt == 'moodle':
            return ['Identifier', 'Full name', 'Grade', 'Maximum Grade', 'Feedback comments']
        if self.fmt == 'canvas':
            return ['Student', 'ID', 'SIS User ID', 'SIS Login ID', 'Section', self.assignment]
        return ['student', 'id', 'grade', 'verdict', 'score', 'first_wrong_link', 'seconds']

    def row(self, student: str, result) -> list[str]:
        """One student's row; result None: not graded (the run was stopped first)."""
        from robot_ai.grading import sandbox
        shown = sandbox.printable(student)
        who = identity(shown, result.source if result is not None else '', self.id_from)
        grade = '' if result is None or result.grade is None else f'{result.grade:.1f}'
        if self.fmt == 'moodle':
            ident = f'Participant {who.id}' if who.id.isdigit() else who.id
            feedback = NOT_GRADED if result is None else (
                result.verdict + (f' [{result.score}]' if result.score else ''))
            return [ident, who.name, grade, str(MAXIMUM_GRADE) if grade else '', feedback]
        if self.fmt == 'canvas':
            return [who.name, who.id, '', '', '', grade]
        if result is None:
            return [shown, who.id, '', NOT_GRADED, '', '', '']
        return [result.student, who.id, grade, result.verdict, result.score, result.first_wrong_link,
                f'{result.seconds:.1f}']

    def start(self) -> None:
        """The header on disk, the file left open for the rows to come."""
        self.stream = open(self.path, 'w', newline='')
        self._write([self.header()])

    def add(self, student: str, result) -> None:
        """A student's row at the end of the file, on disk before this returns."""
        if self.stream is not None:
            self._write([self.row(student, result)])

    def _write(self, rows: list[list[str]]) -> None:
        with self.lock:
            writer = csv.writer(self.stream)
            for row in rows:
                writer.writerow([spreadsheet_cell(c) for c in row])
            self.stream.flush()
            os.fsync(self.stream.fileno())

    def finish(self, results: dict) -> None:
        """The whole class, one row per student in the folder's sorted order (a student without a result: not
        graded), written beside the file and renamed over it: a kill meanwhile leaves the rows written so far."""
        with self.lock:
            if self.stream is not None:
                self.stream.close()
                self.stream = None
        partial = f'{self.path}.partial'
        with open(partial, 'w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow(self.header())
            for student in self.students:
                writer.writerow([spreadsheet_cell(c) for c in self.row(student, results.get(student))])
            f.flush()
            os.fsync(f.fileno())
        os.replace(partial, self.path)
        try:
            folder = os.open(os.path.dirname(os.path.abspath(self.path)), os.O_RDONLY)
            try:
                os.fsync(folder)
            finally:
                os.close(folder)
        except OSError:
            pass
