#!/usr/bin/env bash
# arm_sim: the two commands of the README.
#   ./run.sh demo   -- set up the venv (if needed) and run the demo
#   ./run.sh test   -- set up the venv (if needed) and run ruff, mypy and the whole test suite
#   ./run.sh bench  -- set up, add Pinocchio and MuJoCo, run bench/bench_dynamics.py
#   ./run.sh setup  -- only set up
# Set-up is idempotent: it reinstalls only when constraints.txt, setup.py, setup.cfg or
# package.xml changed. The venv lives in .venv (override with ARM_SIM_VENV).
set -euo pipefail
cd "$(dirname "$0")"
VENV=${ARM_SIM_VENV:-.venv}
PYTHON=${PYTHON:-python3}

setup() {
  if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating $VENV with $($PYTHON --version)"
    "$PYTHON" -m venv "$VENV"
  fi
  local stamp want
  stamp="$VENV/.arm_sim-setup"
  want=$(cat constraints.txt setup.py setup.cfg package.xml | sha256sum | cut -d' ' -f1)
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "[setup] installing ROS 2 Jazzy wheels, numpy, scipy, mcap and test tools (pinned)"
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
      -c constraints.txt -e '.[ros,core,test]' 2>&1 | grep -v '^WARNING: Location' || true
    "$VENV/bin/python" -c 'import rclpy, numpy, scipy, mcap' \
      || { echo "[setup] failed: the venv cannot import rclpy/numpy/scipy/mcap" >&2; exit 1; }
    echo "$want" > "$stamp"
  fi
  # control_msgs and tf2_msgs: no wheel ships them; build them into the venv from the
  # ROS 2 Jazzy definitions in interfaces/ (docs/interfaces.md). About a minute the first
  # time; a no-op (0.2 s) when up to date or when a real ROS 2 install provides them.
  # (A pip-installed arm_sim runs the same script with `arm-sim interfaces`.)
  "$VENV/bin/python" interfaces/build_interfaces.py \
    || { echo "[setup] failed: building control_msgs/tf2_msgs (interfaces/)" >&2; exit 1; }
}

cmd=${1:-demo}
shift || true
case "$cmd" in
  setup) setup ;;
  demo)
    setup
    exec "$VENV/bin/arm-sim" demo "$@" ;;
  test)
    setup
    echo "[test] ruff"
    "$VENV/bin/ruff" check .
    echo "[test] mypy"
    "$VENV/bin/mypy"
    echo "[test] pytest"
    status=0
    "$VENV/bin/python" -m pytest "$@" || status=$?
    # Fast DDS leaves shared-memory files of processes that died (SIGKILL tests, and the
    # test process's own port segments once it exits); remove them.
    "$VENV/bin/fastdds" shm clean > /dev/null 2>&1 || true
    exit $status ;;
  bench)
    setup
    if ! "$VENV/bin/python" -c 'import pinocchio, mujoco' 2>/dev/null; then
      echo "[setup] installing the bench extra (Pinocchio, MuJoCo), pinned"
      "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
        -c constraints.txt -e '.[bench]' 2>&1 | grep -v '^WARNING: Location' || true
    fi
    exec "$VENV/bin/python" bench/bench_dynamics.py "$@" ;;
  *) echo "usage: ./run.sh demo|test|bench|setup [args]" >&2; exit 2 ;;
esac
