"""The IMU over CAN: DBC layouts, the frame rules, the stream and bulk decoders, the encoder, the bus receiver.

See docs/hardware/can.md for the shipped frame layouts (the simulated IMU's and SBG Systems'
published one), the CRC, the signal mapping for an IMU's own DBC, and what the decoders count.
"""

from drivers.imu.bulk import decode_frames
from drivers.imu.encoder import EncodedFrames, ImuEncoder, encode_block
from drivers.imu.layout import (
    CHANNELS,
    COLUMNS,
    DEFAULT_DBC,
    DEFAULT_FD_DBC,
    DEFAULT_FD_SPEC,
    DEFAULT_PACKED_DBC,
    DEFAULT_PACKED_SPEC,
    DEFAULT_SPEC,
    EXTENDED_ID_FLAG,
    SBG_ECAN_DBC,
    SBG_ECAN_SPEC,
    SHIPPED_LAYOUTS,
    ImuFrameSpec,
    ImuLayout,
    default_fd_layout,
    default_layout,
    default_packed_layout,
    sbg_ecan_layout,
    shipped_layout_name,
    spec_of,
)
from drivers.imu.rules import frames_from_messages
from drivers.imu.samples import ImuSampleBlock, ImuStats
from drivers.imu.stream import StreamDecoder

__all__ = ["CHANNELS", "COLUMNS", "DEFAULT_DBC", "DEFAULT_FD_DBC", "DEFAULT_FD_SPEC", "DEFAULT_PACKED_DBC",
           "DEFAULT_PACKED_SPEC", "DEFAULT_SPEC", "EXTENDED_ID_FLAG", "SBG_ECAN_DBC", "SBG_ECAN_SPEC",
           "SHIPPED_LAYOUTS", "EncodedFrames", "ImuEncoder", "ImuFrameSpec", "ImuLayout", "ImuSampleBlock", "ImuStats",
           "StreamDecoder", "decode_frames", "default_fd_layout", "default_layout", "default_packed_layout",
           "encode_block", "frames_from_messages", "sbg_ecan_layout", "shipped_layout_name", "spec_of"]
