"""Grade this controller with arm_sim's pytest plugin (the fixture ``arm_check``).

Run from this directory with arm_sim installed (its venv, or a sourced workspace):
``pytest test/`` (about a minute). Each call starts a fresh simulator, planner, recorder
and reference stream around the controller on a private ROS domain.
"""

import sys
from pathlib import Path

CONTROLLER = [sys.executable, str(Path(__file__).resolve().parents[1] / 'arm_check_example'
                                  / 'controller.py')]


def test_the_lecture_suite_passes(arm_check):
    result = arm_check(CONTROLLER)
    assert result.passed, result.summary()


def test_the_fast_line_stays_within_5_mm(arm_check):
    line = arm_check(CONTROLLER, scenarios=['line_fast'])['line_fast']
    assert line.passed, line.failures()
    assert line.value('line_deviation') < 0.005  # m
    assert max(line.value('peak_torque')) < 55.0  # N m
