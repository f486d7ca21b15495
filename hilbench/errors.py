"""One error hierarchy: every user-facing failure is a HilbenchError with a one-line message.

The CLI turns these into a single line on stderr and the kind's exit code, never a traceback.
"""

from __future__ import annotations

import copy
from typing import TypeVar

_E = TypeVar("_E", bound="HilbenchError")


class HilbenchError(Exception):
    """Base of every error the bench reports to its user."""

    exit_code = 1
    kind = "error"

    def reworded(self: _E, message: str) -> _E:
        """The same error (its class, exit code and what it carries, such as a divergence's
        records) saying ``message``: a caller adds what it did around it."""
        other = copy.copy(self)
        other.args = (message,)
        return other


class ConfigError(HilbenchError):
    """A config file, option or value is wrong (names file, table and key)."""

    exit_code = 2
    kind = "config error"


class ProtocolError(HilbenchError):
    """Bytes that are not a valid frame or message, or a handshake that does not agree."""

    exit_code = 3
    kind = "protocol error"


class DecodeError(ProtocolError):
    """One frame could not be decoded (bad CRC, bad COBS, wrong length, unknown type)."""


class VersionMismatch(ProtocolError):
    """Host and target speak different protocol versions."""


class LinkError(HilbenchError):
    """A port could not be opened, vanished, or the far end went silent."""

    exit_code = 4
    kind = "link error"


class LinkTimeout(LinkError):
    """No frame arrived before the deadline."""


class LinkClosed(LinkError):
    """The transport was closed or the far end hung up."""


class TargetError(HilbenchError):
    """The target refused a request or reported a fault."""

    exit_code = 5
    kind = "target error"


class ParamError(TargetError):
    """A parameter request was refused (unknown id, read-only, out of range, constraint)."""


class RecordingError(HilbenchError):
    """A recording could not be written or read."""

    exit_code = 6
    kind = "recording error"


class SimulationError(HilbenchError):
    """The plant's integration left the physical (a diverging plant: too stiff for its step, or
    driven far past anything the config describes)."""

    exit_code = 7
    kind = "simulation error"


class BenchLimitError(HilbenchError):
    """A bench limit ended the run (overspeed, bus over-voltage): what a dyno's guard would stop."""

    exit_code = 8
    kind = "bench limit"


class CheckFailed(HilbenchError):
    """The run completed but a `[[check]]` of its config failed (hilbench.bench.checks)."""

    exit_code = 9
    kind = "check failed"


class DivergenceError(TargetError):
    """Twin-speculative lockstep: the target's Drives differ from its host twin's (the first
    differing period and field, when the replay located it). Its own exit code."""

    exit_code = 10
    kind = "divergence"

    def __init__(self, message: str, records: str = "") -> None:
        super().__init__(message)
        self.records = records  # both sides' periods around it, a small text table


__all__ = [
    "HilbenchError",
    "DivergenceError",
    "ConfigError",
    "ProtocolError",
    "DecodeError",
    "VersionMismatch",
    "LinkError",
    "LinkTimeout",
    "LinkClosed",
    "TargetError",
    "ParamError",
    "RecordingError",
    "SimulationError",
    "BenchLimitError",
    "CheckFailed",
]
