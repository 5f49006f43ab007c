#!/usr/bin/env python3
"""Print one summary of the JUnit files that `catkin_make run_tests` left, and fail unless all passed.

One line per test file: pytest-*.xml (the unit tests), each rostest .test file (rostest-*.xml, with the cases of
its test node counted from the rosunit-*.xml it names), roslaunch-check*.xml. A rostest file adds its own failures
too, so a test node that died or ran out of time fails the run even without case results; MISSING-*.xml is a
runner that wrote nothing. After the summary line, the end of each failure's text (what a CI log shows). Exits 1
if any test failed or errored, if any was skipped (no test here may skip on the supported machine), if the unit
tests left no results, or if no test ran at all.
"""
import glob
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

WHY_LINES = 12        # lines of each failure's text printed after the summary (what a CI log shows)
WHY_TOTAL = 80        # and of all of them


@dataclass
class Counts:
    passed: int = 0
    failed: int = 0
    skipped: int = 0
    names: list = field(default_factory=list)   # the failed and skipped cases
    why: list = field(default_factory=list)     # (a failed case, the last lines of its failure's text)

    def add(self, other: 'Counts') -> None:
        self.passed += other.passed
        self.failed += other.failed
        self.skipped += other.skipped
        self.names += other.names
        self.why += other.why


def parse(path: str):
    """The root element of a JUnit file, or None if it is not readable XML (a runner killed while writing it)."""
    try:
        return ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return None


def last_lines(text: str, n: int = WHY_LINES) -> list[str]:
    """A failure's text in at most n lines: its first (rosunit's message) and its last (pytest's and unittest's
    assertion), where either names what the test met."""
    lines = [l.rstrip() for l in text.splitlines() if l.strip()]
    return lines if len(lines) <= n else [lines[0], '...'] + lines[2 - n:]


def count(path: str) -> Counts:
    """The cases of one JUnit file; an unreadable file is one failure."""
    c = Counts()
    root = parse(path)
    if root is None:
        return Counts(failed=1, names=[f'{os.path.basename(path)} (not readable)'])
    cases = list(root.iter('testcase'))
    for case in cases:
        name = f'{case.get("classname", "")}.{case.get("name", "")}'
        bad = case.find('failure') if case.find('failure') is not None else case.find('error')
        if bad is not None:
            c.failed += 1
            c.names.append(name)
            c.why.append((name, last_lines(f'{bad.get("message") or ""}\n{bad.text or ""}')))
        elif case.find('skipped') is not None:
            c.skipped += 1
            c.names.append(name + ' (skipped)')
        else:
            c.passed += 1
    if not cases:  # a suite-level error with no test case (e.g. rostest could not start the launch file)
        suites = [root] if root.tag == 'testsuite' else list(root.iter('testsuite'))
        for suite in suites:
            bad = int(suite.get('errors', 0) or 0) + int(suite.get('failures', 0) or 0)
            if bad:
                c.failed += bad
                c.names.append(f'{os.path.basename(path)} (suite error)')
    return c


def rostest_line(path: str, result_dir: str, used: set) -> tuple[str, Counts]:
    """A .test file's line: its test nodes' cases (rosunit-<test-name>.xml), plus the rostest file's failures."""
    own = count(path)
    total = Counts(failed=own.failed, names=own.names)
    root = parse(path)
    for case in root.iter('testcase') if root is not None else ():
        name = case.get('name', '')
        unit = os.path.join(result_dir, f'rosunit-{name[4:] if name.startswith("test") else name}.xml')
        if os.path.exists(unit):
            used.add(unit)
            total.add(count(unit))
    label = os.path.basename(path)[len('rostest-'):-len('.xml')]
    return f'{label[5:] if label.startswith("test_") else label}.test', total


def main(result_dir: str) -> int:
    lines, used = [], set()
    for path in sorted(glob.glob(os.path.join(result_dir, 'rostest-*.xml'))):
        lines.append(rostest_line(path, result_dir, used))
    for pattern in ('pytest-*.xml', 'roslaunch-check*.xml', 'rosunit-*.xml', 'MISSING-*.xml'):
        for path in sorted(glob.glob(os.path.join(result_dir, pattern))):
            if path not in used:
                lines.append((os.path.basename(path), count(path)))
    totals = Counts()
    for label, c in sorted(lines, key=lambda l: (not l[0].startswith('pytest'), l[0])):
        totals.add(c)
        status = 'ok' if not (c.failed or c.skipped) else 'FAILED'
        print(f'{label:<45} {c.passed:4d} passed {c.failed:3d} failed {c.skipped:3d} skipped  {status}')
        for n in c.names:
            print(f'    - {n}')
    try:        # test/run_tests.py's: the load the tests ran under
        with open(os.path.join(result_dir, 'load_average.txt')) as f:
            print(f.read().strip())
    except OSError:
        pass
    print(f'summary: {totals.passed} passed, {totals.failed} failed, {totals.skipped} skipped')
    printed = 0
    for name, text in totals.why:
        if printed >= WHY_TOTAL:
            print(f'    (the rest of the failures: in the JUnit files of {result_dir})')
            break
        print(f'why {name} failed:')
        for line in text or ['(no text)']:
            print(f'    {line}')
        printed += 1 + max(1, len(text))
    if not lines or totals.passed == 0:
        print(f'no test ran (looked in {result_dir})')
        return 1
    if not glob.glob(os.path.join(result_dir, 'pytest-*.xml')):
        print('the unit tests left no results: pytest did not run')
        return 1
    return 1 if totals.failed or totals.skipped else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else '.'))
