"""Hardware I/O: turntable controller dialects and the IMU over CAN.

Never imports `bench`. The drivers themselves arrive with the drivers issue; this
package exists so the layout of DESIGN section 4 holds from the start.
"""
