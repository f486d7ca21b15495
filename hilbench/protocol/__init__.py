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
from hilbench.protocol.handshake import check_target_hello, hello_problem, host_hello_mismatch, version_refusal
from hilbench.protocol.messages import *  # noqa: F403 - constants, IntEnums, message classes
from hilbench.protocol.messages import ParamType as _ParamType

_PARAM_SCALE = {_ParamType.Q15: 2.0 ** -15, _ParamType.IQ24: 2.0 ** -24, _ParamType.INT: 1.0, _ParamType.BOOL: 1.0}


def param_scale(ptype: int) -> float:
    """The real value of one wire unit of a parameter of this ParamInfo.ptype (Q15 2^-15, IQ24 2^-24)."""
    return _PARAM_SCALE[_ParamType(ptype)]

__all__ = [
    "encode_frame",
    "decode_frame",
    "FrameDecoder",
    "COUNTER_NAMES",
    "check_target_hello",
    "hello_problem",
    "host_hello_mismatch",
    "version_refusal",
    "param_scale",
    "CobsError",
    "CrcError",
    "LengthError",
    "OversizedError",
    "UnknownTypeError",
    *_messages.__all__,
]
