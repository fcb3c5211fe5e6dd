"""Motion models (one module each) and their registry; ``sensors/`` holds the measurement models.

Depends on :mod:`ekf_localization.core` only.
"""
