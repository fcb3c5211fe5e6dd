"""Measurement models: dead-wheel encoders (seed 000 eq. 29-33), camera landmark poses.

Linear field selections (z = H x) are in :mod:`ekf_localization.core.linear`.
"""
