"""Grade a forward-kinematics node against the reference, pose by pose. No rospy.

The grader (``nodes/check_fk.py``) drives a candidate node with joint states and hands the poses its tf tree
gives, with the reference's (``KinematicTree.link_poses``, what forward_kinematics publishes), to a ``Grade``;
this module chooses the configurations, the frame the candidate is compared in, and writes the report a student
reads.

    configs = configurations(tree, 50, seed=0)                         # the zero pose, then random ones
    frame, note = comparison_frame(tree, candidate_frames, parentless)  # the root, or the frame standing for it
    grade = Grade(tree, frame, tolerance=1e-6, note=note)
    grade.add(k, configs[k], grade.reference_poses(configs[k]), candidate_poses)   # {link: 4x4 pose}
    print('\\n'.join(grade.report())); grade.verdict()
"""
import math

import numpy as np

CONTINUOUS_TURNS = 3        # continuous joints are driven over +-3 turns
NO_LIMIT = math.pi          # revolute or prismatic joints without usable limits: +-pi


def joint_range(joint) -> tuple[float, float]:
    """The (low, high) a configuration draws a joint's position from."""
    if joint.type == 'continuous':
        return -CONTINUOUS_TURNS * 2 * math.pi, CONTINUOUS_TURNS * 2 * math.pi
    low, high = joint.lower, joint.upper
    if low is None or high is None or not low < high:
        return -NO_LIMIT, NO_LIMIT
    return float(low), float(high)


def configurations(tree, count: int, seed: int = 0) -> list[dict]:
    """count configurations of the driven joints (mimic joints are left to the nodes): the zero pose, then
    positions drawn uniformly within each joint's limits from numpy's default_rng(seed)."""
    rng = np.random.default_rng(seed)
    names = list(tree.active_joints)
    out = [{n: 0.0 for n in names}]
    for _ in range(count - 1):
        out.append({n: float(rng.uniform(*joint_range(tree.joints[n]))) for n in names})
    return out[:max(count, 1)]


def comparison_frame(tree, candidate_frames, parentless=()) -> tuple[str | None, str]:
    """(the candidate's frame that poses are compared in, a note for the report or '').

    The root if the candidate publishes it. Else a frame of the candidate with no parent that the URDF does not
    have (the course's skeleton hangs every link under 'world' or 'world_link' and never publishes the root):
    it stands for the root. Else the first link below the root, in the URDF's order, that the candidate
    publishes."""
    base = tree.floating_base()
    if base is not None:      # a humanoid's pelvis, a mobile base: every link graded relative to it
        joint = next(n for n in tree.floating_joints if tree._floating_child[n] == base)
        if base not in candidate_frames:
            return None, (f'the candidate publishes no frame {base}: {base} is the child of the floating joint '
                          f'{joint}, which joint_states cannot drive, and every link below it is graded relative '
                          f'to it; publish the transforms below {base}')
        return base, (f'{joint} is a floating joint (joint_states cannot drive it): every link below it is graded '
                      f'relative to {base}, whether the candidate publishes {joint}\'s transform or not')
    if tree.root in candidate_frames:
        return tree.root, ''
    stand_ins = sorted(f for f in parentless if f not in tree.links)
    if len(stand_ins) == 1:
        return stand_ins[0], (f'the candidate does not publish the root link {tree.root}; its frame '
                              f'{stand_ins[0]}, which has no parent, stands for it')
    for link in tree.links:
        if link in candidate_frames:
            return link, (f'the candidate does not publish the root link {tree.root} and has no single parentless '
                          f'frame to stand for it: poses are compared relative to {link}, the first link below it '
                          'that both trees have')
    return None, 'the candidate publishes none of the robot\'s links'


def rotation_error(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (rad) of the rotation between the rotation parts of two 4x4 poses."""
    d = a[:3, :3].T.dot(b[:3, :3])
    s = np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2.0
    return abs(math.atan2(s, (np.trace(d) - 1.0) / 2.0))


class Grade:
    """Worst errors per link over the configurations, and what the candidate never published.

    frame: the candidate's frame poses are compared in: the root, a frame standing for it, or a link (then the
    reference poses are taken relative to that link too)."""

    def __init__(self, tree, frame: str | None, tolerance: float = 1e-6, note: str = ''):
        self.tree, self.frame, self.tolerance, self.note = tree, frame, tolerance, note
        self.base = frame if frame is not None and frame == tree.floating_base() else None
        reachable = set(self.reference_poses({}))               # links below a floating joint are not published
        # (unless they are graded relative to the floating joint's child, self.base)
        self.ungradable = [link for link in tree.links if link not in reachable
                           and not (self.base is not None and link == tree.root)]
        self.links = [link for link in tree.links if link in reachable and link not in (tree.root, frame)]
        if frame in tree.links and frame not in reachable:   # compared in a frame the reference cannot place
            self.links = []
        self.worst = {link: [0.0, 0.0, None, None] for link in self.links}  # position, rotation, at configuration
        self.missing, self.extra, self.problems = {}, set(), []   # missing: {link: configurations without it}
        self.configurations = 0
        self.configurations_right = 0   # every graded link published and within the tolerance
        self.poses_right = 0            # (link, configuration) pairs published, finite and within the tolerance
        self.asked = 0                  # configurations the check asks for (the grade's denominator); 0: those compared
        self.non_finite = set()         # links published with NaN or inf
        self.seen = {}          # configuration index -> (joint values, {link: (reference, candidate)} of wrong links)

    def reference_poses(self, positions: dict) -> dict:
        """The reference's {link: 4x4} for a configuration: from the root, or from the floating base."""
        return self.tree.link_poses(positions, base=self.base)

    def reference_in_frame(self, reference: dict) -> dict:
        """The reference poses (in the root frame, or the floating base's) relative to the frame the candidate is
        compared in."""
        if self.base is not None:
            return reference
        if self.frame in self.tree.links and self.frame != self.tree.root:
            if self.frame not in reference:
                return {}
            inverse = np.linalg.inv(reference[self.frame])
            return {link: inverse.dot(m) for link, m in reference.items()}
        return reference

    def add(self, index: int, positions: dict, reference: dict, candidate: dict) -> None:
        """Configuration index: its joint positions, the reference's poses {link: 4x4 in the root frame} and the
        candidate's {link: 4x4 in self.frame}."""
        self.configurations += 1
        reference = self.reference_in_frame(reference)
        wrong, complete = {}, True
        for link in self.links:
            if link not in candidate:
                self.missing[link] = self.missing.get(link, 0) + 1
                complete = False
                continue
            want, got = reference[link], candidate[link]
            if not np.isfinite(got).all():
                self.problems.append(f'configuration {index}: {link} is not finite (NaN or inf)')
                self.non_finite.add(link)
                complete = False
                continue
            position = float(np.linalg.norm(got[:3, 3] - want[:3, 3]))
            rotation = rotation_error(got, want)
            if max(position, rotation) > self.tolerance:
                wrong[link] = (want, got)
            else:
                self.poses_right += 1
            w = self.worst[link]
            if position > w[0]:
                w[0], w[2] = position, index
            if rotation > w[1]:
                w[1], w[3] = rotation, index
        if wrong:
            self.seen[index] = (dict(positions), wrong)
        elif complete:
            self.configurations_right += 1

    def failing(self) -> list[str]:
        """Links whose worst error is over the tolerance, in the URDF's order (parents first)."""
        return [link for link in self.links if max(self.worst[link][:2]) > self.tolerance]

    def _joint_of(self, link):
        return next((j for j in self.tree.joints.values() if j.child == link), None)

    def verdict(self) -> str:
        """'PASS', or 'FAIL: <the first thing to fix>' (the wrong or missing link closest to the root)."""
        if self.problems:
            return f'FAIL: {self.problems[0]}'
        if self.frame is None:
            return f'FAIL: {self.note}'
        if not self.links:      # never a PASS on links nobody compared
            return (f'FAIL: no link can be graded: {", ".join(self.ungradable[:10])} '
                    f'{"are" if len(self.ungradable) > 1 else "is"} below a floating joint')
        if self.configurations == 0:
            return 'FAIL: no configuration could be compared'
        bad = [link for link in self.links if link in self.missing or link in self.failing()]
        if not bad:
            return 'PASS'
        link = bad[0]
        joint = self._joint_of(link)
        mimic = (f'mimic of {joint.mimic[0]}, multiplier {joint.mimic[1]:g}'
                 + (f', offset {joint.mimic[2]:g}' if joint.mimic[2] else '') + ', '
                 if joint is not None and joint.mimic is not None else '')
        check = (f'; check joint {joint.name} ({mimic}{joint.type}'
                 f'{", axis " + _vec(joint.axis) if joint.moving else ""}, '
                 f'origin xyz {_vec(joint.xyz)} rpy {_vec(joint.rpy)})' if joint is not None else '')
        if link in self.missing:
            never = [m for m in self.links if self.missing.get(m) == self.configurations]
            if link in never:
                others = f' ({len(never)} links never published: {", ".join(never[:5])})' if len(never) > 1 else ''
                return f'FAIL: publish a transform for {link}{others}{check}'
            return f'FAIL: {link} was not published in {self.missing[link]} of {self.configurations} configurations'
        pos, rot, at_pos, at_rot = self.worst[link]
        what = f'rotation off by {rot:.3g} rad' if rot > self.tolerance else f'position off by {pos:.3g} m'
        at = at_rot if rot > self.tolerance else at_pos
        everywhere = ', wrong in every configuration, the zero pose included' if 0 in self.seen and all(
            link in wrong for _, wrong in self.seen.values()) and len(self.seen) == self.configurations else ''
        return f'FAIL: {link}, {what} in configuration {at}{everywhere}{check}'

    def worst_configuration_lines(self) -> list[str]:
        """The blamed link's worst configuration: every joint's value, the expected and the received pose, so that
        a student can reproduce it."""
        failing = self.failing()
        if not failing or self.problems:
            return []
        link = failing[0]
        pos, rot, at_pos, at_rot = self.worst[link]
        at = at_rot if rot > self.tolerance else at_pos
        positions, wrong = self.seen.get(at, ({}, {}))
        if link not in wrong:
            return []
        want, got = wrong[link]
        return ([f'configuration {at}: ' + ', '.join(f'{n} = {v:.6g}' for n, v in positions.items()),
                 f'  {link} expected xyz {_vec(want[:3, 3], 4)} rpy {_vec(_rpy(want), 4)}',
                 f'  {link} received xyz {_vec(got[:3, 3], 4)} rpy {_vec(_rpy(got), 4)}'])

    def report(self) -> list[str]:
        """The lines a student reads: a table per link, the frames missing or extra, the verdict."""
        lines = [f'note: {self.note}'] if self.note else []
        lines.append(f'{self.configurations} configurations compared, poses relative to {self.frame}, '
                     f'tolerance {self.tolerance:g}')
        width = max([len(link) for link in self.links] + [4])
        lines.append(f'{"link":<{width}}  {"position (m)":>14}  {"rotation (rad)":>14}  worst at')
        for link in self.links:
            pos, rot, at_pos, at_rot = self.worst[link]
            if self.missing.get(link) == self.configurations:
                lines.append(f'{link:<{width}}  {"-":>14}  {"-":>14}  NEVER PUBLISHED')
                continue
            if link in self.missing:
                lines.append(f'{link:<{width}}  {"-":>14}  {"-":>14}  missing in {self.missing[link]} configurations')
                continue
            wrong = max(pos, rot) > self.tolerance
            at = at_rot if rot > self.tolerance else at_pos
            lines.append(f'{link:<{width}}  {pos:14.3g}  {rot:14.3g}  '
                         + (f'configuration {at}  <- wrong' if wrong else '-'))
        if self.ungradable:
            where = (f'not below {self.base}, the floating joint\'s child' if self.base is not None else
                     'below a floating joint, which joint_states cannot drive')
            lines.append(f'not graded ({where}): {", ".join(self.ungradable[:10])}')
        if self.extra:
            shown = sorted(self.extra)[:10]
            lines.append(f'frames the URDF does not have (not graded): {", ".join(shown)}'
                         + (f' and {len(self.extra) - 10} more' if len(self.extra) > 10 else ''))
        lines.extend(self.worst_configuration_lines())
        lines.extend(self.problems[1:6])
        lines.append(self.score())
        lines.append(self.grade_line())
        lines.append(self.verdict())
        return lines

    def grade_line(self) -> str:
        """The grade, 0 to 100: the share of link poses right over the links graded and the configurations asked for
        (robot_ai.grading.gradebook.grade_of); one not compared (a check ended early) counts as wrong."""
        from robot_ai.grading.gradebook import grade_line
        return grade_line(self.poses_right, len(self.links), max(self.asked, self.configurations))

    def score(self) -> str:
        """One line for course staff: links right out of links graded, configurations right out of those compared
        (a configuration is right when every graded link was published and within the tolerance)."""
        right = [link for link in self.links if link not in self.missing and link not in self.non_finite
                 and max(self.worst[link][:2]) <= self.tolerance]
        return (f'score: {len(right)}/{len(self.links)} links, '
                f'{self.configurations_right}/{self.configurations} configurations')


def _rpy(m: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (URDF's fixed-axis x-y-z) of a 4x4 pose."""
    r = m[:3, :3]
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])


def _vec(v, digits: int = 6) -> str:
    return '(' + ' '.join(f'{float(x):.{digits}g}' for x in v) + ')'
