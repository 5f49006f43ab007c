"""Every launch file sets every private parameter its robot_ai nodes read (issue 27): a parameter left on a master
that stays up (`rosrun robot_ai cartpole_search _policy:=<a file since deleted>`) must not reach the next launch.
The parameters a node reads are found in its module's source (and agent_common's, for the agent nodes), so a
parameter added to a node without its launch files fails here."""
import importlib
import os
import re
import xml.etree.ElementTree as ET

import pytest

ROOT = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..')
LAUNCH = os.path.join(ROOT, 'launch')
PARAM_CALL = re.compile(r"""(?:(?<!set)_param|get_param|has_param)\(\s*'~(\w+)'""")   # set_param: what a node says
# read through search_param with robot_state_publisher's meaning: a launch file must not pin them
SEARCHED = {'forward_kinematics': {'tf_prefix'}}


def params_read(node_type: str) -> set:
    path = os.path.join(ROOT, 'src', 'robot_ai', 'nodes', f'{node_type}.py')
    with open(path) as f:
        source = f.read()
    names = set(PARAM_CALL.findall(source))
    if 'agent_settings(' in source or 'policy_param(' in source:
        with open(os.path.join(ROOT, 'src', 'robot_ai', 'nodes', 'agent_common.py')) as f:
            names |= set(PARAM_CALL.findall(f.read()))
        module = {'cartpole_search': 'linear_search', 'cartpole_q_learning': 'q_learning'}[node_type]
        names |= set(importlib.import_module(f'robot_ai.cartpole.{module}').DEFAULTS)
    if 'get_param(name, {})' in source:       # joint_sweep's ~home and ~scale dictionaries
        names |= {'home', 'scale'}
    return names - SEARCHED.get(node_type, set())


def nodes_of(launch_file: str):
    for node in ET.parse(os.path.join(LAUNCH, launch_file)).getroot().iter('node'):
        if node.get('pkg') == 'robot_ai' and node.get('type') not in ('rviz_view', 'sliders'):
            yield node


def params_set(node) -> set:
    names = {p.get('name') for p in node.iter('param')}
    names |= {p.get('param') for p in node.iter('rosparam') if p.get('param')}
    return names


@pytest.mark.parametrize('launch_file', sorted(f for f in os.listdir(LAUNCH) if f.endswith('.launch')))
def test_every_private_parameter_is_set(launch_file):
    checked = 0
    for node in nodes_of(launch_file):
        missing = params_read(node.get('type')) - params_set(node)
        assert not missing, f'{launch_file}: node {node.get("name")} reads ~{", ~".join(sorted(missing))}, not set'
        checked += 1
    assert checked or launch_file == 'demo.launch' or 'include' in open(os.path.join(LAUNCH, launch_file)).read()
