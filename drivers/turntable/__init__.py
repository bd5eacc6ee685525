"""Turntable controllers: the common interface and one module pair (codec, client) per dialect."""

from drivers.turntable.base import (
    ALL_FRAMES,
    FRAMES,
    AxisLimits,
    AxisMode,
    AxisState,
    AxisStatus,
    TableState,
    Turntable,
    TurntableLimits,
    frame_index,
)

__all__ = ["ALL_FRAMES", "FRAMES", "AxisLimits", "AxisMode", "AxisState", "AxisStatus", "TableState", "Turntable",
           "TurntableLimits", "frame_index"]
