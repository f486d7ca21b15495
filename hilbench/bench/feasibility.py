"""What a run's settings allow, checked before it starts (issue 16, item 12).

Lockstep and real time both carry one hall edge time per period: when the motor's halls change
more often than the bench exchanges, edges are lost and the firmware's speed is wrong (at 1 ms
periods and 2500 rpm on a 5-pole-pair motor: 1250 edges/s against 1000 exchanges/s, 31 % off).
In real time a serial link must also move a Sensors and a Drive frame inside each period, and a
general-purpose host cannot answer within a few tens of microseconds every period. Impossible
settings are refused; doubtful ones give a warning the CLI prints before the run.
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


def _frame_bytes(n_adc: int, n_telemetry: int) -> int:
    """Sensors + Drive frames on the wire, at their largest values."""
    from hilbench.protocol import Drive, Sensors, encode_frame

    sensors = encode_frame(Sensors(255, 0xFF, 0xFFFF, 0xFFFF, (0xFFFF,) * n_adc))
    drive = encode_frame(Drive(255, 0xFFFF, 0xFFFF, 0xFFFF, 1, 2, 3, True, False, 0, (-32768,) * n_telemetry))
    return len(sensors) + len(drive)


def check_run(cfg: BenchConfig, events: tuple = ()) -> list[str]:
    """Warnings for doubtful settings; ConfigError for impossible ones."""
    from hilbench.bench import settings

    warnings: list[str] = []
    period_us = cfg.link.period_us
    exchanges_per_s = Period(period_us).per_s
    refs = [abs(e.ref_rpm) for e in (events or settings.scenario_events(cfg)) if getattr(e, "ref_rpm", None) is not None]
    if refs:
        max_rpm = max(refs)
        edges_per_s = max_rpm / 60.0 * cfg.motor.pole_pairs * HALL_EDGES_PER_ELECTRICAL_REV
        if edges_per_s > exchanges_per_s:
            most_us = math.floor(1e6 / edges_per_s)
            warnings.append(
                f"at {max_rpm:g} rpm the halls change {edges_per_s:.0f} times/s but the bench exchanges "
                f"{exchanges_per_s:.0f} times/s (link.period_us = {period_us}): hall edges are lost and the "
                f"firmware's speed will be wrong; use link.period_us <= {most_us}")
    if cfg.run.mode == "realtime":
        baud = re.search(r"[?&]baud=(\d+)", cfg.link.target)
        if baud:
            try:
                profile = settings.target_profile(cfg.link)
                n_tele = len(profile.telemetry)
            except ConfigError:
                n_tele = 8
            wire_us = _frame_bytes(len(cfg.adc), n_tele) * BITS_PER_BYTE / int(baud.group(1)) * 1e6
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


def overrun_warning(periods: int, overruns: int, limit: float = 0.05) -> str | None:
    """After a real-time run: say so when real time was not held."""
    if periods <= 0 or overruns / periods <= limit:
        return None
    return (f"real time NOT held: {overruns} of {periods} periods ({100.0 * overruns / periods:.1f} %) overran "
            f"their slot; the recording is not a real-time run (try a longer link.period_us)")


__all__ = ["check_run", "overrun_warning"]
