"""test/summarize.py, the summary `make test` prints: one line per test file with its real counts, a .test file's
cases counted from the rosunit file its test node wrote, and a non-zero status for failures, skips and no tests."""
import os
import subprocess
import sys

SUMMARIZE = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'summarize.py')


def junit(path, cases, name='suite'):
    """A JUnit file with cases given as (name, 'passed' | 'failure' | 'skipped')."""
    body = ''.join(f'<testcase classname="c" name="{n}">' + ('' if kind == 'passed' else f'<{kind} message="x"/>')
                   + '</testcase>' for n, kind in cases)
    with open(path, 'w') as f:
        f.write(f'<?xml version="1.0"?><testsuite name="{name}" tests="{len(cases)}">{body}</testsuite>')


def run(folder):
    proc = subprocess.run([sys.executable, SUMMARIZE, str(folder)], capture_output=True, text=True, timeout=60)
    return proc.returncode, proc.stdout.splitlines()


def test_one_line_per_test_file_with_the_cases_of_its_test_node(tmp_path):
    junit(tmp_path / 'pytest-unit.xml', [('a', 'passed'), ('b', 'passed')])
    junit(tmp_path / 'rostest-test_cartpole_search.xml', [('testcartpole_search_node', 'passed')])
    junit(tmp_path / 'rosunit-cartpole_search_node.xml', [(f't{i}', 'passed') for i in range(10)])
    junit(tmp_path / 'roslaunch-check_launch.xml', [('robot_ai_launch', 'passed')])
    status, lines = run(tmp_path)
    assert status == 0
    assert lines[0].split()[:2] == ['pytest-unit.xml', '2']
    assert [l.split()[:2] for l in lines[1:3]] == [['cartpole_search.test', '10'], ['roslaunch-check_launch.xml', '1']]
    assert not any(l.startswith(('rostest-', 'rosunit-')) for l in lines)   # no '0 passed' line per rostest file
    assert lines[-1] == 'summary: 13 passed, 0 failed, 0 skipped'


def test_failures_skips_dead_test_nodes_and_unreadable_files_fail_the_run(tmp_path):
    junit(tmp_path / 'pytest-unit.xml', [('a', 'passed'), ('b', 'skipped')])
    junit(tmp_path / 'rostest-test_x.xml', [('testx', 'failure')])      # the test node died: no rosunit file
    (tmp_path / 'rostest-test_y.xml').write_text('')                     # a runner killed while writing
    status, lines = run(tmp_path)
    assert status == 1
    assert any(l.startswith('x.test') and ' 1 failed' in l for l in lines)
    assert any(l.startswith('y.test') and 'FAILED' in l for l in lines)
    assert '    - c.b (skipped)' in lines
    assert 'summary: 1 passed, 2 failed, 1 skipped' in lines


def test_each_failure_says_why_after_the_summary(tmp_path):
    """A CI log shows the end of the output: each failure's message and last lines come after the summary line."""
    trace = '\n'.join(f'  frame {i}' for i in range(30)) + '\nAssertionError: 1 != 130 : check_fk: stopped early'
    with open(tmp_path / 'rosunit-x.xml', 'w') as f:
        f.write('<?xml version="1.0"?><testsuite name="s" tests="2"><testcase classname="T" name="test_4">'
                f'<failure message="1 != 130">{trace}</failure></testcase>'
                '<testcase classname="T" name="test_5"><error/></testcase></testsuite>')
    junit(tmp_path / 'pytest-unit.xml', [('a', 'passed')])
    status, lines = run(tmp_path)
    assert status == 1
    why = lines[lines.index('summary: 1 passed, 2 failed, 0 skipped') + 1:]
    assert why[:3] == ['why T.test_4 failed:', '    1 != 130', '    ...']           # its message, then its end
    assert why[12] == '    AssertionError: 1 != 130 : check_fk: stopped early'
    assert '      frame 21' in why and '      frame 20' not in why
    assert why[13:] == ['why T.test_5 failed:', '    (no text)']


def test_no_test_at_all_fails(tmp_path):
    status, lines = run(tmp_path)
    assert status == 1 and lines[-1].startswith('no test ran')


def test_the_summary_names_the_load_the_tests_ran_under(tmp_path):
    """Issue 57: a failure on a machine at ten times its cores' load reads differently from one on a quiet machine;
    test/run_tests.py samples the load while the tests run, and the summary says it."""
    sys.path.insert(0, os.path.dirname(SUMMARIZE))
    import run_tests
    sampler = run_tests.LoadSampler(every=0.05)
    import time
    time.sleep(0.2)
    sampler.stop(tmp_path / run_tests.LOAD_FILE, 12.0)
    junit(tmp_path / 'pytest-unit.xml', [('a', 'passed')])
    status, lines = run(tmp_path)
    assert status == 0
    assert lines[-2].startswith('load average over the run: ') and lines[-2].endswith('the tests took 12 s')
    assert f'on {os.cpu_count()} cores' in lines[-2]
    assert lines[-1] == 'summary: 1 passed, 0 failed, 0 skipped'
