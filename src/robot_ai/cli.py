"""What the package's command lines share: argument types, the output folder, and how a run ends. No rospy.

    p.add_argument('--episodes', type=whole_number(1, 1000))
    folder = output_folder(args, parser)             # created and checked before any work
    write_or_say('policy', lambda: save(...))        # `policy            /path`, or why it was not written
    return run_command(parser, sub, argv)            # Ctrl-C, SIGTERM and SIGHUP end a run through its finally clauses
"""
from __future__ import annotations

import argparse
import functools
import os
import signal
import sys
from typing import NoReturn

from robot_ai import artifacts


def command_parser(prog: str, description: str) -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    """A CLI's parser and its commands' (python -m robot_ai.reach train ...): no option is taken from a prefix of
    its name (argparse's default turned `--out reach.npz` into `--output-dir reach.npz`, a folder of that name); an
    option misspelled is refused with the options there are."""
    strict = functools.partial(argparse.ArgumentParser, allow_abbrev=False)
    parser = strict(prog=prog, description=description)
    return parser, parser.add_subparsers(dest='command', required=True, metavar='COMMAND', parser_class=strict)


def whole_number(low: int, high: int):
    """An argparse type: a whole number from low to high, or the one-line error (status 2) that --help's range
    promises. 0 means "the default" in a ROS request only, never here."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'must be a whole number from {low} to {high}, got {text!r}')
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f'must be {low} to {high}, got {value}')
        return value
    return parse


def positive_number(text: str) -> float:
    """An argparse type: a finite number above 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a number above 0, got {text!r}')
    if not 0 < value < float('inf'):
        raise argparse.ArgumentTypeError(f'must be a number above 0, got {text}')
    return value


def fraction(text: str) -> float:
    """An argparse type: a number from 0 to 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a number from 0 to 1, got {text!r}')
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f'must be from 0 to 1, got {value:g}')
    return value


def fraction_above_0(text: str) -> float:
    """An argparse type: a number in (0, 1] (a discount, a velocity scale)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a number in (0, 1], got {text!r}')
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f'must be in (0, 1], got {value:g}')
    return value


def output_folder(a, parser) -> str:
    """The output folder, created and checked before any work: a run never ends in a traceback over its files."""
    folder = os.path.abspath(os.path.expanduser(a.output_dir))
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        parser.error(f'--output-dir: cannot create {folder}: {e.strerror or e}')
    problem = artifacts.unwritable_reason(folder)
    if problem:
        parser.error(f'--output-dir: {problem}')
    return folder


def refuse(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """End the command with one line and status 2, as argparse's errors do but without its usage: the options were
    right, the file or robot they name is not (a missing model, a tip that is no link, another robot's policy)."""
    parser.exit(2, f'{parser.prog}: error: {message}\n')


def add_ray(p: argparse.ArgumentParser, what: str) -> None:
    """--ray ADDRESS: `what` on a Ray cluster (robot_ai.fleet)."""
    p.add_argument('--ray', default='', metavar='ADDRESS',
                   help=f'{what} on a Ray cluster: HOST:PORT of its head, ray://HOST:PORT, or auto (the cluster this '
                   f'machine joined with `ray start`); the same seed gives the same numbers as here. Ray is an '
                   f'optional extra: docs/fleet.md')


def connect_ray(parser: argparse.ArgumentParser, address: str) -> None:
    """With --ray: the connection made now, or one line and status 2 (Ray not installed, no cluster there)."""
    if not address:
        return
    from robot_ai import fleet
    try:
        fleet.connect(address)
    except fleet.FleetError as e:
        refuse(parser, f'--ray: {e}')


def write_or_say(label: str, write) -> None:
    """Print `label  path` once write() has written its file, or why it could not."""
    try:
        print(f'{label:<18}{write()}')
    except Exception as e:  # the numbers above are printed already
        print(f'{label:<18}not written: {e}')


def show_policy(path: str, parser) -> int:
    """`show` of a policy file (its metadata as JSON, then its arrays, the values of small ones) or of an ONNX model
    (its metadata, producer, opset, inputs, outputs and operators, as JSON)."""
    import json

    import numpy as np

    from robot_ai import policies
    from robot_ai.policies import npz, onnx
    try:
        if policies.is_onnx_path(path):
            print(json.dumps(onnx.summary(onnx.read(path)), indent=2))
            return 0
        policy = npz.load(path)
    except policies.PolicyError as e:
        refuse(parser, str(e))
    print(json.dumps(policy.metadata, indent=2))
    for name, array in policies.arrays_of(policy.actor).items():
        value = f' = {np.array2string(array, precision=6)}' if array.size <= 4 else ''
        print(f'{name}: {array.dtype} {array.shape}{value}')
    return 0


class Interrupted(Exception):
    """A SIGTERM or SIGHUP, raised where the run is, so that it ends through its finally clauses."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signal = signal.Signals(signum)


def _interrupt(signum, frame):
    raise Interrupted(signum)


def run_command(parser: argparse.ArgumentParser, sub, argv=None) -> int:
    """Parse argv and run the chosen command (its `run(args, its parser)`); SIGTERM and SIGHUP (a closed terminal)
    end a run as a Ctrl-C does, through its finally clauses (helper processes end with it)."""
    a = parser.parse_args(argv)
    previous = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGTERM, signal.SIGHUP)}
    try:
        return a.run(a, sub.choices[a.command])
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    except Interrupted as e:
        print(f'interrupted by {e.signal.name}', file=sys.stderr)
        return 128 + e.signal
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
