"""Reproductions of the seed papers and their paper-only models, outside the runtime import graph.

:mod:`.experiments` (the papers' experiments), :mod:`.models` (the models only the papers use)
and :mod:`.batched` (the filter and the pure-pursuit follower over N trials at once that the
Monte-Carlo tables run).

A top-level package beside ``ekf_localization`` and ``sim_robot``: it imports both, and nothing
imports it (test/test_import_layers.py).
"""
