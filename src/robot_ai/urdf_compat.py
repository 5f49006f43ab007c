"""ROS 1's ``URDF.from_parameter_server()`` for the venv's urdf_parser_py (urdfdom-py from PyPI, which lacks it).

The course's skeleton reads the robot with ``URDF.from_parameter_server()``: in ROS 1 that is the URDF of the
``robot_description`` parameter (or ``key``), searched up the namespaces as ``rospy.search_param`` does. urdfdom-py
from PyPI has no such method, so a course node dies at start with an AttributeError. ``install()`` gives
urdf_parser_py's ``Robot`` (alias ``URDF``) that method, when ``urdf_parser_py.urdf`` is imported, if it has none.

The Makefile's venv runs ``install()`` at every interpreter start (a line of ``robot_ai_urdf_compat.pth`` in its
site-packages), so that a node runs unchanged under ``rosrun`` and under check_fk alike; the import hook costs
nothing until urdf_parser_py is imported. In a venv of your own: ``python -m robot_ai.urdf_compat --install``.

Old ``<transmission>`` blocks (the PR2's), which urdfdom-py refuses, are left out when the first parse fails on
them: a forward-kinematics node needs links and joints only.
"""
from __future__ import annotations

import importlib.abc
import importlib.util
import re
import sys

MODULE = 'urdf_parser_py.urdf'
TRANSMISSION = re.compile(r'<transmission\b.*?</transmission\s*>', re.S)


def from_parameter_server(cls, key: str = 'robot_description'):
    """The robot of the parameter `key`, searched up the namespaces (ROS 1's meaning); KeyError when none."""
    import rospy
    name = key if key.startswith(('/', '~')) else (rospy.search_param(key) or key)
    xml = rospy.get_param(name)
    try:
        return cls.from_xml_string(xml)
    except Exception:
        if '<transmission' not in xml:
            raise
        return cls.from_xml_string(TRANSMISSION.sub('', xml))


def patch(module) -> None:
    robot = getattr(module, 'Robot', None)
    if robot is not None and not hasattr(robot, 'from_parameter_server'):
        robot.from_parameter_server = classmethod(from_parameter_server)


class _Loader(importlib.abc.Loader):
    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.loader.exec_module(module)
        patch(module)


class _Finder(importlib.abc.MetaPathFinder):
    """Finds urdf_parser_py.urdf as the other finders do, and patches it once it has run."""

    def find_spec(self, name, path, target=None):
        if name != MODULE:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, 'find_spec'):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, 'exec_module'):
                    spec.loader = _Loader(spec.loader)
                return spec
        return None


def install() -> None:
    """From now on (or at once, if it is imported already) urdf_parser_py's URDF has from_parameter_server."""
    if MODULE in sys.modules:
        patch(sys.modules[MODULE])
    elif not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def pth_line() -> str:
    """The .pth line: site runs it at every start; where robot_ai cannot be imported it does nothing. A Ctrl-C that
    comes while it runs (roslaunch interrupted as it starts its nodes) ends that interpreter quietly, with the status of
    an interrupted program, instead of a traceback through this module."""
    return ('import sys; exec("try:\\n import robot_ai.urdf_compat as c\\n c.install()\\n'
            'except KeyboardInterrupt:\\n import os\\n os._exit(130)\\nexcept Exception:\\n pass")\n')


def main(argv=None) -> int:
    import argparse
    import os
    import sysconfig
    p = argparse.ArgumentParser(prog='python -m robot_ai.urdf_compat', description=__doc__.split('\n\n')[0])
    p.add_argument('--install', action='store_true', help='write robot_ai_urdf_compat.pth into this Python\'s '
                   'site-packages, so that every interpreter start installs the method')
    a = p.parse_args(argv)
    if not a.install:
        p.print_help()
        return 0
    path = os.path.join(sysconfig.get_paths()['purelib'], 'robot_ai_urdf_compat.pth')
    with open(path, 'w') as f:
        f.write(pth_line())
    print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
