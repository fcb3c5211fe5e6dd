#!/usr/bin/env bash
# README command 2: set up from scratch (idempotent) and run lint + the whole test suite.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
# shellcheck source=/dev/null
. "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
ruff check .
exec python -m pytest "$@"
