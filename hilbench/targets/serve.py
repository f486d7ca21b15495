"""Serve a target model on a link: answer every request frame until the link closes.

Lockstep: each Sensors advances the model by exactly one period (target.step) and is answered
by its Drive with the same seq. Real time (HostHello mode 1, or forced): each Sensors advances
the model by the wall time since the previous one (target.advance); when no Sensors arrives for
watchdog_ms the model's watchdog trips and its Drive (outputs off) is sent unsolicited. The
watchdog runs in lockstep too (at least LOCKSTEP_WATCHDOG_MIN_S, as the firmware runtime's
HRT_LOCKSTEP_WATCHDOG_MIN_MS): a host gone silent gets its outputs off (a Drive saying OFF and
WATCHDOG, counted in Status), but the model does not step or stop: its time stands still while
the host is away, so a host pausing on a loaded machine changes no recording.
Bad frames are counted by the link's decoder; nothing a host sends can crash the server.
"""

from __future__ import annotations

import logging
import gc
import os
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

from hilbench.errors import HilbenchError, LinkClosed, ParamError
from hilbench.targets.kit import RepeatAnswer
from hilbench.protocol import (
    Drive,
    MODE_LOCKSTEP,
    MODE_REALTIME,
    PROTOCOL_VERSION,
    ErrorCode,
    ErrorReport,
    Fault,
    HostHello,
    OutputMode,
    ParamDescribe,
    ParamGet,
    ParamSet,
    Sensors,
    Start,
    Status,
    StatusRequest,
    TargetDescribe,
    TelemetryDescribe,
    Stop,
    host_hello_mismatch,
)

from hilbench.link.link import Link

try:  # the lockstep loop in C (optional, built with the C cores)
    from hilbench.targets import _remotestep
except ImportError:  # pragma: no cover - no compiler at install time
    _remotestep = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from hilbench.targets.base import Target

log = logging.getLogger("hilbench.serve")

_POLL_S = 0.2  # how often an idle server looks at stop_event
LOCKSTEP_WATCHDOG_MIN_S = 1.0  # the firmware runtime's HRT_LOCKSTEP_WATCHDOG_MIN_MS
_MAX_LOGGED_FAULTS = 5


@dataclass
class ServeReport:
    """What one serve() call did (returned when the link closes or stop_event is set)."""

    reason: str = ""
    sensors: int = 0
    requests: int = 0
    error_reports: int = 0
    watchdog_trips: int = 0
    handler_faults: int = 0
    duplicates: int = 0  # Sensors repeating the last seq, answered with the last Drive
    mode: int = MODE_LOCKSTEP
    link_stats: dict[str, int] = field(default_factory=dict)


class _Server:
    def __init__(self, target: Any, link: Any, stop_event: threading.Event | None, mode: int | None,
                 watchdog_ms: int | None) -> None:
        self.target = target
        self.link = link
        self.stop_event = stop_event
        self.forced_mode = mode
        self.forced_watchdog_ms = watchdog_ms
        self.mode = MODE_LOCKSTEP if mode is None else mode
        self.watchdog_s = (watchdog_ms or 0) / 1000.0
        self.period_us = 0
        self.report = ServeReport(mode=self.mode)
        self.last_error = int(ErrorCode.NONE)
        self.last_sensors_t: float | None = None
        self.tripped = False

    # -- replies ---------------------------------------------------------------------------
    def error(self, seq: int, code: int, detail: int) -> None:
        self.last_error = int(code)
        self.report.error_reports += 1
        self.link.send(ErrorReport(seq, int(code), detail & 0xFF))

    def on_hello(self, msg: HostHello) -> None:
        if host_hello_mismatch(msg) is not None:  # version or schema fingerprint (protocol.handshake)
            log.error("%s: %s; handshake refused", self.link.name, host_hello_mismatch(msg))
            self.error(msg.seq, ErrorCode.VERSION, PROTOCOL_VERSION)
            return
        if msg.mode not in (MODE_LOCKSTEP, MODE_REALTIME):  # PREDICT is the C runtime's: no Python target predicts
            log.error("%s: host asks for mode %d, this server serves 0 and 1; handshake refused", self.link.name, msg.mode)
            self.error(msg.seq, ErrorCode.BAD_REQUEST, msg.mode)
            return
        if self.forced_mode is not None and msg.mode != self.forced_mode:
            log.error("%s: host asks for mode %d but this server runs mode %d; handshake refused",
                      self.link.name, msg.mode, self.forced_mode)
            self.error(msg.seq, ErrorCode.BAD_REQUEST, self.forced_mode)
            return
        if self.forced_watchdog_ms is not None:
            msg = msg._replace(watchdog_ms=self.forced_watchdog_ms)
        try:
            reply = self.target.hello(msg)
        except HilbenchError as exc:
            log.error("%s: handshake refused: %s", self.link.name, exc)
            self.error(msg.seq, ErrorCode.BAD_REQUEST, 0)
            return
        self.mode = msg.mode
        self.report.mode = msg.mode
        self.period_us = msg.period_us
        self.watchdog_s = msg.watchdog_ms / 1000.0
        self.last_sensors_t = None
        self.tripped = False
        self.link.reset_sequence()
        self.link.send(reply._replace(seq=msg.seq))
        log.info("%s: handshake: period %d us, mode %s, watchdog %d ms", self.link.name, msg.period_us,
                 "realtime" if msg.mode == MODE_REALTIME else "lockstep", msg.watchdog_ms)

    def on_describe(self, msg: ParamDescribe) -> None:
        try:
            reply = self.target.describe(msg.param_id)
        except ParamError:
            self.error(msg.seq, ErrorCode.UNKNOWN_PARAM, msg.param_id)
            return
        self.link.send(reply._replace(seq=msg.seq))

    def on_describe_target(self, msg: TargetDescribe) -> None:
        describe = getattr(self.target, "describe_target", None)
        info = describe() if describe is not None else None
        if info is None:  # a model that does not describe itself
            self.error(msg.seq, ErrorCode.BAD_REQUEST, int(TargetDescribe.TYPE))
            return
        self.link.send(info._replace(seq=msg.seq))

    def on_describe_telemetry(self, msg: TelemetryDescribe) -> None:
        describe = getattr(self.target, "describe_telemetry", None)
        info = describe(msg.index) if describe is not None else None
        if info is None:
            self.error(msg.seq, ErrorCode.UNKNOWN_TELEMETRY, msg.index)
            return
        self.link.send(info._replace(seq=msg.seq))

    def on_get(self, msg: ParamGet) -> None:
        self.link.send(self.target.get_param(msg.param_id)._replace(seq=msg.seq))

    def on_set(self, msg: ParamSet) -> None:
        self.link.send(self.target.set_params(tuple(msg.pairs))._replace(seq=msg.seq))

    def on_start(self, msg: Start) -> None:
        self.target.start()

    def on_stop(self, msg: Stop) -> None:
        """The host stopped the outputs and may now leave: the watchdog waits for its next Sensors."""
        self.target.stop()
        self.last_sensors_t = None

    def on_status(self, msg: StatusRequest) -> None:
        own = self.target.status()
        stats = self.link.stats
        self.link.send(Status(
            msg.seq,
            stats.frames_rx & 0xFFFF,
            stats.frame_errors & 0xFFFF,
            stats.resyncs & 0xFFFF,
            stats.unknown_type & 0xFFFF,
            own.overruns & 0xFFFF,
            max(own.watchdog_trips, self.report.watchdog_trips) & 0xFFFF,
            status_last_error(self.last_error, own.last_error),
        ))

    # -- the loop ----------------------------------------------------------------------------
    def run(self) -> ServeReport:
        """Answer frames until the link closes or stop_event is set."""
        self.answer = RepeatAnswer(self._new_period)  # a repeated seq: the last Drive again, no step
        handlers = {
            HostHello: self.on_hello, ParamDescribe: self.on_describe, ParamGet: self.on_get,
            ParamSet: self.on_set, Start: self.on_start, Stop: self.on_stop, StatusRequest: self.on_status,
            TargetDescribe: self.on_describe_target, TelemetryDescribe: self.on_describe_telemetry,
        }
        try:
            while not self._stopped():
                msg = self._lockstep() if self.mode != MODE_REALTIME else self._realtime()
                if msg is None:
                    self.check_watchdog()
                else:  # (both loops answer every Sensors themselves)
                    self._request(msg, handlers)
        except LinkClosed as exc:
            self.report.reason = str(exc)
            log.info("%s", exc)
        self.report.duplicates = self.answer.repeats
        self.report.link_stats = self.link.stats.as_dict()
        return self.report

    def _stopped(self) -> bool:
        stop_event = self.stop_event
        if stop_event is not None and stop_event.is_set():
            self.report.reason = "stopped"
            return True
        return False

    def _lockstep(self) -> Any:
        """Lockstep's hot path: one Sensors in, one Drive out, nothing else per period; returns the
        first other message (None: a poll's timeout, stop_event is to be looked at). With nobody to
        ask us to stop, wait for frames without a timeout (one blocking read per period, no poll)."""
        recv, send, answer, report, stop_event = self.link.recv_or_none, self.link.send, self.answer, self.report, self.stop_event
        watching = self.watchdog_s > 0  # a watchdog agreed: wake to look at it, and note each Sensors' time
        wait = None if stop_event is None and not watching else _POLL_S
        in_c = self._in_c(wait)
        while True:
            msg = recv(wait) if in_c is None else in_c()
            if type(msg) is not Sensors:
                return msg
            report.sensors += 1
            if watching:
                self.last_sensors_t = time.monotonic()
                self.tripped = False
            try:
                send(answer.step(msg))
            except LinkClosed:
                raise
            except Exception as exc:  # noqa: BLE001 - a model bug must not take the server down
                self.handler_fault(msg, exc)
            if stop_event is not None and stop_event.is_set():
                return None

    def _realtime(self) -> Any:
        """Real time's hot path (`_lockstep`'s twin): each Sensors answered in place, waiting at
        most until the watchdog is due (`realtime_wait`); returns the first other message
        (None: nothing within the wait, or stop_event set)."""
        recv, send, answer, report, stop_event = self.link.recv_or_none, self.link.send, self.answer, self.report, self.stop_event
        wait = self.realtime_wait
        in_c = self._realtime_in_c()
        while True:
            msg = recv(wait()) if in_c is None else in_c()
            if type(msg) is not Sensors:
                return msg
            report.sensors += 1
            try:
                send(answer.step(msg))
            except LinkClosed:
                raise
            except Exception as exc:  # noqa: BLE001 - a model bug must not take the server down
                self.handler_fault(msg, exc)
            if stop_event is not None and stop_event.is_set():
                return None

    def _in_c(self, wait: float | None) -> Callable[[], Any] | None:
        """This loop's periods in C (hilbench/targets/_remotestep.c `serve_lockstep`: the Sensors
        that arrive alone on a clean stream, answered through the target's C step, until the first
        message it leaves to this loop), when the target has a C step that is its `step` (its
        `span_core`), the link is a plain Link on a file descriptor, nobody may ask us to stop and
        HILBENCH_SERVE_LOOP is not "python" (the reference, this loop alone); else None."""
        span_core = getattr(self.target, "span_core", None)
        fd = self._c_loop_fd()
        if span_core is None or fd is None or wait is None:
            return None
        core = span_core()
        if core is None or self.target.step != core[1].step:
            return None
        args = (self, self.link, fd, core[0], core[1], wait, self.watchdog_s > 0, Drive, Sensors)
        serve_lockstep = _remotestep.serve_lockstep
        return lambda: serve_lockstep(*args)

    def _realtime_in_c(self) -> Callable[[], Any] | None:
        """`_realtime` in C (hilbench/targets/_remotestep.c `serve_realtime`: the Sensors that arrive
        alone on a clean stream, each advanced through the target's C advance by the wall time since
        the last one, until the first message it leaves to this loop), on `_in_c`'s conditions, when
        the target's `advance` is the C one its `realtime_core` offers; else None. In real time each
        period meets a cold cache: this Python loop cost the emulator 74 us of CPU per 1 ms period
        (`c0fb63a`'s 52 us), the C loop 15 us (issue 28)."""
        realtime_core = getattr(self.target, "realtime_core", None)
        fd = self._c_loop_fd()
        if realtime_core is None or fd is None:
            return None
        # the target's advance must be the one the core stands for: not a wrapper's around it
        if getattr(self.target.advance, "__self__", None) is not getattr(realtime_core, "__self__", None):
            return None
        core = realtime_core()  # None: a subclass's own advance
        if core is None:
            return None
        api, fw = core
        link = self.link
        return lambda: _remotestep.serve_realtime(self, link, fd, api, fw, _POLL_S, self.watchdog_s,
                                                  float(self.period_us), Drive, Sensors)

    def _c_loop_fd(self) -> int | None:
        """The fd a serve loop in C (`_in_c`, `_realtime_in_c`) works on: the C loops are built, the
        link is a plain Link on a file descriptor, nobody may ask us to stop and HILBENCH_SERVE_LOOP is
        not "python" (the reference, the Python loops alone); else None."""
        link = self.link
        fd = getattr(link, "_fd_w", -1)
        if (_remotestep is None or self.stop_event is not None or type(link) is not Link or fd < 0
                or os.environ.get("HILBENCH_SERVE_LOOP") == "python"):
            return None
        return fd

    def _new_period(self, msg: Sensors) -> Drive:
        """A new Sensors (not a repeat): lockstep steps one period, real time the wall time since the
        last one; the Drive answers with the Sensors' seq."""
        if self.mode != MODE_REALTIME:
            drive = self.target.step(msg)
        else:
            now = time.monotonic()
            last = self.last_sensors_t
            span_us = (now - last) * 1e6 if last is not None else float(self.period_us)
            self.last_sensors_t = now
            self.tripped = False
            drive = self.target.advance(span_us, msg)
        return drive if drive.seq == msg.seq else drive._replace(seq=msg.seq)

    def _request(self, msg: Any, handlers: dict[type, Any]) -> None:
        """A request between periods: the next Sensors is a new period whatever its seq."""
        self.report.requests += 1
        self.answer.forget()
        handler = handlers.get(type(msg))
        try:
            if handler is None:
                self.error(msg.seq, ErrorCode.BAD_REQUEST, 0)
            else:
                handler(msg)
        except LinkClosed:
            raise
        except Exception as exc:  # noqa: BLE001 - a model bug must not take the server down
            self.handler_fault(msg, exc)

    def realtime_wait(self) -> float:
        """How long the real-time loop may wait for a frame: until the watchdog is due, at most _POLL_S."""
        if self.watchdog_s > 0 and self.last_sensors_t is not None and not self.tripped:
            return min(_POLL_S, max(0.0, self.last_sensors_t + self.watchdog_s - time.monotonic()))
        return _POLL_S

    def handler_fault(self, msg: Any, exc: Exception) -> None:
        """A model raised while handling msg: log (the first few), answer BAD_REQUEST, keep serving."""
        if isinstance(exc, LinkClosed):
            raise exc
        report = self.report
        report.handler_faults += 1
        if report.handler_faults <= _MAX_LOGGED_FAULTS:
            log.error("%s: %s while handling %s: %s", self.link.name, type(exc).__name__, type(msg).__name__, exc)
        try:
            self.error(msg.seq, ErrorCode.BAD_REQUEST, 0)
        except LinkClosed:
            raise
        except Exception:  # noqa: BLE001
            pass

    def check_watchdog(self) -> None:
        """No Sensors for the watchdog time: outputs off and one unsolicited Drive that says so (real
        time: the model's own trip; lockstep: the last Drive with the outputs OFF, the model untouched)."""
        if self.watchdog_s <= 0 or self.last_sensors_t is None or self.tripped:
            return
        lockstep = self.mode != MODE_REALTIME
        limit_s = max(self.watchdog_s, LOCKSTEP_WATCHDOG_MIN_S) if lockstep else self.watchdog_s
        if time.monotonic() - self.last_sensors_t >= limit_s:
            self.tripped = True
            self.report.watchdog_trips += 1
            self.last_error = int(ErrorCode.WATCHDOG)
            last = self.answer.last
            if lockstep and last is None:
                return  # no Drive yet to say it with: the outputs were never on since the last request
            drive = last._replace(output_mode=OutputMode.OFF, fault=Fault.WATCHDOG) if lockstep else self.target.watchdog_trip()
            if not lockstep:  # the model stopped: a Sensors repeating the last seq is a new period, not
                self.answer.forget()  # an answer with the outputs still on (lockstep's model stands still)
            log.warning("%s: no Sensors for %.0f ms: watchdog tripped, outputs off", self.link.name,
                        self.watchdog_s * 1000)
            self.link.send(drive)


_ERROR_OF_FAULT = {int(Fault.WATCHDOG): int(ErrorCode.WATCHDOG)}


def status_last_error(server_error: int, target_value: int) -> int:
    """Status.last_error as an ErrorCode: the server's own view (the last ErrorReport it sent, or
    WATCHDOG when it tripped the watchdog) first; else the target's value when it is an ErrorCode
    (or a plain int naming one). A value of another enum, such as a Drive fault code (Fault), is not
    an ErrorCode: Fault.WATCHDOG maps to ErrorCode.WATCHDOG and the other faults to NONE.
    """
    if server_error:
        return int(server_error)
    if isinstance(target_value, Fault):
        return _ERROR_OF_FAULT.get(int(target_value), int(ErrorCode.NONE))
    if isinstance(target_value, ErrorCode) or type(target_value) is int:
        try:
            return int(ErrorCode(target_value))
        except ValueError:
            return int(ErrorCode.NONE)
    return int(ErrorCode.NONE)


def serve(target: "Target", link: "Link", *, stop_event: threading.Event | None = None, mode: int | None = None,
          watchdog_ms: int | None = None) -> ServeReport:
    """Answer frames on link with target until the link closes or stop_event is set.

    mode None follows the host's HostHello; MODE_LOCKSTEP or MODE_REALTIME refuses a host that
    asks for the other. watchdog_ms overrides the host's watchdog (0 disables it).
    """
    if mode is not None and mode not in (MODE_LOCKSTEP, MODE_REALTIME):
        raise ValueError(f"serve: mode must be {MODE_LOCKSTEP} or {MODE_REALTIME}, got {mode}")
    # No collector pauses while serving: a full collection takes milliseconds, longer than a
    # real-time period, and the frame path makes no reference cycles.
    gc_was_enabled = gc.isenabled()
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        return _Server(target, link, stop_event, mode, watchdog_ms).run()
    finally:
        gc.unfreeze()
        if gc_was_enabled:
            gc.enable()


__all__ = ["ServeReport", "serve", "status_last_error"]
