"""Private parameters read once at start: a value of the wrong kind falls back to the default with one warning
that names the parameter and says what is allowed, never a traceback."""
import math

import rospy


def number_param(name, default, allowed, valid):
    """A numeric private parameter; a value that is not `allowed` falls back to the default with one warning."""
    value = rospy.get_param(name, default)
    try:
        number = float(value)
        if isinstance(value, bool) or not math.isfinite(number) or not valid(number):
            raise ValueError
    except (TypeError, ValueError):
        rospy.logwarn('%s must be %s, got %r: using %r' % (name, allowed, value, default))
        return default
    return number


def bool_param(name, default):
    """A boolean private parameter: true/false (or 1/0); anything else falls back to the default with a warning."""
    value = rospy.get_param(name, default)
    if isinstance(value, bool):
        return value
    if value in (0, 1) or str(value).lower() in ('true', 'false'):
        return value in (1, True) or str(value).lower() == 'true'
    rospy.logwarn('%s must be true or false, got %r: using %r' % (name, value, default))
    return default


def int_param(name, default, allowed='a whole number of at least 1', valid=lambda v: v >= 1):
    """An integer private parameter (see number_param)."""
    value = number_param(name, default, allowed, lambda v: v == int(v) and valid(v))
    return int(value)


def str_param(name, default):
    """A text private parameter; anything else falls back to the default with a warning."""
    value = rospy.get_param(name, default)
    if isinstance(value, str):
        return value
    rospy.logwarn('%s must be text, got %r: using %r' % (name, value, default))
    return default
