"""The robot of a reach task: a URDF or xacro file (as ``model:=`` takes it), or a URDF text, as a kinematic tree.
No rospy.

    model = load_model('/path/robot.urdf.xacro', xacro_args='hand:=true')   # or load_model(urdf=text)
    model.tree, model.name, model.sha256

The default is the package's UR5 (urdf/ur5_arm.urdf). A model is read once per process for the same file, contents
and arguments (gymnasium's SyncVectorEnv makes one env per copy), and every failure is a ReachError of one line.
"""
from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass

from robot_ai.kinematics import KinematicTree, URDFError
from robot_ai.reach.arm import ReachError
from robot_ai.urdf_source import XacroError, expand, parse_mappings

PACKAGE_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
DEFAULT_MODEL = 'urdf/ur5_arm.urdf'


@dataclass(frozen=True, eq=False)
class Model:
    """A robot file read for a reach task: its tree, the file's name (or 'robot_description'), the xacro arguments,
    and the SHA-256 of its URDF text (a policy file names the robot it learned on by it)."""
    tree: KinematicTree
    name: str
    path: str
    xacro_args: tuple[tuple[str, str], ...]
    sha256: str
    urdf: str


def package_file(relative: str) -> str:
    """A file of the robot_ai package: beside the sources, or where ROS_PACKAGE_PATH has the package installed."""
    here = os.path.join(PACKAGE_ROOT, relative)
    if os.path.exists(here):
        return here
    try:
        import rospkg
        return os.path.join(rospkg.RosPack().get_path('robot_ai'), relative)
    except Exception:      # no rospkg, or no robot_ai on ROS_PACKAGE_PATH: the path as it is says what is missing
        return here


def xacro_mappings(xacro_args) -> tuple[tuple[str, str], ...]:
    """xacro arguments as a text ('a:=1 b=2'), a sequence of such words, or a dict -> sorted (name, value) pairs."""
    if not xacro_args:
        return ()
    try:
        if isinstance(xacro_args, dict):
            pairs = {str(k): str(v) for k, v in xacro_args.items()}
        else:
            words = xacro_args.split() if isinstance(xacro_args, str) else [str(w) for w in xacro_args]
            pairs = parse_mappings(words)
    except XacroError as e:
        raise ReachError(str(e)) from None
    return tuple(sorted(pairs.items()))


def load_model(model: str | None = None, xacro_args=None, urdf: str | None = None) -> Model:
    """The robot of model (a URDF or xacro path; None: the package's UR5) with its xacro arguments, or of urdf (the
    text of a URDF: a robot_description)."""
    mappings = xacro_mappings(xacro_args)
    if urdf is not None:
        if model:
            raise ReachError('give a model file or a URDF text, not both')
        return _from_text(urdf, 'robot_description', '', ())
    path = os.path.abspath(os.path.expanduser(model)) if model else package_file(DEFAULT_MODEL)
    try:
        st = os.stat(path)
    except OSError as e:
        raise ReachError(f'model {path}: {e.strerror or e}') from None
    return _load_file(path, st.st_mtime_ns, st.st_size, mappings)


@functools.lru_cache(maxsize=16)
def _load_file(path: str, mtime_ns: int, size: int, mappings: tuple) -> Model:
    try:
        text = expand(path, dict(mappings))
    except XacroError as e:
        raise ReachError(str(e)) from None
    return _from_text(text, os.path.basename(path), path, mappings)


@functools.lru_cache(maxsize=16)
def _from_text(text: str, name: str, path: str, mappings: tuple) -> Model:
    try:
        tree = KinematicTree.from_xml_string(text)
    except URDFError as e:
        raise ReachError(f'{path or name}: {e}') from None
    return Model(tree, name, path, mappings, hashlib.sha256(text.encode()).hexdigest(), text)
