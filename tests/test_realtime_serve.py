"""Real time's serve loop in C (hilbench/targets/_remotestep.c `serve_realtime`) against its Python
reference (`_Server._realtime`): the AN1017 and the FOC cores' C advance equal their targets' Python
`advance`, and the loop answers, counts and keeps the model on the wall clock as the Python loop does."""

from __future__ import annotations

import random
import time
from typing import Any, Callable

import pytest

from hilbench.protocol import (FAULT_WATCHDOG, INPUT_INDEX, INPUT_S2, MODE_REALTIME, OUTPUT_OFF, OUTPUT_PWM, Drive,
                               Sensors)
from hilbench.targets import make_target, remote
from hilbench.targets.an1017.target import TCY_PER_US, An1017Target, _CAn1017Target
from hilbench.targets.foc.target import FocTarget, _CFocTarget
from hilbench.targets import serve as serve_module
from test_remote_step import count_c_calls, served_on_a_pty

pytestmark = pytest.mark.skipif(_CAn1017Target is None or remote._remotestep is None,
                                reason="the AN1017 C core or the process paths' C loop is not built")

PERIOD_US = 50


def _sensors(k: int, rng: random.Random) -> Sensors:
    """A Sensors with up to two hall edges (time in 100 ns, lines) and a pot code."""
    edges = tuple(sorted((rng.randrange(0, 20_000), rng.randrange(0, 8)) for _ in range(rng.randrange(0, 3))))
    return Sensors(k & 0xFF, rng.randrange(0, 8), edges, 0, (rng.randrange(0, 1024),))


def test_the_c_advance_is_the_python_advance_drive_for_drive() -> None:
    """`fw.advance` (what the C loop runs) against the Python `An1017Target.advance` on the same core,
    and against the Python reference firmware: every Drive and the carried Tcy fraction equal, over
    spans of a whole period, a little more or less, zero and several periods, the motor started."""
    python_core, c_core = _CAn1017Target(), _CAn1017Target()
    reference = An1017Target(reference=True)
    for target in (python_core, c_core, reference):
        target.start()
    rng = random.Random(28)
    for k in range(6000):
        span_us = rng.choice([1000.0, 999.97, 1000.4, 0.0, 0.02, rng.uniform(0.0, 3000.0)])
        sensors = _sensors(k, rng)
        expected = An1017Target.advance(python_core, span_us, sensors)
        assert c_core.fw.advance(span_us, sensors) == expected, k
        assert An1017Target.advance(reference, span_us, sensors) == expected, k
        assert c_core.fw.frac_tcy == python_core.fw.frac_tcy == reference._frac_tcy, k
    assert c_core.fw.t == python_core.fw.t


def _foc_sensors(k: int, rng: random.Random, encoder: int) -> Sensors:
    """A servo's Sensors: S2 now and then, the encoder's count and index, (ia, ib, vbus) codes."""
    inputs = (INPUT_S2 if rng.random() < 0.002 else 0) | (INPUT_INDEX if rng.random() < 0.01 else 0)
    return Sensors(k & 0xFF, inputs, (), encoder, (rng.randint(0, 4095), rng.randint(0, 4095), rng.randint(3000, 3300)))


@pytest.mark.skipif(_CFocTarget is None, reason="the FOC C core is not built")
def test_the_foc_c_advance_is_the_python_advance_drive_for_drive() -> None:
    """The FOC core's `fw.advance` against `_CFocTarget.advance` on the same core and against the
    Python reference firmware's `FocTarget.advance`: every Drive and the carried part of a half
    period equal, over spans of whole and broken half periods, zero, and several periods."""
    python_core, c_core = _CFocTarget(), _CFocTarget()
    reference = FocTarget(backend="python")
    targets = (python_core, c_core, reference)
    for target in targets:
        target.start()
    rng = random.Random(29)
    encoder = 0
    for k in range(6000):
        encoder = (encoder + rng.randint(-12, 12)) & 0xFFFF
        span_us = rng.choice([1000.0, 999.97, 1000.4, 50.0, 49.99, 0.0, 0.02, rng.uniform(0.0, 3000.0)])
        sensors = _foc_sensors(k, rng, encoder)
        expected = _CFocTarget.advance(python_core, span_us, sensors)
        assert c_core.fw.advance(span_us, sensors) == expected, k
        assert reference.advance(span_us, sensors) == expected, k
        assert c_core.fw.frac_us == python_core.fw.frac_us == reference._frac_us, k
    assert c_core.fw.isr_count == python_core.fw.isr_count == reference.fw.isr_count > 0
    with pytest.raises(ValueError, match="is not a finite time"):
        c_core.fw.advance(float("nan"), sensors)
    with pytest.raises(ValueError, match="half periods in one exchange"):  # more than one exchange may hold
        c_core.fw.advance(1e9, sensors)


def _served_realtime(loop: str, host_side: Callable[[remote.RemoteTarget], dict[str, Any]],
                     monkeypatch: pytest.MonkeyPatch, target: Any = None, watchdog_ms: int = 5000) -> dict[str, Any]:
    """serve(``target``, default the AN1017 C core) in a thread on a pty in real time, its loop in C
    or Python (``loop``), ``host_side(host)`` driving it after the handshake (a watchdog of
    ``watchdog_ms``). Returns what host_side returned, with the report, the calls into C, the
    firmware's time over the run and the server's last_sensors_t."""
    monkeypatch.setenv("HILBENCH_SERVE_LOOP", loop)
    calls = count_c_calls(monkeypatch, "serve_realtime")
    servers: list[Any] = []
    run = serve_module._Server.run

    def kept(self: Any) -> Any:  # the server itself, for its last_sensors_t
        servers.append(self)
        return run(self)

    monkeypatch.setattr(serve_module._Server, "run", kept)
    target = make_target("an1017") if target is None else target
    with served_on_a_pty(target) as (host_link, reports):
        host = remote.RemoteTarget(host_link, timeout_s=20.0, retry_s=10.0)
        host.handshake(PERIOD_US, MODE_REALTIME, watchdog_ms)
        t_start_us = target.time_us
        out = host_side(host)
        host.status()
    return {**out, "report": reports[0], "c_calls": calls[0], "t_us": target.time_us - t_start_us,
            "last_sensors_t": servers[0].last_sensors_t}


def _streamed(stream: list[Sensors]) -> Callable[[remote.RemoteTarget], dict[str, Any]]:
    """The host sends ``stream`` (a Sensors twice in a row: a repeated seq), a ParamGet every 300;
    its Drives, and the times around the first exchange (before the send, after the answer)."""

    def host_side(host: remote.RemoteTarget) -> dict[str, Any]:
        drives, first = [], (0.0, 0.0)
        for i, sensors in enumerate(stream):
            if i % 300 == 299:
                host.get_param(0)
            sent = time.monotonic()
            drives.append(host.step(sensors))
            if i == 0:
                first = (sent, time.monotonic())
        return {"drives": drives, "first": first}

    return host_side


def test_serves_c_realtime_loop_answers_and_counts_as_its_python_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = random.Random(31)
    stream: list[Sensors] = []
    for k in range(1500):
        stream.append(_sensors(k, rng))
        if rng.random() < 0.02:
            stream.append(stream[-1])  # sent again: answered with the last Drive, no advance
    c = _served_realtime("c", _streamed(stream), monkeypatch)
    py = _served_realtime("python", _streamed(stream), monkeypatch)
    assert py["c_calls"] == 0
    assert 0 < c["c_calls"] < len(stream) / 10  # C answered most Sensors, many per call
    for run in (c, py):
        assert [type(d) for d in run["drives"]] == [Drive] * len(stream)
        assert [d.seq for d in run["drives"]] == [s.seq for s in stream]
    assert c["report"].duplicates == py["report"].duplicates > 0
    assert (c["report"].sensors, c["report"].requests, c["report"].handler_faults) == (
        py["report"].sensors, py["report"].requests, py["report"].handler_faults)
    for key in ("frames_rx", "frames_tx", "bytes_rx", "bytes_tx", "seq_gaps", "frame_errors"):
        assert c["report"].link_stats[key] == py["report"].link_stats[key], key


@pytest.mark.parametrize("loop", ["c", "python"])
def test_the_realtime_loop_keeps_the_model_on_the_wall_clock(loop: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The firmware's time over a real-time run is the first period plus the wall time from the first
    Sensors' arrival to the last one's (`last_sensors_t`, written back by C): the first arrival lies
    between the host's send and its Drive's return, which bounds it however loaded the machine."""
    rng = random.Random(32)
    stream = [_sensors(k, rng) for k in range(400)]
    run = _served_realtime(loop, _streamed(stream), monkeypatch)
    assert (run["c_calls"] > 0) == (loop == "c")
    last_s = run["last_sensors_t"]
    sent_s, answered_s = run["first"]
    low_us = PERIOD_US + (last_s - answered_s) * 1e6
    high_us = PERIOD_US + (last_s - sent_s) * 1e6
    slack_us = 2.0 / TCY_PER_US  # whole Tcy: the carried fraction
    assert low_us - slack_us <= run["t_us"] <= high_us + slack_us, (low_us, run["t_us"], high_us)


def _trip_and_resume(host: remote.RemoteTarget) -> dict[str, Any]:
    """S2, run until the PWM is on, fall silent until the watchdog's Drive, send the last seq again
    (a repeat after the trip), then new seqs."""
    seq = [0]

    def sensors(inputs: int = 5) -> Sensors:
        seq[0] = (seq[0] + 1) & 0xFF
        return Sensors(seq[0], inputs, (), 0, (600,))

    host.step(sensors())
    host.step(sensors(5 | 0x08))  # S2
    deadline = time.monotonic() + 30.0
    drive = host.step(sensors())
    while drive.output_mode != OUTPUT_PWM:  # the 10 ms bootstrap on the firmware's wall clock
        assert time.monotonic() < deadline, drive
        drive = host.step(sensors())
    tripped = host.watchdog_trip()
    repeat = host.step(Sensors(seq[0], 5, (), 0, (600,)))
    after = [host.step(sensors()) for _ in range(3)]
    return {"running": drive, "tripped": tripped, "repeat": repeat, "after": after}


def test_a_watchdog_trip_and_the_sensors_after_it_are_the_same_in_both_loops(monkeypatch: pytest.MonkeyPatch) -> None:
    """The watchdog fires in the C loop's wait as in the Python loop's; a Sensors repeating the last
    seq after the trip is a new period (outputs off, not the running Drive again), and new seqs go on."""
    runs = {loop: _served_realtime(loop, _trip_and_resume, monkeypatch, watchdog_ms=30) for loop in ("c", "python")}
    for loop, run in runs.items():
        assert run["running"].output_mode == OUTPUT_PWM, loop
        assert (run["tripped"].output_mode, run["tripped"].fault) == (OUTPUT_OFF, FAULT_WATCHDOG), loop
        assert run["repeat"].output_mode == OUTPUT_OFF and run["repeat"].seq == run["tripped"].seq, loop
        assert [d.output_mode for d in run["after"]] == [OUTPUT_OFF] * 3, loop
        assert run["report"].watchdog_trips == 1 and run["report"].duplicates == 0, loop
    assert runs["c"]["c_calls"] > 0 and runs["python"]["c_calls"] == 0


class _OwnAdvance(_CAn1017Target):  # type: ignore[misc, valid-type]
    """A subclass with an advance of its own: the C loop would skip it."""

    advanced = 0

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        type(self).advanced += 1
        return super().advance(duration_us, sensors)


class _Wrapped:
    """A wrapper around the C target with its own advance (a stalling or faulting test target's
    pattern), everything else passed through."""

    def __init__(self) -> None:
        self.inner = make_target("an1017")
        self.advanced = 0

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        self.advanced += 1
        return self.inner.advance(duration_us, sensors)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@pytest.mark.skipif(_CFocTarget is None, reason="the FOC C core is not built")
def test_the_foc_emulator_is_served_by_the_c_realtime_loop_as_by_the_python_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = random.Random(33)
    stream: list[Sensors] = []
    for k in range(1500):
        stream.append(_foc_sensors(k, rng, (k * 7) & 0xFFFF))
        if rng.random() < 0.02:
            stream.append(stream[-1])  # sent again: answered with the last Drive, no advance
    runs = {loop: _served_realtime(loop, _streamed(stream), monkeypatch, target=make_target("foc")) for loop in ("c", "python")}
    assert runs["python"]["c_calls"] == 0 and 0 < runs["c"]["c_calls"] < len(stream) / 10
    for run in runs.values():
        assert [d.seq for d in run["drives"]] == [s.seq for s in stream]
        assert run["report"].handler_faults == 0 and run["report"].duplicates > 0
    assert runs["c"]["report"].sensors == runs["python"]["report"].sensors


def _s2_refused_then_repeat(host: remote.RemoteTarget) -> dict[str, Any]:
    """Sensors answered; the next one presses S2 but lacks the ADC codes its span needs (the FOC
    advance raises after taking S2); then the last answered seq again: the repeat's answer."""
    for seq in range(1, 21):  # (the C loop answers from the second or so on)
        first = host.step(Sensors(seq, 0, (), 0, (2048, 2048, 3100)))
    time.sleep(0.002)  # real time: let the span hold underflows (which read the ADC codes it lacks)
    host.link.send(Sensors(21, int(INPUT_S2), (), 0, ()))
    refused = host.link.recv_or_none(20.0)
    repeat = host.step(Sensors(20, 0, (), 0, (2048, 2048, 3100)))
    return {"first": first, "refused": refused, "repeat": repeat}


@pytest.mark.skipif(_CFocTarget is None, reason="the FOC C core is not built")
def test_a_repeat_after_a_refused_sensors_is_the_drive_sent_in_both_loops(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Python loop keeps the Drive it sent as the repeat's answer when the next advance raises; the
    C loop did rebuild it from the core, which had taken that Sensors' S2 before the raise."""
    runs = {loop: _served_realtime(loop, _s2_refused_then_repeat, monkeypatch, target=make_target("foc"))
            for loop in ("c", "python")}
    for loop, run in runs.items():
        assert type(run["refused"]).__name__ == "ErrorReport", (loop, run["refused"])
        assert run["repeat"] == run["first"], loop
        assert run["report"].handler_faults == 1 and run["report"].duplicates == 1, loop
    assert runs["c"]["c_calls"] > 0


def test_a_target_with_its_own_advance_is_served_by_the_python_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    stream = [Sensors(k & 0xFF, 5, (), 0, (600,)) for k in range(50)]
    wrapped = _Wrapped()
    run = _served_realtime("c", _streamed(stream), monkeypatch, target=wrapped)
    assert run["c_calls"] == 0 and wrapped.advanced == len(stream)
    _OwnAdvance.advanced = 0
    run = _served_realtime("c", _streamed(stream), monkeypatch, target=_OwnAdvance())
    assert run["c_calls"] == 0 and _OwnAdvance.advanced == len(stream)


def test_the_c_advance_refuses_a_span_that_is_not_a_finite_time() -> None:
    target = _CAn1017Target()
    for span_us in (float("nan"), float("inf"), -float("inf"), 1e300):
        with pytest.raises(ValueError, match="is not a finite time"):
            target.fw.advance(span_us, Sensors(1, 5, (), 0, (600,)))


@pytest.mark.skipif(_CFocTarget is None, reason="the FOC C core is not built")
def test_both_foc_advances_refuse_a_span_back_in_time_or_too_long() -> None:
    """The reference refuses what the C core cannot run (it returned zero duties for a negative span)."""
    sensors = Sensors(1, 0, (), 0, (2048, 2048, 3100))
    for target in (FocTarget(), _CFocTarget()):
        for span_us in (-200.0, 50.0 * 572_663):
            with pytest.raises(ValueError, match=r"half periods in one exchange \(0\.\.572662\)"):
                target.advance(span_us, sensors)
