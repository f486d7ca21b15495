"""The interface every target shares: firmware models, the loopback target and the remote proxy.

The session only ever talks to this interface, so a board on a serial port, an emulator process
on a pty and an in-process model are interchangeable.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:  # the protocol package defines the message classes
    from hilbench.protocol import (
        Drive,
        HostHello,
        ParamInfo,
        ParamSetResult,
        ParamValue,
        Sensors,
        Status,
        TargetHello,
    )


@runtime_checkable
class Target(Protocol):
    """A firmware seen through the wire protocol's messages."""

    firmware_name: str

    def hello(self, host: "HostHello") -> "TargetHello":
        """Agree period and mode; returns the target's declaration."""

    def describe(self, param_id: int) -> "ParamInfo":
        """Describe one declared parameter (result carried in ParamInfo's fields)."""

    def get_param(self, param_id: int) -> "ParamValue":
        """Read one declared parameter."""

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> "ParamSetResult":
        """Write a set of parameters atomically: all of them or none."""

    def start(self) -> None:
        """The S2 button as a command: start when stopped."""

    def stop(self) -> None:
        """Stop: all switches off, the motor coasts."""

    def step(self, sensors: "Sensors") -> "Drive":
        """Lockstep: advance the firmware by exactly one agreed period."""

    def advance(self, duration_us: float, sensors: "Sensors") -> "Drive":
        """Real time: advance the firmware by any span of wall time."""

    def watchdog_trip(self) -> "Drive":
        """Sensors stopped arriving: outputs off, fault WATCHDOG."""

    def status(self) -> "Status":
        """Counters and the last error."""
