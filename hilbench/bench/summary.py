"""What a session reports: the run's Summary, its speed Segments, and live Snapshots for observers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Sequence

if TYPE_CHECKING:
    from hilbench.bench.checks import CheckResult


@dataclass
class Segment:
    """One held speed reference and how well the motor followed it."""

    t_start_s: float
    t_end_s: float
    ref_rpm: float
    plant_rpm: float = float("nan")
    measured_rpm: float = float("nan")

    @property
    def error_pct(self) -> float:
        if self.ref_rpm == 0:
            return float("nan")
        return 100.0 * (self.plant_rpm - self.ref_rpm) / abs(self.ref_rpm)


@dataclass
class Summary:
    """What a run did, for the CLI's table, --json and the tests."""

    target: str
    mode: str
    period_us: int
    #: lockstep whose Drives carried the duties predicted over each period (HostHello mode PREDICT)
    predicted_duties: bool = False
    periods: int = 0
    sim_s: float = 0.0
    wall_s: float = 0.0
    end_reason: str = "completed"
    fault: str | None = None
    segments: list[Segment] = field(default_factory=list)
    rtt_us: dict[str, float] = field(default_factory=dict)
    lateness_us: dict[str, float] = field(default_factory=dict)
    overruns: int = 0
    #: overruns in which the host was a whole period late, so no exchange took place (Drive held)
    skipped_periods: int = 0
    #: the most periods skipped in a row (the Drive held, the firmware without sensors) and when it began
    longest_stall_periods: int = 0
    longest_stall_at_s: float = 0.0
    #: real time: whether idle CPUs were kept awake (the PM QoS request), or why not
    cpu_latency: str = ""
    #: real time: which CPU the host loop and the emulator process shared (set by bench.run)
    cpus: str = ""
    link: dict[str, int] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    recording: str | None = None
    rows_recorded: int = 0
    firmware: str = ""
    #: what the run's settings did not allow (checked before the start, and real time not held)
    warnings: list[str] = field(default_factory=list)
    #: the firmware's fault code as the live history saw it (every history period, rows kept or not):
    #: the first code, and the first and last times it was non-zero (None: never)
    fault_code: int = 0
    fault_first_s: float | None = None
    fault_last_s: float | None = None
    #: the config's [[check]] verdicts (hilbench.bench.checks), judged when the run ended
    checks: list["CheckResult"] = field(default_factory=list)

    @property
    def checks_passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def realtime_factor(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else float("inf")

    def as_dict(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "firmware": self.firmware,
            "mode": self.mode,
            "period_us": self.period_us,
            "predicted_duties": self.predicted_duties,
            "periods": self.periods,
            "sim_s": self.sim_s,
            "wall_s": self.wall_s,
            "realtime_factor": self.realtime_factor,
            "end_reason": self.end_reason,
            "fault": self.fault,
            "segments": [
                {
                    "t_start_s": s.t_start_s,
                    "t_end_s": s.t_end_s,
                    "ref_rpm": s.ref_rpm,
                    "plant_rpm": s.plant_rpm,
                    "measured_rpm": s.measured_rpm,
                    "error_pct": s.error_pct,
                }
                for s in self.segments
            ],
            "rtt_us": self.rtt_us,
            "lateness_us": self.lateness_us,
            "overruns": self.overruns,
            "skipped_periods": self.skipped_periods,
            "longest_stall_periods": self.longest_stall_periods,
            "longest_stall_at_s": self.longest_stall_at_s,
            "cpu_latency": self.cpu_latency,
            "cpus": self.cpus,
            "link": self.link,
            "params": self.params,
            "recording": self.recording,
            "rows_recorded": self.rows_recorded,
            "fault_code": self.fault_code,
            "fault_first_s": self.fault_first_s,
            "fault_last_s": self.fault_last_s,
            "checks": [c.as_dict() for c in self.checks],
            "checks_passed": self.checks_passed,
        }


@dataclass
class Snapshot:
    """What a live view shows; built every ``observe_every_periods`` periods."""

    t_s: float
    duration_s: float
    period: int
    ref_rpm: float
    speed_rpm: float
    measured_rpm: float
    state: int
    sector: int
    direction_ccw: bool
    output_mode: int
    duties: tuple[int, int, int]
    i_abc: tuple[float, float, float]
    i_bus: float
    telemetry: dict[str, float]  # the target's telemetry columns, scaled
    periods_per_s: float
    rtt_p50_us: float
    rtt_p99_us: float
    link: dict[str, int]
    overruns: int
    messages: list[str]
    history: Sequence[tuple[float, float, float, float]]  # oldest first (the session's SpeedHistory, live)
    fault: int = 0  # the firmware's fault code (0: none)


def percentiles(values: list[float]) -> dict[str, float]:
    """p50, p99, max and n of a list (empty dict for none)."""
    if not values:
        return {}
    ordered = sorted(values)
    n = len(ordered)

    def pick(q: float) -> float:
        return ordered[min(n - 1, int(q * (n - 1) + 0.5))]

    return {"p50": pick(0.5), "p99": pick(0.99), "max": ordered[-1], "n": float(n)}


__all__ = ["Segment", "Snapshot", "Summary", "percentiles"]
