"""`python -m robot_ai.cartpole` from the venv with nothing sourced, as docs/cli.md shows it."""
import csv
import os
import re
import subprocess
import sys

import pytest


def run(args, tmp_path, **env):
    clean = {k: v for k, v in os.environ.items()
             if not k.startswith('ROS') and k not in ('PYTHONPATH', 'CMAKE_PREFIX_PATH')}
    clean.update(env)
    return subprocess.run([sys.executable, '-m', 'robot_ai.cartpole'] + args, cwd=str(tmp_path), env=clean,
                          capture_output=True, text=True, timeout=300)


def test_help_shows_every_option_with_its_default(tmp_path):
    out = run(['random-search', '--help'], tmp_path).stdout
    for option, default in (('--iterations', '100'), ('--episodes', '100'), ('--env-id', 'CartPole-v1'),
                            ('--final-episodes', '100'), ('--max-steps', '0'), ('--seed', '0')):
        assert option in out and '(default: %s)' % default in out.replace('\n', ' ').replace('  ', ' ')


def test_random_search_with_nothing_sourced_writes_under_ros_home(tmp_path):
    proc = run(['random-search', '--iterations', '100', '--episodes', '100', '--seed', '0'], tmp_path,
               ROS_HOME=str(tmp_path / 'rh'))
    assert proc.returncode == 0, proc.stderr
    assert 'best average      493.80' in proc.stdout and 'final average     492.37' in proc.stdout
    assert '100/100' in proc.stderr  # the progress bar
    plot = path_of(proc, 'plot')
    assert plot.startswith(str(tmp_path / 'rh' / 'robot_ai')) and os.path.isfile(plot)
    # the policy file and the CSV log beside the plot; evaluate and show read the policy back
    policy, log = path_of(proc, 'policy'), path_of(proc, 'log')
    assert policy == plot[:-4] + '.npz' and log == plot[:-4] + '.csv'
    with open(log) as f:
        rows = list(csv.reader(f))
    assert rows[0] == ['candidate', 'w_x', 'w_x_dot', 'w_theta', 'w_theta_dot', 'avg_length'] and len(rows) == 101
    assert max(float(r[5]) for r in rows[1:]) == 493.8
    shown = run(['show', policy], tmp_path)
    assert shown.returncode == 0 and '"kind": "linear"' in shown.stdout and '"final_avg_length": 492.37' in shown.stdout
    ev = run(['evaluate', policy, '--episodes', '100', '--seed', '0'], tmp_path)
    assert ev.returncode == 0, ev.stderr
    from robot_ai.cartpole import linear_search
    from robot_ai.cartpole.dynamics import CartPoleDynamics
    weights = [float(v) for v in rows[int(shown.stdout.split('"best_candidate": ')[1].split(',')[0])][1:5]]
    want = linear_search.evaluate(CartPoleDynamics.of('CartPole-v1'), weights, 100, 500, 0).mean()
    assert f'average length: {want:.2f}' in ev.stdout


def path_of(proc, label):
    return [l.split()[-1] for l in proc.stdout.splitlines() if l.split() and l.split()[0] == label][0]


@pytest.mark.parametrize('args, message', [(['random-search', '--iterations', '-5'],
                                            '--iterations: must be 1 to 100000, got -5'),
                                           (['random-search', '--env-id', 'x'], 'invalid choice')])
def test_bad_options_say_what_is_allowed(tmp_path, args, message):
    proc = run(args, tmp_path)
    assert proc.returncode == 2 and message in proc.stderr and 'Traceback' not in proc.stderr


def test_q_learning_ends_as_the_course_prints(tmp_path):
    proc = run(['q-learning', '--episodes', '120', '--components', '200', '--learners', '2', '--seed', '4',
                '--output-dir', str(tmp_path)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1].startswith('avg reward for last 100 episodes: ')
    learners = [float(re.search(r'last-100 average ([0-9.]+)', l).group(1)) for l in lines if l.startswith('learner ')]
    assert len(learners) == 2 and float(lines[-1].split()[-1]) == round(sum(learners) / 2, 2)
    assert sum('<- best' in l for l in lines) == 1
    assert proc.stdout.isascii() and ' +/- ' in proc.stdout      # terminals and rosservice show anything else badly
    assert '240/240' in proc.stderr  # the progress bar counts every learner's episodes
    plot = path_of(proc, 'plot')
    assert os.path.isfile(plot) and '_CartPole-v0_seed4' in plot
    with open(path_of(proc, 'log')) as f:
        rows = list(csv.reader(f))
    assert rows[0] == ['learner', 'seed', 'episode', 'total_reward', 'epsilon'] and len(rows) == 1 + 240
    assert [r[:3] for r in rows[1:3]] == [['0', '4', '1'], ['0', '4', '2']] and rows[-1][:3] == ['1', '5', '120']
    ev = run(['evaluate', path_of(proc, 'policy'), '--episodes', '30', '--seed', '4'], tmp_path)
    assert ev.returncode == 0 and 'q_learning policy' in ev.stdout and 'average length: ' in ev.stdout
    # issue 27: see a policy play
    video = run(['evaluate', path_of(proc, 'policy'), '--episodes', '3', '--video', '--output-dir',
                 str(tmp_path / 'videos')], tmp_path)
    assert video.returncode == 0, video.stderr
    mp4 = path_of(video, 'video')
    assert mp4.startswith(str(tmp_path / 'videos')) and mp4.endswith('.mp4') and os.path.getsize(mp4) > 1000
    help_text = run(['q-learning', '--help'], tmp_path).stdout.replace('\n', ' ')
    for option in ('--episodes', '--gamma', '--regressor', '--components', '--learners', '--bootstrap-at-time-limit',
                   '--video', '--seed', '--env-id'):
        assert option in help_text


@pytest.mark.parametrize('args, message', [
    (['evaluate', '/nonexistent.npz'], 'no policy file at /nonexistent.npz'),
    (['show', '/etc/hostname'], 'not an .npz archive'),
    (['q-learning', '--episodes', '5', '--output-dir', '/proc/nope'], '--output-dir: cannot create /proc/nope')])
def test_bad_files_and_folders_are_one_line_before_any_work(tmp_path, args, message):
    proc = run(args, tmp_path)
    assert proc.returncode == 2 and message in proc.stderr and 'Traceback' not in proc.stderr, proc.stderr


@pytest.mark.parametrize('args, message', [
    (['random-search', '--iterations', '0'], '--iterations: must be 1 to 100000, got 0'),
    (['random-search', '--episodes', '0'], '--episodes: must be 1 to 10000, got 0'),
    (['random-search', '--final-episodes', '0'], '--final-episodes: must be 1 to 10000, got 0'),
    (['q-learning', '--gamma', '0'], '--gamma: must be in (0, 1], got 0'),
    (['q-learning', '--learners', '0'], '--learners: must be 1 to 64, got 0'),
    (['q-learning', '--components', 'many'], "--components: must be a whole number from 1 to 10000, got 'many'"),
    (['evaluate', 'x.npz', '--episodes', '0'], '--episodes: must be 1 to 1000, got 0')])
def test_the_cli_refuses_what_its_help_does_not_allow(tmp_path, args, message):
    """Issue 27: --iterations 0, --episodes 0 and --gamma 0 silently used the defaults while --help gave the ranges
    1-100000 and (0, 1]. 0 meaning "the default" is a ROS request's habit only."""
    proc = run(args, tmp_path)
    assert proc.returncode == 2 and message in proc.stderr.strip().splitlines()[-1], proc.stderr
    assert not os.listdir(tmp_path) or all(not f.endswith('.npz') for f in os.listdir(tmp_path))


def test_the_package_prints_ascii_only():
    """What the nodes, the CLI and the launch files say stays ASCII: rosservice call shows a non-ASCII character as
    an escape (193.22 \\xB1 3.18)."""
    root = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..')
    offenders = []
    for folder in ('src', 'launch', 'scripts', 'srv', 'msg', 'action'):
        for dirpath, _, files in os.walk(os.path.join(root, folder)):
            for name in files:
                with open(os.path.join(dirpath, name), 'rb') as f:
                    for n, line in enumerate(f, 1):
                        if not line.isascii():
                            offenders.append(f'{os.path.join(dirpath, name)}:{n}')
    assert offenders == []
