"""Words for what the package prints. No rospy.

    counted(1, 'step') == '1 step'; counted(3, 'episode') == '3 episodes'; percent(0.993) == '99.3 %'
"""


def counted(n: int, noun: str) -> str:
    """n and the noun, plural unless n is 1 ('1 step', '2 steps', '0 candidates')."""
    return f'{n} {noun}' if n == 1 else f'{n} {noun}s'


def percent(rate: float) -> str:
    """A rate (0 to 1) as every summary prints it: a percentage with one decimal ('99.3 %'), so that two rates side
    by side are never rounded into the same number (0.993 and 0.996 are 99.3 % and 99.6 %, not 0.99 and 1.00)."""
    return f'{100 * float(rate):.1f} %'
