"""robot_ai.grading.processes: a candidate's output drained into a bounded tail, and the exception a crash ended on,
which its verdict quotes (issue 56: a crash's line lacked the exception)."""
import os

from robot_ai.grading.processes import Output


def output_of(text: bytes) -> Output:
    read, write = os.pipe()
    os.write(write, text)
    os.close(write)
    with os.fdopen(read, 'rb') as stream:
        out = Output(stream, '')
        out.thread.join(10)
    return out


def test_a_crash_is_named_by_its_traceback_last_line():
    out = output_of(b'[INFO] starting\nTraceback (most recent call last):\n  File "fk.py", line 3, in <module>\n'
                    b'    joints.index("tool_mount")\nValueError: \'tool_mount\' is not in list\n'
                    b'[rospy.core] shutting down\n')
    assert out.exception() == "ValueError: 'tool_mount' is not in list"
    assert out.lines()[0] == 'its last output:'


def test_output_without_a_traceback_names_no_exception():
    assert output_of(b'KeyError is what I print\nbye\n').exception() == ''
    assert output_of(b'').exception() == ''
