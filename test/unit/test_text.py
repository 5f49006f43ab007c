"""robot_ai.text: '1 step', not '1 steps' (issue 27)."""
from robot_ai.text import counted


def test_counted_is_singular_for_one_only():
    assert [counted(n, 'step') for n in (0, 1, 2, 500)] == ['0 steps', '1 step', '2 steps', '500 steps']
