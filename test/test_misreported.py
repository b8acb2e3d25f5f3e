"""Misgraded and misreported (issue 35, item 5): a suite's simulator value the simulator
would refuse is a usage error when the suite is read (exit 2, not a failed scenario), and
``analyze`` of a killed bag it cannot recover in place (read-only storage) suggests the
recovery that works there (``arm-sim bag recover BAG --output DIR``)."""

from __future__ import annotations

import os
import re
import subprocess

import pytest

from arm_bag.bagfile import recover_hint
from arm_bag.cli import analyze_one, run_recover
from arm_bag.recover import recover_advice
from arm_sim.check.suite import SuiteFileError, parse_suite
from arm_sim.cli import main

LINE = {'name': 'noisy', 'start_tip': [0.5, 1.2],
        'goals': [{'tip': [1.4, 0.2], 'mode': 'straight_line', 'duration': 0.8}],
        'thresholds': {'line_deviation': 0.01}}


# ------------------------------------------------------------ (a) the suite's simulator values
def test_a_simulator_value_only_the_simulator_refuses_is_a_usage_error_exit_2(tmp_path, capsys):
    """``position_noise: -1`` passes the suite's own checks (a known key) but the simulator
    refuses it at start-up: it was a failed scenario (exit 1) after starting the nodes;
    now one line naming the scenario, the key and the value, exit 2, before anything."""
    bad = tmp_path / 'bad.yaml'
    bad.write_text('scenarios:\n'
                   '  - name: noisy\n'
                   '    goals: [{tip: [1.0, 1.0]}]\n'
                   '    thresholds: {final_tip_error: 0.003}\n'
                   '    simulator: {position_noise: -1}\n')
    assert main(['check', '--suite', str(bad), '--', 'true']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1, err
    assert err.startswith(f'arm-sim check: {bad}: scenarios[0] (noisy): '
                          'simulator.position_noise: -1 refused by the simulator: '), err


@pytest.mark.parametrize('simulator, words', [
    ({'position_noise': [-1e-3, 0.0]}, 'position_noise must be >= 0 rad, got -0.001'),
    ({'position_noise': [1e-3]}, 'position_noise has 1 values but the robot has 2 joints'),
    ({'velocity_noise': [0.0, 2000.0]}, 'velocity_noise must be <= 1000 rad/s'),
    ({'encoder_resolution': [100.5, 4096]}, 'encoder_resolution must be whole counts'),
    ({'sensing_delay': 0.5}, 'sensing_delay must be an integer, got 0.5'),
    ({'actuation_delay': -1}, 'actuation_delay must be >= 0 periods, got -1'),
    ({'noise_seed': 'seven'}, 'noise_seed must be a number'),
])
def test_each_simulator_key_is_checked_against_the_simulators_own_spec(simulator, words):
    (key, value), = simulator.items()
    with pytest.raises(SuiteFileError) as err:
        parse_suite({'scenarios': [{**LINE, 'simulator': simulator}]}, 'my.yaml')
    text = str(err.value)
    assert text.startswith(f'my.yaml: scenarios[0] (noisy): simulator.{key}: {value!r}'), text
    assert words in text, text


def test_values_the_simulator_takes_are_kept_as_written():
    sim = {'position_noise': [4e-4, 4e-4], 'encoder_resolution': [16384, 16384],
           'sensing_delay': 1, 'actuation_delay': 0, 'noise_seed': 1}
    suite = parse_suite({'scenarios': [{**LINE, 'simulator': sim}]}, 'ok.yaml')
    assert suite.scenarios[0].simulator == sim


# ------------------------------------------------------------ (c) recovering read-only bags
def test_the_recovery_suggested_is_in_place_only_where_it_can_write(tmp_path):
    bag = tmp_path / 'run'
    bag.mkdir()
    assert recover_advice(bag, writable=True) == recover_hint(bag)
    ro = recover_advice(bag, writable=False)
    assert f'`arm-sim bag recover {bag} --output DIR`' in ro and 'cannot be written' in ro
    assert recover_hint(bag) not in ro
    mcap = bag / 'run_0.mcap'
    assert f'{bag} cannot be written' in recover_advice(mcap, writable=False)
    assert recover_advice(bag) == recover_hint(bag)  # tmp_path is writable


@pytest.fixture
def read_only_view(tmp_path):
    """``(source, view)``: a directory and a read-only bind mount of it (as root, chmod
    does not stop writes; a read-only mount does). Skipped where mounting is not allowed."""
    source, view = tmp_path / 'source', tmp_path / 'view'
    source.mkdir()
    view.mkdir()
    done = subprocess.run(['mount', '--bind', '-o', 'ro', str(source), str(view)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f'cannot make a read-only bind mount here: {done.stderr.strip()}')
    try:
        subprocess.run(['mount', '-o', 'remount,ro,bind', str(view)], check=True,
                       capture_output=True)
        if os.access(view, os.W_OK):
            pytest.skip('the bind mount is not read-only')
        yield source, view
    finally:
        subprocess.run(['umount', str(view)], capture_output=True)


def test_analyze_of_a_killed_bag_on_read_only_storage_suggests_recover_to_another_dir(
        read_only_view, tmp_path, capsys):
    """The bag a SIGKILLed recorder left, seen through a read-only mount: analyze cannot
    recover it in place (EROFS); its one line suggests ``--output DIR``, not the in-place
    recovery, and that suggestion works (a complete bag in DIR)."""
    import argparse

    from test_bag_robustness import killed_bag

    source, view = read_only_view
    flushed = killed_bag(source / 'run')
    bag = str(view / 'run')
    kind, message = analyze_one(bag)
    assert kind == 'unreadable'
    assert 'automatic recovery failed' in str(message), message
    assert recover_hint(bag) not in str(message), message
    assert f'`arm-sim bag recover {bag} --output DIR`' in str(message), message

    out = tmp_path / 'recovered'
    assert run_recover(argparse.Namespace(bag=bag, output=str(out))) == 0
    kept = re.search(r'kept (\d+) messages', capsys.readouterr().out)
    assert kept and int(kept.group(1)) == flushed, kept
    kind, report = analyze_one(str(out))
    assert kind == 'ok', report


def test_bag_recover_in_place_on_read_only_storage_says_use_output(read_only_view, capsys):
    import argparse

    from test_bag_robustness import killed_bag

    source, view = read_only_view
    killed_bag(source / 'run')
    bag = str(view / 'run')
    assert run_recover(argparse.Namespace(bag=bag, output=None)) == 4
    err = capsys.readouterr().err
    assert err.count('\n') == 1, err
    assert f'`arm-sim bag recover {bag} --output DIR`' in err, err
