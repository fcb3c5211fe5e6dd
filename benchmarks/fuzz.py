"""Property-based fuzzing at scale: >= 10 000 hypothesis cases, prints the count and the failures.

The properties are test/helpers/fuzz_cases.py's (the suite runs them with a small budget in
test/test_fuzz.py): Localizer sequences of good, invalid and absurd data, stamps, resets,
set_pose and clock jumps (finite outputs, symmetric PSD covariance, increasing stamps,
back near the truth after 3 s of good data); message conversions on any field values;
the three nodes' parameter parsers on any values.

    python benchmarks/fuzz.py [--sequences 100] [--quick-sequences 0] [--messages 5000]
                              [--parameters 5000] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from helpers.fuzz_cases import (  # noqa: E402
    MESSAGE_CASES,
    PARAMETER_CASES,
    SEQUENCES,
    check_message,
    check_parameters,
    check_quick_sequence,
    check_sequence,
)
from hypothesis import HealthCheck, given, seed, settings  # noqa: E402


def run_property(name: str, strategy, check, cases: int, rng_seed: int) -> tuple[int, list[str]]:
    """Run ``check`` on ``cases`` generated examples; (cases run, failure descriptions)."""
    count = [0]
    failures: list[str] = []

    @seed(rng_seed)
    @settings(max_examples=cases, deadline=None, database=None, derandomize=False,
              phases=("generate", "shrink"), report_multiple_bugs=False,
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def prop(case) -> None:
        count[0] += 1
        check(case)

    t0 = time.perf_counter()
    try:
        prop()
    except Exception as exc:  # hypothesis re-raises the (shrunk) failing example
        failures.append(f"{name}: {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}")
    print(f"{name:12s} {count[0]:6d} cases  {len(failures)} failures  {time.perf_counter() - t0:7.1f} s",
          flush=True)
    return count[0], failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequences", type=int, default=100, help="Localizer sequences (about 1 s each)")
    parser.add_argument("--quick-sequences", type=int, default=0,
                        help="Localizer sequences without the 3 s return to the truth")
    parser.add_argument("--messages", type=int, default=5000)
    parser.add_argument("--parameters", type=int, default=5000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    total, failures = 0, []
    for name, strategy, check, n in (("sequences", SEQUENCES, check_sequence, args.sequences),
                                     ("quick", SEQUENCES, check_quick_sequence, args.quick_sequences),
                                     ("messages", MESSAGE_CASES, check_message, args.messages),
                                     ("parameters", PARAMETER_CASES, check_parameters, args.parameters)):
        if n <= 0:
            continue
        count, fails = run_property(name, strategy, check, n, args.seed)
        total += count
        failures += fails
    print(f"fuzz: {total} cases, {len(failures)} failures")
    for f in failures:
        print(f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
