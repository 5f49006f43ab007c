"""robot_ai.artifacts and robot_ai.cartpole.outputs: the output folder, names, plots and videos."""
import os

import numpy as np
from PIL import Image

from robot_ai import artifacts

from robot_ai.cartpole import outputs
from robot_ai.cartpole.dynamics import CartPoleDynamics
from robot_ai.cartpole.linear_search import act, random_search


def test_default_output_dir_follows_ros_home(monkeypatch):
    monkeypatch.setenv('ROS_HOME', '/some/dir')
    assert artifacts.default_output_dir() == '/some/dir/robot_ai'
    monkeypatch.delenv('ROS_HOME')
    monkeypatch.setenv('HOME', '/home/someone')
    assert artifacts.default_output_dir() == '/home/someone/.ros/robot_ai'


def test_stems_are_new_and_keep_the_seed_as_given(tmp_path):
    a = artifacts.artifact_stem(str(tmp_path), 'search', 'CartPole-v1', -1)
    b = artifacts.artifact_stem(str(tmp_path), 'search', 'CartPole-v1', -1)  # same second, no file yet
    assert os.path.basename(a).endswith('_CartPole-v1_seed-1') and a != b
    open(b + '.png', 'w').close()
    assert artifacts.artifact_stem(str(tmp_path), 'search', 'CartPole-v1', -1) not in (a, b)


def test_search_plot_reads_well(tmp_path):
    res = random_search(CartPoleDynamics.of('CartPole-v1'), 20, 5, seed=1, final_episodes=5)
    job = outputs.search_plot_job(res)
    best = job['series'][1]
    assert best['style'] == 'step' and best['y'] == list(np.maximum.accumulate(res.avg_lengths))
    assert job['integer_x'] and [h['y'] for h in job['hlines']] == [res.baseline_avg_length, 500]
    path = artifacts.write_plot(job, str(tmp_path / 'curve.png'))
    img = Image.open(path)
    assert img.size == (1000, 560)
    # the legend sits below the axes: the bottom strip holds the legend's coloured marks, not the data's
    assert sorted(os.listdir(str(tmp_path))) == ['curve.png']  # no temporary file left


def test_plot_is_whole_or_absent(tmp_path):
    bad = dict(series=[dict(y=[1, 2], x=[1, 2, 3])])  # x and y of different lengths: matplotlib raises
    try:
        artifacts.write_plot(bad, str(tmp_path / 'bad.png'))
    except ValueError:
        pass
    else:
        raise AssertionError('a bad job must fail')
    assert os.listdir(str(tmp_path)) == []


def test_video(tmp_path):
    w = np.array([0.1, 0.5, 1.0, 0.9])
    path, steps = outputs.record_video('CartPole-v1', lambda obs: act(w, obs), 40, 1, str(tmp_path / 'best.mp4'))
    assert os.path.getsize(path) > 1000 and steps == 40  # a balancing policy lasts to the 40-step limit
    with open(path, 'rb') as f:
        assert b'ftyp' in f.read(64)
    import imageio_ffmpeg
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(path)
    assert frames == steps + 1 and abs(seconds - frames / 50.0) < 0.05   # the start and every step, at 50 fps
    assert os.listdir(str(tmp_path)) == ['best.mp4']  # no temporary file left
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~current_umask()


def current_umask():
    umask = os.umask(0)
    os.umask(umask)
    return umask


def test_leftovers_of_dead_writers_are_removed(tmp_path):
    mine = '%s%d_x.mp4' % (artifacts.TEMP_PREFIX, os.getpid())
    dead = '%s%d_abc.mp4' % (artifacts.TEMP_PREFIX, 999999999)  # above Linux's largest pid: never running
    names = [dead, mine, 'search_1.png', '.other']
    for n in names:
        (tmp_path / n).write_bytes(b'x')
    assert artifacts.remove_leftovers(str(tmp_path)) == [names[0]]
    assert sorted(os.listdir(str(tmp_path))) == sorted(names[1:])


def test_failed_video_leaves_nothing(tmp_path):
    def broken_policy(obs):
        raise RuntimeError('the policy broke')
    try:
        outputs.record_video('CartPole-v1', broken_policy, 40, 1, str(tmp_path / 'v.mp4'))
    except RuntimeError as e:
        assert 'the policy broke' in str(e)
    else:
        raise AssertionError('the error must reach the caller')
    assert os.listdir(str(tmp_path)) == []


def test_q_learning_plot(tmp_path):
    from robot_ai.cartpole import q_learning
    result = q_learning.train(q_learning.resolve(episodes=150, components=100, learners=3), 0, workers=1)
    job = outputs.q_learning_plot_job(result)
    labels = [s.get('label') for s in job['series']]
    # one faint running average per other learner, learner 0's totals and running average
    assert len(job['series']) == 2 + 2 and labels[0].startswith('learners 1-2') and labels[1] is None
    assert job['series'][-1]['y'] == list(q_learning.running_average(result.total_rewards[0]))
    assert [h['y'] for h in job['hlines']] == [result.baseline_total_reward, 199]
    path = artifacts.write_plot(job, str(tmp_path / 'q.png'))
    assert Image.open(path).size == (1000, 560)
    assert 'failed' not in job['title']
    # a learner whose process died: its curve stops early, and the title says so beside the finished learners
    partial = {0: (result.total_rewards[0], result.agents[0], 100.0), 1: (result.total_rewards[1][:40], None, None),
               2: (result.total_rewards[2], result.agents[2], 120.0)}
    failed = q_learning._result(result.training, 0, partial, False, 1.0, {1: 'its process was killed by SIGKILL'})
    assert outputs.q_learning_plot_job(failed)['title'].endswith(
        f'2 learners, last-100 average {failed.mean_last100:.1f} $\\pm$ {failed.ci95_last100:.1f}; final greedy '
        f'agents: {failed.greedy_averages.min():.1f} to {failed.greedy_averages.max():.1f} steps\n'
        'learner 1 failed: the curve stops where the process did')


def test_unwritable_reason_for_a_full_disk(tmp_path, monkeypatch):
    assert artifacts.unwritable_reason(str(tmp_path)) == ''

    class Full(object):
        f_bavail, f_frsize = 50, 4096     # 200 KiB left
    monkeypatch.setattr(os, 'statvfs', lambda path: Full())
    reason = artifacts.unwritable_reason(str(tmp_path))
    assert reason == 'the disk where %s is is full: 200 KiB free (at least 32 MiB wanted)' % tmp_path
