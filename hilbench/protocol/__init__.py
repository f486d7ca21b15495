"""The hilbench wire protocol (Python side): messages, framing and codec.

Messages and constants are generated from firmware_protocol/schema.toml (prose in
firmware_protocol/PROTOCOL.md); the C target library is generated from the same schema.
"""

from hilbench.protocol import messages as _messages
from hilbench.protocol.codec import COUNTER_NAMES, FrameDecoder, decode_frame, encode_frame
from hilbench.protocol.framing import (
    CobsError,
    CrcError,
    LengthError,
    OversizedError,
    UnknownTypeError,
)
from hilbench.protocol.messages import *  # noqa: F403 - constants, IntEnums, message classes

__all__ = [
    "encode_frame",
    "decode_frame",
    "FrameDecoder",
    "COUNTER_NAMES",
    "CobsError",
    "CrcError",
    "LengthError",
    "OversizedError",
    "UnknownTypeError",
    *_messages.__all__,
]
