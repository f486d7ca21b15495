"""Twin-speculative lockstep: a board run at the speed of the board, not of the wire.

When the target's firmware has a bit-exact twin on the host (its profile's `twin`: an in-process
target built from the same C source), the session's periods are answered by the twin at once, and
their Sensors go to the board in batches (SensorsBatch: what changed, period by period), two in
flight so the wire never idles. The board runs each period exactly as per-period lockstep does and
answers each batch with the CRC-32 of its Drives chained over every batch since the handshake
(BatchDigest); a batch is committed when that digest equals the twin's. Parameter writes, Start
and Stop drain the batches first and then act on both sides, so they fall at the same period.

A lost or corrupted frame costs a resend (a repeated batch is answered from the kept digest, a
gap is refused with the period expected), never a wrong commit. A digest that differs is a
divergence: the run stops and, when a fresh target and twin can be opened, the run's inputs are
replayed from a reset in per-period lockstep to name the first differing period and field.
"""

from __future__ import annotations

import pickle
import tempfile
import time
import zlib
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

from hilbench.errors import DivergenceError, HilbenchError, LinkTimeout, TargetError
from hilbench.protocol import (
    MODE_LOCKSTEP,
    BatchDigest,
    Drive,
    ErrorCode,
    ErrorReport,
    HostHello,
    ParamInfo,
    ParamSetResult,
    ParamValue,
    Sensors,
    Status,
    TargetHello,
    TargetInfo,
    TelemetryInfo,
)
from hilbench.protocol.batch import MIN_BATCH_BYTES, BatchBuilder, BatchState, RecordTooLarge, decode_records
from hilbench.protocol.messages import MAX_BATCH_BYTES, pack_drive
from hilbench.targets.base import Target
from hilbench.targets.remote import RemoteTarget

WINDOW = 2  # batches in flight: one the board runs, one waiting in its receive buffer
_DRIVE_FIELDS = Drive._fields[1:]


@dataclass
class _Batch:
    first: int  # the period number of its first period (from the handshake)
    count: int
    records: bytes
    digest: int  # the twin's digest chained through this batch
    frame_seq: int = -1  # the seq of its latest send (a refusal of an older send is stale)
    sent_s: float = 0.0


@dataclass
class SpeculationStats:
    periods: int = 0  # periods committed by a digest
    batches: int = 0
    resends: int = 0
    alone: int = 0  # periods whose record fit no batch: sent as a per-period Sensors
    wall_s: float = 0.0  # time from the first batch to the last commit

    def as_dict(self) -> dict[str, int]:
        rate = self.periods / self.wall_s if self.wall_s > 0 else 0.0
        return {"speculative_periods": self.periods, "speculative_batches": self.batches,
                "speculative_resends": self.resends, "speculative_alone": self.alone,
                "speculative_periods_per_s": int(rate)}


LogItem = tuple[str, object]


class RunLog:
    """What the run sent (handshake, batches' records, writes, Start/Stop), in order, for the replay
    that locates a divergence: kept in a temporary file, so memory stays flat however long the run."""

    def __init__(self) -> None:
        self._file = tempfile.TemporaryFile()

    def clear(self) -> None:
        self._file.seek(0)
        self._file.truncate()

    def append(self, item: LogItem) -> None:
        pickle.dump(item, self._file, protocol=pickle.HIGHEST_PROTOCOL)

    def items(self) -> Iterator[LogItem]:
        """Every item so far, in order (the file is read from the start; appends go on after)."""
        self._file.flush()
        end = self._file.tell()
        self._file.seek(0)
        try:
            while self._file.tell() < end:
                yield pickle.load(self._file)  # our own items, written above
        finally:
            self._file.seek(end)

    def close(self) -> None:
        self._file.close()


class SpeculativeTarget:
    """A RemoteTarget with its host twin: the Target interface, speculating in lockstep."""

    def __init__(self, remote: RemoteTarget, twin: Target, *, reopen: Callable[[], tuple[Target, Callable[[], None]]] | None = None,
                 make_twin: Callable[[], Target] | None = None, period_us: int = 50, window: int = WINDOW,
                 keep_going: bool = False) -> None:
        """``keep_going``: after a divergence the run goes on one exchange a period (the error is kept
        in ``divergence`` for the end of the run) instead of ending with it."""
        self.remote = remote
        self.twin = twin
        self.link = remote.link
        self.firmware_name = remote.firmware_name
        self.reopen = reopen
        self.make_twin = make_twin
        self.window = window
        self.period_us = period_us
        self.active = False
        self.keep_going = keep_going
        self.divergence: DivergenceError | None = None
        #: keep_going: told (first, resume) when the run goes per period after a divergence: the rows
        #: of periods first..resume-1 are the twin's, unconfirmed (the target's differ in them)
        self.on_unconfirmed: Callable[[int, int], None] | None = None
        self._diverged_from = 0
        self.stats = SpeculationStats()
        self._log = RunLog()
        self._reset()

    # -- bookkeeping -------------------------------------------------------------------------
    def _reset(self) -> None:
        self._builder = BatchBuilder(max_bytes=MIN_BATCH_BYTES)  # until a digest says the target's room
        self._next: int | None = None  # the period number the next step is
        self._first = 0  # the first period of the batch being built
        self._crc = 0  # the twin's digest through the last period stepped
        self._pending: deque[_Batch] = deque()
        self._synced = False  # a batch was confirmed since the handshake (the board's records run on)
        self._t0: float | None = None
        self._progress_s = time.monotonic()  # the last commit (or the first send after one)
        self._asked_again: set[int] = set()  # batches whose digest differed once and were sent again
        self._unconfirmed: list[tuple[int, Sensors, Drive]] = []  # the periods before the first digest

    @property
    def retries(self) -> int:
        return self.remote.retries + self.stats.resends

    def speculation_stats(self) -> dict[str, int]:
        return self.stats.as_dict()

    # -- the Target interface ----------------------------------------------------------------
    def hello(self, host: HostHello) -> TargetHello:
        """Both sides agree; speculation only in plain lockstep, with the twin saying the same."""
        self._reset()
        hello = self.remote.hello(host)
        self.firmware_name = self.remote.firmware_name
        self.active = False
        if host.mode == MODE_LOCKSTEP:
            twin_hello = self.twin.hello(host)
            self.active = twin_hello._replace(seq=hello.seq) == hello
        self._log.clear()
        self._log.append(("hello", host))
        return hello

    def step(self, sensors: Sensors) -> Drive:
        if not self.active:
            return self.remote.step(sensors)
        if self._next is None:
            self._next = self._first = sensors.seq
        elif sensors.seq != self._next & 0xFF:  # not the next period (a repeat): per period from here
            self.drain()
            self.active = False
            return self.remote.step(sensors)
        drive = self.twin.step(sensors)
        if not self._synced:  # until the target has taken a batch: kept, to run one by one if it refuses
            self._unconfirmed.append((self._next, sensors, drive))
        try:
            if not self._builder.add(sensors):
                self._flush()
                if not self.active:  # it refused batches: the periods so far, this one included, ran one by one
                    return drive
                self._builder.add(sensors)
        except RecordTooLarge:
            return self._alone(sensors, drive)
        self._crc = zlib.crc32(pack_drive(drive), self._crc)
        self._next += 1
        if self.divergence is not None:  # keep_going: what is batched runs out (unchecked), then per period
            self.drain()
        return drive

    def _alone(self, sensors: Sensors, drive: Drive) -> Drive:
        """A period whose record fits no batch the target takes (e.g. an encoder, six ADC codes and
        edges in a first batch's 17 bytes): what is batched is committed, then the period goes as a
        per-period Sensors and its Drive is checked against the twin's; both sides start the next
        batch's records and digest afresh (PROTOCOL.md, "Batches"), and the run goes on in batches."""
        k = self._next
        assert k is not None
        if self._unconfirmed and self._unconfirmed[-1][0] == k:
            self._unconfirmed.pop()  # it goes now, not with the unconfirmed periods of a refusal
        self.drain()
        theirs = self.remote.step(sensors)
        self._log.append(("step", (k, sensors)))
        self.stats.alone += 1
        self._next = k + 1
        if theirs != drive:
            error = _divergence_error(k, sensors, theirs, drive, deque([(k, sensors, theirs, drive)]), self.period_us)
            self.active = False
            if not self.keep_going:
                raise error
            self.divergence = self.divergence or error
        if self.active:  # the target's records and digest start afresh with the next batch: so do ours
            builder = BatchBuilder(max_bytes=self._builder.max_bytes)
            builder.state.ignore_encoder = self._builder.state.ignore_encoder
            self._builder, self._crc, self._first, self._synced = builder, 0, k + 1, False
        return theirs

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        self.drain()
        if not self.active:
            return self.remote.set_params(pairs)
        result = self.remote.set_params(pairs)
        mine = self.twin.set_params(pairs)
        self._log.append(("set", pairs))
        if tuple(mine)[1:] != tuple(result)[1:]:
            self.active = False
            raise DivergenceError(f"{self.link.name}: parameter write {pairs} at period {self._next}: the target "
                                  f"answered {tuple(result)[1:]}, its twin {tuple(mine)[1:]}")
        return result

    def start(self) -> None:
        self._both("start")

    def stop(self) -> None:
        self._both("stop")

    def _both(self, what: str) -> None:
        self.drain()
        if self.active:
            getattr(self.twin, what)()
            self._log.append((what, None))
        getattr(self.remote, what)()

    def describe(self, param_id: int) -> ParamInfo:
        self.drain()
        return self.remote.describe(param_id)

    def get_param(self, param_id: int) -> ParamValue:
        self.drain()
        return self.remote.get_param(param_id)

    def status(self) -> Status:
        self.drain()
        return self.remote.status()

    def describe_target(self) -> TargetInfo | None:
        """TargetInfo; a target with no encoder (encoder_counts 0) is sent none in batches (the twin
        still steps on the plant's count, so a firmware that read it after all would diverge)."""
        info = self.remote.describe_target()
        self._builder.state.ignore_encoder = info is not None and info.encoder_counts == 0
        return info

    def describe_telemetry(self, index: int) -> TelemetryInfo:
        return self.remote.describe_telemetry(index)

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        return self.remote.advance(duration_us, sensors)

    def watchdog_trip(self) -> Drive:
        return self.remote.watchdog_trip()

    def close(self) -> None:
        self._log.close()
        self.remote.close()

    # -- batches -----------------------------------------------------------------------------
    def drain(self) -> None:
        """Send what is batched and wait until every batch is committed (or a divergence)."""
        if not self.active:
            return
        self._flush()
        while self._pending:
            self._wait()
        if self.divergence is not None:  # keep_going: the batches ran out; one exchange a period from here
            self.active = False
            if self.on_unconfirmed is not None and self._next is not None:
                self.on_unconfirmed(self._diverged_from, self._next)

    def _flush(self) -> None:
        count, records = self._builder.take()
        if count == 0:
            return
        batch = _Batch(self._first, count, records, self._crc)
        self._first += count
        self._log.append(("batch", (batch.first, count, records)))
        # the first batch after a handshake goes alone: the board takes any first period then
        limit = self.window if self._synced else 1
        while len(self._pending) >= limit:
            self._wait()
            if not self.active:
                return  # the target refused batches (`_refused`): these periods ran one by one
            limit = self.window if self._synced else 1
        if self._t0 is None:
            self._t0 = time.perf_counter()
        self.stats.batches += 1
        if not self._pending:
            self._progress_s = time.monotonic()
        self._send(batch)
        self._pending.append(batch)

    def _send(self, batch: _Batch) -> None:
        batch.frame_seq = self.remote.send_batch(batch.first, batch.count, batch.records)
        batch.sent_s = time.monotonic()

    def _wait(self) -> None:
        """One answer (or a resend of the unanswered batches after retry_s of silence); LinkTimeout
        when nothing was committed for the link's timeout and three resends."""
        head = self._pending[0]
        timeout_s = self.remote.timeout_s + 3 * self.remote.retry_s
        while True:
            if time.monotonic() - self._progress_s >= timeout_s:
                raise LinkTimeout(f"link {self.link.name}: no BatchDigest for the batch at period {head.first} "
                                  f"within {timeout_s * 1000:.0f} ms ({self.stats.resends} batches resent)")
            reply = self.remote.recv_digest(max(self.remote.retry_s - (time.monotonic() - self._last_sent()), 1e-4))
            if type(reply) is ErrorReport:
                if any(b.frame_seq == reply.seq for b in self._pending):
                    self._refused(reply)
                    return
                continue  # a stray report (counted by the remote)
            if reply is not None:
                self._answer(reply)
                return
            if time.monotonic() - self._last_sent() >= self.remote.retry_s:
                self._resend(list(self._pending))
                return

    def _refused(self, report: ErrorReport) -> None:
        """The target answered a batch with an ErrorReport: before its first digest, it does not take
        batches (a Python emulator, a build with HRT_SPECULATE=0): every period the twin ran ahead goes
        to it one by one, its Drive checked against the twin's, and the run goes on per period."""
        if self._synced:
            raise TargetError(f"{self.link.name}: the target refused a SensorsBatch after taking others: "
                              f"{_error_text(report)}")
        self.active = False
        self._pending.clear()
        self._builder.take()
        unconfirmed, self._unconfirmed = self._unconfirmed, []
        recent: deque[tuple[int, Sensors, Drive, Drive]] = deque(maxlen=4)
        for k, sensors, mine in unconfirmed:
            theirs = self.remote.step(sensors)
            recent.append((k, sensors, theirs, mine))
            if theirs != mine:
                raise _divergence_error(k, sensors, theirs, mine, recent, self.period_us)

    def _last_sent(self) -> float:
        return max(b.sent_s for b in self._pending)

    def _resend(self, batches: list[_Batch]) -> None:
        for batch in batches:
            self.stats.resends += 1
            self._send(batch)

    def _answer(self, reply: BatchDigest) -> None:
        """Commit what a digest vouches for, resend what a refusal says was lost."""
        pending = self._pending
        if reply.count == 0:  # refused: the board has run through next_seq - 1, digest reply.digest
            done = [b for b in pending if (b.first + b.count) & 0xFFFF == reply.next_seq]
            if done:
                self._commit(done[0], reply.digest)
            refused = [b for b in pending if b.frame_seq == reply.seq and b.first & 0xFFFF == reply.first_seq]
            if refused:  # a batch before it was lost: send again from the one the board expects
                self._resend([b for b in pending if b.first <= refused[0].first])
            return
        for batch in pending:
            if batch.first & 0xFFFF == reply.first_seq and batch.count == reply.count:
                self._commit(batch, reply.digest)
                self._synced = True
                self._unconfirmed = []
                self._builder.max_bytes = max(MIN_BATCH_BYTES, min(reply.room, MAX_BATCH_BYTES))
                return
        # a stale answer (a batch already committed, a resend's second answer): nothing to do

    def _commit(self, batch: _Batch, digest: int) -> None:
        if digest != batch.digest and self.divergence is None:
            if batch.first not in self._asked_again:  # an answer the wire corrupted past its CRC (2^-16)?
                self._asked_again.add(batch.first)  # ask again: a repeat gets the kept digest
                self._resend([b for b in self._pending if b.first >= batch.first])
                return
            error = self._diverged(batch)
            if not self.keep_going:
                self.active = False
                raise error
            self.divergence = error  # the batches in flight run out unchecked; then per period (`step`)
            self._diverged_from = self._committed_through()  # the first period no digest confirmed
        while self._pending and self._pending[0].first <= batch.first:
            done = self._pending.popleft()
            self.stats.periods += done.count
        self._progress_s = time.monotonic()
        if self._t0 is not None:
            self.stats.wall_s = time.perf_counter() - self._t0

    # -- a divergence ------------------------------------------------------------------------
    def _diverged(self, batch: _Batch) -> DivergenceError:
        """The divergence in or before ``batch``, located by a replay when a fresh target can be opened."""
        last = batch.first + batch.count - 1
        where = f"in periods {self._committed_through()}..{last} (batch at period {batch.first})"
        if self.reopen is None or self.make_twin is None:
            return DivergenceError(f"{self.link.name}: the target's Drives differ from its twin's {where}; "
                                   "a board on a port cannot be reset from here to replay the run and locate "
                                   "it (run the same scenario on its SIL build, or per period with twin = \"off\")")
        try:
            found = locate_divergence(self._log.items(), self.reopen, self.make_twin, last, self.period_us)
        except HilbenchError as exc:  # the divergence stays the run's error; why it was not located is said
            return DivergenceError(f"{self.link.name}: the target's Drives differ from its twin's {where}; "
                                   f"the replay that locates it failed: {exc}")
        if found is None:
            return DivergenceError(f"{self.link.name}: the target's digest differs from its twin's {where}, but a "
                                   "replay from a reset in per-period lockstep found no differing Drive (is the "
                                   "target deterministic?)")
        return found



    def _committed_through(self) -> int:
        return self._pending[0].first if self._pending else 0


def _error_text(report: ErrorReport) -> str:
    try:
        return f"{ErrorCode(report.code).name} (detail {report.detail})"
    except ValueError:
        return f"error code {report.code} (detail {report.detail})"


def locate_divergence(log: Iterable[LogItem], reopen: Callable[[], tuple[Target, Callable[[], None]]],
                      make_twin: Callable[[], Target], last: int, period_us: int, context: int = 3) -> DivergenceError | None:
    """Replay ``log`` (the run's handshake, batches, writes) from a reset on a fresh target and twin,
    one period at a time, up to period ``last``: the first Drive field that differs, as an error
    whose message names it and whose records show both sides around it; None when none differs."""
    target, close = reopen()
    twin = make_twin()
    recent: deque[tuple[int, Sensors, Drive, Drive]] = deque(maxlen=context + 1)
    try:
        state = BatchState()
        for kind, item in log:
            if kind == "hello":
                assert isinstance(item, HostHello)
                target.hello(item)
                twin.hello(item)
                state = BatchState()
            elif kind == "set":
                target.set_params(item)  # type: ignore[arg-type]
                twin.set_params(item)  # type: ignore[arg-type]
            elif kind in ("start", "stop"):
                getattr(target, kind)()
                getattr(twin, kind)()
            else:
                if kind == "step":  # a period that went alone: the records start afresh after it
                    periods: Iterable[tuple[int, Sensors]] = (item,)  # type: ignore[assignment]
                    state = BatchState()
                else:
                    first, count, records = item  # type: ignore[misc]
                    periods = ((first + i, s) for i, s in enumerate(decode_records(state, first, count, records)))
                for k, sensors in periods:
                    mine, theirs = twin.step(sensors), target.step(sensors)
                    recent.append((k, sensors, theirs, mine))
                    if mine != theirs:
                        return _divergence_error(k, sensors, theirs, mine, recent, period_us)
                    if k >= last:
                        return None
        return None
    finally:
        close()


def _divergence_error(k: int, sensors: Sensors, target: Drive, twin: Drive,
                      recent: deque[tuple[int, Sensors, Drive, Drive]], period_us: int) -> DivergenceError:
    field = next(f for f in _DRIVE_FIELDS if getattr(target, f) != getattr(twin, f))
    lines = [f"{'period':>8} {'side':<6} {'inputs':>6} {'adc':<18} {'edges':<14} " + " ".join(_DRIVE_FIELDS)]
    for j, s, theirs, mine in recent:
        for side, d in (("target", theirs), ("twin", mine)):
            lines.append(f"{j:>8} {side:<6} {s.inputs:>#6x} {str(tuple(s.adc)):<18} {str(tuple(s.edges)):<14} "
                         + " ".join(str(getattr(d, f)) for f in _DRIVE_FIELDS))
    message = (f"first differing period {k} (t = {k * period_us / 1e6:.6f} s), field {field}: target "
               f"{getattr(target, field)}, twin {getattr(twin, field)} (inputs {sensors.inputs:#04x}, "
               f"ADC {tuple(sensors.adc)}, edges {tuple(sensors.edges)})")
    return DivergenceError(message, "\n".join(lines))


__all__ = ["SpeculativeTarget", "SpeculationStats", "WINDOW", "locate_divergence"]
