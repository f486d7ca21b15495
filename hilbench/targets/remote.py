"""RemoteTarget: the Target interface over a link, for a board or an emulator process.

Requests carry their own sequence number and wait for the answer with the same seq; frames that
arrive meanwhile (a late Drive, a stray reply) are counted and skipped. step() is the bench's
hot path: one send, one receive, one type-and-seq check.
"""

from __future__ import annotations

import time
from types import MethodType
from typing import TYPE_CHECKING, Any, Callable

from hilbench.errors import HilbenchError, LinkTimeout, ParamError, TargetError, VersionMismatch
from hilbench.protocol import (
    MODE_LOCKSTEP,
    BatchDigest,
    SensorsBatch,
    PROTOCOL_VERSION,
    RESULT_OK,
    Drive,
    ErrorCode,
    ErrorReport,
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
    version_refusal,
)

from hilbench.link.link import Link

try:  # step in C for the session's C span (optional, built with the C cores)
    from hilbench.targets import _remotestep
except ImportError:  # pragma: no cover - no compiler at install time
    _remotestep = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from hilbench.link import FaultyLink


#: the TargetHello fields that must equal the registered model's before it may describe a target's parameters
_SAME_BUILD = ("firmware_version", "n_params", "telemetry_ids", "adc_roles", "pwm_period_counts")


def _field(hello: TargetHello, name: str) -> Any:
    """A TargetHello field as compared: a sequence as a tuple (a model may build its hello with lists)."""
    value = getattr(hello, name)
    return tuple(value) if isinstance(value, (list, tuple)) else value


def _error_name(code: int) -> str:
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"code {code}"


#: at most this many StatusRequests before a command, waiting for one answered without a resend
SETTLE_PROBES = 4


def settle(resends: Callable[[], int], probe: Callable[[], object]) -> None:
    """Before a command without a reply (Start, Stop): the target's receiver drops whole a frame that
    arrives while it still handles the previous one (Status.overruns), and a lost Start or Stop is
    seen nowhere. A frame may still be in hand there: a resent request's twin, a batch's, a Sensors
    whose exchange a Ctrl-C cut short. So ``probe`` (a StatusRequest) until one is answered without
    a resend: every frame sent before it was then handled or dropped, and nothing waits. After
    SETTLE_PROBES the command goes anyway (a target this slow gets it best-effort, as before). A probe
    after the command would not do: it is the frame dropped behind a command still in hand, and in
    monitor mode a frame after a Stop arms the watchdog again."""
    for _ in range(SETTLE_PROBES):
        before = resends()
        probe()
        if resends() == before:
            return


class RemoteTarget:
    """A target on the far end of a link, seen through the Target interface."""

    def __init__(self, link: "Link | FaultyLink", *, timeout_s: float = 1.0, retry_s: float = 0.1,
                 protocol_version: int = PROTOCOL_VERSION) -> None:
        """``retry_s``: send a frame again after this long without its answer (a lost frame on a
        noisy line then costs one retry, not the run); a repeated Sensors is answered by the target
        with its last Drive, not acted on twice (the protocol's rule), so a retry is safe."""
        self.link = link
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.protocol_version = protocol_version
        self.firmware_name = ""
        self.target_hello: TargetHello | None = None
        self.stale_frames = 0
        self.error_reports = 0
        self.last_error_report: ErrorReport | None = None
        self.watchdog_ms = 0
        self.retries = 0  # frames sent again after no answer within retry_s (a lost frame either way)
        self._req_seq = 0
        #: where frames that answer nothing go instead of being counted as stale (None: counted)
        self.stray_sink: Callable[[Any], None] | None = None
        #: the in-process model that describes the parameters of a build that does not (None: not needed yet)
        self._describer: Any = None
        self._period_us = 0  # the agreed period (the model's HELLO asks for the same)
        self._send = link.send
        self._recv = link.recv

    # -- plumbing ------------------------------------------------------------------------
    def _next_seq(self) -> int:
        self._req_seq = (self._req_seq + 1) & 0xFF
        return self._req_seq

    def _request(self, msg: Any, reply_type: type, timeout_s: float | None = None) -> Any:
        """Send msg and wait for reply_type (or an ErrorReport) with msg's seq; requests are
        idempotent, so asking again after retry_s is safe."""
        self._send(msg)
        timeout = self.timeout_s if timeout_s is None else timeout_s
        reply = self._await(msg, (reply_type, ErrorReport), time.monotonic(), timeout,
                            f"no {reply_type.__name__} for {type(msg).__name__}")
        if type(reply) is ErrorReport:
            self._note_stray(reply)  # (counted and kept as the last one, like any ErrorReport)
        return reply

    def _await(self, msg: Any, kinds: tuple[type, ...], start: float, timeout_s: float, what: str) -> Any:
        """The answer to ``msg`` sent at ``start``: a frame of one of ``kinds`` with its seq. Strays
        are counted and skipped; ``msg`` is sent again every retry_s (a lost frame either way);
        LinkTimeout after ``timeout_s``."""
        deadline = start + timeout_s
        resend_at = start + self.retry_s
        while True:
            now = time.monotonic()
            if now >= deadline:
                raise LinkTimeout(f"link {self.link.name}: {what} within {timeout_s * 1000:.0f} ms "
                                  f"({self.retries} retries so far)")
            if now >= resend_at:
                self.retries += 1
                self._send(msg)
                resend_at = now + self.retry_s
            reply = self.link.recv_or_none(min(deadline - now, max(resend_at - now, 1e-4)))
            if reply is None:
                continue
            if type(reply) in kinds and reply.seq == msg.seq:
                return reply
            self._note_stray(reply)

    def gate_sends(self, before: Callable[[Any], None] | None) -> None:
        """Monitor mode: ``before(msg)`` runs ahead of every frame this target sends (a board that
        holds one received frame loses a second one sent too soon); None: frames go straight out."""
        link = self.link
        if before is None:
            self._send = link.send
            return

        def send(msg: Any) -> None:
            before(msg)
            link.send(msg)

        self._send = send

    def _note_stray(self, reply: Any) -> None:
        if self.stray_sink is not None and type(reply) is not ErrorReport:
            self.stray_sink(reply)  # monitor mode: the Drives streamed while a request waits its answer
            return
        if type(reply) is ErrorReport:
            self.error_reports += 1
            self.last_error_report = reply
        else:
            self.stale_frames += 1

    def _refused(self, what: str, report: ErrorReport) -> TargetError:
        return TargetError(
            f"link {self.link.name}: target refused {what}: {_error_name(report.code)} (detail {report.detail})"
        )

    # -- handshake -----------------------------------------------------------------------
    def handshake(self, period_us: int, mode: int = MODE_LOCKSTEP, watchdog_ms: int = 0, *,
                  attempts: int = 3) -> TargetHello:
        """HostHello -> TargetHello; VersionMismatch naming both versions when they differ.

        Retries on silence (a board may still be booting, a fresh tty may have flushed input).
        """
        last: LinkTimeout | None = None
        for _ in range(max(1, attempts)):
            host = HostHello(self._next_seq(), self.protocol_version, period_us, mode, watchdog_ms)
            try:
                return self.hello(host)
            except LinkTimeout as exc:
                last = exc
        assert last is not None
        raise LinkTimeout(f"{last} (after {attempts} HostHello attempts)")

    def hello(self, host: HostHello) -> TargetHello:
        reply = self._request(host, TargetHello)
        if type(reply) is ErrorReport:
            if reply.code == ErrorCode.VERSION:  # both fingerprints and versions, one line
                raise version_refusal(reply, host, where=f"target {self.link.name}")
            raise self._refused(f"HostHello (period {host.period_us} us, mode {host.mode})", reply)
        if reply.protocol_version != host.protocol_version:
            raise VersionMismatch(
                f"link {self.link.name}: host speaks protocol version {host.protocol_version}, "
                f"target {reply.firmware_name!r} speaks version {reply.protocol_version}"
            )
        self.target_hello = reply
        self.watchdog_ms = host.watchdog_ms
        self.firmware_name = reply.firmware_name
        self._period_us = host.period_us
        self._describer = None
        self.link.reset_sequence()
        return reply

    # -- self-description (protocol 3) --------------------------------------------------------
    def describe_target(self) -> TargetInfo | None:
        """The target's TargetInfo (duty timing, the inputs it reads, its encoder, the edges a Sensors
        may carry); None when it answers with an ErrorReport (a target that does not describe itself)."""
        reply = self._request(TargetDescribe(self._next_seq()), TargetInfo)
        return None if type(reply) is ErrorReport else reply

    def describe_telemetry(self, index: int) -> TelemetryInfo:
        """Telemetry slot ``index`` of Drive: name, unit, scale (TargetError when it has none)."""
        reply = self._request(TelemetryDescribe(self._next_seq(), index), TelemetryInfo)
        if type(reply) is ErrorReport:
            raise self._refused(f"TelemetryDescribe {index}", reply)
        return reply

    # -- parameters ----------------------------------------------------------------------
    def describe(self, param_id: int) -> ParamInfo:
        reply = self._request(ParamDescribe(self._next_seq(), param_id), ParamInfo)
        if type(reply) is ErrorReport:
            if reply.code == ErrorCode.UNKNOWN_PARAM:
                raise ParamError(f"link {self.link.name}: target {self.firmware_name!r} has no param id {param_id}")
            if reply.code == ErrorCode.BAD_REQUEST:
                return self._described_by_profile(param_id)
            raise self._refused(f"ParamDescribe {param_id}", reply)
        return reply

    def _described_by_profile(self, param_id: int) -> ParamInfo:
        """A build without its self-description (HRT_DESCRIBE 0: the dsPIC30F2010's, which has no flash
        for it, docs/board.md "Does it fit") refuses ParamDescribe: the registered profile's in-process
        model of the same build declares the same parameters, and the target's own ParamGet gives the
        value."""
        if self._describer is None:
            self._describer = self._profile_model()
        if param_id >= (self.target_hello.n_params if self.target_hello is not None else 0):
            raise ParamError(f"link {self.link.name}: target {self.firmware_name!r} has no param id {param_id}")
        value = self.get_param(param_id)
        if value.result != RESULT_OK:
            raise ParamError(f"link {self.link.name}: target {self.firmware_name!r} answers ParamGet {param_id} "
                             f"with result {value.result}")
        return self._describer.describe(param_id)._replace(seq=value.seq, value=value.value)

    def _profile_model(self) -> Any:
        """The registered profile's model, only if its own TargetHello declares what the target's does:
        a name alone is a guess, and nothing acts on a board by guess (another version or fork of the
        firmware may number or bound its parameters otherwise)."""
        from hilbench.targets.registry import registered_for_firmware

        mine = self.target_hello
        profile = registered_for_firmware(self.firmware_name) if mine is not None else None
        if profile is None or mine is None:  # (mine for the type checker: no profile without it)
            raise TargetError(f"link {self.link.name}: target {self.firmware_name!r} does not describe its "
                              "parameters (built without HRT_DESCRIBE?) and no registered firmware profile knows it")
        model = profile.make(profile.default_options())
        where = f"link {self.link.name}: target {self.firmware_name!r} does not describe its parameters and"
        try:
            theirs = model.hello(HostHello(0, PROTOCOL_VERSION, self._period_us, MODE_LOCKSTEP, 0))
        except HilbenchError as exc:
            raise TargetError(f"{where} the model of profile {profile.name!r} refuses its period: {exc}") from exc
        differ = [f"{f} {_field(mine, f)!r} (model {_field(theirs, f)!r})" for f in _SAME_BUILD
                  if _field(mine, f) != _field(theirs, f)]
        if differ:
            raise TargetError(f"{where} is not the build profile {profile.name!r} models: " + ", ".join(differ))
        return model

    def describe_all(self) -> list[ParamInfo]:
        """Every declared parameter (ids 0..n_params-1 by the handshake's count)."""
        n = self.target_hello.n_params if self.target_hello is not None else 0
        return [self.describe(pid) for pid in range(n)]

    def get_param(self, param_id: int) -> ParamValue:
        reply = self._request(ParamGet(self._next_seq(), param_id), ParamValue)
        if type(reply) is ErrorReport:
            raise self._refused(f"ParamGet {param_id}", reply)
        return reply

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        reply = self._request(ParamSet(self._next_seq(), tuple(pairs)), ParamSetResult)
        if type(reply) is ErrorReport:
            raise self._refused(f"ParamSet {pairs}", reply)
        return reply

    # -- commands --------------------------------------------------------------------------
    def start(self) -> None:
        self._command(Start)

    def stop(self) -> None:
        self._command(Stop)

    def _command(self, kind: type[Start] | type[Stop]) -> None:
        """Start or Stop once nothing waits in the target's receiver (`settle`); sent also when the
        probe fails (a target that answers nothing may still take its Stop), that error raised after,
        of the same kind, saying the command went out."""
        try:
            settle(lambda: self.retries, self.status)
        except HilbenchError as exc:
            self._send(kind(self._next_seq()))
            raise exc.reworded(f"{kind.__name__} sent, unconfirmed: the StatusRequest before it failed: {exc}") from exc
        self._send(kind(self._next_seq()))

    def status(self) -> Status:
        reply = self._request(StatusRequest(self._next_seq()), Status)
        if type(reply) is ErrorReport:
            raise self._refused("StatusRequest", reply)
        return reply

    # -- the hot path ----------------------------------------------------------------------
    def step(self, sensors: Sensors) -> Drive:
        """One exchange: Sensors out, the Drive with the same seq back (LinkTimeout if none)."""
        self._send(sensors)
        msg = self.link.recv_or_none(self.retry_s)
        if type(msg) is Drive and msg.seq == sensors.seq:
            return msg
        return self._answer(sensors, msg)

    def _answer(self, sensors: Sensors, msg: Any) -> Drive:
        """`step`'s end when the first thing received (``msg``; None: nothing within retry_s) is not
        our Drive (also where hilbench/targets/_remotestep.c hands such an answer back)."""
        if type(msg) is Drive and msg.seq == sensors.seq:
            return msg
        if msg is not None:
            self._note_stray(msg)
        return self._step_slow(sensors)

    def span_core(self) -> tuple[Any, Any] | None:
        """The C form of `step` for the session's C span (hilbench/targets/_remotestep.c): (hbglue.h's
        target capsule, the core whose `step` it stands for), or None (not built, or a link that is
        not a plain Link on a file descriptor: a fault injector, TCP through a transport)."""
        link = self.link
        fd = getattr(link, "_fd_w", -1)
        if _remotestep is None or type(link) is not Link or fd < 0:
            return None
        core = _remotestep.Remote(target=self, link=link, step=MethodType(RemoteTarget.step, self), drive_type=Drive,
                                  sensors_type=Sensors, fd=fd, retry_s=self.retry_s)
        return _remotestep.SPAN_API, core

    def _step_slow(self, sensors: Sensors) -> Drive:
        """The first answer was late, lost or something else: skip strays, send the same Sensors
        again every retry_s (the target answers a repeated seq with its last Drive), until ours
        arrives or the timeout."""
        return self._await(sensors, (Drive,), time.monotonic(), self.timeout_s, f"no Drive for Sensors seq {sensors.seq}")

    # -- twin-speculative lockstep (hilbench.bench.speculative) ------------------------------
    def send_batch(self, first_seq: int, count: int, records: bytes) -> int:
        """Send a SensorsBatch without waiting; its frame seq (the answer echoes it)."""
        seq = self._next_seq()
        self._send(SensorsBatch(seq, first_seq & 0xFFFF, count, tuple(records)))
        return seq

    def recv_digest(self, timeout_s: float) -> BatchDigest | ErrorReport | None:
        """The next BatchDigest or ErrorReport (a target that refused a batch) within timeout_s (None:
        none); other frames are counted as strays."""
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.link.recv_or_none(max(deadline - time.monotonic(), 0.0))
            if msg is None:
                return None
            if type(msg) is BatchDigest:
                return msg
            self._note_stray(msg)
            if type(msg) is ErrorReport:
                return msg
            if time.monotonic() >= deadline:
                return None

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        """Real time: the far end runs on its own clock; the exchange is the same."""
        return self.step(sensors)

    def watchdog_trip(self) -> Drive:
        """Stay silent and wait for the far end's watchdog Drive (outputs off)."""
        watchdog_ms = self.watchdog_ms
        deadline = time.monotonic() + self.timeout_s + watchdog_ms / 1000.0
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise LinkTimeout(f"link {self.link.name}: target sent no watchdog Drive within "
                                  f"{self.timeout_s * 1000:.0f} ms")
            msg = self._recv(remaining)
            if type(msg) is Drive and msg.fault:
                return msg
            self._note_stray(msg)

    def close(self) -> None:
        self.link.close()


__all__ = ["RemoteTarget"]
