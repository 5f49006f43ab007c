"""robot_description for the nodes: searched up the namespaces, parsed, waited for while missing or invalid."""
import rospy

from robot_ai.kinematics import KinematicTree, URDFError


class MissingDescription(Exception):
    """No robot_description parameter where the node looks for it."""


def load_tree(warn_meshes=False):
    """(KinematicTree, parameter key) of robot_description; raise MissingDescription or URDFError. warn_meshes:
    warn of mesh packages not found (forward_kinematics does, once per package: one line in a launch's output)."""
    key = rospy.search_param('robot_description')
    if key is None:
        raise MissingDescription('no robot_description parameter in %s or above' % rospy.get_namespace())
    xml = rospy.get_param(key)
    if not isinstance(xml, str):
        raise URDFError('%s is not a URDF: it holds %s %r, not text' % (key, type(xml).__name__, xml))
    try:
        tree = KinematicTree.from_xml_string(xml)
        if warn_meshes:
            warn_missing_meshes(key, xml)
        return tree, key
    except URDFError:
        raise
    except Exception as e:  # whatever the parser meets: one clear line, never a traceback
        raise URDFError('%s could not be read: %s: %s' % (key, type(e).__name__, e))


_warned = set()


def warn_missing_meshes(key, xml):
    """One warning per package:// package of the robot's meshes that ROS_PACKAGE_PATH does not hold (rviz then
    draws those links in red, and says why only inside its own window)."""
    from robot_ai.urdf_source import mesh_packages, missing_packages
    try:
        missing = missing_packages([p for p in mesh_packages(xml) if p not in _warned])
    except Exception:       # rospkg's own trouble: the meshes are rviz's business
        return
    for name in missing:
        _warned.add(name)
        rospy.logwarn('%s: its meshes come from package://%s/..., and the package %s is not found: rviz draws those '
                      'links in red; put %s on ROS_PACKAGE_PATH' % (key, name, name, name))


def wait_for_tree(warn_meshes=False):
    """load_tree() until it succeeds, logging each distinct problem once; (None, None) at shutdown."""
    last_error = None
    while not rospy.is_shutdown():
        try:
            return load_tree(warn_meshes)
        except (MissingDescription, URDFError) as e:
            if str(e) != last_error:
                rospy.logwarn('%s; waiting for a valid robot_description' % e)
                last_error = str(e)
            rospy.sleep(0.5)
    return None, None
