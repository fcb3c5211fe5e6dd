"""Moved to :mod:`ekf_localization.core.units` (the one time module).

Kept only because ``tools/demo.py`` still imports ``stamp_to_ns`` from here; delete this file
with that import line. Nothing else may import it (``test/test_one_of_each.py``).
"""

from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns

__all__ = ["ns_to_sec_nanosec", "stamp_to_ns"]
