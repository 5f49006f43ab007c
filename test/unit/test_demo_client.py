"""demo_client's report of a node that died (issue 27): its last FATAL or ERROR line, read from the launch's
rosout.log, so that the summary says which node died and why instead of `timeout exceeded while waiting`."""
import os

import rospkg
import rospy

from robot_ai.nodes import demo_client

ROSOUT_LOG = '''\
1796158203.930420495  Node Startup
1796158204.685150861 INFO /forward_kinematics [forward_kinematics.py:144(_log_loaded)] [topics: /rosout, /tf] robot
1796158205.100000000 ERROR /cartpole_search [agent_common.py:40(x)] [topics: /rosout] an earlier error
1796158205.200000000 FATAL /cartpole_search [params.py:30(run_node)] [topics: /rosout] cartpole_search: bad \
parameter: ~policy: no policy file at /tmp/deleted.npz
1796158205.300000000 FATAL /cartpole_q_learning [params.py:30(run_node)] [topics: /rosout] another node's
'''


def test_last_words_are_the_nodes_last_fatal_or_error_line(tmp_path, monkeypatch):
    os.makedirs(tmp_path / 'run-1')
    (tmp_path / 'run-1' / 'rosout.log').write_text(ROSOUT_LOG)
    monkeypatch.setattr(rospkg, 'get_log_dir', lambda: str(tmp_path))
    monkeypatch.setattr(rospy, 'get_param', lambda name: 'run-1')
    assert demo_client.last_words('/cartpole_search') == ('cartpole_search: bad parameter: ~policy: no policy file '
                                                          'at /tmp/deleted.npz')
    assert demo_client.last_words('/forward_kinematics') == ''     # INFO lines are no last words
    assert demo_client.last_words('/nobody') == ''
    monkeypatch.setattr(rospkg, 'get_log_dir', lambda: str(tmp_path / 'missing'))
    assert demo_client.last_words('/cartpole_search') == ''
