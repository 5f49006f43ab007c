"""`python -m robot_ai.cartpole` from the venv with nothing sourced, as the README shows it."""
import os
import subprocess
import sys

import pytest


def run(args, tmp_path, **env):
    clean = {k: v for k, v in os.environ.items() if not k.startswith('ROS') and k not in ('PYTHONPATH', 'CMAKE_PREFIX_PATH')}
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
    plot = [l.split()[-1] for l in proc.stdout.splitlines() if l.startswith('plot')][0]
    assert plot.startswith(str(tmp_path / 'rh' / 'robot_ai')) and os.path.isfile(plot)


@pytest.mark.parametrize('args, message', [(['random-search', '--iterations', '-5'], 'iterations must be 1 to'),
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
    learners = [float(l.split()[-1]) for l in lines if l.startswith('learner ')]
    assert len(learners) == 2 and float(lines[-1].split()[-1]) == round(sum(learners) / 2, 2)
    assert '240/240' in proc.stderr  # the progress bar counts every learner's episodes
    plot = [l.split()[-1] for l in lines if l.startswith('plot')][0]
    assert os.path.isfile(plot) and '_CartPole-v0_seed4' in plot
    help_text = run(['q-learning', '--help'], tmp_path).stdout.replace('\n', ' ')
    for option in ('--episodes', '--gamma', '--regressor', '--components', '--learners', '--bootstrap-at-time-limit',
                   '--video', '--seed', '--env-id'):
        assert option in help_text
