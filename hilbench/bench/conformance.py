"""The conformance suite: what every target must do on the wire, checked on any target spec.

    hilbench conformance sil:firmware/tiny
    hilbench conformance serial:/dev/ttyUSB0?baud=250000 --json
    pytest --pyargs hilbench.testing.conformance --hil-target simavr:firmware/tiny   (marker hil_conformance)

The promises (firmware_protocol/PROTOCOL.md; the runtime keeps them for every firmware on it, the
Python target kit and `serve` for the in-process and emulator targets):

- handshake: a TargetHello with this host's protocol version and schema fingerprint (its
  fingerprint is what the firmware was built from); a HostHello of another schema gets
  ErrorReport(VERSION) naming the firmware's fingerprint and no TargetHello; a second HostHello
  starts a new session;
- self-description: TargetInfo and one TelemetryInfo per telemetry slot with the HELLO's ids (or,
  from a target that does not describe itself, ErrorReport BAD_REQUEST); a slot past the last:
  UNKNOWN_TELEMETRY;
- parameters: ParamInfo for every declared id and UNKNOWN_PARAM past them; ParamGet OK with a value
  in range, UNKNOWN_ID past them; ParamSet: OK, OUT_OF_RANGE, UNKNOWN_ID, READ_ONLY (when a
  parameter is read-only), BAD_REQUEST for an id twice and for no pairs, each naming the parameter,
  and all or nothing (a refused set changes no value);
- a repeated Sensors (the same seq again, as a host sends after losing a Drive) is answered with the
  same Drive and not acted on: the firmware steps once;
- Stop turns the outputs off; Start runs the firmware again;
- the watchdog: with one agreed, a host that goes silent gets one Drive with the outputs off and
  fault WATCHDOG (real time: after watchdog_ms; lockstep: after at least 1 s), counted in Status;
- bad frames (bad check bytes, bad COBS, a wrong length, garbage, a frame of an unknown type) are
  counted in Status and never acted on: no reply, no parameter changed, the next good request
  answered.

What the protocol lets a build leave out and refuse (real time, refused at the HELLO with BAD_REQUEST;
ParamDescribe, refused with BAD_REQUEST and its type as the detail, by a build without its
self-description) is reported "not served", not a failure; the parameter checks then run with the
declaration the host's RemoteTarget.describe gives (the registered model of the same build).
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterator

from hilbench.errors import ConfigError, HilbenchError, LinkTimeout
from hilbench.targets.remote import settle
from hilbench.protocol import (
    ACCESS_RO,
    ACCESS_RW,
    FAULT_WATCHDOG,
    MODE_LOCKSTEP,
    MODE_REALTIME,
    OUTPUT_OFF,
    PROTOCOL_VERSION,
    RESULT_BAD_REQUEST,
    RESULT_OK,
    RESULT_OUT_OF_RANGE,
    RESULT_READ_ONLY,
    RESULT_UNKNOWN_ID,
    SCHEMA_FINGERPRINT,
    Drive,
    ErrorCode,
    ErrorReport,
    hello_problem,
    HostHello,
    ParamDescribe,
    ParamGet,
    ParamInfo,
    ParamSet,
    ParamSetResult,
    ParamValue,
    Sensors,
    Start,
    Status,
    StatusRequest,
    Stop,
    TargetDescribe,
    TargetHello,
    TargetInfo,
    TelemetryDescribe,
    TelemetryInfo,
    encode_frame,
)

REPLY_S = 2.0  # how long a check waits for an answer (a simulated MCU on a loaded machine is slow)
SILENCE_S = 0.3  # how long "no answer" is waited for
RETRY_S = 0.25  # an unanswered request is sent again after this long (the host's link.retry_ms)


@dataclass
class CheckResult:
    name: str
    ok: bool | None  # None: not applicable to this target (skipped, or not served, with the reason)
    detail: str
    served: bool = True  # False: the target refuses what the check needs as the protocol says (NotServed)

    @property
    def status(self) -> str:
        if not self.served:
            return "not served"
        return "skip" if self.ok is None else ("PASS" if self.ok else "FAIL")


class ConformanceFailure(AssertionError):
    pass


class NotServed(Exception):
    """The target refuses an optional capability the check needs, as the protocol says it may (a build
    without real time or without its self-description, firmware_protocol/PROTOCOL.md): no failure."""


def _require(cond: bool, what: str) -> None:
    if not cond:
        raise ConformanceFailure(what)


class Wire:
    """Frames to and from a target over its link: each request with its own seq, the answer with it."""

    def __init__(self, link: Any, period_us: int) -> None:
        self.link = link
        self.period_us = period_us
        self.seq = 0
        self.hello: TargetHello | None = None
        self.k = 0  # the next period's number
        #: a fresh target of the same spec, for the checks that compare with one (None: a port)
        self.fresh: Callable[[], "FreshWire"] | None = None
        self.simulated = False  # an MCU in a simulator (simavr:, qemu:): its time is not the wall's
        self.resent = 0  # requests sent again for want of an answer (ask)

    def next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFF
        return self.seq

    def drain(self, quiet_s: float = 0.05) -> list[Any]:
        got = []
        while True:
            msg = self.link.recv_or_none(quiet_s)
            if msg is None:
                return got
            got.append(msg)

    def ask(self, msg: Any, kinds: tuple[type, ...], timeout_s: float = REPLY_S) -> Any:
        """Send ``msg``; the first frame of ``kinds`` with its seq (others are skipped). Unanswered, it
        is sent again every RETRY_S with the same seq, as a host does (a simulated MCU busy with the
        last request may miss a frame; the same seq again is answered once, never acted on twice)."""
        self.link.send(msg)
        start = time.monotonic()
        deadline, resend_at = start + timeout_s, start + RETRY_S
        while True:
            now = time.monotonic()
            if now >= deadline:
                raise ConformanceFailure(f"no {'/'.join(k.__name__ for k in kinds)} for {type(msg).__name__} "
                                         f"within {timeout_s:.1f} s ({self.resent} frames sent again so far)")
            if now >= resend_at:
                self.resent += 1
                self.link.send(msg)
                resend_at = now + RETRY_S
            reply = self.link.recv_or_none(min(deadline, resend_at) - now)
            if reply is not None and type(reply) in kinds and reply.seq == msg.seq:
                return reply

    def silence(self, quiet_s: float = SILENCE_S) -> list[Any]:
        """Every frame that arrives within ``quiet_s`` (a check that wants none)."""
        got = []
        deadline = time.monotonic() + quiet_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.link.recv_or_none(remaining)
            if msg is not None:
                got.append(msg)
        return got

    def handshake(self, mode: int = MODE_LOCKSTEP, watchdog_ms: int = 0) -> TargetHello:
        """A new session; NotServed when a mode other than lockstep (which every target serves) is
        refused with BAD_REQUEST."""
        reply = self.ask(HostHello(self.next_seq(), PROTOCOL_VERSION, self.period_us, mode, watchdog_ms),
                         (TargetHello, ErrorReport))
        if mode != MODE_LOCKSTEP and type(reply) is ErrorReport and reply.code == ErrorCode.BAD_REQUEST:
            raise NotServed(f"HostHello mode {mode} refused (BAD_REQUEST, detail {reply.detail}): a build without it")
        if watchdog_ms == 0 and type(reply) is ErrorReport and reply.code == ErrorCode.BAD_REQUEST:  # (the period)
            raise ConfigError(f"conformance --period-us {self.period_us}: the target refuses that period (HostHello "
                              f"answered BAD_REQUEST, detail {reply.detail}); give a multiple of its PWM period")
        _require(isinstance(reply, TargetHello), f"HostHello answered {reply}")
        self.hello = reply
        self.k = 0
        self.link.reset_sequence()
        return reply

    def sensors(self, seq: int | None = None, inputs: int = 0) -> Sensors:
        hello = self.hello
        n_adc = len(hello.adc_roles) if hello is not None else 0
        mid = (1 << max(hello.adc_bits - 1, 0)) if hello is not None else 512
        k = self.k if seq is None else seq
        if seq is None:
            self.k += 1
        return Sensors(k & 0xFF, inputs, (), 0, (mid,) * n_adc)

    def period(self, inputs: int = 0) -> Drive:
        s = self.sensors(inputs=inputs)
        return self.ask(s, (Drive,))

    def status(self) -> Status:
        return self.ask(StatusRequest(self.next_seq()), (Status,))

    def command(self, kind: type[Start] | type[Stop]) -> None:
        """Start or Stop once nothing waits in the target's receiver (`settle`; a probe that fails
        fails the check)."""
        settle(lambda: self.resent, self.status)
        self.link.send(kind(self.next_seq()))


# ------------------------------------------------------------------------------------- the checks

def check_handshake(w: Wire) -> str:
    hello = w.handshake()
    _require(hello.protocol_version == PROTOCOL_VERSION, f"protocol version {hello.protocol_version}")
    _require(hello.schema_fingerprint == SCHEMA_FINGERPRINT,
             f"schema fingerprint {hello.schema_fingerprint:#010x}, this host {SCHEMA_FINGERPRINT:#010x}")
    problem = hello_problem(hello)
    _require(problem is None, f"the TargetHello declares {problem}: {hello}")
    other = HostHello(w.next_seq(), PROTOCOL_VERSION, w.period_us, MODE_LOCKSTEP, 0, SCHEMA_FINGERPRINT ^ 0x5A5A5A5A)
    refusal = w.ask(other, (TargetHello, ErrorReport))
    _require(type(refusal) is ErrorReport and refusal.code == ErrorCode.VERSION,
             f"a HostHello of another schema answered {refusal}")
    _require(refusal.schema_fingerprint == SCHEMA_FINGERPRINT, "the refusal names another fingerprint")
    again = w.handshake()
    _require(again == hello._replace(seq=again.seq), "a second HostHello gave another TargetHello")
    return (f"{hello.firmware_name} version {hello.firmware_version:#06x}, protocol {hello.protocol_version}, "
            f"schema {hello.schema_fingerprint:#010x}; another schema refused with VERSION")


def check_self_description(w: Wire) -> str:
    hello = w.handshake()
    info = w.ask(TargetDescribe(w.next_seq()), (TargetInfo, ErrorReport))
    if type(info) is ErrorReport:
        _require(_refused_optional(info, TargetDescribe), f"TargetDescribe answered {info}")
        return "does not describe itself (ErrorReport BAD_REQUEST): served from its HELLO"
    _require(info.duty_timing in (0, 1, 2) and info.duty_report in (0, 1), f"TargetInfo {info}")
    _require(1 <= info.max_edges <= 16, f"TargetInfo.max_edges {info.max_edges}")
    names = []
    for index, tid in enumerate(hello.telemetry_ids):
        t = w.ask(TelemetryDescribe(w.next_seq(), index), (TelemetryInfo, ErrorReport))
        _require(type(t) is TelemetryInfo, f"TelemetryDescribe {index} answered {t}")
        _require(t.index == index and t.telemetry_id == tid and t.scale_den > 0 and t.name,
                 f"TelemetryInfo {index}: {t} (HELLO id {tid})")
        names.append(f"{t.name}[{t.unit}]" if t.unit else t.name)
    past = w.ask(TelemetryDescribe(w.next_seq(), len(hello.telemetry_ids)), (TelemetryInfo, ErrorReport))
    _require(type(past) is ErrorReport and past.code == ErrorCode.UNKNOWN_TELEMETRY,
             f"TelemetryDescribe past the last slot answered {past}")
    return f"TargetInfo {tuple(info)[1:]}; telemetry {', '.join(names) or 'none'}"


def _refused_optional(reply: Any, request: type) -> bool:
    """Whether ``reply`` is the protocol's refusal of a request the target does not serve: ErrorReport
    BAD_REQUEST whose detail is the request's type (a wrong detail fails the check)."""
    if type(reply) is not ErrorReport or reply.code != ErrorCode.BAD_REQUEST:
        return False
    _require(reply.detail == request.TYPE,
             f"{request.__name__} refused with detail {reply.detail:#04x}, not its type {request.TYPE:#04x}")
    return True


def _params(w: Wire) -> tuple[list[ParamInfo], bool]:
    """Every declared parameter's ParamInfo and whether the target gave them itself: a build without
    its self-description refuses ParamDescribe, and the declaration is then the one the host's
    RemoteTarget.describe gives (the registered model of the same build, the target's values)."""
    hello = w.hello or w.handshake()
    out = []
    for pid in range(hello.n_params):
        p = w.ask(ParamDescribe(w.next_seq(), pid), (ParamInfo, ErrorReport))
        if pid == 0 and _refused_optional(p, ParamDescribe):
            return _declared_by_host(w), False
        _require(type(p) is ParamInfo and p.param_id == pid, f"ParamDescribe {pid} answered {p}")
        out.append(p)
    return out, True


def _declared_by_host(w: Wire) -> list[ParamInfo]:
    """RemoteTarget.describe for every id, in a session of its own (the Wire's next one starts afresh)."""
    from hilbench.targets.remote import RemoteTarget

    remote = RemoteTarget(w.link, timeout_s=REPLY_S, retry_s=RETRY_S)
    w.hello, w.k = remote.handshake(w.period_us), 0
    return [remote.describe(pid) for pid in range(w.hello.n_params)]


def check_param_describe_get(w: Wire) -> str:
    w.handshake()
    params, own = _params(w)
    n = len(params)
    if own:
        past = w.ask(ParamDescribe(w.next_seq(), n), (ParamInfo, ErrorReport))
        _require(type(past) is ErrorReport and past.code == ErrorCode.UNKNOWN_PARAM and past.detail == n,
                 f"ParamDescribe {n} (past the last) answered {past}")
    for p in params:
        _require(p.min_value <= p.max_value and p.access in (ACCESS_RO, ACCESS_RW), f"ParamInfo {p}")
        v = w.ask(ParamGet(w.next_seq(), p.param_id), (ParamValue, ErrorReport))
        _require(type(v) is ParamValue and v.result == RESULT_OK and v.value == p.value,
                 f"ParamGet {p.param_id} answered {v} (ParamInfo says {p.value})")
        _require(p.min_value <= v.value <= p.max_value, f"{p.name} = {v.value} outside [{p.min_value}, {p.max_value}]")
    past_get = w.ask(ParamGet(w.next_seq(), n), (ParamValue, ErrorReport))
    _require(type(past_get) is ParamValue and past_get.result == RESULT_UNKNOWN_ID, f"ParamGet {n} answered {past_get}")
    what = f"{n} parameters: " + ", ".join(f"{p.name}{f' [{p.unit}]' if p.unit else ''}" for p in params)
    if not own:
        raise NotServed(f"ParamDescribe refused (BAD_REQUEST); ParamGet checked against the host's model: {what}")
    return what


def _value(w: Wire, pid: int) -> int:
    return w.ask(ParamGet(w.next_seq(), pid), (ParamValue,)).value


def _set(w: Wire, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
    r = w.ask(ParamSet(w.next_seq(), pairs), (ParamSetResult, ErrorReport))
    _require(type(r) is ParamSetResult, f"ParamSet {pairs} answered {r}")
    return r


def check_param_set(w: Wire) -> str:
    w.handshake()
    params, _ = _params(w)
    rw = [p for p in params if p.access == ACCESS_RW]
    ro = [p for p in params if p.access == ACCESS_RO]
    n = len(params)
    seen = []
    before = {p.param_id: _value(w, p.param_id) for p in params}
    r = _set(w, ((n, 0),))
    _require(r.result == RESULT_UNKNOWN_ID and r.param_id == n, f"an unknown id: {r}")
    seen.append("UNKNOWN_ID")
    r = _set(w, ())
    _require(r.result == RESULT_BAD_REQUEST, f"no pairs: {r}")
    seen.append("BAD_REQUEST")
    if ro:
        r = _set(w, ((ro[0].param_id, ro[0].value),))
        _require(r.result == RESULT_READ_ONLY and r.param_id == ro[0].param_id, f"a read-only parameter: {r}")
        seen.append("READ_ONLY")
    if rw:
        p = rw[0]
        r = _set(w, ((p.param_id, before[p.param_id]),))
        _require(r.result == RESULT_OK, f"{p.name} to its own value: {r}")
        seen.append("OK")
        r = _set(w, ((p.param_id, before[p.param_id]), (p.param_id, before[p.param_id])))
        _require(r.result == RESULT_BAD_REQUEST, f"the same id twice: {r}")
        if p.max_value < 0x7FFFFFFF or p.min_value > -0x80000000:
            bad = p.max_value + 1 if p.max_value < 0x7FFFFFFF else p.min_value - 1
            r = _set(w, ((p.param_id, bad),))
            _require(r.result == RESULT_OUT_OF_RANGE and r.param_id == p.param_id, f"{p.name} = {bad}: {r}")
            seen.append("OUT_OF_RANGE")
            # all or nothing: a legal new value for one parameter with an illegal one for another
            other = rw[1] if len(rw) > 1 else None
            if other is not None:
                new = next((v for v in (other.min_value, other.max_value) if v != before[other.param_id]), None)
                if new is not None:
                    r = _set(w, ((other.param_id, new), (p.param_id, bad)))
                    _require(r.result == RESULT_OUT_OF_RANGE, f"a set with one bad pair: {r}")
                    _require(_value(w, other.param_id) == before[other.param_id],
                             f"a refused set changed {other.name}: not all or nothing")
                    seen.append("all-or-nothing")
    after = {p.param_id: _value(w, p.param_id) for p in params}
    _require(after == before, f"values changed by the checks: {before} -> {after}")
    return "results " + ", ".join(seen)


def _stream(w: Wire, repeat_at: int | None) -> list[Drive]:
    """A fresh session's 40 periods after Start, Sensors `repeat_at` sent twice."""
    w.handshake()
    w.command(Start)
    out = []
    for k in range(40):
        s = w.sensors()
        d = w.ask(s, (Drive,))
        if k == repeat_at:
            again = w.ask(s, (Drive,))
            _require(again == d, f"a repeated Sensors seq {s.seq} answered {again}, first {d}")
            _require(w.silence(0.05) == [], "a repeated Sensors answered more than once")
        out.append(d)
    return out


def check_repeated_seq(w: Wire) -> str:
    """The same Sensors twice is answered twice with one Drive and stepped once: on a fresh target a
    stream with a repeat in it gives the Drives of the same stream without it (a second step would
    move the firmware a period on)."""
    repeated = _stream(w, 20)
    if w.fresh is None:
        return "a repeated seq answered once with the same Drive (a port: no fresh target to compare with)"
    first, second = w.fresh(), w.fresh()
    try:
        plain, again = _stream(first, None), _stream(second, None)
    finally:
        first.close()
        second.close()
    if plain != again:
        return "a repeated seq answered once with the same Drive (two fresh targets differ: not compared)"
    _require(repeated == plain, "a repeated Sensors was acted on: the Drives after it differ from a stream without it")
    return "a repeated seq answered once with the same Drive, not stepped (equal to a fresh target's stream)"


def check_stop_start(w: Wire) -> str:
    w.handshake()
    w.command(Start)
    started = None
    for i in range(4000):
        if w.period().output_mode != OUTPUT_OFF:
            started = i
            break
    _require(started is not None, f"outputs still off {4000 * w.period_us / 1000:.0f} ms after Start")
    w.command(Stop)
    off = [w.period() for _ in range(3)]
    _require(all(d.output_mode == OUTPUT_OFF for d in off), f"outputs not off after Stop: {off[-1]}")
    return f"outputs on {started * w.period_us} us after Start, off at the first period after Stop"


def check_stop_disarms_watchdog(w: Wire) -> str:
    """A host that stops the outputs and leaves is no host gone: no watchdog trip after its Stop (a
    trip would leave a FAULT the next session starts in); the next Sensors arms it again."""
    watchdog_ms = 200
    w.handshake(MODE_REALTIME, watchdog_ms)
    trips0 = w.status().watchdog_trips
    w.command(Start)
    for _ in range(20):
        w.period()
    w.command(Stop)
    quiet_s = 3 * watchdog_ms / 1000
    tripped = [m for m in w.silence(quiet_s) if type(m) is Drive and m.fault == FAULT_WATCHDOG]
    _require(not tripped, f"the watchdog tripped after the host's Stop: {tripped[0] if tripped else ''}")
    trips = w.status().watchdog_trips
    _require(trips == trips0, f"Status.watchdog_trips {trips0} -> {trips} after a Stop")
    return f"no trip in {quiet_s * 1000:.0f} ms after a Stop (watchdog {watchdog_ms} ms)"


def check_watchdog(w: Wire, mode: int) -> str:
    watchdog_ms = 200
    w.handshake(mode, watchdog_ms)
    trips0 = w.status().watchdog_trips
    w.command(Start)
    before = [w.period() for _ in range(20)][-1]
    silent_from = time.monotonic()
    limit_s = watchdog_ms / 1000 if mode == MODE_REALTIME else max(watchdog_ms / 1000, 1.0)
    deadline = silent_from + limit_s + 3.0
    got = None
    while (remaining := deadline - time.monotonic()) > 0:
        msg = w.link.recv_or_none(remaining)
        if type(msg) is Drive:
            got = msg
            break
    waited = time.monotonic() - silent_from
    _require(got is not None, f"no watchdog Drive {limit_s + 3.0:.1f} s after the host went silent")
    _require(got.output_mode == OUTPUT_OFF and got.fault == FAULT_WATCHDOG, f"the watchdog Drive {got}")
    if not w.simulated:  # a simulated MCU's clock is the simulator's, not the wall's
        _require(waited >= limit_s * 0.9, f"the watchdog tripped after {waited * 1000:.0f} ms, before {limit_s * 1000:.0f} ms")
    trips = w.status().watchdog_trips
    counted = (trips - trips0) & 0xFFFF
    # A host stalled longer than the watchdog on a loaded machine trips it during the 20 periods
    # too: more than one trip is the watchdog doing its job; none is a trip not counted.
    _require(counted >= 1, f"Status.watchdog_trips {trips0} -> {trips}: the trip was not counted")
    resumed = "" if counted == 1 else f" ({counted - 1} more trip(s) while this host stalled)"
    if mode != MODE_REALTIME:  # lockstep: the firmware was left as it was; the next Sensors gives the outputs back
        after = w.period()
        _require(after.fault != FAULT_WATCHDOG and after.output_mode == before.output_mode,
                 f"lockstep: the period after the trip {after}, before it {before} (the trip changed the firmware)")
        resumed = ", the next Sensors gave them back" + resumed
    w.handshake()  # a new session for the next check
    name = "real time" if mode == MODE_REALTIME else "lockstep"
    return (f"{name}: outputs off, fault WATCHDOG, {waited * 1000:.0f} ms after the last Sensors (limit "
            f"{limit_s * 1000:.0f} ms){resumed}")


def _wire(message: bytes, lengths: tuple[int, int] | None = None) -> bytes:
    """The wire bytes of a message (type . seq . payload), with other lengths when given."""
    from hilbench.protocol.framing import wire_join

    n = len(message) + 6
    first, last = lengths if lengths is not None else (n, n)
    return wire_join((bytes((first,)) + message + bytes((last,))).split(b"\x00"))


def check_bad_frames(w: Wire) -> str:
    from hilbench.protocol.framing import unframe

    w.handshake()
    params, _ = _params(w)
    rw = next((p for p in params if p.access == ACCESS_RW and p.min_value != p.max_value), None)
    before = _value(w, rw.param_id) if rw is not None else None
    status0 = w.status()
    if rw is not None:  # each bad frame would set a parameter if it were acted on
        new = rw.min_value if before != rw.min_value else rw.max_value
        msg: Any = ParamSet(0x77, ((rw.param_id, new),))
    else:
        msg = Stop(0x77)
    wire = encode_frame(msg)
    raw = wire[:-1]
    message = unframe(raw)
    n = len(raw)
    bad = [
        raw[:-2] + bytes((raw[-2] ^ 0x01,)) + raw[-1:] + b"\x00",  # a bit of the check
        _wire(message, (n + 1, n)),                                   # the leading length wrong
        _wire(message, (n, n - 1)),                                   # the trailing length wrong
        bytes((raw[0] ^ 0x01,)) + raw[1:] + b"\x00",                 # the COBS code byte
        raw[:-4] + raw[-3:] + b"\x00",                               # a byte lost
        raw[:4] + raw[3:] + b"\x00",                                 # a byte doubled
        b"\x05\x01\x02\x00",                                         # garbage
    ]
    w.drain()
    for frame in bad:
        w.link.send_bytes(frame)
    answered = w.silence()
    _require(not answered, f"bad frames were answered: {answered}")
    w.link.send_bytes(_wire(bytes((0x7E, 0x78))))  # a good frame of a type the protocol does not have
    answered = w.silence()
    _require(not answered, f"a frame of an unknown type was answered: {answered}")
    status = w.status()
    errors = (status.rx_errors - status0.rx_errors) & 0xFFFF
    _require(errors >= len(bad), f"Status.rx_errors grew by {errors} for {len(bad)} bad frames")
    _require(((status.unknown - status0.unknown) & 0xFFFF) == 1, f"Status.unknown {status0.unknown} -> {status.unknown}")
    if rw is not None:
        _require(_value(w, rw.param_id) == before, f"a bad ParamSet frame changed {rw.name}")
    return f"{len(bad)} bad frames counted ({errors} rx errors), 1 unknown type counted, none answered or acted on"


CHECKS: tuple[tuple[str, Callable[[Wire], str]], ...] = (
    ("handshake", check_handshake),
    ("self-description", check_self_description),
    ("parameters: describe and get", check_param_describe_get),
    ("parameters: set, all or nothing", check_param_set),
    ("repeated seq answered once", check_repeated_seq),
    ("stop and start", check_stop_start),
    ("watchdog (lockstep)", lambda w: check_watchdog(w, MODE_LOCKSTEP)),
    ("watchdog (real time)", lambda w: check_watchdog(w, MODE_REALTIME)),
    ("bad frames counted, never acted on", check_bad_frames),
)


# ------------------------------------------------------------------------------------- running them

class FreshWire(Wire):
    """A Wire on its own Connection (closed with it)."""

    conn: "Connection"

    def close(self) -> None:
        self.conn.close()


class Connection:
    """A target spec as a link to talk frames on: a process or a port as it is; an in-process target
    served over a pty pair by `serve` in a thread (the kit's answers, as an emulator gives them)."""

    def __init__(self, spec: str, period_us: int = 50) -> None:
        from hilbench.bench.launcher import open_target

        self.spec = spec
        self.handle = open_target(spec, timeout_s=REPLY_S, mode="any", watchdog_ms=None)  # as each HostHello asks
        self.thread: threading.Thread | None = None
        self.stop_event: threading.Event | None = None
        self.far = None
        if self.handle.link is None:
            from hilbench.link import open_link
            from hilbench.targets.serve import serve

            host = open_link("pty", timeout_s=REPLY_S)
            self.far = open_link(host.peer_path, timeout_s=REPLY_S)
            self.stop_event = threading.Event()
            self.thread = threading.Thread(target=serve, args=(self.handle.target, self.far),
                                           kwargs={"stop_event": self.stop_event}, daemon=True)
            self.thread.start()
            self.link = host
        else:
            self.link = self.handle.link
        self.wire = Wire(self.link, period_us)
        self.wire.simulated = simulated(spec)
        if spawnable(spec):
            self.wire.fresh = lambda: self.fresh_wire(period_us)

    def fresh_wire(self, period_us: int) -> FreshWire:
        conn = Connection(self.spec, period_us)
        wire = FreshWire(conn.link, period_us)
        wire.conn = conn
        wire.simulated = conn.wire.simulated
        return wire

    def close(self) -> None:
        if self.thread is not None:
            assert self.stop_event is not None
            self.stop_event.set()
            self.link.close()
            self.thread.join(timeout=5)
            if self.far is not None:
                self.far.close()
        self.handle.close()


def spawnable(spec: str) -> bool:
    """Whether opening ``spec`` makes a fresh target (a model or a started process, not a port)."""
    from hilbench.link import parse_target_spec
    from hilbench.targets.starters import FIRMWARE_KINDS

    return parse_target_spec(spec).kind in ("inprocess", "emulator", *FIRMWARE_KINDS)


def simulated(spec: str) -> bool:
    from hilbench.link import parse_target_spec

    return parse_target_spec(spec).kind in ("simavr", "qemu")


def run_checks(spec: str, *, period_us: int = 50, only: tuple[str, ...] = ()) -> list[CheckResult]:
    """Every check on ``spec`` (or those whose names contain one of ``only``), one connection."""
    _check_only(only)
    conn = Connection(spec, period_us)
    results = []
    try:
        for name, check in CHECKS:
            if only and not any(o in name for o in only):
                continue
            try:
                conn.wire.drain()
                results.append(CheckResult(name, True, check(conn.wire)))
            except NotServed as exc:
                results.append(CheckResult(name, None, f"not served: {exc}", served=False))
            except ConformanceFailure as exc:
                results.append(CheckResult(name, False, str(exc)))
            except ConfigError:  # what was asked for, not the target, is wrong: no check can say more
                raise
            except (HilbenchError, LinkTimeout) as exc:
                results.append(CheckResult(name, False, f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()
    return results


def _check_only(only: tuple[str, ...]) -> None:
    """Refuse an ``only`` that names no check, before connecting: a typo would run nothing and pass."""
    names = [name for name, _ in CHECKS]
    unknown = [o for o in only if not any(o in name for name in names)]
    if unknown:
        raise ConfigError(f"conformance --only {', '.join(map(repr, unknown))}: no check's name contains it; "
                          f"the checks: {', '.join(map(repr, names))}")


def iter_check_names() -> Iterator[str]:
    return (name for name, _ in CHECKS)


def as_dicts(results: list[CheckResult]) -> list[dict[str, Any]]:
    return [dict(asdict(r), status=r.status) for r in results]


__all__ = ["CHECKS", "CheckResult", "Connection", "FreshWire", "spawnable", "ConformanceFailure", "NotServed", "Wire",
           "as_dicts", "iter_check_names", "run_checks"]
