#!/usr/bin/env python3
"""A candidate for check_fk's tests that runs and never publishes a transform (never installed)."""
import rospy

if __name__ == '__main__':
    rospy.init_node('silent_fk')
    rospy.spin()
