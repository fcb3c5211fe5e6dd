#!/usr/bin/env bash
# Idempotent project setup: creates .venv with the pinned ROS 2 Jazzy wheels and the
# package installed in editable mode. Re-running it is cheap when nothing changed.
# It calls no apt-get: the test command's extra system tools (a browser, iproute2) are
# scripts/setup_test_tools.sh's.
#
#   bash scripts/setup_env.sh [--venv DIR] [--constraints FILE]
#
# --venv DIR (or EKF_VENV): the venv to create or update (default: .venv in the checkout).
# --constraints FILE (or EKF_CONSTRAINTS): pip constraints over requirements.txt, e.g.
#   constraints/ubuntu-24.04.txt (Ubuntu 24.04's numpy, scipy, ...). A package the file names
#   loses its pin in requirements.txt (pip refuses two different == pins for one package), so the
#   constraint decides its version; every other pin stays.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${EKF_VENV:-$ROOT/.venv}"
CONSTRAINTS="${EKF_CONSTRAINTS:-}"
while [ $# -gt 0 ]; do
  case "$1" in
    --venv) VENV="$2"; shift 2 ;;
    --constraints) CONSTRAINTS="$2"; shift 2 ;;
    -h|--help) sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "setup_env: unknown argument '$1' (--venv DIR, --constraints FILE)" >&2; exit 2 ;;
  esac
done
case "$VENV" in /*) ;; *) VENV="$PWD/$VENV" ;; esac
if [ -n "$CONSTRAINTS" ]; then
  [ -f "$CONSTRAINTS" ] || { echo "setup_env: constraints file '$CONSTRAINTS' not found" >&2; exit 2; }
  CONSTRAINTS="$(cd "$(dirname "$CONSTRAINTS")" && pwd)/$(basename "$CONSTRAINTS")"
fi
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
# With constraints: requirements.txt less the pins of the packages the constraints file names.
REQS="$ROOT/requirements.txt"
if [ -n "$CONSTRAINTS" ]; then
  REQS="$VENV/requirements-constrained.txt"
  "$PY" - "$ROOT/requirements.txt" "$CONSTRAINTS" > "$REQS" <<'PYEOF'
import re, sys

def name(line):
    line = line.split("#", 1)[0].strip()
    return re.split(r"[\s\[<>=!~;]", line, maxsplit=1)[0].lower().replace("_", "-") if line else ""

with open(sys.argv[2]) as f:
    constrained = {name(line) for line in f} - {""}
with open(sys.argv[1]) as f:
    for line in f:
        n = name(line)
        print(n if n in constrained else line.rstrip("\n"))
PYEOF
fi
PINS="$(cat "$REQS" ${CONSTRAINTS:+"$CONSTRAINTS"})"
WANT="$( (echo "$PINS"; cat "$ROOT/setup.py"; cd "$ROOT" && ls -d ./*/__init__.py) | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$WANT" ]; then
  echo "setup_env: installing pinned dependencies (first run takes about a minute)"
  pipi() {  # pip install, quiet unless it fails
    local log; log="$(mktemp)"
    if ! "$VENV/bin/python" -m pip install --disable-pip-version-check "$@" >"$log" 2>&1; then
      grep -v "^WARNING: Location" "$log" >&2; rm -f "$log"; exit 1
    fi
    rm -f "$log"
  }
  pipi -r "$REQS" ${CONSTRAINTS:+-c "$CONSTRAINTS"}
  pipi --no-deps --no-build-isolation -e "$ROOT"
  "$VENV/bin/python" -c "import rclpy, nav_msgs.msg, rosbags, ntcore" \
    || { echo "setup_env: install incomplete" >&2; exit 1; }
  echo "$WANT" > "$STAMP"
fi

# tf2_msgs (TFMessage only, interfaces/tf2_msgs) built with the rosidl generators from PyPI,
# so /tf and /tf_static are real DDS topics here; rebuilt when its sources or the pins change.
TF2_STAMP="$VENV/.tf2_msgs_stamp"
TF2_SRC="$ROOT/interfaces/tf2_msgs"
TF2_WANT="$( (echo "$PINS"; cd "$TF2_SRC" && cat CMakeLists.txt package.xml msg/*.msg) \
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

# Byte-compile the package: with PYTHONDONTWRITEBYTECODE set (as here), Python never writes the
# .pyc files itself, and every start would compile ekf_node's modules from source (~0.1 s).
"$VENV/bin/python" -m compileall -q "$ROOT/ekf_localization" "$ROOT/sim_robot" "$ROOT/seed_experiments" >/dev/null \
  || echo "setup_env: package not byte-compiled (each start compiles its modules)" >&2
