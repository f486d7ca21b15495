"""A target's profile: everything the bench needs to know about one firmware, declared by its package.

The bench names no firmware. It learns from a profile how to build the firmware in-process or as
an emulator process, which `[target]` options it takes, which of its parameters are gains and what
constraints they obey, how a speed reference reaches it (a pot ADC channel or a parameter), which
telemetry it sends and how each becomes a recording column, and the motor constants it was built
for. Profiles are registered in `hilbench.targets.registry` (built-ins, and outside packages
through the ``hilbench.targets`` entry-point group).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Generic, Literal, Mapping, Protocol, TypeVar

from hilbench.pwm import PwmTiming
from hilbench.targets.kit import ParamSpec

if TYPE_CHECKING:
    import subprocess

    from hilbench.targets.base import Target
    from hilbench.targets.starters import FirmwareStarter

#: a target's options: the frozen dataclass of its `[target]` table (None for a target with none)
Options = TypeVar("Options")

#: capabilities a profile may declare (the pytest plugin's `hil_requires` and the CLI check them);
#: "encoder": the target reads the quadrature encoder and its index (the session forwards the index);
#: "link_check": every Drive is a documented function of the Sensors alone, so `link-test` checks
#: each against the in-process model
CAPABILITIES = ("speed_loop", "realtime", "fault_injection", "tuning", "hall_sensors", "encoder", "link_check")


@dataclass(frozen=True)
class TelemetryColumn:
    """One telemetry id of the Drive as a recording column: column = raw × scale."""

    telemetry_id: int
    column: str  # e.g. "measured_speed_rpm"
    unit: str = ""
    scale: float = 1.0
    fmt: str = "%.3f"


class ReferenceInput(Protocol):
    """How a speed reference in rpm reaches the firmware."""

    kind: Literal["pot", "param"]

    def effective_rpm(self, speed_rpm: float) -> float:
        """The reference the firmware actually gets for ``speed_rpm`` (after its quantisation)."""


@dataclass(frozen=True)
class PotReference:
    """Through the speed pot: an ADC channel whose code the firmware scales into its reference."""

    code_for_rpm: Callable[[float], int]
    rpm_for_code: Callable[[int], float]
    full_scale_code: int = 1023
    kind: Literal["pot", "param"] = "pot"

    def pot_fraction(self, speed_rpm: float) -> float:
        return self.code_for_rpm(speed_rpm) / self.full_scale_code

    def effective_rpm(self, speed_rpm: float) -> float:
        return self.rpm_for_code(self.code_for_rpm(speed_rpm))


@dataclass(frozen=True)
class ParamReference:
    """Through a declared parameter: value = rpm × value_per_rpm, as the host writes it."""

    param: str
    value_per_rpm: float
    kind: Literal["pot", "param"] = "param"
    #: a boolean parameter written 1 with the value (a firmware whose reference is a pot takes a
    #: written one only while its override is on: monitor mode, where the pot is the board's)
    enable: str | None = None

    def value(self, speed_rpm: float) -> float:
        return speed_rpm * self.value_per_rpm

    def effective_rpm(self, speed_rpm: float) -> float:
        return speed_rpm


@dataclass(frozen=True)
class MotorBuild:
    """The motor constants a firmware build assumes (the bench checks them against the plant)."""

    pole_pairs: int
    max_speed_rpm: float = math.inf


def _no_build(options: Any) -> MotorBuild | None:
    return None


def _no_params(options: Any) -> dict[str, float]:
    return {}


@dataclass(frozen=True)
class TargetProfile(Generic[Options]):
    """One firmware as the bench sees it, for its options type ``Options`` (the dataclass of its
    `[target]` table; None when it takes none). Only ``name``, ``firmware_name`` and ``make`` are
    required; a profile built from a self-describing firmware's handshake fills ``params`` and
    ``telemetry`` from what the firmware declared."""

    name: str  # the spec name: `inprocess:NAME`, `emulator:NAME`
    firmware_name: str  # the name its HELLO carries
    make: Callable[[Options], "Target"]  # options -> an in-process Target
    description: str = ""
    options_type: type[Options] | None = None  # frozen dataclass validated from the [target] table
    tunable: tuple[str, ...] = ()  # the gains `step`, `sweep` and the guard work on
    check_params: Callable[[Mapping[str, int]], str | None] | None = None  # raw values -> broken constraint
    reference: PotReference | ParamReference | None = None
    #: how the host sets the reference in monitor mode (the board's own pot is not the bench's);
    #: None: `reference` when it is a parameter
    monitor_reference: ParamReference | None = None
    telemetry: tuple[TelemetryColumn, ...] = ()
    params: tuple[ParamSpec, ...] = ()  # the declared parameters (name, type, range, unit), when known
    speed_column: str | None = None  # the telemetry column that is the firmware's measured speed
    built_for: Callable[[Options], MotorBuild | None] = field(default=_no_build)
    initial_params: Callable[[Options], dict[str, float]] = field(default=_no_params)
    capabilities: frozenset[str] = frozenset()
    #: the default grid of `hilbench sweep`: (parameter, "A:B:N") pairs
    sweep_defaults: tuple[tuple[str, str], ...] = ()
    emulator_module: str = "hilbench.targets.emulator"  # `python -m MODULE NAME --port ...`
    #: a firmware-in-the-loop build of the board's own C firmware: (options, tty path) -> the started
    #: process, serving that tty once this returns (`sil:NAME`); None: the target has none. (Older
    #: form of starters["sil"]; the launcher takes either.)
    start_sil: "Callable[[Options, str], subprocess.Popen[bytes]] | None" = None
    #: the builds of its C firmware that run as processes, by spec kind: "sil", "simavr", "qemu"
    #: (hilbench.targets.starters)
    starters: "Mapping[str, FirmwareStarter]" = field(default_factory=dict)
    #: the profile of a build with these options, for a firmware whose build constants are options
    #: (its reference scale, telemetry scales and `built_for` follow them); None: options change none
    configure: "Callable[[Options], TargetProfile[Options]] | None" = None
    #: an in-process target bit-exact with the builds of `starters` (the same C source compiled into this
    #: process): the host twin of twin-speculative lockstep ([link] twin); None: the target has none
    twin: "Callable[[Options], Target] | None" = None
    #: where its PWM unit centres the pulses and when its ADC samples the phase currents (the plant's
    #: switching inverter reads it); None: the plant's default (PwmTiming())
    pwm_timing: PwmTiming | None = None

    def configured(self, options: Options | None) -> "TargetProfile[Options]":
        """This profile as built with ``options`` (itself when the target has no build constants)."""
        return self if self.configure is None or options is None else self.configure(options)

    def default_options(self) -> Options | None:
        """The options dataclass with every default (None when the target takes no options)."""
        return None if self.options_type is None else self.options_type()

    def option_names(self) -> tuple[str, ...]:
        """The names of the options dataclass's fields (none when the target takes no options)."""
        if self.options_type is None:
            return ()
        return tuple(f.name for f in dataclasses.fields(self.options_type))  # type: ignore[arg-type]

    def options_from(self, values: Mapping[str, object]) -> Options | None:
        """Options from plain values (the emulator process gets them as JSON)."""
        if self.options_type is None:
            return None
        known = self.option_names()
        return self.options_type(**{k: v for k, v in values.items() if k in known})

    def options_as_dict(self, options: Options | None) -> dict[str, object]:
        if options is None or not dataclasses.is_dataclass(options):
            return {}
        return {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}

    def telemetry_column(self, telemetry_id: int) -> TelemetryColumn:
        """The column of a telemetry id (a raw `telemetry_<id>` column for ids it does not name)."""
        for column in self.telemetry:
            if column.telemetry_id == telemetry_id:
                return column
        return TelemetryColumn(telemetry_id, f"telemetry_{telemetry_id}", "raw", 1.0, "%d")

    def has(self, capability: str) -> bool:
        return capability in self.capabilities


def generic_profile(firmware_name: str, *, params: tuple[ParamSpec, ...] = (),
                    telemetry: tuple[TelemetryColumn, ...] = ()) -> TargetProfile[None]:
    """The profile of a firmware met only through its HELLO (a board with no registered profile):
    what it declared of its parameters and telemetry, when it describes itself."""

    def cannot_make(options: None) -> "Target":
        from hilbench.errors import ConfigError

        raise ConfigError(f"firmware {firmware_name!r}: no in-process model is registered")

    return TargetProfile(name=firmware_name.lower() or "generic", firmware_name=firmware_name, make=cannot_make,
                         params=params, telemetry=telemetry)


__all__ = [
    "CAPABILITIES",
    "MotorBuild",
    "Options",
    "ParamReference",
    "PotReference",
    "ReferenceInput",
    "TargetProfile",
    "TelemetryColumn",
    "generic_profile",
]
