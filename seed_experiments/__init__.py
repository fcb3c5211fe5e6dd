"""Reproductions of the seed papers and their paper-only models, outside the runtime import graph.

A top-level package beside ``ekf_localization`` and ``sim_robot``: it imports both, and nothing
imports it (test/test_import_layers.py).
"""
