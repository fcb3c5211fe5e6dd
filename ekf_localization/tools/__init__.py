"""Offline and orchestration tools: bag I/O, recorder, replay, the closed-loop demo and the
shared evaluation report (RMSE table and plots).
"""
