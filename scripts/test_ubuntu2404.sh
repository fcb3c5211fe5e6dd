#!/usr/bin/env bash
# The test command on Ubuntu 24.04's library versions (constraints/ubuntu-24.04.txt: numpy 1.26.4,
# scipy 1.11.4, matplotlib 3.6.3, PyYAML 6.0.1, aiohttp 3.9.1) instead of requirements.txt's
# pins: builds a venv of its own, .venv-2404 (first run: a minute or two), then runs
# scripts/test.sh there (lint + the fast unit and integration suite on two workers; arguments
# are passed on, e.g. `-m slow`). .ci/run runs it as its second leg.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export EKF_VENV="${EKF_VENV_2404:-$ROOT/.venv-2404}"
export EKF_CONSTRAINTS="$ROOT/constraints/ubuntu-24.04.txt"
echo "=== Ubuntu 24.04's library versions ($EKF_CONSTRAINTS) in $EKF_VENV ==="
bash "$ROOT/scripts/setup_env.sh"
"$EKF_VENV/bin/python" - "$EKF_CONSTRAINTS" <<'PYEOF'
import sys
from importlib.metadata import version

want = dict(line.split("#", 1)[0].strip().split("==") for line in open(sys.argv[1])
            if line.split("#", 1)[0].strip())
got = {name: version(name) for name in want}
bad = {n: (want[n], got[n]) for n in want if got[n] != want[n]}
print("versions: " + ", ".join(f"{n} {v}" for n, v in got.items()))
sys.exit(f"not the constrained versions: {bad}" if bad else 0)
PYEOF
exec bash "$ROOT/scripts/test.sh" "$@"
