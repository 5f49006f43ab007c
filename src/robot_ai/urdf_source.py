"""A URDF or xacro file -> URDF text, as ROS 1 users bring their robots (no rospy).

A xacro file (``.xacro``, ``.urdf.xacro``, or any file that declares the xacro namespace) is expanded by PyPI's
``xacro`` (2.x, the ROS 2 release of the same library), with its arguments (``hand:=true``); ``$(find pkg)``
resolves through ``ROS_PACKAGE_PATH`` as in ROS 1 (Debian's rospkg: the ROS 2 library would ask ament). Any
other file is returned as it is. A failure is one line naming the file and the cause (an unknown macro, a
missing package, a missing argument), raised as XacroError.

A robot file is data to its user. xacro evaluates ``${...}`` and ``$(eval ...)`` with Python's eval, and PyPI
xacro's guards can be walked around (its ``python.vars`` and ``python.type`` reach any function's globals, and so
os.system; ``$(eval)`` gets Python's real builtins). Here every expression is checked before it runs
(``check_expression``: no name or attribute that starts with an underscore, no frame, generator or code attributes,
no ``format``) and run with no builtins but xacro's list of harmless ones, ``vars`` and ``type`` taken out of it;
what real robot files use (arithmetic, math, properties, macros, comprehensions,
``xacro.load_yaml``) passes. ``xacro.load_yaml`` and ``xacro:include`` read only files in the robot file's folder
and in the packages ``$(find)`` names (``${xacro.load_yaml('/etc/shadow')}`` is refused). And the expansion runs
in a child process bounded in wall time (EXPAND_SECONDS), CPU time and memory (EXPAND_MEMORY), whose output is at
most MAX_BYTES: ``${10**10**10}`` is an error after
EXPAND_SECONDS, and a Ctrl-C ends it at once.

    rosrun robot_ai xacro FILE [name:=value ...]     # the URDF on stdout, for your own launch files
"""
from __future__ import annotations

import ast
import json
import os
import re
import signal
import subprocess
import sys

MARKERS = ('xmlns:xacro', '<xacro:')
MAX_BYTES = 64 * 1024 * 1024
EXPAND_SECONDS = int(os.environ.get('ROBOT_AI_XACRO_SECONDS', 60))   # wall and CPU seconds an expansion may take
EXPAND_MEMORY = 2 * 1024 ** 3    # bytes of address space of the expanding process
CHILD_FLAG = '--expand-in-child'


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
        return _expand_in_child(path, mappings)
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


def _expand_in_child(path: str, mappings: dict[str, str] | None) -> str:
    """_expand in a child process of its own, bounded in time and memory (see the module's docstring)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    child = subprocess.Popen([sys.executable, '-m', 'robot_ai.urdf_source', CHILD_FLAG], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, close_fds=True)
    request = json.dumps({'path': os.path.abspath(path), 'mappings': dict(mappings or {})}).encode()
    try:
        out, err = child.communicate(request, timeout=EXPAND_SECONDS)
    except subprocess.TimeoutExpired:
        raise XacroError(f'{path}: xacro: the expansion took more than {EXPAND_SECONDS} s and was stopped (an '
                         f'expression that never ends, such as a huge power?)') from None
    finally:         # a timeout, a Ctrl-C (KeyboardInterrupt here) or any error: the child ends with this call
        if child.poll() is None:
            child.kill()
            child.wait()
    if child.returncode == 0:
        return out.decode('utf-8')
    lines = err.decode('utf-8', errors='replace').strip().splitlines()
    if child.returncode in (-signal.SIGXCPU, -signal.SIGKILL):
        raise XacroError(f'{path}: xacro: the expansion used more than {EXPAND_SECONDS} s of CPU and was stopped')
    if lines and lines[-1].startswith('xacro: '):
        raise XacroError(lines[-1][len('xacro: '):])
    raise XacroError(f'{path}: xacro: the expansion failed (status {child.returncode}): '
                     f'{lines[-1] if lines else "no message"}'[:600])


def _child_main() -> int:
    """The expanding process: limits first, then one expansion, the URDF on stdout or one line on stderr."""
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (EXPAND_MEMORY, EXPAND_MEMORY))
    resource.setrlimit(resource.RLIMIT_CPU, (EXPAND_SECONDS, EXPAND_SECONDS + 1))
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))       # it writes no file
    request = json.loads(sys.stdin.buffer.read(1024 * 1024))
    path = request['path']
    try:
        with open(path, 'rb') as f:
            text = f.read(MAX_BYTES + 1).decode('utf-8', errors='replace')
        urdf = _expand(path, text, request['mappings'])
    except XacroError as e:
        print(f'xacro: {e}', file=sys.stderr)
        return 3
    except MemoryError:
        print(f'xacro: {path}: xacro: the expansion needed more than {EXPAND_MEMORY // 1024 ** 3} GiB of memory and '
              f'was stopped', file=sys.stderr)
        return 3
    data = urdf.encode('utf-8')
    if len(data) > MAX_BYTES:
        print(f'xacro: {path}: xacro: the expansion is larger than {MAX_BYTES // 2 ** 20} MiB: not a robot '
              f'description', file=sys.stderr)
        return 3
    sys.stdout.buffer.write(data)
    return 0


# ------------------------------------------------------------------------------------------ restricted evaluation
# Names resolve only to the symbol table (no builtins): properties, macro parameters (a parameter may be called
# `type`), xacro's harmless functions. Builtins that reach other objects' insides are taken out of it.
UNSAFE_BUILTINS = ('vars', 'type')
# Attributes: none that starts with an underscore (__globals__, __subclasses__), none of a frame, generator,
# coroutine, traceback or code object (gi_frame.f_globals), and no str.format (its fields walk attributes).
BLOCKED_ATTRIBUTES = frozenset({'format', 'format_map', 'mro'})
BLOCKED_PREFIXES = ('_', 'gi_', 'cr_', 'ag_', 'f_', 'tb_', 'co_', 'func_', 'im_')
ALLOWED_NODES = (ast.Expression, ast.Constant, ast.Name, ast.Attribute, ast.BinOp, ast.UnaryOp, ast.BoolOp,
                 ast.Compare, ast.IfExp, ast.Call, ast.keyword, ast.Subscript, ast.Slice, ast.List, ast.Tuple,
                 ast.Dict, ast.Set, ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp, ast.comprehension,
                 ast.JoinedStr, ast.FormattedValue, ast.expr_context, ast.operator, ast.unaryop, ast.boolop,
                 ast.cmpop)


def _blocked(name: str, attribute: bool) -> bool:
    if attribute:
        return name in BLOCKED_ATTRIBUTES or name.startswith(BLOCKED_PREFIXES)
    return name.startswith('_')


def check_expression(expression: str) -> ast.Expression:
    """The parsed expression, if it is one a robot file may hold; XacroError naming what it may not hold."""
    try:
        tree = ast.parse(expression.strip(), mode='eval')
    except SyntaxError as e:
        raise XacroError(f'not an expression: {expression.strip()[:80]!r} ({e.msg})') from None
    for node in ast.walk(tree):
        if not isinstance(node, ALLOWED_NODES):
            raise XacroError(f'a robot file\'s expression may not hold {type(node).__name__.lower()}: '
                             f'{expression.strip()[:80]!r}')
        name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
        if name is not None and _blocked(name, isinstance(node, ast.Attribute)):
            raise XacroError(f'a robot file\'s expression may not use {name!r} (it could run commands): '
                             f'{expression.strip()[:80]!r}')
        if isinstance(node, ast.keyword) and node.arg is None:
            raise XacroError(f'a robot file\'s expression may not use ** arguments: {expression.strip()[:80]!r}')
    return tree


def restricted_eval(expression: str, symbols, local_symbols=None):
    """xacro's safe_eval, checked (check_expression) and run with no builtins."""
    code = compile(check_expression(expression), '<expression>', 'eval')
    symbols.update(__builtins__={})
    return eval(code, symbols, local_symbols)


def _harden(xacro, substitution_args) -> None:
    """xacro's evaluators replaced by restricted ones; vars and type out of its python namespace."""
    xacro.safe_eval = restricted_eval
    for name in UNSAFE_BUILTINS:
        xacro._global_symbols.pop(name, None)
        xacro._global_symbols['python'].pop(name, None)
    safe_builtins = dict(xacro._global_symbols['python'])

    def eval_substitution(s: str, context: dict) -> str:      # $(eval ...): roslaunch's functions, no builtins
        context.setdefault('arg', {})
        functions = dict(substitution_args._eval_dict)
        functions['arg'] = lambda name: substitution_args.convert_value(
            substitution_args._eval_arg(name, args=context['arg']), 'auto')
        functions['dirname'] = lambda: substitution_args._eval_dirname(context['filename'])
        code = compile(check_expression(s), '<expression>', 'eval')
        return str(eval(code, dict(safe_builtins, __builtins__={}),
                        substitution_args._DictWrapper(context['arg'], functions)))
    substitution_args._eval = eval_substitution


def _under(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _confine(xacro, roots: list[str], packages: list[str]) -> None:
    """xacro.load_yaml and xacro:include read only files inside the model's folder (links resolved: a link in it
    that leads out is out) and inside the package folders $(find) gave (as found: a workspace's package may be a
    folder of links, as the Makefile's is). `${xacro.load_yaml('/etc/shadow')}` would copy any file the user can read
    into the URDF, and from there into robot_description."""
    absolute, include_files = xacro.abs_filename_spec, xacro.get_include_files

    def inside(filename: str) -> str:
        real, plain = os.path.realpath(filename), os.path.abspath(filename)
        if not (any(_under(real, root) for root in roots + [os.path.realpath(p) for p in packages])
                or any(_under(plain, package) for package in packages)):
            raise xacro.XacroException(f'{filename} is outside the robot file\'s folder ({roots[0]}) and the '
                                       f'packages found with $(find): a robot file reads only those')
        return filename

    def confined_includes(filename_spec, symbols):
        for filename in include_files(filename_spec, symbols):
            yield inside(filename)
    xacro.abs_filename_spec = lambda filename_spec: inside(absolute(filename_spec))
    xacro.get_include_files = confined_includes


def _expand(path: str, text: str, mappings: dict[str, str] | None) -> str:
    try:
        import xacro
        from xacro import substitution_args
    except ImportError:
        raise XacroError(f'{path} is xacro, and the xacro library is not installed (pip install xacro)') from None
    roots = [os.path.dirname(os.path.realpath(path))]
    packages = []

    def find(pkg: str) -> str:                     # $(find pkg): ROS 1's meaning; its folder may be read
        found = _find_ros1(pkg)
        packages.append(os.path.abspath(found))
        return found
    substitution_args._eval_find = find
    _harden(xacro, substitution_args)
    _confine(xacro, roots, packages)
    try:
        doc = xacro.process_file(os.path.abspath(path), mappings=dict(mappings or {}))
    except Exception as e:       # XacroException, SubstitutionException, XML errors, whatever a file does
        where = xacro.filestack[-1] if getattr(xacro, 'filestack', None) else path
        inner = getattr(e, 'exc', None)     # xacro wraps the cause, and its str() repeats it
        if isinstance(inner, MemoryError) or isinstance(e, MemoryError):
            cause = (f'the expansion needed more than {EXPAND_MEMORY // 1024 ** 3} GiB of memory and was stopped '
                     f'({_one_line(e)[:200]})')
        elif isinstance(inner, substitution_args.ArgException) or isinstance(e, substitution_args.ArgException):
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
    if argv == [CHILD_FLAG]:
        return _child_main()
    if not argv or argv[0] in ('-h', '--help'):
        print(__doc__.strip().splitlines()[-1].strip())
        return 0 if argv else 2
    try:
        urdf = expand(argv[0], parse_mappings(argv[1:]))
    except XacroError as e:
        print(f'xacro: {e}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:         # a Ctrl-C: the expanding child ended with it (expand's finally)
        print('interrupted', file=sys.stderr)
        return 130
    sys.stdout.write(urdf)
    return 0


if __name__ == '__main__':
    sys.exit(main())
