"""The recording's row for a session: the bench's columns plus the target's telemetry columns.

The session packs its own fields (period, hall, sector, duties, state, link timing, marker, the
host's reference), then the raw telemetry, and the plant appends its STATE_FIELDS. The target's
profile says how each telemetry id becomes a column (name, unit, scale); they go after
``speed_rpm``. A target that reports no ``ref_speed_rpm`` gets the host's reference there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilbench.bench.recorder import RowLayout
from hilbench.plant.model import STATE_FIELDS
from hilbench.targets.profile import TargetProfile

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

#: fields the session packs for every period, in this order, before the host's reference (only
#: for a target that reports none) and the telemetry
OWN_FIELDS: tuple[tuple[str, str], ...] = (
    ("k", "Q"), ("hall", "i"), ("sector", "i"), ("duty_a", "i"), ("duty_b", "i"), ("duty_c", "i"),
    ("output_mode", "i"), ("state", "i"), ("fault", "i"), ("rtt_s", "d"), ("lateness_s", "d"),
    ("marker", "B"),
)


@dataclass(frozen=True)
class SessionRow:
    """The layout of a session's recorded row and the session's own part of it."""

    layout: RowLayout
    own_fields: tuple[tuple[str, str], ...]  # the session's fields before the telemetry
    telemetry_fields: tuple[tuple[str, str], ...]  # the raw telemetry, packed on its own (no `*` in the hot call)


def session_row(profile: TargetProfile, telemetry_ids: tuple[int, ...], period_s: float) -> SessionRow:
    """The row for a target that sends ``telemetry_ids`` (in the HELLO's order)."""
    telemetry = [profile.telemetry_column(tid) for tid in telemetry_ids]
    tele_fields = tuple((f"tele_{i}", "i") for i in range(len(telemetry)))
    ordered = sorted(range(len(telemetry)), key=lambda i: _declared_order(profile, telemetry[i].telemetry_id))
    tele_columns = tuple(
        (telemetry[i].column, telemetry[i].unit, telemetry[i].fmt, f"tele_{i}", telemetry[i].scale) for i in ordered
    )
    own = OWN_FIELDS
    if not any(c[0] == "ref_speed_rpm" for c in tele_columns):  # the host's reference instead
        tele_columns += (("ref_speed_rpm", "rpm", "%.3f", "host_ref_rpm", 1.0),)
        own += (("host_ref_rpm", "d"),)
    columns = (
        ("t_s", "s", "%.6f", "k", period_s), ("seq", "", "%d", "k", 1.0), ("hall", "bits CBA", "%d", "hall", 1.0),
        ("sector", "", "%d", "sector", 1.0), ("theta_e_deg", "deg", "%.3f", "theta_e_rad", 180.0 / math.pi),
        ("speed_rpm", "rpm", "%.3f", "w_m_rad_s", RPM_PER_RAD_S),
        *tele_columns,
        ("ia_a", "A", "%.5f", "ia_a", 1.0), ("ib_a", "A", "%.5f", "ib_a", 1.0), ("ic_a", "A", "%.5f", "ic_a", 1.0),
        ("ibus_a", "A", "%.5f", "ibus_a", 1.0), ("duty_a", "counts", "%d", "duty_a", 1.0),
        ("duty_b", "counts", "%d", "duty_b", 1.0), ("duty_c", "counts", "%d", "duty_c", 1.0),
        ("output_mode", "", "%d", "output_mode", 1.0), ("state", "", "%d", "state", 1.0),
        ("fault", "", "%d", "fault", 1.0), ("load_nm", "N*m", "%.5f", "load_nm", 1.0),
        ("rtt_us", "us", "%.1f", "rtt_s", 1e6), ("lateness_us", "us", "%.1f", "lateness_s", 1e6),
        ("marker", "", "%d", "marker", 1.0),
    )
    return SessionRow(RowLayout(own + tele_fields + STATE_FIELDS, columns, wrap=(("theta_e_deg", 360.0),)), own,
                      tele_fields)


def _declared_order(profile: TargetProfile, telemetry_id: int) -> int:
    """Columns the profile names come in its order; others after them, by id."""
    for index, column in enumerate(profile.telemetry):
        if column.telemetry_id == telemetry_id:
            return index
    return len(profile.telemetry) + telemetry_id


__all__ = ["OWN_FIELDS", "RPM_PER_RAD_S", "SessionRow", "session_row"]
