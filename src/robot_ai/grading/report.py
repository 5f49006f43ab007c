"""What a check reports: the model it grades, its budget, a judge's result for its class run, the exit status, and
the results file rostest asks for. No rospy.

    xml, tree = read_model('robot.urdf.xacro', 'hand:=true')    # ValueError: one line
    status = exit_status(verdict_line, 'pass')
"""
import os

from robot_ai.grading import candidates
from robot_ai.kinematics import KinematicTree, URDFError

MAX_NAME = 120          # characters of a frame name kept for the report
BUDGET_BASE = 120.0            # seconds: the default --budget is this plus BUDGET_PER_CONFIGURATION per configuration
BUDGET_PER_CONFIGURATION = 3.0
RESULT_BYTES = 64 * 1024       # a judge's result (JSON) is at most this


def read_model(path: str, xacro_args: str = '') -> tuple[str, KinematicTree]:
    """(the URDF text, its tree); a xacro file expanded first (robot_ai.urdf_source, with xacro_args); ValueError
    with one line for anything that is not a URDF this can grade."""
    from robot_ai.urdf_source import XacroError, expand, parse_mappings
    try:
        xml = expand(path, parse_mappings(xacro_args.split()))
    except XacroError as e:
        message = str(e)
        raise ValueError('cannot read the model ' + message[len('cannot read '):] if message.startswith('cannot read ')
                         else message)
    xacro = (f'{path} looks like unexpanded xacro without the xacro namespace: expand it first (rosrun robot_ai '
             f'xacro {path} > robot.urdf) and grade the URDF')
    try:
        tree = KinematicTree.from_xml_string(xml)
    except URDFError as e:
        if '${' in xml or '<xacro:' in xml:     # ${half_pi} in an rpy, a macro call where a link should be
            raise ValueError(f'{xacro} ({e})')
        raise ValueError(f'cannot read the model {path}: {e}')
    except (Exception, RecursionError) as e:    # whatever a hostile file does to the parser: one line
        raise ValueError(f'cannot read the model {path}: {type(e).__name__}: {" ".join(str(e).split())[:300]}')
    # an expanded URDF may keep xacro calls and ${...} in blocks nobody reads (the PR2's, the course's KUKA), but
    # no definitions: with them, links inside macros would load as a robot of one link
    if any(d in xml for d in ('<xacro:macro', '<xacro:property', '<xacro:include', '<xacro:arg')):
        raise ValueError(f'{xacro}: it defines xacro macros or properties')
    return xml, tree


def graded_links(tree: KinematicTree) -> int:
    """How many links a grade of this robot compares (every link but the root, or the floating base's)."""
    from robot_ai.grading.fk import Grade, comparison_frame
    try:
        frame, _ = comparison_frame(tree, set(tree.links), set())
        return len(Grade(tree, frame).links)
    except Exception:       # a tree the grade cannot frame: every link but the root
        return len(tree.links) - 1


def nothing_graded(tree: KinematicTree, configurations: int) -> str:
    """The score line of a check that ended before any configuration was graded (a Python 2 file, a node that died
    or published nothing): none of the links a grade compares is right, as course staff's spreadsheets need it."""
    return f'score: 0/{graded_links(tree)} links, 0/{configurations} configurations'


def budget_of(a) -> float:
    """--budget, or its default for the run's configurations (0 given)."""
    return a.budget or BUDGET_BASE + BUDGET_PER_CONFIGURATION * a.configurations


def exit_status(verdict: str, expect: str) -> int:
    """0 when the verdict is the one expected (--expect pass: PASS; --expect fail: a FAIL), else 1."""
    return 0 if verdict.startswith('PASS') == (expect == 'pass') else 1


def result_of(lines: list[str], tree, status: int, seconds: float) -> dict:
    """What a judge hands its class run (JSON on --result-fd): the verdict line, the score, the first wrong link,
    the exit status; from this process's own report, never from text the candidate wrote."""
    r = candidates.Result.of('', '\n'.join(lines), seconds, tree.links)
    return dict(verdict=r.verdict, score=r.score, first_wrong_link=r.first_wrong_link, status=status,
                seconds=seconds, grade=r.grade)


def write_junit(path: str, candidate: str, lines: list, seconds: float, expect: str = 'pass') -> None:
    """The results file rostest asks a <test> node for: one test case, failed unless the verdict is the one
    expected (--expect: PASS, or with fail a FAIL)."""
    from xml.sax.saxutils import escape, quoteattr
    failed = exit_status(lines[-1], expect) != 0
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    message = lines[-1] if expect == 'pass' else f'expected a FAIL, got {lines[-1]}'
    failure = (f'    <failure message={quoteattr(message)}>{escape(chr(10).join(lines))}</failure>\n'
               if failed else '')
    with open(path, 'w') as f:
        f.write(f'<?xml version="1.0" encoding="utf-8"?>\n<testsuite name="check_fk" tests="1" errors="0" '
                f'failures="{int(failed)}" time="{seconds:.3f}">\n  <testcase classname="check_fk" '
                f'name={quoteattr(candidate)} time="{seconds:.3f}">\n{failure}  </testcase>\n</testsuite>\n')
