"""Words for what the package prints. No rospy.

    counted(1, 'step') == '1 step'; counted(3, 'episode') == '3 episodes'
"""


def counted(n: int, noun: str) -> str:
    """n and the noun, plural unless n is 1 ('1 step', '2 steps', '0 candidates')."""
    return f'{n} {noun}' if n == 1 else f'{n} {noun}s'
