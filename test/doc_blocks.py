"""The docs' code blocks as a user runs them (issue 57: "every command in the docs should run as written"): the python
blocks and the `python -m robot_ai.<cli>` commands of README.md and docs/, with the placeholders a reader fills in
(their own arm file, the file an earlier command wrote) filled in the same way. Those that need the ROS graph run in
the rostest that starts what they lease (ros_env.test: CartPole sims; reach_ros.test: arms); those that need what
this machine cannot have (stable-baselines3 and torch, a Ray cluster) are named with the reason, which the tests
check is still true here."""
from __future__ import annotations

import glob
import importlib.util
import os
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_ROBOTS = ROOT.parent / 'shared' / 'robots'
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').rglob('*.md'))]
FENCED = re.compile(r'^```(\w*)\n(.*?)^```', re.S | re.M)
# a block that names no import gets these: the docs' fragments go on from the block above them
PRELUDE = 'import gymnasium\nimport robot_ai.reach\nimport robot_ai.envs\n'
CLI = re.compile(r'(?:^|\s)(?:\S*/)?python3? -m robot_ai\.(reach|cartpole) (.*)$')
# what a command needs that this machine does not have, by a word of its line
NEEDS = {'--ray': 'a Ray cluster (docs/fleet.md; ray_cluster.test runs the package on one)',
         '.onnx': 'a model an example exports with stable-baselines3 (torch: never installed here)'}


@dataclass
class Block:
    page: str
    code: str
    needs_ros: str            # '' (runs anywhere), 'cartpole' (CartPole sims to lease), 'reach' (arms to lease) or
    #                           'manipulation' (arms with physics to lease)
    missing: list[str]        # modules it imports that are not installed here

    def source(self, arm: str) -> str:
        """The block as a reader runs it: their arm file is `arm`, their arm with a gripper the package's UR5 with a
        Robotiq 2F-85, their world the tests' world."""
        code = self.code.replace('/path/arm.urdf', arm).replace('"arm.urdf"', f'"{arm}"')
        code = code.replace('"gripper_arm.urdf"', f'"{ROOT / "urdf" / "ur5_robotiq_2f85.urdf.xacro"}"')
        code = code.replace('"world.yaml"', f'"{ROOT / "test" / "world.yaml"}"')
        return ('' if re.search(r'^import |^from ', code, re.M) else PRELUDE) + code


def python_blocks() -> list[Block]:
    found = []
    for page in PAGES:
        for lang, code in FENCED.findall(page.read_text()):
            if lang not in ('python', 'py'):
                continue
            needs_ros = 'cartpole' if re.search(r'["\']robot_ai/RosCartPole', code) else \
                'reach' if re.search(r'["\']robot_ai/RosReach', code) else \
                'manipulation' if re.search(r'["\']robot_ai/Ros(Push|PickAndPlace)', code) else ''
            imported = re.findall(r'^\s*(?:from|import) ([\w.]+)', code, re.M)
            missing = sorted({m for m in imported if not _importable(m)})
            found.append(Block(str(page.relative_to(ROOT)), code, needs_ros, missing))
    return found


def run_as_written(block: Block, arm: str = '', timeout: float = 300) -> str:
    """The block run as a reader runs it, in a process of its own (their arm file: arm): '' if it ended well, else
    the block and what it printed, a failure's message."""
    import subprocess
    run = subprocess.run([sys.executable, '-c', block.source(arm)], capture_output=True, text=True, timeout=timeout,
                         stdin=subprocess.DEVNULL)
    return '' if run.returncode == 0 else f'{block.page}:\n{block.code}\n{run.stdout[-2000:]}{run.stderr[-3000:]}'


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


@dataclass
class Command:
    page: str
    line: str                 # as the docs show it (continuation lines joined)
    cli: str                  # reach or cartpole
    words: list[str]          # after `python -m robot_ai.<cli>`
    needs: str                # why it cannot run here, or ''


def cli_commands() -> list[Command]:
    """Every `python -m robot_ai.reach|cartpole ...` line of the docs' shell blocks, once each, in the docs' order."""
    found, seen = [], set()
    for page in PAGES:
        for lang, code in FENCED.findall(page.read_text()):
            if lang not in ('sh', 'bash', 'shell'):
                continue
            for line in re.sub(r'\\\n\s*', ' ', code).splitlines():
                m = CLI.search(line.split('  #')[0].split(' # ')[0])
                if not m:
                    continue
                words = shlex.split(m.group(2))
                if (m.group(1), *words) in seen:
                    continue
                seen.add((m.group(1), *words))
                needs = next((why for word, why in NEEDS.items() if any(word in w for w in words)), '')
                found.append(Command(str(page.relative_to(ROOT)), line.strip(), m.group(1), words, needs))
    return found


def arm_xacro(folder: Path) -> Path:
    """A reader's own arm.urdf.xacro with a `hand` argument: the UR5 of ../shared/robots (its tool0), a hand link on
    tool0 when hand:=true."""
    text = (SHARED_ROBOTS / 'ur5.urdf').read_text()
    text = re.sub(r'<robot ([^>]*)>', r'<robot \1 xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
                  r'  <xacro:arg name="hand" default="false"/>', text, count=1)
    text = text.replace('</robot>', '  <xacro:if value="$(arg hand)">\n    <link name="hand"/>\n'
                        '    <joint name="tool0_hand" type="fixed"><parent link="tool0"/><child link="hand"/>'
                        '<origin xyz="0 0 0.05"/></joint>\n  </xacro:if>\n</robot>')
    path = folder / 'arm.urdf.xacro'
    path.write_text(text)
    return path


def filled(command: Command, folder: Path, home: Path) -> list[str]:
    """The command's argv as a reader runs it in folder, HOME=home: their arm files are the UR5 (a xacro with a hand
    argument for a .xacro, written in folder), '..._seed0' and FILE the newest file a command wrote in home,
    ../shared/robots the shared robots."""
    out = []
    for word in command.words:
        word = word.replace('../shared/robots/', f'{SHARED_ROBOTS}/')
        if word.endswith('.urdf.xacro') and not word.startswith(str(SHARED_ROBOTS)):
            word = str(arm_xacro(folder))
        elif word.endswith('.urdf') and not os.path.exists(word) and not word.startswith(str(SHARED_ROBOTS)):
            word = str(SHARED_ROBOTS / 'ur5.urdf')
        elif '...' in word or word == 'FILE':
            pattern = str(home / '.ros' / 'robot_ai' / f'{"reach-" if command.cli == "reach" else ""}*.npz') \
                if word == 'FILE' else str(home) + word[1:] if word.startswith('~') else word
            matches = sorted(glob.glob(pattern.replace('...', '*')), key=os.path.getmtime)
            word = matches[-1] if matches else word
        out.append(word)
    return [sys.executable, '-m', f'robot_ai.{command.cli}'] + out
