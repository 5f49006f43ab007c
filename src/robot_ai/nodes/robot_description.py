"""robot_description for the nodes: searched up the namespaces, parsed, waited for while missing or invalid."""
import rospy

from robot_ai.kinematics import KinematicTree, URDFError


class MissingDescription(Exception):
    """No robot_description parameter where the node looks for it."""


def load_tree():
    """(KinematicTree, parameter key) of robot_description; raise MissingDescription or URDFError."""
    key = rospy.search_param('robot_description')
    if key is None:
        raise MissingDescription('no robot_description parameter in %s or above' % rospy.get_namespace())
    xml = rospy.get_param(key)
    if not isinstance(xml, str):
        raise URDFError('%s is not a URDF: it holds %s %r, not text' % (key, type(xml).__name__, xml))
    try:
        return KinematicTree.from_xml_string(xml), key
    except URDFError:
        raise
    except Exception as e:  # whatever the parser meets: one clear line, never a traceback
        raise URDFError('%s could not be read: %s: %s' % (key, type(e).__name__, e))


def wait_for_tree():
    """load_tree() until it succeeds, logging each distinct problem once; (None, None) at shutdown."""
    last_error = None
    while not rospy.is_shutdown():
        try:
            return load_tree()
        except (MissingDescription, URDFError) as e:
            if str(e) != last_error:
                rospy.logwarn('%s; waiting for a valid robot_description' % e)
                last_error = str(e)
            rospy.sleep(0.5)
    return None, None
