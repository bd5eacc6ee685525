"""Hardware I/O: turntable controller dialects (`drivers.turntable`) and the IMU over CAN (`drivers.imu`).

Never imports `bench`: the simulators in `bench/sim/` serve the wire formats these
clients speak. See docs/hardware/index.md.
"""
