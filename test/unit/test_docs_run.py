"""Issue 57: every command in the docs runs as written. The python blocks and the `python -m robot_ai.<cli>` commands
of README.md and docs/ that need no ROS graph run here as a reader runs them (their arm file: the UR5 of
../shared/robots; a file an earlier command wrote: one the CLI wrote, `home`); the python blocks that lease ROS sims
run in ros_env.test, reach_ros.test and manipulation_gym.test; what cannot run on this machine is named with its
reason, checked true."""
import os
import subprocess
import sys

import pytest

from doc_blocks import SHARED_ROBOTS, cli_commands, filled, python_blocks

ARM = str(SHARED_ROBOTS / 'ur5.urdf')
# the blocks that need what this machine cannot have: each a module that does not import here
NOT_HERE = {'stable_baselines3': 'stable-baselines3 needs torch (gigabytes): a venv of its own (docs/install.md)',
            'ray.rllib.algorithms.ppo': 'RLlib needs torch and dm-tree, which `make build ray` does not install',
            'ray.tune.registry': 'ray[tune], which `make build ray` does not install'}


def env_of(home):
    env = dict(os.environ, HOME=str(home), MPLBACKEND='Agg')
    env.pop('ROS_HOME', None)
    return env


def test_the_blocks_are_found_and_what_cannot_run_here_says_why():
    blocks = python_blocks()
    assert len([b for b in blocks if not b.needs_ros and not b.missing]) >= 4, 'the test finds too few blocks'
    assert {b.needs_ros for b in blocks} == {'', 'cartpole', 'reach', 'manipulation'}
    for block in blocks:
        unknown = [m for m in block.missing if not any(m == k or m.startswith(k + '.') for k in NOT_HERE)]
        assert not unknown, f'{block.page}: {unknown} do not import here:\n{block.code}'
    commands = cli_commands()
    assert len([c for c in commands if not c.needs]) >= 8 and {c.cli for c in commands} == {'reach', 'cartpole'}
    assert {c.words[0] for c in commands if not c.needs} >= {'train', 'evaluate', 'show', 'random-search',
                                                             'q-learning', 'ars'}


@pytest.mark.parametrize('block', [b for b in python_blocks() if not b.needs_ros and not b.missing],
                         ids=lambda b: b.page)
def test_a_python_block_runs_as_written(block, tmp_path):
    run = subprocess.run([sys.executable, '-c', block.source(ARM)], cwd=tmp_path, env=env_of(tmp_path),
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f'{block.page}:\n{block.code}\n{run.stdout[-2000:]}{run.stderr[-3000:]}'


@pytest.fixture(scope='module')
def home(tmp_path_factory):
    """A reader's HOME with the files the docs' reading commands name (~/.ros/robot_ai/qlearning_..._seed0.npz,
    reach-..._seed0.npz), written by the CLIs themselves, briefly: the docs' own training commands are tested on
    their own, each in its test, so that the tests can run side by side."""
    home = tmp_path_factory.mktemp('home')
    for argv in (['cartpole', 'q-learning', '--episodes', '20', '--seed', '0'],
                 ['reach', 'train', '--model', str(SHARED_ROBOTS / 'kuka_lwr_arm.urdf'), '--iterations', '3']):
        run = subprocess.run([sys.executable, '-m', f'robot_ai.{argv[0]}', *argv[1:]], cwd=home, env=env_of(home),
                             capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
        assert run.returncode == 0, run.stdout + run.stderr
    return home


@pytest.mark.parametrize('command', [c for c in cli_commands() if not c.needs],
                         ids=lambda c: f'{c.page}:{c.cli}-{"-".join(c.words)[:40]}')
def test_a_cli_command_runs_as_written(command, home, tmp_path):
    """Each command as written, ending with status 0 and no traceback: `reach evaluate
    ~/.ros/robot_ai/reach-..._seed0.npz` plays a file `reach train` wrote, `reach train --model my_arm.urdf` trains
    a reader's arm (the UR5)."""
    argv = filled(command, tmp_path, home)
    run = subprocess.run(argv, cwd=tmp_path, env=env_of(home), capture_output=True, text=True, timeout=600,
                         stdin=subprocess.DEVNULL)
    assert run.returncode == 0 and 'Traceback' not in run.stderr, \
        f'{command.page}: {command.line}\nran as {argv[1:]}\n{run.stdout[-2000:]}{run.stderr[-3000:]}'
    assert run.stdout.strip(), 'it printed nothing'
