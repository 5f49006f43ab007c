#!/usr/bin/env python3
"""Print one summary of the JUnit files that `catkin_make run_tests` left, and fail unless all passed.

Counts the test cases of pytest-*.xml (unit tests), rosunit-*.xml (the cases of each rostest test node)
and roslaunch-check*.xml. A rostest-*.xml (one per .test file) adds its failures too, so a test node that
died or ran out of time fails the run even without case results; MISSING-*.xml is a runner that wrote
nothing. Exits 1 if any test failed or errored, if any was skipped (no test here may skip on the supported
machine), if the unit tests left no results, or if no test ran at all.
"""
import glob
import os
import sys
import xml.etree.ElementTree as ET


def count(path):
    """Return (passed, failed, skipped, failed_names) of one JUnit file."""
    passed, failed, skipped, names = 0, 0, 0, []
    root = ET.parse(path).getroot()
    cases = list(root.iter('testcase'))
    for case in cases:
        name = '%s.%s' % (case.get('classname', ''), case.get('name', ''))
        if case.find('failure') is not None or case.find('error') is not None:
            failed += 1
            names.append(name)
        elif case.find('skipped') is not None:
            skipped += 1
            names.append(name + ' (skipped)')
        else:
            passed += 1
    if not cases:  # a suite-level error with no test case (e.g. rostest could not start the launch file)
        suites = [root] if root.tag == 'testsuite' else list(root.iter('testsuite'))
        for suite in suites:
            bad = int(suite.get('errors', 0) or 0) + int(suite.get('failures', 0) or 0)
            if bad:
                failed += bad
                names.append('%s (suite error)' % os.path.basename(path))
    return passed, failed, skipped, names


def main(result_dir):
    files = sorted(f for pattern in ('pytest-*.xml', 'rosunit-*.xml', 'roslaunch-check*.xml', 'rostest-*.xml',
                                     'MISSING-*.xml')
                   for f in glob.glob(os.path.join(result_dir, pattern)))
    totals = [0, 0, 0]
    for path in files:
        p, f, s, names = count(path)
        if os.path.basename(path).startswith('rostest-'):
            p = 0  # its cases are counted in the rosunit files; only its failures count here
        totals = [totals[0] + p, totals[1] + f, totals[2] + s]
        status = 'ok' if not (f or s) else 'FAILED'
        print('%-55s %4d passed %3d failed %3d skipped  %s' % (os.path.basename(path), p, f, s, status))
        for n in names:
            print('    - %s' % n)
    passed, failed, skipped = totals
    print('summary: %d passed, %d failed, %d skipped' % (passed, failed, skipped))
    if not files or passed == 0:
        print('no test ran (looked in %s)' % result_dir)
        return 1
    if not glob.glob(os.path.join(result_dir, 'pytest-*.xml')):
        print('the unit tests left no results: pytest did not run')
        return 1
    return 1 if failed or skipped else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else '.'))
