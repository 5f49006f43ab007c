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
        self._background = None
        self._artists()

    def _artists(self) -> None:
        """The axes, the legend and the view drawn once (the background); the moving parts as artists whose data
        each frame sets: a frame redraws only them (ax.cla() and a full draw made each frame cost 0.16 s, nine
        tenths of a video's time)."""
        from mpl_toolkits.mplot3d.art3d import Line3DCollection
        ax, c, r = self.ax, self.centre, self.half
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
        ax.set_box_aspect((1, 1, 1), zoom=1.05)
        ax.set_xlabel('x (m)')
        ax.set_ylabel('y (m)')
        ax.set_zlabel('z (m)')
        ax.set_autoscale_on(False)
        none = ([], [], [])
        self.bone_lines = Line3DCollection([], colors='0.6', linewidths=1.5)
        ax.add_collection3d(self.bone_lines, autolim=False)
        (self.chain_line,) = ax.plot(*none, '-o', color='tab:blue', lw=4, ms=4)
        (self.path_line,) = ax.plot(*none, color='tab:orange', lw=1)
        ax.plot([0], [0], [0], 's', color='black', ms=6, label=f'base ({self.arm.base})')
        (self.tip_dot,) = ax.plot(*none, 'o', color='tab:red', ms=6, label='tip')
        (self.goal_dot,) = ax.plot(*none, 'o', color='tab:green', ms=9, label='goal')
        self.sphere_lines = Line3DCollection([], colors='tab:green', linewidths=0.4, alpha=0.5)
        ax.add_collection3d(self.sphere_lines, autolim=False)
        self.title_text = self.fig.text(0.5, 0.985, self.title, ha='center', va='top', fontsize=10)
        ax.legend(loc='upper left', fontsize=8, frameon=False)
        self.moving = [self.bone_lines, self.chain_line, self.path_line, self.tip_dot, self.goal_dot,
                       self.sphere_lines, self.title_text]

    def new_episode(self) -> None:
        self.path = []

    def draw(self, q, goal) -> np.ndarray:
        """An RGB frame (HEIGHT, WIDTH, 3) of the arm at q (n,) with the goal (3,) (None: no goal yet)."""
        arm = self.arm
        poses = arm.tree.link_poses(arm.tree.resolve_positions(arm.positions(q)), base=arm.base)
        tip = poses[arm.tip][:3, 3]
        self.path.append(tip)
        if self._background is None:              # the view without the moving parts, once
            for artist in self.moving:
                artist.set_visible(False)
            self.canvas.draw()
            self._background = self.canvas.copy_from_bbox(self.fig.bbox)
            for artist in self.moving:
                artist.set_visible(True)
        self.bone_lines.set_segments([(poses[a][:3, 3], poses[b][:3, 3]) for a, b in self.bones])
        chain = np.array([poses[link][:3, 3] for link in self.chain_links])
        self.chain_line.set_data_3d(chain[:, 0], chain[:, 1], chain[:, 2])
        path = np.array(self.path)
        self.path_line.set_data_3d(path[:, 0], path[:, 1], path[:, 2])
        self.tip_dot.set_data_3d([tip[0]], [tip[1]], [tip[2]])
        text = self.title
        shown = [self.bone_lines, self.chain_line, self.path_line, self.tip_dot]
        if goal is not None:
            self.goal_dot.set_data_3d([goal[0]], [goal[1]], [goal[2]])
            s = self._sphere * self.threshold + np.asarray(goal, dtype=float)[:, None, None]
            rings = [np.column_stack((s[0][i], s[1][i], s[2][i])) for i in range(s.shape[1])]
            rings += [np.column_stack((s[0][:, j], s[1][:, j], s[2][:, j])) for j in range(s.shape[2])]
            self.sphere_lines.set_segments(rings)
            shown = shown[:1] + [self.sphere_lines] + shown[1:] + [self.goal_dot]
            d = float(goal_distance(tip, goal))
            text += f'\ndistance {d:.3f} m' + ('  reached' if d < self.threshold else '')
        self.title_text.set_text(text)
        self.canvas.restore_region(self._background)
        for artist in shown:
            if hasattr(artist, 'do_3d_projection'):
                artist.do_3d_projection()
            self.ax.draw_artist(artist)
        self.fig.draw_artist(self.title_text)
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()

    def close(self) -> None:
        self.fig.clear()
