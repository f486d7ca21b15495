"""The bench's config tables ([run], [link], [target], [tuning], [[scenario]], [[check]]) and
what a session is made of them (`SessionOptions`, `GuardSettings`).

`SECTIONS` is the bench's registry: the plant's tables and these, so a bench file is validated as
a whole — plant and bench tables together, every problem at once. `load_config` here (the API's
`hilbench.load_config`) reads a bench config with it.
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Sequence

from hilbench.bench.checks import CheckEntry
from hilbench.bench.cpus import FifoWhen
from hilbench.bench.livetuning import GuardSettings
from hilbench.bench.pacing import CONTENDED_EPISODES, CONTENDED_WINDOW_S
from hilbench.bench.faults import FAULT_KINDS
from hilbench.bench.scenario import LOAD_KINDS, Event, default_scenario
from hilbench.config import PLANT_SECTIONS, BenchConfig, Override, parse_toml
from hilbench.config import load_config as _load_tables
from hilbench.errors import ConfigError
from hilbench.fieldspec import spec
from hilbench.targets.profile import TargetProfile
from hilbench.targets.registry import DEFAULT_TARGET, get_profile

LoadKind = Literal["constant", "linear", "quadratic", "locked"]
assert LoadKind.__args__ == LOAD_KINDS  # type: ignore[attr-defined]


@dataclass(frozen=True)
class RunSection:
    """[run]: how long and how."""

    mode: Literal["lockstep", "realtime", "monitor"] = field(default="lockstep", metadata=spec(doc="lockstep (virtual time), realtime (wall clock) or monitor (the board runs its real motor; no plant)"))
    duration_s: float | None = field(default=None, metadata=spec(unit="s", gt=0, le=86400, doc="default: the scenario's end"))
    seed: int | None = field(default=None, metadata=spec(ge=0, doc="seed of every random source of the run (default: [plant] seed)"))


@dataclass(frozen=True)
class LinkSection:
    """[link]: which target, the exchange period and the timing policy."""

    target: str = field(default=DEFAULT_TARGET, metadata=spec(doc="emulator:NAME, inprocess:NAME, serial:PORT?baud=N, a pyserial URL or a device path"))
    firmware: str | None = field(default=None, metadata=spec(doc="the registered target a board on a port runs (for its [target] options)"))
    period_us: int = field(default=50, metadata=spec(unit="us", ge=50, le=6000, doc="one exchange per period"))
    timeout_ms: int = field(default=500, metadata=spec(unit="ms", ge=1, le=60000, doc="silence that ends the run"))
    retry_ms: int = field(default=100, metadata=spec(unit="ms", ge=1, le=60000, doc="send a frame again after this long without its answer (a lost frame costs a retry, not the run)"))
    watchdog_ms: int = field(default=100, metadata=spec(unit="ms", ge=0, le=60000, doc="target turns its outputs off after this silence (real time; lockstep: at least 1 s, the firmware left as it was, the next Sensors gives them back)"))
    actuation_delay_periods: int = field(default=0, metadata=spec(ge=0, le=100, doc="extra whole periods before duties reach the plant"))
    overrun_policy: Literal["continue", "abort"] = "continue"
    max_consecutive_overruns: int = field(default=10, metadata=spec(ge=1, le=1_000_000))
    cpu_latency_qos: bool = field(default=True, metadata=spec(doc="real time: hold /dev/cpu_dma_latency at 0 so idle CPUs poll, not halt (needs root)"))
    predict_duties: bool = field(default=True, metadata=spec(doc="lockstep, a period of 2 PWM periods or more: the target's duties predicted over each period when it can (HostHello mode PREDICT), not its last ones held"))
    twin: Literal["auto", "off"] = field(default="off", metadata=spec(doc="lockstep on a firmware build whose profile has a bit-exact host twin: auto runs the twin ahead and has the target confirm batches of periods by digest (twin-speculative lockstep; same recording, at the target's speed rather than the wire's); off: one exchange a period"))
    on_divergence: Literal["end", "continue"] = field(default="end", metadata=spec(doc="twin-speculative lockstep: when the target's Drives differ from its twin's, end the run (exit code 10), or go on one exchange a period and exit with code 10 at the end"))
    pin_realtime: bool = field(default=True, metadata=spec(doc="real time: the host loop and the emulator process it started share one CPU"))
    realtime_cpu: int | None = field(default=None, metadata=spec(ge=0, le=4095, doc="that CPU (default: the last one this process may use)"))
    realtime_priority: int = field(default=10, metadata=spec(ge=0, le=99, doc="real time: SCHED_FIFO priority of the host loop and the emulator process it started while the run lasts, ahead of the machine's other work (needs root or CAP_SYS_NICE; 0: normal scheduling)"))
    realtime_fifo: FifoWhen = field(default="contended", metadata=spec(doc=f"real time: when that priority is taken: contended, once overruns say other work takes the run's CPU ({CONTENDED_EPISODES} overrun episodes within {CONTENDED_WINDOW_S:g} s; on an idle CPU FIFO costs overruns), for the rest of the run; always: from the start"))
    allow_pole_pair_mismatch: bool = field(default=False, metadata=spec(doc="run a plant whose [motor] pole_pairs differ from the firmware's build (its speeds then scale by the ratio)"))


@dataclass(frozen=True)
class ScenarioEntry:
    """[[scenario]]: one timed action; exactly one of the action keys."""

    at_s: float = field(metadata=spec(unit="s", ge=0))
    ref_rpm: float | None = field(default=None, metadata=spec(unit="rpm", ge=-20000, le=20000))
    pot: float | None = field(default=None, metadata=spec(ge=0, le=1))
    ramp_s: float = field(default=0.0, metadata=spec(unit="s", ge=0, le=3600))
    load_nm: float | None = field(default=None, metadata=spec(unit="N*m", ge=-1000, le=1000))
    load_kind: LoadKind = "constant"
    vbus_v: float | None = field(default=None, metadata=spec(unit="V", ge=0, le=1500))
    press: Literal["s2", "s3"] | None = None
    fault: str | None = field(default=None, metadata=spec(doc="a sensor fault (bench.faults.FAULT_KINDS)"))
    fault_duration_s: float | None = field(default=None, metadata=spec(unit="s", gt=0))
    set: dict[str, float] | None = field(default=None, metadata=spec(doc="live parameter change, e.g. { kp = 0.12 }"))
    end: bool = False

    def check(self) -> list[tuple[str, str]]:
        actions = [k for k in ("ref_rpm", "pot", "load_nm", "vbus_v", "press", "fault", "set") if getattr(self, k) is not None]
        if self.end:
            actions.append("end")
        if len(actions) != 1:
            return [("at_s", f"needs exactly one action of ref_rpm, pot, load_nm, vbus_v, press, fault, set, end (found {actions or 'none'})")]
        if self.set is not None and not self.set:
            return [("set", "names no parameter (e.g. set = { kp = 0.12 })")]
        if self.fault is not None and self.fault not in FAULT_KINDS:
            close = difflib.get_close_matches(self.fault, FAULT_KINDS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            return [("fault", f"{self.fault[:40]!r} is not one of {', '.join(repr(k) for k in FAULT_KINDS)}{hint}")]
        return []

    def to_event(self) -> Event:
        params = tuple((k, float(v)) for k, v in (self.set or {}).items())
        return Event(
            at_s=self.at_s, ref_rpm=self.ref_rpm, pot=self.pot, ramp_s=self.ramp_s, load_nm=self.load_nm,
            load_kind=self.load_kind, vbus_v=self.vbus_v, press=self.press, fault=self.fault,
            fault_duration_s=self.fault_duration_s, params=params, end=self.end,
        )


@dataclass(frozen=True)
class TuningSection:
    """[tuning]: guarded live tuning (restore the previous gains when a change goes bad)."""

    guard: bool = True
    guard_window_s: float = field(default=1.0, metadata=spec(unit="s", gt=0, le=60))
    guard_oscillation_rpm: float = field(default=150.0, metadata=spec(unit="rpm", gt=0, le=20000))
    guard_swings: int = field(default=4, metadata=spec(ge=1, le=1000))
    guard_current_a: float = field(default=3.0, metadata=spec(unit="A", gt=0, le=1000))


@dataclass(frozen=True)
class SessionOptions:
    """How a session runs (the [run], [link] and [protection] tables of a bench config)."""

    period_us: int = 50
    mode: Literal["lockstep", "realtime", "monitor"] = "lockstep"
    duration_s: float | None = None  # None: until the scenario's end event
    actuation_delay_periods: int = 0
    timeout_s: float = 0.5
    watchdog_ms: int = 100
    overrun_policy: Literal["continue", "abort"] = "continue"
    max_consecutive_overruns: int = 10
    cpu_latency_qos: bool = True  # real time: keep idle CPUs from halting (clock.CpuLatencyRequest)
    predict_duties: bool = True  # lockstep, periods of >= 2 PWM periods: HostHello mode PREDICT when the target has it
    seed: int = 0
    observe_every_periods: int = 400
    history_every_periods: int = 20
    overspeed_rpm: float = 0.0  # bench limit ([protection] overspeed_rpm): the run ends with a fault; 0: none
    bus_capacitance_f: float = 0.0  # the bus capacitor regeneration charges ([protection]); 0: a stiff bus
    overvoltage_v: float = 0.0  # bench limit on the bus voltage; 0: none


def _target_options_type(built: Any) -> type | None:
    """[target]'s dataclass: the options of the target [link] names."""
    return target_profile(built.get("link")).options_type


def _target_owner(keys: frozenset[str]) -> str | None:
    """Which other known target's [target] options these keys are (a config written for it)."""
    import dataclasses as dc

    from hilbench.targets.registry import get_profile, known_targets

    owners = []
    for name in known_targets():
        try:
            options = get_profile(name).options_type
        except ConfigError:
            continue
        if options is not None and dc.is_dataclass(options) and keys <= {f.name for f in dc.fields(options)}:
            owners.append(name)
    if not owners:
        return None
    return (f"these are the {' or '.join(owners)} target's options: this [target] table belongs to "
            f"{owners[0]} (run it with its own target, or drop the table for this one)")


#: every table of a bench config: the plant's and the bench's (an explicit registry)
SECTIONS = (
    PLANT_SECTIONS
    .with_table("tuning", TuningSection)
    .with_table("run", RunSection)
    .with_table("link", LinkSection)
    .with_table("target", None, chooser=_target_options_type, needs=("link",), chosen_by=("link.target",),
                explain=_target_owner)
    .with_table("scenario", ScenarioEntry, many=True)
    .with_table("check", CheckEntry, many=True)  # pass/fail criteria of a run (hilbench.bench.checks)
)


def load_config(path: str | Path | None = None, overrides: Sequence[str | Override] = (), *,
                scenario_path: str | Path | None = None) -> BenchConfig:
    """A bench config: a file (None: the packaged default) with its `extends` chain, `overrides`
    ("table.key=value") and a scenario file, validated as a whole (hilbench.config.load_config
    with `SECTIONS`)."""
    return _load_tables(path, overrides, sections=SECTIONS, scenario_path=scenario_path)


def session_options(cfg: BenchConfig) -> SessionOptions:
    """SessionOptions from the [run] and [link] tables."""
    run, link = cfg.run, cfg.link
    return SessionOptions(
        period_us=link.period_us,
        mode=run.mode,
        duration_s=run.duration_s,
        actuation_delay_periods=link.actuation_delay_periods,
        timeout_s=link.timeout_ms / 1000.0,
        watchdog_ms=link.watchdog_ms,
        overrun_policy=link.overrun_policy,
        max_consecutive_overruns=link.max_consecutive_overruns,
        cpu_latency_qos=link.cpu_latency_qos,
        predict_duties=link.predict_duties,
        seed=effective_seed(cfg),
        overspeed_rpm=cfg.protection.overspeed_rpm,
        bus_capacitance_f=cfg.protection.bus_capacitance_f,
        overvoltage_v=cfg.protection.overvoltage_v,
    )


def effective_seed(cfg: BenchConfig) -> int:
    """[run] seed when given, else [plant] seed."""
    return cfg.run.seed if cfg.run.seed is not None else cfg.plant.seed


def guard_settings(cfg: BenchConfig) -> GuardSettings:
    """GuardSettings from the [tuning] table."""
    t = cfg.tuning
    return GuardSettings(t.guard, t.guard_window_s, t.guard_oscillation_rpm, t.guard_swings, t.guard_current_a)


def target_name(spec_text: str) -> str | None:
    """The registered target a spec names (`inprocess:NAME`, `emulator:NAME`, `sil:NAME`), else None."""
    from hilbench.link.spec import parse_target_spec

    return parse_target_spec(spec_text).name or None


def target_profile(link: "LinkSection | None") -> TargetProfile:
    """The profile of the configured target: named by the spec, by [link] firmware for a port,
    else the default target's."""
    spec_text = link.target if link is not None else DEFAULT_TARGET
    name = target_name(spec_text) or (link.firmware if link is not None else None) or target_name(DEFAULT_TARGET)
    assert name is not None
    try:
        return get_profile(name)
    except ConfigError as exc:
        raise ConfigError(f"[link] target {spec_text!r}: {exc}") from None


def configured_target_profile(cfg: BenchConfig) -> TargetProfile:
    """The configured target's profile as its `[target]` options build it (a firmware built for
    another motor reads its pot and telemetry with other scales)."""
    return target_profile(cfg.link).configured(cfg.target)


def params_file_overrides(path: str) -> tuple[Override, ...]:
    """`--gains-file FILE`: the values of a saved fragment's [target] table as overrides."""
    from hilbench.limits import CONFIG_MAX_BYTES, read_text_bounded

    data = parse_toml(read_text_bounded(path, CONFIG_MAX_BYTES, ConfigError, path), path)
    table = data.get("target")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{path}: no [target] table with parameters (write one with `hilbench ctl save`)")
    return tuple(Override(f"target.{k}={_toml_value(v)}", path) for k, v in table.items())


def _toml_value(value: object) -> str:
    """A value read from TOML written back as TOML (`repr` wrote True for true: a string to the loader)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return json.dumps(str(value))  # a string (TOML's basic strings take JSON's escapes)


def scenario_events(cfg: BenchConfig) -> tuple[Event, ...]:
    """The config's scenario, or the default bench scenario when it has none."""
    entries = cfg.scenario
    if not entries:
        return default_scenario()
    return tuple(sorted((e.to_event() for e in entries), key=lambda e: e.at_s))


def link_warnings(cfg: BenchConfig) -> list[str]:
    """What a user should know about the configured link before a run starts."""
    from hilbench.link.spec import parse_target_spec

    spec = parse_target_spec(cfg.link.target)
    out = []
    if cfg.run.mode == "realtime" and spec.port_kind == "url" and not spec.port.startswith("loop://"):
        out.append(f"real time over {spec.port.split('://')[0]}:// : the network's latency and jitter add to the "
                   f"loop's ({cfg.link.period_us} us periods); check the summary's RTT and overruns")
    return out


def check_motor_build(cfg: BenchConfig, profile: TargetProfile) -> None:
    """Refuse a plant the firmware is not built for: a firmware's speed scale follows from the pole
    pairs it was built for, so a motor with others runs at the ratio of its reference. A profile
    that states no build is not checked; [link] allow_pole_pair_mismatch = true runs it anyway."""
    build = profile.built_for(cfg.target)
    if build is None or cfg.link.allow_pole_pair_mismatch:
        return
    if build.pole_pairs != cfg.motor.pole_pairs:
        raise ConfigError(
            f"{cfg.source} [motor] pole_pairs: the plant has {cfg.motor.pole_pairs} pole pairs, the {profile.name} "
            f"firmware is built for {build.pole_pairs} (set the firmware's, or [link] allow_pole_pair_mismatch = true)")


def initial_params(cfg: BenchConfig) -> dict[str, float]:
    """Parameters the [target] table asks to write after the handshake (the rest keep the firmware's)."""
    return target_profile(cfg.link).initial_params(cfg.target)


def config_metadata(cfg: BenchConfig) -> dict[str, Any]:
    """The validated config as plain data, for a recording's metadata."""
    import dataclasses

    def plain(obj: Any) -> Any:
        if dataclasses.is_dataclass(obj):
            return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
        if isinstance(obj, tuple):
            return [plain(x) for x in obj]
        return obj

    return {name: plain(value) for name, value in cfg.sections.items()}
