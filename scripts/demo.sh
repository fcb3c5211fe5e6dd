#!/usr/bin/env bash
# README command 1: set up from scratch (idempotent) and run the closed-loop demo.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
# shellcheck source=/dev/null
. "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
exec ekf_demo "$@"
