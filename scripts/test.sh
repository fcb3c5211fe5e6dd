#!/usr/bin/env bash
# README command 2: set up from scratch (idempotent), then lint and the fast test suite on (at most)
# two workers (pytest-xdist; each test module on one worker, its module fixtures built once).
# The slow studies (marked `slow`) are a separate step: `bash scripts/test.sh -m slow -n 0` (.ci/run runs
# both); a later -m replaces the default, `-n 0` runs the tests one at a time in this process.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
bash "$ROOT/scripts/setup_test_tools.sh"  # chromium, iproute2 (apt-get as root; else those tests skip)
# shellcheck source=/dev/null
. "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
ruff check .
CORES="$(nproc 2>/dev/null || echo 1)"
WORKERS="$(( CORES < 2 ? CORES : 2 ))"
exec python -m pytest -n "$WORKERS" --dist loadscope -m "not slow" "$@"
