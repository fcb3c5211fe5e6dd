"""Property-based fuzzing with a small, derandomized budget (benchmarks/fuzz.py runs >= 10 000 cases).

The properties and strategies are in helpers/fuzz_cases.py: the Localizer under random sequences of
good, invalid and absurd data, stamps, resets, set_pose and clock jumps; the message
conversions on any field values; the three nodes' parameter parsers on any values.
"""

from __future__ import annotations

from helpers.fuzz_cases import (
    MESSAGE_CASES,
    PARAMETER_CASES,
    SEQUENCES,
    check_message,
    check_parameters,
    check_sequence,
)
from hypothesis import HealthCheck, given, settings

FAST = settings(max_examples=15, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@FAST
@given(SEQUENCES)
def test_localizer_survives_any_sequence_and_recovers(ops) -> None:
    check_sequence(ops)


@settings(FAST, max_examples=100)
@given(MESSAGE_CASES)
def test_any_message_converts_and_is_fused_or_rejected_finitely(case) -> None:
    check_message(case)


@settings(FAST, max_examples=100)
@given(PARAMETER_CASES)
def test_any_parameter_values_give_a_config_or_a_parameter_error(case) -> None:
    check_parameters(case)
