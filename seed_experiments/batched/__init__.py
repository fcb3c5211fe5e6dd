"""The filter and the pure-pursuit follower run over N trials at once, for the Monte-Carlo tables.

:mod:`.ekf` (``BatchedEKF``) and :mod:`.pure_pursuit` (``BatchedPurePursuit``) compute what N
:class:`~ekf_localization.core.ekf.ExtendedKalmanFilter` and N
:class:`~ekf_localization.control.pure_pursuit.PurePursuitFollower` objects compute, with numpy
stacks over the trials in place of a loop (``test/test_batched_ekf.py`` and
``test/test_batched_pure_pursuit.py`` compare them). The robot runs the single ones.
"""
