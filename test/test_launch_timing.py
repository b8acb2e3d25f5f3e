"""launch/arm.launch.py's ``timing_mode`` on real processes: the simulator (in ``composed``
or on its own) runs in the mode the launch argument names even though config/arm.yaml's
``/**/simulator`` section says otherwise, and in the file's mode when the argument is empty.

The command lines are the ones launch_ros (Jazzy) builds from what the launch file hands
``launch_ros.actions.Node``, taken through the stand-ins of test_launch_file.py, so this test
follows the file (PyPI has no launch_ros to run it with).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from conftest import statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from test_launch_file import CONFIG, load_launch_module, loop_nodes


def file_mode() -> str:
    """The timing_mode config/arm.yaml sets for the simulator."""
    return yaml.safe_load(CONFIG.read_text())['/**/simulator']['ros__parameters']['timing_mode']


def launch_ros_arguments(node, params_file, tmp_path: Path) -> list[str]:
    """The ROS arguments launch_ros gives the recorded Node, in its order: ``ros_arguments``
    first (when given), then the node name, each entry of ``parameters`` as a params file (a
    dict as a file keyed by the node's full name, or ``/**`` for a node left unnamed) or a
    ``-p`` rule (a ``Parameter``), remappings.
    The root namespace, as the launch file's default."""
    kw = node.kwargs
    name = kw.get('name')
    args = (['--ros-args', *kw['ros_arguments']] if kw.get('ros_arguments') is not None
            else []) + ['--ros-args']
    if name:
        args += ['-r', f'__node:={name}']
    for k, entry in enumerate(kw.get('parameters', [])):
        if entry is params_file:
            args += ['--params-file', str(CONFIG)]
            continue
        if type(entry).__name__ == 'Parameter':  # launch_ros: -p name:=<yaml.dump(value)>
            args += ['-p', f'{entry.args[0]}:={yaml.dump(entry.args[1])}']
            continue
        assert isinstance(entry, dict) and all(
            isinstance(v, (bool, int, float, str)) or (
                isinstance(v, list) and all(isinstance(x, str) for x in v))
            for v in entry.values()), entry
        path = tmp_path / f'launch_params_{k}.yaml'
        path.write_text(yaml.dump({f'/{name}' if name else '/**':
                                   {'ros__parameters': entry}}))
        args += ['--params-file', str(path)]
    for src, dst in kw.get('remappings', []):
        args += ['-r', f'{src}:={dst}']
    return args


@pytest.mark.parametrize('mode', ['lockstep', ''])
@pytest.mark.parametrize('composed', ['true', 'false'])
def test_the_simulator_runs_in_the_launch_arguments_timing_mode(ros, launch, tmp_path,
                                                                 composed, mode):
    expected = mode or file_mode()
    if mode:
        assert mode != file_mode(), 'the file must say otherwise for this to test anything'
    with pytest.MonkeyPatch.context() as mp:  # the stand-ins only while reading the file
        module = load_launch_module(mp)
        sim = loop_nodes(module, composed=composed, timing_mode=mode)[0]
        args = launch_ros_arguments(sim, module.params_file, tmp_path)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    proc = launch(sim.kwargs['executable'], extra_args=args)

    def reported() -> list[str]:  # (the first summaries may come before it is known)
        return [v['timing_mode'] for s in statuses(diags, '/simulator', 'summary')
                for v in [values(s)] if v.get('timing_mode')]

    ros.wait_for(reported, timeout=30, what='the simulator\'s summary on /diagnostics')
    assert set(reported()) == {expected}, proc.cmd
    # The start-up line says the same (logged before the first summary).
    ros.wait_for(lambda: ' mode: ' in proc.output(), what='the start-up line')
    assert f' in {expected} mode: ' in proc.output(), proc.output()
