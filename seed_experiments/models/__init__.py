"""Paper-only models: seed 002's unicycle, seed 004's 2-D linear KF, dead reckoning.
"""
