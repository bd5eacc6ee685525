"""turntable-bench: calibrate an IMU on a three-axis turntable."""

__version__ = "0.1.0"
