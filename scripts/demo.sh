#!/usr/bin/env bash
# README command 1: set up from scratch (idempotent) and run the closed-loop demo.
# `--calibration` runs the calibration demo instead (docs/ekf_calibrate.md): a miscalibrated
# simulated robot's calibration drive, ekf_calibrate, and the replay before and after.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
# shellcheck source=/dev/null
. "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
if [[ "${1:-}" == "--calibration" ]]; then
  shift
  exec python -m ekf_localization.tools.calibration_demo "$@"
fi
exec ekf_demo "$@"
