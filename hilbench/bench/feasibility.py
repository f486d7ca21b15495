"""What a run's settings allow, checked before it starts (issue 16, item 12).

A Sensors carries every hall edge and index mark of its period with its time (protocol 3), so
no edge is lost at any period; a period may hold at most the target's TargetInfo.max_edges (16
on the wire): more, at a long period and a high speed, is said before the run and refused in it.
In real time a serial link must also move a Sensors (3 bytes more per edge) and a Drive frame
inside each period, and a general-purpose host cannot answer within a few tens of microseconds
every period. Impossible settings are refused; doubtful ones give a warning the CLI prints before
the run.
"""

from __future__ import annotations

import math
import re

from hilbench.config import BenchConfig
from hilbench.errors import ConfigError
from hilbench.plant.period import Period

#: hall transitions per electrical revolution (three sensors, 60° apart)
HALL_EDGES_PER_ELECTRICAL_REV = 6
#: bits on the wire per byte (8N1)
BITS_PER_BYTE = 10
#: real-time periods below this rarely hold on a general-purpose host (benchmarks/bench_realtime.py)
REALTIME_MIN_PERIOD_US = 250


def _frame_bytes(n_adc: int, n_telemetry: int, n_edges: int = 0) -> int:
    """Sensors (with ``n_edges`` edges) + Drive frames on the wire, at their largest values."""
    from hilbench.protocol import Drive, Sensors, encode_frame

    sensors = encode_frame(Sensors(255, 0xFF, ((0xFFFF, 0xFF),) * n_edges, 0xFFFF, (0xFFFF,) * n_adc))
    drive = encode_frame(Drive(255, 0xFFFF, 0xFFFF, 0xFFFF, 1, 2, 3, True, False, 0, (-32768,) * n_telemetry))
    return len(sensors) + len(drive)


def check_run(cfg: BenchConfig, events: tuple = ()) -> list[str]:
    """Warnings for doubtful settings; ConfigError for impossible ones."""
    from hilbench.bench import settings

    warnings: list[str] = []
    period_us = cfg.link.period_us
    events = events or settings.scenario_events(cfg)
    refs = [abs(e.ref_rpm) for e in events if getattr(e, "ref_rpm", None) is not None]
    edges_per_period = 1
    if refs:
        from hilbench.protocol import MAX_EDGES

        max_rpm = max(refs)
        edges_per_s = max_rpm / 60.0 * cfg.motor.pole_pairs * HALL_EDGES_PER_ELECTRICAL_REV
        # edges in a window of one period (one more when it starts just before an edge), an index a turn
        edges_per_period = math.floor(edges_per_s * period_us / 1e6) + 1 + math.ceil(max_rpm / 60.0 * period_us / 1e6)
        if edges_per_period > MAX_EDGES:
            most_us = math.floor((MAX_EDGES - 2) * 1e6 / edges_per_s)
            warnings.append(
                f"at {max_rpm:g} rpm a period of {period_us} us holds up to {edges_per_period} hall edges, more "
                f"than the {MAX_EDGES} a Sensors carries (a firmware may take fewer: its TargetInfo.max_edges); "
                f"the run stops if a period has more; use link.period_us <= {most_us}")
    held = _held_frames_warning(cfg, events)
    if held:
        warnings.append(held)
    if cfg.run.mode == "realtime":
        baud = re.search(r"[?&]baud=(\d+)", cfg.link.target)
        if baud:
            try:
                profile = settings.target_profile(cfg.link)
                n_tele = len(profile.telemetry)
            except ConfigError:
                n_tele = 8
            wire_us = _frame_bytes(len(cfg.adc), n_tele, min(edges_per_period, 16)) * BITS_PER_BYTE / int(baud.group(1)) * 1e6
            if wire_us >= period_us:
                raise ConfigError(
                    f"[link] period_us: {period_us} us is shorter than the {wire_us:.0f} us a Sensors and a Drive "
                    f"frame take at {baud.group(1)} baud; use link.period_us >= {math.ceil(wire_us * 1.2)} or a faster link")
        if period_us < REALTIME_MIN_PERIOD_US:
            warnings.append(
                f"real time at {period_us} us periods: a general-purpose host rarely answers within that every "
                f"period; expect overruns (the summary counts them); link.period_us >= {REALTIME_MIN_PERIOD_US} "
                f"is safer")
    return warnings


#: a link fault's delay that makes a run wait this much longer in all is said before the run
HELD_FRAMES_NOTE_S = 60.0


def _held_frames_warning(cfg: BenchConfig, events: tuple) -> str | None:
    """A delay_ms fault on most frames holds each exchange that long: a run that then takes hours
    looks hung unless it is said before it starts."""
    from hilbench.link.spec import parse_target_spec

    try:
        faults = parse_target_spec(cfg.link.target).faults
    except ConfigError:  # (said where the target is opened)
        return None
    if faults is None or faults.delay_s <= 0.0:
        return None
    end_s = cfg.run.duration_s or next((e.at_s for e in events if getattr(e, "end", False)), None)
    if end_s is None:
        return None
    periods = end_s / (cfg.link.period_us * 1e-6)
    waited_s = periods * faults.delay_rate * faults.delay_s
    if waited_s < HELD_FRAMES_NOTE_S:
        return None
    return (f"link fault delay_ms={faults.delay_s * 1e3:g} on {faults.delay_rate:.0%} of the frames the host sends: "
            f"the {end_s:g} s run waits about {_duration_text(waited_s)} in all (Ctrl-C ends it, the recording kept)")


def _duration_text(seconds: float) -> str:
    if seconds >= 7200:
        return f"{seconds / 3600:.0f} h"
    if seconds >= 120:
        return f"{seconds / 60:.0f} min"
    return f"{seconds:.0f} s"


def hall_sector_s(cfg: BenchConfig) -> float | None:
    """The time one hall sector takes at the scenario's fastest reference (None: no reference)."""
    from hilbench.bench import settings

    refs = [abs(e.ref_rpm) for e in settings.scenario_events(cfg) if getattr(e, "ref_rpm", None)]
    if not refs:
        return None
    return 60.0 / (max(refs) * cfg.motor.pole_pairs * HALL_EDGES_PER_ELECTRICAL_REV)


def overrun_warning(periods: int, overruns: int, limit: float = 0.05, *, stall_periods: int = 0,
                    stall_at_s: float = 0.0, period_us: int = 0, sector_s: float | None = None) -> str | None:
    """After a real-time run: say so when real time was not held: too many overruns, or one stall in
    which the Drive was held (no exchange) for two hall sectors or more at the scenario's top speed:
    the firmware then drives 120 degrees or more behind the rotor, which brakes it and can trip the
    overcurrent limit however few periods overran in all."""
    if periods <= 0:
        return None
    stall_s = stall_periods * Period(period_us).s if period_us > 0 else 0.0
    if sector_s is not None and stall_periods > 0 and stall_s >= 2.0 * sector_s:
        return (f"real time NOT held: the host stalled {stall_periods} periods in a row at {stall_at_s:.3f} s "
                f"({stall_s * 1e3:.1f} ms with the Drive held, {stall_s / sector_s:.1f} hall sectors at the "
                f"scenario's top speed); the recording is not a real-time run from there (a less loaded host, "
                f"or --mode lockstep)")
    if overruns / periods <= limit:
        return None
    return (f"real time NOT held: {overruns} of {periods} periods ({100.0 * overruns / periods:.1f} %) overran "
            f"their slot; the recording is not a real-time run (try a longer link.period_us)")


__all__ = ["check_run", "hall_sector_s", "overrun_warning"]
