"""EKF localization for small holonomic and tank-drive competition robots."""

__version__ = "0.1.0"
