"""Grading students' forward-kinematics nodes, one or a class, each in a sandbox. No rospy: the judge of one candidate
is the check_fk node (robot_ai.nodes.check_fk), which this package starts, bounds and reads.

- ``fk``: the configurations a candidate is driven through, the comparison frame, errors, a grade's report.
- ``candidates``: students' files as they wrote them: which file is the node, how it starts, Python 2 verdicts.
- ``sandbox``: a candidate's sandbox (bubblewrap, unshare, setpriv, prlimit) and escaping what it prints.
- ``processes``: a check's roscore, the candidate's bounded output, and what it leaves behind ended.
- ``report``: the model graded, the budget, a judge's result, exit status and rostest's results file.
- ``class_run``: a class graded at once (--candidates DIR), or one candidate sandboxed (--sandbox).
"""
