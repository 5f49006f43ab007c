"""sliders: joint_state_publisher_gui as Debian 12 ships it (1.15.1), with the upstream fix for Python 3.10+.

Debian 12's joint_state_publisher_gui passes floats to QSlider.setValue, which PyQt5 on Python 3.10 and newer
refuses (``TypeError: setValue(self, a0: int): argument 1 has unexpected type 'float'``), so its window never
opens. Upstream later rounded those values to int; this node gives the module a QSlider that does the same,
then starts the GUI exactly as its own script does. Its ROS interface is joint_state_publisher_gui's.
"""
import signal
import sys
import threading

import rospy

from robot_ai.nodes.params import quiet_on_shutdown


def patched_gui_module():
    """joint_state_publisher_gui, whose sliders take the float positions it computes, rounded."""
    import joint_state_publisher_gui
    from python_qt_binding.QtWidgets import QSlider

    class IntSlider(QSlider):
        def setValue(self, value):
            super(IntSlider, self).setValue(int(round(value)))

    joint_state_publisher_gui.QSlider = IntSlider
    return joint_state_publisher_gui


def beside_rviz(app, gui) -> None:
    """The sliders at the screen's right edge: rviz_view makes rviz's window narrower when sliders run
    (rviz_view.WIDTH_BESIDE_SLIDERS), so that on a 1024-pixel screen (Xvfb's) the two stand side by side; without a
    window manager the window mapped last, rviz's, would otherwise hide them."""
    screen = app.primaryScreen().availableGeometry()
    gui.move(max(screen.left(), screen.right() + 1 - gui.frameGeometry().width()), screen.top())


@quiet_on_shutdown
def main():
    import joint_state_publisher
    from python_qt_binding.QtCore import QTimer
    from python_qt_binding.QtWidgets import QApplication
    gui_module = patched_gui_module()
    try:
        rospy.init_node('joint_state_publisher_gui')
        app = QApplication(sys.argv)
        app.setApplicationDisplayName('Joint State Publisher')
        num_rows = joint_state_publisher.get_param('num_rows', 0)
        gui = gui_module.JointStatePublisherGui('Node: ' + rospy.get_name(),
                                                joint_state_publisher.JointStatePublisher(), num_rows)
        gui.show()
        beside_rviz(app, gui)
        gui.sliderUpdateTrigger.emit()
        threading.Thread(target=gui.jsp.loop, daemon=True).start()
        # Ctrl-C (roslaunch's SIGINT) and SIGTERM close the window and shut rospy down, which unregisters the node
        # from the master: killed by the default SIGINT, it stayed in `rosnode list` on a master that stays up.
        # Qt's event loop runs no Python code by itself: a timer lets the interpreter run the handler.
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: app.quit())
        timer = QTimer()
        timer.timeout.connect(lambda: None)
        timer.start(200)
        status = app.exec_()
        rospy.signal_shutdown('the sliders window closed')
        sys.exit(status)
    except rospy.ROSInterruptException:
        pass
