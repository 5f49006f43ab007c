"""A URDF or xacro file -> URDF text, as ROS 1 users bring their robots (no rospy).

A xacro file (``.xacro``, ``.urdf.xacro``, or any file that declares the xacro namespace) is expanded by PyPI's
``xacro`` (2.x, the ROS 2 release of the same library), with its arguments (``hand:=true``); ``$(find pkg)``
resolves through ``ROS_PACKAGE_PATH`` as in ROS 1 (Debian's rospkg: the ROS 2 library would ask ament). Any
other file is returned as it is. A failure is one line naming the file and the cause (an unknown macro, a
missing package, a missing argument), raised as XacroError.

    rosrun robot_ai xacro FILE [name:=value ...]     # the URDF on stdout, for your own launch files
"""
from __future__ import annotations

import os
import re
import sys

MARKERS = ('xmlns:xacro', '<xacro:')
MAX_BYTES = 64 * 1024 * 1024


class XacroError(ValueError):
    """A xacro file that cannot be expanded: one line."""


def is_xacro(path: str, text: str) -> bool:
    return path.endswith('.xacro') or any(m in text for m in MARKERS)


def parse_mappings(words) -> dict[str, str]:
    """'name:=value' words (xacro's arguments, as xacro takes them) -> {name: value}; 'name=value' too, which
    roslaunch's command line can carry inside xacro_args:=... (it refuses a second ':=')."""
    out = {}
    for word in words:
        name, sep, value = word.partition(':=')
        if not sep:
            name, sep, value = word.partition('=')
        if not sep or not name or not name.replace('_', 'a').replace('-', 'a').isalnum():
            raise XacroError(f'a xacro argument is name:=value (or name=value), got {word!r}')
        out[name] = value
    return out


def _find_ros1(pkg: str) -> str:
    import rospkg
    from xacro.substitution_args import SubstitutionException
    try:
        return rospkg.RosPack().get_path(pkg)
    except rospkg.ResourceNotFound:
        raise SubstitutionException(f'package {pkg} not found: put it on ROS_PACKAGE_PATH') from None


def _one_line(e: BaseException) -> str:
    text = ' '.join(str(e).split())
    for noise in ('[', ']'):
        text = text.strip(noise)
    return text[:400] or type(e).__name__


def expand(path: str, mappings: dict[str, str] | None = None) -> str:
    """The URDF text of path: expanded when it is xacro, as it is otherwise."""
    try:
        with open(path, 'rb') as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise XacroError(f'cannot read {path}: {e.strerror or e}') from None
    if len(data) > MAX_BYTES:
        raise XacroError(f'{path} is larger than {MAX_BYTES // 2 ** 20} MiB: not a robot description')
    text = data.decode('utf-8', errors='replace')
    if not is_xacro(path, text):
        return text
    try:
        return _expand(path, text, mappings)
    except XacroError:
        # an expanded URDF may keep xacro calls in blocks nobody reads (the PR2's gazebo and transmission
        # macros): a file that is not named .xacro and reads as a robot as it is, is that robot
        if path.endswith('.xacro') or mappings or not _reads_as_urdf(text):
            raise
        return text


def _reads_as_urdf(text: str) -> bool:
    from robot_ai.kinematics import KinematicTree
    try:
        KinematicTree.from_xml_string(text)
        return True
    except Exception:
        return False


def _expand(path: str, text: str, mappings: dict[str, str] | None) -> str:
    try:
        import xacro
        from xacro import substitution_args
    except ImportError:
        raise XacroError(f'{path} is xacro, and the xacro library is not installed (pip install xacro)') from None
    substitution_args._eval_find = _find_ros1     # $(find pkg): ROS 1's meaning
    try:
        doc = xacro.process_file(os.path.abspath(path), mappings=dict(mappings or {}))
    except Exception as e:       # XacroException, SubstitutionException, XML errors, whatever a file does
        where = xacro.filestack[-1] if getattr(xacro, 'filestack', None) else path
        inner = getattr(e, 'exc', None)     # xacro wraps the cause, and its str() repeats it
        if isinstance(inner, substitution_args.ArgException) or isinstance(e, substitution_args.ArgException):
            name = _one_line(inner or e)
            cause = f'argument {name} is not set: give {name}:=value'
        elif isinstance(inner, substitution_args.SubstitutionException):
            cause = _one_line(inner)
        else:
            cause = _one_line(e).replace('Unknown macro name', 'unknown macro')
        shown = where if where == path or not where else f'{path} (in {where})'
        raise XacroError(f'{shown}: xacro: {cause}') from None
    return doc.toprettyxml(indent='  ')


def mesh_packages(xml: str) -> list[str]:
    """The packages the URDF's package:// resources (meshes, textures) name, in order of first use."""
    seen = []
    for name in re.findall(r'package://([^/"\'\s<>]+)', xml):
        if name not in seen:
            seen.append(name)
    return seen


def missing_packages(names) -> list[str]:
    """Those of names that ROS_PACKAGE_PATH (rospkg, as rviz resolves package://) does not hold."""
    import rospkg
    pack = rospkg.RosPack()
    missing = []
    for name in names:
        try:
            pack.get_path(name)
        except rospkg.ResourceNotFound:
            missing.append(name)
    return missing


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ('-h', '--help'):
        print(__doc__.strip().splitlines()[-1].strip())
        return 0 if argv else 2
    try:
        urdf = expand(argv[0], parse_mappings(argv[1:]))
    except XacroError as e:
        print(f'xacro: {e}', file=sys.stderr)
        return 1
    sys.stdout.write(urdf)
    return 0


if __name__ == '__main__':
    sys.exit(main())
