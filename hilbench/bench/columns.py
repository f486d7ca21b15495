"""The recording's row for a session: the bench's columns, the plant's declared outputs and the
target's telemetry columns.

The session packs its own fields (period, hall, sector, duties, state, link timing, marker, the
host's reference), then the raw telemetry, and the plant appends its declared outputs
(`hilbench.plant.model.OUTPUTS`: each a raw field and the column made of it). The target's profile
says how each telemetry id becomes a column (name, unit, scale). A target that reports no
``ref_speed_rpm`` gets the host's reference there. Column order: time, sequence, halls and sector,
the plant's outputs in their declared order, the telemetry, then the target's outputs and the
link's figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from hilbench.bench.recorder import RowLayout
from hilbench.plant.model import OUTPUTS, RPM_PER_RAD_S, PlantOutput
from hilbench.targets.profile import TargetProfile

#: fields the session packs for every period, in this order, before the host's reference (only
#: for a target that reports none) and the telemetry
OWN_FIELDS: tuple[tuple[str, str], ...] = (
    ("k", "Q"), ("hall", "i"), ("sector", "i"), ("duty_a", "i"), ("duty_b", "i"), ("duty_c", "i"),
    ("output_mode", "i"), ("state", "i"), ("fault", "i"), ("rtt_s", "d"), ("lateness_s", "d"),
    ("marker", "B"),
)


#: the bench's own columns (a telemetry column of a self-described firmware never takes these names)
BENCH_COLUMNS = ("t_s", "seq", "hall", "sector", "duty_a", "duty_b", "duty_c", "output_mode", "state", "fault",
                 "rtt_us", "lateness_us", "marker")


@dataclass(frozen=True)
class SessionRow:
    """The layout of a session's recorded row and the session's own part of it."""

    layout: RowLayout
    own_fields: tuple[tuple[str, str], ...]  # the session's fields before the telemetry
    telemetry_fields: tuple[tuple[str, str], ...]  # the raw telemetry, packed on its own (no `*` in the hot call)


def session_row(profile: TargetProfile, telemetry_ids: tuple[int, ...], period_s: float,
                plant_outputs: Sequence[PlantOutput] = OUTPUTS, halls: bool = True) -> SessionRow:
    """The row for a target that sends ``telemetry_ids`` (in the HELLO's order) and a plant that
    records ``plant_outputs`` (its `outputs`); ``halls`` False: no hall column (no one sends the
    halls to a monitor session: the board reads them itself)."""
    telemetry = [profile.telemetry_column(tid) for tid in telemetry_ids]
    tele_fields = tuple((f"tele_{i}", "i") for i in range(len(telemetry)))
    ordered = sorted(range(len(telemetry)), key=lambda i: _declared_order(profile, telemetry[i].telemetry_id))
    tele_columns = tuple(
        (telemetry[i].column, telemetry[i].unit, telemetry[i].fmt, f"tele_{i}", telemetry[i].scale) for i in ordered
    )
    own = OWN_FIELDS if halls else tuple(f for f in OWN_FIELDS if f[0] != "hall")
    if not any(c[0] == "ref_speed_rpm" for c in tele_columns):  # the host's reference instead
        tele_columns += (("ref_speed_rpm", "rpm", "%.3f", "host_ref_rpm", 1.0),)
        own += (("host_ref_rpm", "d"),)
    plant_columns = tuple((out.column, out.unit, out.fmt, out.field, out.scale) for out in plant_outputs)
    columns = (
        ("t_s", "s", "%.6f", "k", period_s), ("seq", "", "%d", "k", 1.0),
        *((("hall", "bits CBA", "%d", "hall", 1.0),) if halls else ()), ("sector", "", "%d", "sector", 1.0),
        *plant_columns,
        *tele_columns,
        ("duty_a", "counts", "%d", "duty_a", 1.0), ("duty_b", "counts", "%d", "duty_b", 1.0),
        ("duty_c", "counts", "%d", "duty_c", 1.0), ("output_mode", "", "%d", "output_mode", 1.0),
        ("state", "", "%d", "state", 1.0), ("fault", "", "%d", "fault", 1.0),
        ("rtt_us", "us", "%.1f", "rtt_s", 1e6), ("lateness_us", "us", "%.1f", "lateness_s", 1e6),
        ("marker", "", "%d", "marker", 1.0),
    )
    plant_fields = tuple((out.field, "d") for out in plant_outputs)
    wrap = tuple((out.column, out.wrap) for out in plant_outputs if out.wrap)
    return SessionRow(RowLayout(own + tele_fields + plant_fields, columns, wrap=wrap), own, tele_fields)


def _declared_order(profile: TargetProfile, telemetry_id: int) -> int:
    """Columns the profile names come in its order; others after them, by id."""
    for index, column in enumerate(profile.telemetry):
        if column.telemetry_id == telemetry_id:
            return index
    return len(profile.telemetry) + telemetry_id


__all__ = ["BENCH_COLUMNS", "OWN_FIELDS", "RPM_PER_RAD_S", "SessionRow", "session_row"]
