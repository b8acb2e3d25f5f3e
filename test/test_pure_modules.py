"""The maths stays ROS-free: importing any pure module must not load rclpy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PURE_PACKAGES = ('arm_dynamics', 'arm_control', 'arm_planner', 'arm_bag')
PURE_GLUE = ('arm_common.params', 'arm_sim.launcher', 'arm_common.throttle', 'arm_common.process',
             'arm_common.cluster', 'arm_common.stamps',
             'arm_sim.sweep', 'arm_sim.urdf_cli', 'arm_sim.draw', 'arm_sim.live',
             'arm_sim.markers', 'arm_sim.tf', 'arm_common.yamlfile')


def pure_modules() -> list[str]:
    """Every module of the pure packages except the thin node modules (``*_node.py``)."""
    mods = list(PURE_GLUE)
    for pkg in PURE_PACKAGES:
        for path in sorted((ROOT / pkg).glob('**/*.py')):
            if path.name.endswith('_node.py'):
                continue
            rel = path.relative_to(ROOT).with_suffix('')
            parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
            mods.append('.'.join(parts))
    return mods


def test_pure_modules_do_not_import_rclpy():
    mods = pure_modules()
    assert 'arm_dynamics.two_link' in mods and 'arm_dynamics.simulation' in mods
    code = ('import importlib, sys\n'
            f'for m in {mods!r}:\n'
            '    importlib.import_module(m)\n'
            '    if "rclpy" in sys.modules:\n'
            '        print(m); break\n')
    out = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '', f'{out.stdout.strip()} imports rclpy'


def test_the_check_notices_a_module_that_imports_rclpy():
    code = 'import sys, arm_common.node; print("rclpy" in sys.modules)'
    out = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.strip() == 'True', 'the detection itself works'
