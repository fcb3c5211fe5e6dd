"""Reproductions of the seed papers' experiments (ROS-free, seeded, headless).

``ekf_experiments`` (:mod:`.cli`) reruns them and writes ``docs/results.md`` plus PNGs:

* :mod:`.seed000_tables` — seed 000 tables VI B and VI C (100 trials on the test path);
* :mod:`.dt_sweep` — seed 000 fig. 13, (x, y) RMSE against the EKF Δt;
* :mod:`.cycle_drift` — seed 000 fig. 12, drift over FTC cycles with and without camera;
* :mod:`.seed002_comparison` — seed 002, dead reckoning vs linear KF vs EKF, and Table I;
* :mod:`.seed004_kf2d` — seed 004, the 2-D KF with error ellipses, std vs variance.

Shared pieces: :mod:`.seed000_sim` (the batched world + follower + estimators loop),
:mod:`.seed000_estimators` (what "model", "odo", "model + odo", "+ camera" and our improved
filter are), :mod:`.progress` (a progress bar on stderr) and :mod:`.report` (Markdown).
"""
