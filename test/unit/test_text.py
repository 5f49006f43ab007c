"""robot_ai.text: '1 step', not '1 steps' (issue 27); rates as percentages with one decimal, everywhere (issue 41)."""
import numpy as np

from robot_ai import ars, policies
from robot_ai.text import counted, percent


def test_counted_is_singular_for_one_only():
    assert [counted(n, 'step') for n in (0, 1, 2, 500)] == ['0 steps', '1 step', '2 steps', '500 steps']


def test_rates_side_by_side_are_never_rounded_into_one_number():
    assert [percent(r) for r in (0.993, 0.996, 1.0, 0.0, 0.9275)] == ['99.3 %', '99.6 %', '100.0 %', '0.0 %',
                                                                    '92.8 %']


def test_a_policys_description_shows_its_rates_as_percentages(tmp_path):
    """`success_rate 0.99 ... p_controller_success_rate 1.00` for 0.993 and 0.996 was the complaint."""
    actor = ars.LinearPolicy(np.ones((3, 15)), np.zeros(15), np.ones(15), np.zeros(3), -np.ones(3), np.ones(3))
    path = policies.save(str(tmp_path / 'r.npz'), actor, 'robot_ai/Reach-v0', 0,
                         figures=dict(success_rate=0.993, p_controller_success_rate=0.996, mean_final_distance=0.0123))
    line = policies.npz.load(path).describe()
    assert 'success_rate 99.3 %' in line and 'p_controller_success_rate 99.6 %' in line, line
    assert 'mean_final_distance 0.01' in line and '0.99' not in line, line
