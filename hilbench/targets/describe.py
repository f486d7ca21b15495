"""A profile from a firmware's own description (protocol 3): how the bench serves a firmware no
hilbench module knows.

After the handshake the session asks a target the registry has no profile for to describe itself:
`TargetDescribe` (duty timing, the inputs it reads, its encoder, the edges a Sensors may carry),
`TelemetryDescribe` for each telemetry slot (name, unit, scale) and `ParamDescribe` for each
parameter (name, type, range, unit). From the answers it builds the profile a plug-in would have
declared: telemetry columns named `NAME_UNIT` with their units and scales (the recording, `report`
and the scope then show them as named columns), the measured-speed column (the slot whose id is
MEASURED_SPEED), the parameters (`ctl`, `step`, the pytest plugin work on them by name) and, when
a read-write parameter is the speed reference by the porting guide's convention (named `speed_ref`
or ending in `_ref`, unit "rpm", an INT), the reference input, so `ref_rpm` events and `step` drive it.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any

from hilbench.errors import HilbenchError, TargetError
from hilbench.protocol import (
    ACCESS_RW,
    INPUT_HALL_A,
    PTYPE_INT,
    PTYPE_Q15,
    TELEMETRY_MEASURED_SPEED,
    ParamInfo,
    TargetHello,
    TargetInfo,
    TelemetryInfo,
)
from hilbench.targets.profile import ParamReference, TargetProfile, TelemetryColumn

_NOT_NAME = re.compile(r"[^a-z0-9_]+")


@dataclass(frozen=True)
class Description:
    """What a firmware said of itself beyond its HELLO."""

    target: TargetInfo | None
    telemetry: tuple[TelemetryInfo, ...]
    params: tuple[ParamInfo, ...]


def column_name(name: str, unit: str) -> str:
    """A recording column for telemetry `name` in `unit`: `measured_speed` in rpm -> `measured_speed_rpm`."""
    base = _NOT_NAME.sub("_", name.lower()).strip("_") or "telemetry"
    suffix = _NOT_NAME.sub("_", unit.lower()).strip("_")
    if suffix and not base.endswith("_" + suffix) and base != suffix:
        base = f"{base}_{suffix}"
    return base


def describe(target: Any, hello: TargetHello, where: str = "") -> Description:
    """Ask ``target`` everything it can say of itself (what it cannot is left out: a firmware that does
    not describe its telemetry gives no TelemetryInfo, and its columns stay raw); ``where``: the
    target's label, for the errors."""
    ask_target = getattr(target, "describe_target", None)
    ask_telemetry = getattr(target, "describe_telemetry", None)
    info = ask_target() if ask_target is not None else None
    telemetry: list[TelemetryInfo] = []
    if ask_telemetry is not None and info is not None:
        for index in range(len(hello.telemetry_ids)):
            try:
                item = ask_telemetry(index)
            except HilbenchError:
                item = None
            if item is None:
                telemetry = []
                break
            telemetry.append(item)
    params = []
    for param_id in range(hello.n_params):
        try:
            params.append(target.describe(param_id))
        except HilbenchError:
            break
    _check_params(params, f"{where}: {hello.firmware_name}" if where else hello.firmware_name)
    return Description(info, tuple(telemetry), tuple(params))


def _check_params(params: list[ParamInfo], firmware: str) -> None:
    """Parameters are set by name and checked against their range: a description with two of one
    name (which would `set` write?), an answer for another id or a range whose ends are swapped
    is the firmware's error, said at the handshake."""
    names: dict[str, int] = {}
    for param_id, info in enumerate(params):
        where = f"{firmware}: ParamDescribe {param_id}"
        if info.param_id != param_id:
            raise TargetError(f"{where}: answered for parameter {info.param_id}")
        if info.name in names:
            raise TargetError(f"{where}: the name {info.name[:40]!r} is parameter {names[info.name]}'s too")
        if info.min_value > info.max_value:
            raise TargetError(f"{where} ({info.name[:40]!r}): min {info.min_value} > max {info.max_value}")
        names[info.name] = param_id


def _format(info: TelemetryInfo) -> str:
    if info.scale_num == info.scale_den and info.ptype != PTYPE_Q15:
        return "%d"
    return "%.6g"


def telemetry_columns(description: Description, reserved: frozenset[str] = frozenset()) -> tuple[TelemetryColumn, ...]:
    """The firmware's telemetry as recording columns (value = raw x scale_num / scale_den); a name the
    recording already has (``reserved``: the bench's and the plant's columns) or that an earlier slot
    took is prefixed `fw_` (then numbered)."""
    columns = []
    taken = set(reserved)
    for item in description.telemetry:
        scale = item.scale_num / item.scale_den if item.scale_den else 1.0
        name = column_name(item.name, item.unit)
        if name in taken:
            name = f"fw_{name}"
            k = 2
            while name in taken:
                name = f"fw_{column_name(item.name, item.unit)}_{k}"
                k += 1
        taken.add(name)
        columns.append(TelemetryColumn(int(item.telemetry_id), name, item.unit, scale, _format(item)))
    return tuple(columns)


def speed_reference(params: tuple[ParamInfo, ...]) -> ParamReference | None:
    """The speed reference by convention: a read-write INT parameter in rpm named `speed_ref` or `*_ref`."""
    for p in params:
        if (p.access == ACCESS_RW and p.ptype == PTYPE_INT and p.unit.strip().lower() == "rpm"
                and (p.name == "speed_ref" or p.name.endswith("_ref"))):
            return ParamReference(p.name, 1.0)
    return None


def described_profile(base: TargetProfile, description: Description,
                      reserved: frozenset[str] = frozenset()) -> TargetProfile:
    """``base`` (the registry's neutral profile for an unknown firmware) with what the firmware said;
    ``reserved``: the recording's other column names."""
    columns = telemetry_columns(description, reserved)
    speed = next((c.column for c in columns if c.telemetry_id == int(TELEMETRY_MEASURED_SPEED)), None)
    capabilities = set(base.capabilities)
    info = description.target
    if info is not None:
        if info.inputs & INPUT_HALL_A:
            capabilities.add("hall_sensors")
        if info.encoder_counts:
            capabilities.add("encoder")
    reference = speed_reference(description.params)
    if reference is not None:  # a speed reference to step (the plant's speed is what a step test measures)
        capabilities.add("speed_loop")
    if description.params:
        capabilities.add("tuning")
    changes: dict[str, Any] = {
        "telemetry": columns or base.telemetry,
        "speed_column": speed or base.speed_column,
        "capabilities": frozenset(capabilities),
        "description": base.description or f"{base.firmware_name}, as it describes itself",
    }
    if reference is not None and base.reference is None:
        changes["reference"] = reference
    return dataclasses.replace(base, **changes)


__all__ = ["Description", "column_name", "describe", "described_profile", "speed_reference", "telemetry_columns"]
