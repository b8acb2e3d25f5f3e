"""One parameter truth: every entry point that takes the robot and node parameters refuses
a bad value with the same reason words, or accepts it, because they all validate through
the same code (arm_common.params.resolve).

Entry points: each node's start (a real process, given the value by ``-p`` and, as the
launch file gives it, in a params file), the composed executable, ``arm-sim urdf`` (``-p``
and ``--params-file``: the launch file makes robot_state_publisher's URDF this way),
:func:`arm_dynamics.robot.resolve_robot` and, for the settings it shares, the sweep; for the
simulator's initial state also a run-time change (``ros2 param set``).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from conftest import DOMAIN_ID
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from std_srvs.srv import Trigger

from arm_common.params import command_line_parameters
from arm_dynamics.robot import resolve_robot
from arm_sim.cli import main as arm_sim
from arm_sim.launcher import NodeProcess
from arm_sim.sweep.spec import check_setting

NODES = ('simulator', 'controller', 'planner', 'recorder', 'visualizer', 'composed')

# id: (-p rules, the reason's words every entry point must give; None: all accept)
ROBOT_CASES = {
    'an integer in a float array': (['link_lengths:=[1,0.8]'], None),
    'duplicate joint names': (['joint_names:=[a,a]'],
                              "joint_names must not repeat a value, got ('a', 'a')"),
    'a joint named as a frame': (['joint_names:=[tool0,b]'],
                                 'joint_names must not name a frame of the robot'),
    'a list of mixed types': (['joint_names:=[a,1]'], 'joint_names must be a string, got 1'),
    'not a list': (['link_lengths:=[1,0.8'], "link_lengths must be a list, got '[1,0.8'"),
    'a zero mass': (['link_masses:=[0,1.5]'], 'link_masses must be > 0 kg, got 0.0'),
    'a zero effort limit': (['effort_limits:=[0,20]'], 'effort_limits must be > 0 N m'),
    'limits out of order': (['position_limits_lower:=[1.0,0.0]',
                             'position_limits_upper:=[0.5,1.0]'],
                            'joint 1 position limits must satisfy lower < upper, got [1, '
                            '0.5] rad'),
    'one link for two': (['link_lengths:=[1.0]'],
                         'link_lengths has 1 values but model two_link has 2 links'),
}
#: Cases also given in a params file (the launch file's way) to every node.
FILE_CASES = ('an integer in a float array', 'duplicate joint names', 'a list of mixed types')


def ros_args(rules: list[str]) -> list[str]:
    return ['--ros-args', *[a for r in rules for a in ('-p', r)]]


def params_file(path: Path, rules: list[str]) -> Path:
    """The rules as a params file's /** section, each value in the words it was typed."""
    lines = ['/**:', '  ros__parameters:']
    lines += [f"    {name}: {text}" for name, text in (r.split(':=', 1) for r in rules)]
    path.write_text('\n'.join(lines) + '\n')
    return path


def refusal(proc: NodeProcess, name: str) -> str:
    """The one line a refused start prints (exit 2), or the failure (a node that started
    anyway is stopped)."""
    try:
        code = proc.proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.stop()
        pytest.fail(f'{name} started instead of refusing: {proc.output()[-1000:]}')
    lines = proc.output().strip().splitlines()
    assert code == 2, f'{name} exited {code}, expected a refusal (2): {lines}'
    assert len(lines) == 1 and lines[0].startswith(f'{name}: refused parameters: '), lines
    return lines[0]


def urdf_outcome(capsys, argv: list[str]) -> str | None:
    """``arm-sim urdf ...``: None if it printed a URDF, else its one refusal line."""
    code = arm_sim(['urdf', *argv])
    out, err = capsys.readouterr()
    if code == 0:
        assert out.startswith('<?xml') and not err
        return None
    assert code == 2 and len(err.strip().splitlines()) == 1 and not out, (code, err)
    return err.strip()


def pure_outcome(rules: list[str]) -> str | None:
    """resolve_robot on the rules' values (read as rcl reads them): None or the reason."""
    try:
        resolve_robot(command_line_parameters(ros_args(rules), 'urdf', '/urdf'))
    except ValueError as exc:
        return str(exc)
    return None


def start_all(tmp_path: Path, rules: list[str], file: Path | None = None,
              launcher=None) -> dict[str, NodeProcess]:
    """Every node executable started with the rules (``-p``) or the params file, at once
    (``launcher``: the test's, for starts that must stay up, each in its own namespace)."""
    procs = {}
    for name in NODES:
        kwargs: dict = dict(params_file=file) if file else dict(extra_args=ros_args(rules))
        if name == 'recorder':
            kwargs['params'] = {'output': str(tmp_path / f'bag-{len(procs)}-{bool(file)}')}
        if launcher is not None:
            procs[name] = launcher(name, namespace=f"/{'file' if file else 'dash_p'}",
                                   **kwargs)
        else:
            procs[name] = NodeProcess(name, domain_id=DOMAIN_ID,
                                      log_path=tmp_path / f'{name}-{bool(file)}.log', **kwargs)
    return procs


@pytest.mark.parametrize('case', [c for c, (_, words) in ROBOT_CASES.items() if words])
def test_a_bad_robot_value_is_refused_everywhere_in_the_same_words(case, tmp_path, capsys):
    rules, words = ROBOT_CASES[case]
    starts = {('-p', n): p for n, p in start_all(tmp_path, rules).items()}
    if case in FILE_CASES:
        file = params_file(tmp_path / 'robot.yaml', rules)
        starts.update({('file', n): p for n, p in start_all(tmp_path, rules, file).items()})
    else:
        file = None
    outcomes = {'resolve_robot': pure_outcome(rules),
                'arm-sim urdf -p': urdf_outcome(capsys, [a for r in rules for a in ('-p', r)])}
    if file is not None:
        outcomes['arm-sim urdf --params-file'] = urdf_outcome(capsys, ['--params-file',
                                                                       str(file)])
    if case == 'a zero effort limit':  # the sweep's own setting, the same check
        try:
            check_setting('effort_limits', [0, 20])
        except ValueError as exc:
            outcomes['sweep'] = str(exc)
        else:
            outcomes['sweep'] = None
    try:
        for (source, name), proc in starts.items():
            outcomes[f'{name} ({source})'] = refusal(proc, name)
    finally:
        for proc in starts.values():
            proc.stop()
    words_of = {'sweep': words.replace('effort_limits', 'effort_limits[0]')}
    missing = {k: v for k, v in outcomes.items()
               if v is None or words_of.get(k, words) not in v}
    assert not missing, f'{words!r} not in: {json.dumps(missing, indent=1)}'


def test_an_integer_in_a_float_array_is_accepted_everywhere_as_doubles(ros, launch,
                                                                       tmp_path, capsys):
    """``-p link_lengths:=[1,0.8]`` crashed rcl's start-up with a traceback (rcl refuses a
    list of mixed types) while ``arm-sim urdf`` took it; a params file's ``[1, 0.8]`` did
    the same. Now every node runs with it as the double array [1.0, 0.8]."""
    rules, _ = ROBOT_CASES['an integer in a float array']
    file = params_file(tmp_path / 'robot.yaml', rules)
    assert pure_outcome(rules) is None
    assert resolve_robot({'link_lengths': [1, 0.8]})['link_lengths'] == [1.0, 0.8]
    assert urdf_outcome(capsys, ['-p', rules[0]]) is None
    assert urdf_outcome(capsys, ['--params-file', str(file)]) is None
    started = {**{('/dash_p', n): p for n, p in start_all(tmp_path, rules,
                                                          launcher=launch).items()},
               **{('/file', n): p for n, p in start_all(tmp_path, rules, file,
                                                        launcher=launch).items()}}
    for (ns, name), proc in started.items():
        node = f'{ns}/simulator' if name == 'composed' else f'{ns}/{name}'
        client_name = f'{node}/get_parameters'
        try:
            reply = ros.call(GetParameters, client_name,
                             GetParameters.Request(names=['link_lengths']), timeout=60)
        except BaseException:
            pytest.fail(f'{name} ({ns}) did not come up:\n{proc.output()[-2000:]}')
        value = reply.values[0]
        assert value.type == ParameterType.PARAMETER_DOUBLE_ARRAY, (name, ns, value)
        assert parameter_value_to_python(value) == [1.0, 0.8], (name, ns)
        assert proc.alive() and 'Traceback' not in proc.output()


# ---------------------------------------------------------------------- the initial state
# (rule, the reason's words): an initial state outside the runaway envelope (positions
# beyond the limits + fault_position_margin, speeds beyond fault_velocity_factor x
# velocity_limits) or faster than velocity_limit: the first step, or a ~/reset, would be a
# fault at once.
INITIAL_CASES = {
    'too fast': ('initial_velocities:=[990.0,-990.0]',
                 'initial_velocities: joint 1 initial speed 990 rad/s > limit 16 rad/s, '
                 'beyond the runaway envelope'),
    'too far': ('initial_positions:=[9.0,0.0]',
                'initial_positions: joint 1 initial position 9 rad > upper limit 6.78319 '
                'rad, beyond the runaway envelope'),
}


@pytest.mark.parametrize('case', INITIAL_CASES)
def test_an_initial_state_beyond_the_runaway_envelope_is_refused_at_start(case, tmp_path):
    rule, words = INITIAL_CASES[case]
    for name in ('simulator', 'composed'):
        proc = NodeProcess(name, domain_id=DOMAIN_ID, log_path=tmp_path / f'{name}.log',
                           extra_args=ros_args([rule]))
        assert words in refusal(proc, name)


def test_the_divergence_limit_bounds_the_initial_speed_too(tmp_path):
    proc = NodeProcess('simulator', domain_id=DOMAIN_ID, log_path=tmp_path / 'sim.log',
                       extra_args=ros_args(['velocity_limit:=10.0',
                                            'initial_velocities:=[0.0,12.0]']))
    assert ('initial_velocities: joint 2 initial speed 12 rad/s > velocity_limit 10 rad/s'
            in refusal(proc, 'simulator'))


def test_an_initial_state_beyond_the_envelope_is_refused_at_run_time_in_the_same_words(
        ros, launch):
    """``ros2 param set /simulator initial_velocities "[990, -990]"`` was accepted, and the
    next ~/reset was an immediate runaway: refused now, with the reason the start gives,
    and the reset restores the state as it was."""
    launch('simulator', params={'timing_mode': 'lockstep'})
    for rule, words in INITIAL_CASES.values():
        name, text = rule.split(':=')
        result = ros.set_params('/simulator', **{name: json.loads(text)})[0]
        assert not result.successful and words in result.reason, result.reason
    within = ros.set_params('/simulator', initial_velocities=[10.0, 0.0])[0]
    assert within.successful, within.reason
    back = ros.set_params('/simulator', initial_velocities=[0.0, 0.0])[0]
    assert back.successful, back.reason
    reply = ros.call(Trigger, '/simulator/reset', Trigger.Request())
    assert reply.success and 'qd=[0.0, 0.0]' in reply.message, reply.message


def test_the_names_joints_may_not_take_are_those_of_the_urdf():
    from arm_dynamics.robot import urdf_names
    from arm_dynamics.urdf import BASE_FRAME, TIP_FRAME, link_frames, urdf_from_params

    for n in range(1, 6):
        assert urdf_names(n) == {BASE_FRAME, TIP_FRAME, 'tool0_joint', *link_frames(n)}
    text = urdf_from_params()
    assert all(f'"{name}"' in text for name in urdf_names(2))
