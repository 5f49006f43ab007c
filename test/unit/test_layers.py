"""The package's layers: no module of src/robot_ai imports one of a higher layer or of a sibling of its layer, and no
modules import each other in a circle. Every import counts, those inside functions too (a lazy import is still a
dependency). This list is the one place that says what may import what: a module may import its own part and any
part of a lower layer. A part's ``__main__`` (``python -m robot_ai.cartpole``) is an entry point, as a script is: it
stands above every layer (the cart-pole's `evaluate --ros-env` runs an env over ROS) and nothing imports it.
"""
import ast
import pathlib

import pytest

SRC = pathlib.Path(__file__).resolve().parents[2] / 'src'
PACKAGE = SRC / 'robot_ai'

# Lowest first. The parts of one layer are siblings: none imports another.
LAYERS = [
    ['text', 'child_process', 'fleet', 'priority'],            # plain helpers; the fleet engine (Ray, optional)
    ['kinematics', 'tf_wire'],                                 # robots: URDF -> kinematic tree -> frames; wire formats
    ['urdf_source', 'artifacts'],                              # robot files (xacro); a run's output files
    ['urdf_compat', 'policies'],                               # course nodes' URDF parser; policy files of every kind
    ['ars', 'plot_worker', 'launch_guard'],                    # the learner any env shares; processes
    ['cli', 'motion'],                                         # what the command lines share; joint-space paths
    ['cartpole', 'reach', 'grading'],                          # the package's capabilities, none knowing another
    ['physics'],                                               # MuJoCo under the arms, from reach's robot model
    ['sb3', 'msg', 'srv'],                                     # stable-baselines3's adapter; generated ROS messages
    ['lease'],                                                 # rospy: a sim's lease, for sims and envs
    ['envs'],                                                  # gymnasium envs over ROS (rospy clients)
    ['nodes'],                                                 # ROS glue only
]
GENERATED = {'msg', 'srv'}       # built by catkin into the workspace: imported, never in src/


def part_of(module: str) -> str:
    """robot_ai.reach.env -> reach; robot_ai -> '' (the package itself)."""
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else ''


def module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(SRC).with_suffix('')
    parts = list(rel.parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def imports_of(path: pathlib.Path) -> set[str]:
    """The robot_ai modules a file imports, anywhere in it (from robot_ai import x: robot_ai.x when x is a module)."""
    tree = ast.parse(path.read_text(), str(path))
    here = module_name(path)
    package = here if path.name == '__init__.py' else here.rpartition('.')[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split('.')[0] == 'robot_ai'}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parent = package.split('.')[:len(package.split('.')) - node.level + 1]
                base = '.'.join(parent + ([base] if base else []))
            if base.split('.')[0] != 'robot_ai':
                continue
            for alias in node.names:
                sub = f'{base}.{alias.name}'
                found.add(sub if is_module(sub) else base)
    return found


def is_module(name: str) -> bool:
    path = SRC.joinpath(*name.split('.'))
    return path.with_suffix('.py').is_file() or (path / '__init__.py').is_file() or part_of(name) in GENERATED


def all_modules() -> dict[str, set[str]]:
    return {module_name(p): imports_of(p) for p in sorted(PACKAGE.rglob('*.py'))}


GRAPH = all_modules()
LAYER_OF = {part: i for i, layer in enumerate(LAYERS) for part in layer}


def test_every_part_has_a_layer():
    parts = {part_of(m) for m in GRAPH} - {''}
    assert not sorted(parts - set(LAYER_OF)), 'a part of src/robot_ai that LAYERS does not place'
    assert not sorted(set(LAYER_OF) - parts - GENERATED), 'LAYERS names a part src/robot_ai does not have'


@pytest.mark.parametrize('module', sorted(m for m in GRAPH if part_of(m)))
def test_no_import_up_a_layer_or_across_it(module):
    mine = part_of(module)
    wrong = [f'{t} (an entry point)' for t in sorted(GRAPH[module]) if t.endswith('.__main__')]
    for target in sorted(GRAPH[module]):
        other = part_of(target)
        if other in ('', mine) or module.endswith('.__main__'):
            continue
        if LAYER_OF[other] >= LAYER_OF[mine]:
            where = 'a sibling' if LAYER_OF[other] == LAYER_OF[mine] else 'a higher layer'
            wrong.append(f'{target} ({where}: {other})')
    assert not wrong, f'{module} imports {", ".join(wrong)}'


def test_no_circle():
    """Depth-first search over the modules' imports (a package's __init__ is a module of its own)."""
    state, path, circles = {}, [], []

    def visit(m):
        state[m] = 'open'
        path.append(m)
        for t in sorted(GRAPH.get(m, ())):
            if t not in GRAPH:
                continue
            if state.get(t) == 'open':
                circles.append(path[path.index(t):] + [t])
            elif t not in state:
                visit(t)
        path.pop()
        state[m] = 'done'
    for m in sorted(GRAPH):
        if m not in state:
            visit(m)
    assert not circles, 'import circles: ' + '; '.join(' -> '.join(c) for c in circles)


def test_the_test_sees_imports():
    """The reader finds what it must: a lazy import inside a function, and a relative one."""
    assert 'robot_ai.cartpole.dynamics' in GRAPH['robot_ai.cartpole.policy_kinds']
    assert 'robot_ai.policies.npz' in GRAPH['robot_ai.policies']
    assert any(part_of(t) == 'reach' for t in GRAPH['robot_ai.nodes.demo_client'])   # imported inside a function


def test_setup_py_installs_every_package():
    """catkin_python_setup installs the packages setup.py names: one missing (motion, grading, policies were) is in
    the devel space, through src/, and not in an install space."""
    tree = ast.parse((SRC.parent / 'setup.py').read_text())
    named = next(ast.literal_eval(k.value) for node in ast.walk(tree) if isinstance(node, ast.Call)
                 for k in node.keywords if k.arg == 'packages')
    found = sorted(module_name(p) for p in PACKAGE.rglob('__init__.py'))
    assert sorted(named) == found
