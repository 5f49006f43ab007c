"""The README and docs/: every link resolves (files and #anchors, as GitHub renders them), and every interface the
code declares is on its page: each node's parameters, topics, services and actions, each launch file's arguments,
check_fk's options and the CLIs' commands. No rospy."""
from __future__ import annotations

import ast
import importlib
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from doc_blocks import PAGES

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / 'docs'
NODES = ROOT / 'src' / 'robot_ai' / 'nodes'

# node module -> its page; the helpers share one
NODE_PAGES = {name: DOCS / 'nodes' / f'{name}.md' for name in (
    'forward_kinematics', 'check_fk', 'cartpole_search', 'cartpole_q_learning', 'cartpole_sim', 'cartpole_controller',
    'arm_sim', 'reach_controller', 'pick_place')}
NODE_PAGES.update({name: DOCS / 'nodes' / 'helpers.md' for name in ('joint_sweep', 'demo_client', 'rviz_view',
                                                                     'sliders')})

FENCE = re.compile(r'^```.*?^```', re.S | re.M)
LINK = re.compile(r'(?<!`)\[[^\]]*\]\(([^)\s]+)\)')
HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$', re.M)


def prose(text: str) -> str:
    """The text without its fenced code blocks (a `# comment` in a shell block is no heading)."""
    return FENCE.sub('', text)


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: markup dropped, lower case, punctuation but - and _ removed, spaces to -."""
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', heading).replace('`', '').lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, heading in HEADING.findall(prose(path.read_text())):
        a = anchor(heading)
        n = seen.get(a, 0)
        out.add(a if n == 0 else f'{a}-{n}')
        seen[a] = n + 1
    return out


def links():
    for page in PAGES:
        for target in LINK.findall(prose(page.read_text())):
            yield page, target


def test_the_readme_is_short_and_the_pages_exist():
    assert len((ROOT / 'README.md').read_text().splitlines()) <= 220
    for page in set(NODE_PAGES.values()):
        assert page.is_file(), page
    for env in ('RosCartPole', 'Reach', 'RosReach', 'Push', 'PickAndPlace'):
        assert (DOCS / 'envs' / f'{env}.md').is_file()


@pytest.mark.parametrize('page,target', list(links()), ids=lambda v: str(v).replace(str(ROOT) + '/', ''))
def test_every_link_resolves(page, target):
    if re.match(r'[a-z]+://', target) or target.startswith('mailto:'):
        return                                          # the web is not checked offline
    path, _, fragment = target.partition('#')
    dest = (page.parent / path).resolve() if path else page
    assert dest.exists(), f'{page.name}: {target}: no such file'
    assert ROOT in dest.parents or dest == ROOT, f'{page.name}: {target} leaves the repository'
    if fragment:
        assert dest.suffix == '.md', f'{page.name}: {target}: an anchor in a file that is not markdown'
        assert fragment in anchors(dest), f'{page.name}: {target}: no such heading in {dest.name}'


def test_the_anchor_rules_are_githubs():
    assert anchor('forward_kinematics.launch') == 'forward_kinematicslaunch'
    assert anchor('ONNX: policies from any RL library') == 'onnx-policies-from-any-rl-library'
    assert anchor('`.npz` policy files') == 'npz-policy-files'


def _strings(node_module: Path) -> tuple[set[str], set[str]]:
    """('~private' names, graph names) a node module declares: get_param/param literals, and the first argument of
    every Publisher, Subscriber, Service and SimpleActionServer that is a literal or a module constant."""
    tree = ast.parse(node_module.read_text())
    constants = {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
                 for t in n.targets if isinstance(t, ast.Name) and isinstance(n.value, ast.Constant)
                 and isinstance(n.value.value, str)}
    private, names = set(), set()
    for n in ast.walk(tree):
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and re.fullmatch(r'~[a-z_]+', n.value):
            private.add(n.value)
        if isinstance(n, ast.Call) and n.args:
            func = n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, 'id', '')
            if func in ('Publisher', 'Subscriber', 'Service', 'SimpleActionServer'):
                first = n.args[0]
                value = first.value if isinstance(first, ast.Constant) else constants.get(getattr(first, 'id', ''))
                if isinstance(value, str):
                    names.add(value)
    return private, names - private


def _agent_defaults(module: str) -> set[str]:
    defaults = importlib.import_module(f'robot_ai.cartpole.{module}').DEFAULTS
    return {f'~{k}' for k in defaults}


def declared(node: str) -> set[str]:
    private, names = _strings(NODES / f'{node}.py')
    if node in ('cartpole_search', 'cartpole_q_learning'):
        common, _ = _strings(NODES / 'agent_common.py')
        private |= common | _agent_defaults('linear_search' if node == 'cartpole_search' else 'q_learning')
    if node in ('cartpole_sim', 'arm_sim'):
        private.add('~lease')
    if node == 'check_fk':       # the candidate's remapped topics are check_fk's own business, not its interface
        return set()
    return private | {n for n in names if '{' not in n}


@pytest.mark.parametrize('node', sorted(NODE_PAGES))
def test_every_node_interface_is_on_its_page(node):
    text = NODE_PAGES[node].read_text()
    names = declared(node)
    if node not in ('sliders', 'check_fk'):
        assert names, f'{node}: nothing found to check: the test is wrong'
    missing = sorted(n for n in names if f'`{n}`' not in text)
    assert not missing, f'{NODE_PAGES[node].name} does not name {missing} of {node}'


def launch_args(path: Path) -> set[str]:
    """The arguments a user can give: <arg> with a default or none, not those with a fixed value."""
    return {a.get('name') for a in ET.parse(path).getroot().iter('arg') if a.get('value') is None}


@pytest.mark.parametrize('launch', sorted(p.name for p in (ROOT / 'launch').glob('*.launch')))
def test_every_launch_argument_is_on_the_launch_page(launch):
    text = prose((DOCS / 'launch.md').read_text())
    sections = re.split(r'^## ', text, flags=re.M)
    section = next((s for s in sections if s.startswith(launch + '\n')), None)
    assert section is not None, f'docs/launch.md has no section "## {launch}"'
    missing = sorted(a for a in launch_args(ROOT / 'launch' / launch) if f'`{a}`' not in section)
    assert not missing, f'docs/launch.md\'s {launch} does not name {missing}'


def test_check_fk_options_are_on_its_page():
    source = (NODES / 'check_fk.py').read_text()
    options = set(re.findall(r"add_argument\(\s*'(--[a-z-]+)'", source))
    hidden = set(re.findall(r"add_argument\(\s*'(--[a-z-]+)'[^)]*help=argparse.SUPPRESS", source, re.S))
    assert options - hidden, 'no option found: the test is wrong'
    text = (DOCS / 'nodes' / 'check_fk.md').read_text()
    assert not sorted(o for o in options - hidden if f'`{o}' not in text)


def test_every_cli_command_is_on_the_cli_page():
    text = (DOCS / 'cli.md').read_text()
    for module in ('cartpole', 'reach', 'physics'):
        source = (ROOT / 'src' / 'robot_ai' / module / '__main__.py').read_text()
        source += (ROOT / 'src' / 'robot_ai' / 'cli.py').read_text() if module == 'cartpole' else ''
        commands = set(re.findall(r"add_parser\(\s*'([a-z-]+)'", source))
        assert commands, f'{module}: no command found: the test is wrong'
        assert not sorted(c for c in commands if f'`{c}' not in text), module


def documented_commands(module: str) -> list[tuple[str, list[str], bool]]:
    """(page, words after `python -m robot_ai.<module>`, whole) of every such command in the docs' code blocks (with
    continuation lines; whole) and inline code (a command named in a sentence may leave out its file); $VARIABLES
    and $(commands) kept as words (a file name to the parser)."""
    import shlex
    found = []
    for page in PAGES:
        text = page.read_text()
        spans = re.findall(r'`([^`\n]*python -m robot_ai[^`\n]*)`', prose(text))     # `...` in a sentence too
        for whole, blocks in ((True, FENCE.findall(text)), (False, spans)):
            for block in blocks:
                for line in re.sub(r'\\\n\s*', ' ', block).splitlines():
                    at = line.find(f'python -m robot_ai.{module} ')
                    if at < 0:
                        continue
                    command = line[at + len(f'python -m robot_ai.{module} '):].split('#')[0]
                    command = re.split(r'\s(?:&&|\||;|>)\s?', command)[0]
                    if len(command.split()) > 1:        # a command, not its name in a sentence (`reach evaluate`)
                        found.append((page.name, shlex.split(command), whole))
    return found


@pytest.mark.parametrize('module', ['reach', 'cartpole', 'physics'])
def test_every_cli_command_in_the_docs_parses_as_written(module, capsys):
    """Issue 57: docs/bringup.md's `reach train --out reach_ur5e.npz` made a folder of that name (argparse took
    `--out` for `--output-dir`). The CLIs take no abbreviation now; every command the docs show parses, and every
    option a sentence names is its command's."""
    build = importlib.import_module(f'robot_ai.{module}.__main__').build_parser
    commands = documented_commands(module)
    assert commands, f'no `python -m robot_ai.{module}` command in the docs: the test is wrong'
    for page, words, whole in commands:
        parser, sub = build()
        if not whole:
            known = sub.choices[words[0]]._option_string_actions if words[0] in sub.choices else {}
            unknown = [w.split('=')[0] for w in words[1:] if w.startswith('--') and w.split('=')[0] not in known]
            assert words[0] in sub.choices and not unknown, f'{page}: `python -m robot_ai.{module} ' \
                f'{" ".join(words)}`: {words[0]} has no {unknown}'
            continue
        try:
            parser.parse_args(words)
        except SystemExit:
            pytest.fail(f'{page}: python -m robot_ai.{module} {" ".join(words)}: '
                        f'{capsys.readouterr().err.strip().splitlines()[-1]}')
