"""Pictures of an arm reaching, drawn from its kinematics alone (no meshes, no physics engine). No rospy.

    renderer = ArmRenderer(arm, distance_threshold=0.05)
    frame = renderer.draw(q, goal)       # (480, 640, 3) uint8: the robot's links as a skeleton, the arm's chain
                                         # thick, the tip's path this episode, the goal and its 0.05 m sphere

The view is fixed for a robot (a cube around where its tip can go and the robot at home), so that a video does
not jump.
"""
from __future__ import annotations

import numpy as np

from robot_ai.reach.arm import Arm
from robot_ai.reach.task import goal_distance

WIDTH, HEIGHT, DPI = 640, 480, 100


class ArmRenderer:
    """Frames of one arm (see the module's docstring); new_episode() clears the tip's path."""

    def __init__(self, arm: Arm, distance_threshold: float = 0.05, title: str = ''):
        import matplotlib
        matplotlib.use('Agg')
        from matplotlib.figure import Figure
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        self.arm = arm
        self.threshold = distance_threshold
        self.title = title or f'{arm.tree.name or "robot"}: {arm.base} to {arm.tip}'
        tree = arm.tree
        poses = tree.link_poses(base=arm.base)
        self.bones = [(tree.joints[n].parent, tree.joints[n].child) for n in tree.joint_order
                      if tree.joints[n].parent in poses]
        self.chain_links = [arm.base] + [tree.joints[n].child for n in arm.chain]
        self.fig = Figure(figsize=(WIDTH / DPI, HEIGHT / DPI), dpi=DPI)
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_subplot(projection='3d')
        self.fig.subplots_adjust(left=0.0, right=0.97, bottom=0.03, top=0.9)
        self.path: list[np.ndarray] = []
        # the view: where the tip can go (sampled) and the robot at home, in a cube, so that a video does not jump
        rng = np.random.default_rng(0)
        points = np.concatenate((arm.tip_positions(rng.uniform(arm.lower, arm.upper, (500, arm.n))),
                                 [pose[:3, 3] for pose in poses.values()], np.zeros((1, 3))))
        low, high = points.min(axis=0), points.max(axis=0)
        self.centre, self.half = (low + high) / 2, max(float((high - low).max()) / 2 * 1.1, 1e-3)
        sphere_u, sphere_v = np.mgrid[0:2 * np.pi:16j, 0:np.pi:9j]
        self._sphere = np.stack((np.cos(sphere_u) * np.sin(sphere_v), np.sin(sphere_u) * np.sin(sphere_v),
                                 np.cos(sphere_v)))

    def new_episode(self) -> None:
        self.path = []

    def draw(self, q, goal) -> np.ndarray:
        """An RGB frame (HEIGHT, WIDTH, 3) of the arm at q (n,) with the goal (3,) (None: no goal yet)."""
        arm, ax = self.arm, self.ax
        poses = arm.tree.link_poses(arm.tree.resolve_positions(arm.positions(q)), base=arm.base)
        tip = poses[arm.tip][:3, 3]
        self.path.append(tip)
        ax.cla()
        for parent, child in self.bones:
            a, b = poses[parent][:3, 3], poses[child][:3, 3]
            ax.plot(*np.column_stack((a, b)), color='0.6', lw=1.5)
        ax.scatter(0, 0, 0, color='black', marker='s', s=40, depthshade=False, label=f'base ({self.arm.base})')
        chain = np.array([poses[link][:3, 3] for link in self.chain_links])
        ax.plot(chain[:, 0], chain[:, 1], chain[:, 2], '-o', color='tab:blue', lw=4, ms=4)
        path = np.array(self.path)
        ax.plot(path[:, 0], path[:, 1], path[:, 2], color='tab:orange', lw=1)
        ax.scatter(*tip, color='tab:red', s=40, depthshade=False, label='tip')
        text = f'{self.title}'
        if goal is not None:
            ax.scatter(*goal, color='tab:green', s=80, depthshade=False, label='goal')
            s = self._sphere * self.threshold
            ax.plot_wireframe(s[0] + goal[0], s[1] + goal[1], s[2] + goal[2], color='tab:green', lw=0.4, alpha=0.5)
            d = float(goal_distance(tip, goal))
            text += f'\ndistance {d:.3f} m' + ('  reached' if d < self.threshold else '')
        c, r = self.centre, self.half
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
        ax.set_box_aspect((1, 1, 1), zoom=1.05)
        ax.set_xlabel('x (m)')
        ax.set_ylabel('y (m)')
        ax.set_zlabel('z (m)')
        ax.set_title(text, fontsize=10)
        ax.legend(loc='upper left', fontsize=8, frameon=False)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()

    def close(self) -> None:
        self.fig.clear()
