"""Grade a forward-kinematics node against the reference, pose by pose. No rospy.

The grader (``nodes/check_fk.py``) drives a candidate node and the package's forward_kinematics with the same
joint states and hands the poses both tf trees give to a ``Grade``; this module chooses the configurations,
the frame both trees are compared in, and writes the report a student reads.

    configs = configurations(tree, 50, seed=0)                 # the zero pose, then random ones
    frame, note = comparison_frame(tree, candidate_frames)      # the root, or the first link below it both have
    grade = Grade(tree, frame, tolerance=1e-6)
    grade.add(k, reference_poses, candidate_poses)              # {link: 4x4 pose in `frame`} per configuration
    print('\\n'.join(grade.report())); grade.verdict()
"""
import math

import numpy as np

CONTINUOUS_TURNS = 3        # continuous joints are driven over +-3 turns
NO_LIMIT = math.pi          # revolute or prismatic joints without usable limits: +-pi


def joint_range(joint):
    """The (low, high) a configuration draws a joint's position from."""
    if joint.type == 'continuous':
        return -CONTINUOUS_TURNS * 2 * math.pi, CONTINUOUS_TURNS * 2 * math.pi
    low, high = joint.lower, joint.upper
    if low is None or high is None or not low < high:
        return -NO_LIMIT, NO_LIMIT
    return float(low), float(high)


def configurations(tree, count, seed=0):
    """count configurations of the driven joints (mimic joints are left to the nodes): the zero pose, then
    positions drawn uniformly within each joint's limits from numpy's default_rng(seed)."""
    rng = np.random.default_rng(seed)
    names = list(tree.active_joints)
    out = [{n: 0.0 for n in names}]
    for _ in range(count - 1):
        out.append({n: float(rng.uniform(*joint_range(tree.joints[n]))) for n in names})
    return out[:max(count, 1)]


def comparison_frame(tree, candidate_frames):
    """(the frame poses are compared in, a note for the report or '').

    The root if the candidate publishes it; else the first link below the root, in the URDF's order, that the
    candidate publishes (the course's skeleton hangs every link under a 'world' the URDF may not have)."""
    if tree.root in candidate_frames:
        return tree.root, ''
    for link in tree.links:
        if link in candidate_frames:
            return link, ('the candidate does not publish the root link %s: poses are compared relative to %s, '
                          'the first link below it that both trees have' % (tree.root, link))
    return None, 'the candidate publishes none of the robot\'s links'


def rotation_error(a, b):
    """The angle (rad) of the rotation between the rotation parts of two 4x4 poses."""
    d = a[:3, :3].T.dot(b[:3, :3])
    s = np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2.0
    return abs(math.atan2(s, (np.trace(d) - 1.0) / 2.0))


class Grade(object):
    """Worst errors per link over the configurations, and what the candidate never published."""

    def __init__(self, tree, frame, tolerance=1e-6, note=''):
        self.tree, self.frame, self.tolerance, self.note = tree, frame, tolerance, note
        self.links = [l for l in tree.links if l != frame]
        self.worst = {l: [0.0, 0.0, None, None] for l in self.links}   # position, rotation, at configuration
        self.missing, self.extra, self.problems = {}, set(), []   # missing: {link: configurations without it}
        self.configurations = 0

    def add(self, index, reference, candidate):
        """Poses {link: 4x4 in self.frame} of configuration index, as each node's tf tree gives them."""
        self.configurations += 1
        for link in self.links:
            if link not in reference:
                continue
            if link not in candidate:
                self.missing[link] = self.missing.get(link, 0) + 1
                continue
            want, got = reference[link], candidate[link]
            if not np.isfinite(got).all():
                self.problems.append('configuration %d: %s is not finite (NaN or inf)' % (index, link))
                continue
            position = float(np.linalg.norm(got[:3, 3] - want[:3, 3]))
            rotation = rotation_error(got, want)
            w = self.worst[link]
            if position > w[0]:
                w[0], w[2] = position, index
            if rotation > w[1]:
                w[1], w[3] = rotation, index

    def failing(self):
        """Links whose worst error is over the tolerance, in the URDF's order (parents first)."""
        return [l for l in self.links if max(self.worst[l][:2]) > self.tolerance]

    def verdict(self):
        """'PASS', or 'FAIL: <the first thing to fix>'."""
        if self.problems:
            return 'FAIL: %s' % self.problems[0]
        if self.frame is None:
            return 'FAIL: %s' % self.note
        if self.configurations == 0:
            return 'FAIL: no configuration could be compared'
        missing = [l for l in self.links if l in self.missing]
        if missing:
            never = [l for l in missing if self.missing[l] == self.configurations]
            if never:
                return 'FAIL: publish a transform for %s (%d link%s never published)' % (
                    never[0], len(never), 's' if len(never) > 1 else '')
            return 'FAIL: %s was not published in %d of %d configurations' % (
                missing[0], self.missing[missing[0]], self.configurations)
        failing = self.failing()
        if failing:
            link = failing[0]
            pos, rot, at_pos, at_rot = self.worst[link]
            joint = next((j for j in self.tree.joints.values() if j.child == link), None)
            what = ('rotation off by %.3g rad' % rot) if rot > self.tolerance else ('position off by %.3g m' % pos)
            where = 'FAIL: %s, %s in configuration %d' % (link, what, at_rot if rot > self.tolerance else at_pos)
            if joint is None:
                return where
            return '%s; check joint %s (%s%s, origin xyz %s rpy %s)' % (
                where, joint.name, joint.type, ', axis %s' % _vec(joint.axis) if joint.moving else '',
                _vec(joint.xyz), _vec(joint.rpy))
        return 'PASS'

    def report(self):
        """The lines a student reads: a table per link, the frames missing or extra, the verdict."""
        lines = []
        if self.note:
            lines.append('note: %s' % self.note)
        lines.append('%d configurations compared, poses relative to %s, tolerance %g' % (
            self.configurations, self.frame, self.tolerance))
        width = max([len(l) for l in self.links] + [4])
        lines.append('%-*s  %14s  %14s  %s' % (width, 'link', 'position (m)', 'rotation (rad)', 'worst at'))
        for link in self.links:
            pos, rot, at_pos, at_rot = self.worst[link]
            if self.missing.get(link) == self.configurations:
                lines.append('%-*s  %14s  %14s  %s' % (width, link, '-', '-', 'NEVER PUBLISHED'))
                continue
            if link in self.missing:
                lines.append('%-*s  %14s  %14s  %s' % (width, link, '-', '-', 'missing in %d configurations'
                                                       % self.missing[link]))
                continue
            wrong = max(pos, rot) > self.tolerance
            at = at_rot if rot > self.tolerance else at_pos
            lines.append('%-*s  %14.3g  %14.3g  %s' % (width, link, pos, rot,
                                                      'configuration %d  <- wrong' % at if wrong else '-'))
        if self.extra:
            lines.append('frames the URDF does not have (not graded): %s' % ', '.join(sorted(self.extra)))
        lines.extend(self.problems[1:6])
        lines.append(self.verdict())
        return lines


def _vec(v):
    return '(%s)' % ' '.join('%g' % float(x) for x in v)
