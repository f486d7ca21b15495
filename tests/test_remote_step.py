"""RemoteTarget.step in C (hilbench/targets/_remotestep.c) for the session's C span with a process
target is the Python loop's exchange, proven equal: its codec gives the Python codec's bytes and
answers, the recordings and link counters of emulator and SIL runs are the Python loop's column for
column (also with live writes, sensor faults, and a target whose own link corrupts and duplicates
frames), and a target that falls silent or dies ends both runs with the same error."""

from __future__ import annotations

import contextlib
import os
import random
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

import hilbench
from hilbench.bench.session import Session, _span
from hilbench.errors import DecodeError, HilbenchError, ProtocolError
from hilbench.link import Link
from hilbench.plant import model
from hilbench.processes import reap, spawn
from hilbench.protocol import Drive, Sensors, decode_frame, encode_frame
from hilbench.targets import remote

from _firmware import require_tool

ROOT = Path(__file__).resolve().parent.parent
RANDOM = ROOT / "tests" / "golden" / "random_an1017.toml"
SERVO = ROOT / "bench_configs" / "servo_200w.toml"

pytestmark = pytest.mark.skipif(_span is None or model._CPlant is None or remote._remotestep is None,
                                reason="the C span or the C remote step is not built")


# ------------------------------------------------------------------------------------ the codec
def _random_sensors(rng: random.Random) -> Sensors:
    edges = tuple(sorted((rng.randrange(0, 1 << 16), rng.randrange(256)) for _ in range(rng.choice((0, 0, 1, 2, 5, 16)))))
    adc = tuple(rng.randrange(0, 1 << 16) for _ in range(rng.choice((0, 1, 3, 8))))
    return Sensors(rng.randrange(256), rng.randrange(256), edges, rng.randrange(0, 1 << 16), adc)


def test_the_c_sensors_frame_is_the_python_encoders() -> None:
    """Every count of ADC codes and edges; a message too long for a frame is None in C and a
    ProtocolError in Python (the C step leaves it to the Python reference, which raises it)."""
    rng = random.Random(27)
    too_long = 0
    for _ in range(3000):
        s = _random_sensors(rng)
        try:
            expected: bytes | None = encode_frame(s)
        except ProtocolError:
            expected, too_long = None, too_long + 1
        assert remote._remotestep.encode_sensors(s.seq, s.inputs, s.edges, s.encoder, s.adc) == expected
    assert 0 < too_long < 3000


@pytest.mark.parametrize("field, value", [("encoder", 1 << 16), ("encoder", -1), ("inputs", 256), ("adc", (70000,)),
                                          ("adc", (1,) * 9), ("edges", ((70000, 1),)), ("edges", ((5, 300),)),
                                          ("edges", ((5, 1),) * 17)])
def test_a_sensors_field_outside_its_wire_range_is_left_to_the_python_encoder(field: str, value: Any) -> None:
    s = Sensors(1, 2, (), 3, (4, 5, 6))._replace(**{field: value})
    assert remote._remotestep.encode_sensors(s.seq, s.inputs, s.edges, s.encoder, s.adc) is None
    with pytest.raises(ProtocolError):
        encode_frame(s)


def _python_drive(data: bytes) -> tuple | None:
    """What Link._take_read's fast path takes as one Drive from one read (else None)."""
    if not data or data[-1] != 0:
        return None
    try:
        msg = decode_frame(data[:-1])
    except DecodeError:
        return None
    return tuple(msg) if type(msg) is Drive else None


def test_the_c_drive_decoder_accepts_what_the_python_decoder_accepts() -> None:
    """Good Drives of every telemetry count, and for each: every single-bit flip, bursts, cuts,
    two frames in one read, another message type."""
    rng = random.Random(28)
    decode = remote._remotestep.decode_drive
    for i in range(300):
        d = Drive(rng.randrange(256), rng.randrange(1 << 12), rng.randrange(1 << 12), rng.randrange(1 << 12),
                  rng.randrange(4), rng.randrange(8), rng.randrange(8), rng.random() < 0.5, rng.random() < 0.5,
                  rng.randrange(64), tuple(rng.randrange(-32768, 32768) for _ in range(rng.randrange(9))))
        wire = encode_frame(d)
        assert decode(wire) == tuple(d)
        variants = [wire[:-1], wire[:n] + b"\x00" if (n := rng.randrange(1, len(wire))) else wire, wire + wire,
                    encode_frame(Sensors(1, 2, (), 3, (4,)))]
        for bit in range(len(wire) * 8):
            variants.append(bytes(b ^ (1 << (bit % 8)) if j == bit // 8 else b for j, b in enumerate(wire)))
        for _ in range(20):
            at, width = rng.randrange(len(wire)), rng.randrange(1, 17)
            burst = int.from_bytes(wire, "big") ^ (((1 << width) - 1) << (8 * len(wire) - at * 8 - width if
                                                                           8 * len(wire) - at * 8 - width > 0 else 0))
            variants.append(burst.to_bytes(len(wire), "big"))
        for v in variants:
            assert decode(v) == _python_drive(v), (i, v.hex())


def test_the_c_sensors_decoder_accepts_what_the_python_decoder_accepts() -> None:
    """serve's C loop reads Sensors: good ones of every size, every single-bit flip of each, cuts."""
    rng = random.Random(29)
    decode = remote._remotestep.decode_sensors
    for i in range(300):
        s = _random_sensors(rng)
        try:
            wire = encode_frame(s)
        except ProtocolError:
            continue
        assert decode(wire) == tuple(s)
        variants = [wire[:-1], wire + wire, wire[: rng.randrange(1, len(wire))] + b"\x00"]
        for bit in range(len(wire) * 8):
            variants.append(bytes(b ^ (1 << (bit % 8)) if j == bit // 8 else b for j, b in enumerate(wire)))
        for v in variants:
            expected = None
            if v and v[-1] == 0:
                try:
                    msg = decode_frame(v[:-1])
                except DecodeError:
                    msg = None
                expected = tuple(msg) if type(msg) is Sensors else None
            assert decode(v) == expected, (i, v.hex())


# ------------------------------------------------------------------------------- the recordings
def _run(mode: str, target: str, config: Path | None, scenario: Path | None, seconds: float,
         overrides: tuple[str, ...] = ()) -> tuple[dict[str, np.ndarray], tuple[str, ...], dict[str, int], list[Any]]:
    """One run with the C span ("c") or the Python loop ("python"): the columns, the events, the
    link's counters and the span objects the session made."""
    cfg = hilbench.load_config(config, [f'link.target="{target}"', f"run.duration_s={seconds}", *overrides],
                               scenario_path=scenario)
    spans: list[Any] = []
    # the Python reference on both ends: an emulator process started here runs serve()'s Python loop
    os.environ["HILBENCH_SERVE_LOOP"] = "c" if mode == "c" else "python"
    cores: list[Any] = []
    span_core = remote.RemoteTarget.span_core

    def noted_span_core(self: remote.RemoteTarget) -> Any:  # the C cores the spans run (a spy, not a stand-in)
        core = span_core(self)
        cores.append(core)
        return core

    with hilbench.Bench(cfg, scenario=True) as bench, pytest.MonkeyPatch.context() as patch:
        patch.setattr(remote.RemoteTarget, "span_core", noted_span_core)
        session = bench.session
        assert isinstance(session, Session)
        session.c_span = mode == "c"  # type: ignore[misc]
        make = session._c_span
        session._c_span = lambda rows: spans.append(make(rows)) or spans[-1]  # type: ignore[method-assign]
        bench.run()
        signals = bench.signals()
        columns = {name: np.asarray(signals[name]) for name in signals}
        link = session.target.link  # type: ignore[attr-defined]
        stats = link.stats.as_dict()
        stats["stale_frames"] = session.target.stale_frames  # type: ignore[attr-defined]
        stats["retries"] = session.target.retries  # type: ignore[attr-defined]
        stats["fast_frames"] = getattr(link, "fast_frames", -1)
        stats["c_steps"] = sum(core[1].c_steps for core in cores if core is not None)
        return columns, bench.events, stats, spans


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    assert a.keys() == b.keys() and len(a["t_s"]) > 1000
    return [name for name in a if not np.array_equal(a[name], b[name], equal_nan=True)]


@pytest.fixture(autouse=True)
def _serve_loop_env(monkeypatch: pytest.MonkeyPatch) -> None:
    """`_run` sets HILBENCH_SERVE_LOOP for the emulator processes it starts; put it back after."""
    monkeypatch.setenv("HILBENCH_SERVE_LOOP", "c")


@pytest.mark.parametrize("target, config, scenario, seconds, overrides", [
    ("emulator:an1017", None, None, 0.3, ()),
    # the host's own injector corrupts and duplicates its Sensors: the host steps in Python (a
    # FaultyLink), the emulator's C loop hands every bad frame and repeated seq to its Python loop
    ("emulator:an1017?corrupt=5e-5&corrupt_dir=tx&dup=0.003&fault_seed=5", None, None, 0.4,
     ("link.timeout_ms=2000", "link.retry_ms=20")),
    ("emulator:an1017", None, RANDOM, 0.8, ()),  # live writes, every sensor fault kind, buttons
    ("emulator:an1017", None, None, 1.5, ("link.period_us=1000",)),  # several hall edges per Sensors
    ("sil:an1017", None, None, 0.3, ()),
    ("sil:foc", SERVO, None, 0.3, ()),
])
def test_a_process_target_records_with_the_c_step_what_the_python_loop_records(
        target: str, config: Path | None, scenario: Path | None, seconds: float, overrides: tuple[str, ...]) -> None:
    if target.startswith("sil:"):
        require_tool("gcc", "the SIL firmware is built with gcc")
    c, c_events, c_stats, c_spans = _run("c", target, config, scenario, seconds, overrides)
    py, py_events, py_stats, py_spans = _run("python", target, config, scenario, seconds, overrides)
    assert not _same(c, py)
    assert c_events == py_events
    assert all(span is None for span in py_spans)
    if "corrupt" in target:  # (a retry on a loaded machine moves the injector's later faults)
        assert c_stats["retries"] > 0 and py_stats["retries"] > 0
        assert c_stats["c_steps"] == py_stats["c_steps"] == 0  # a FaultyLink: no C step
        return
    c_steps = c_stats.pop("c_steps")
    assert py_stats.pop("c_steps") == 0
    differ = {key: (c_stats[key], py_stats[key]) for key in c_stats if c_stats[key] != py_stats[key]}
    if any(c_stats[key] or py_stats[key] for key in ("retries", "timeouts")):
        # a host that waited out its timeout on a loaded machine resent a Sensors and got its Drive
        # twice: the frame and byte counts of that run move, and the repeated Drive's seq counts a
        # gap (the Python run of sil:foc in a loaded full suite: seq_gaps 0 -> 1); the error
        # counters must not move
        moved = {"retries", "timeouts", "frames_tx", "frames_rx", "bytes_tx", "bytes_rx", "stale_frames", "fast_frames",
                 "seq_gaps"}
        differ = {key: value for key, value in differ.items() if key not in moved}
    assert not differ, f"link counters (C, Python) that differ: {differ}"
    assert any(span is not None and span.k > 0 for span in c_spans)  # the C span ran, with the C step
    assert c_steps > c_stats["frames_tx"] / 2  # and the C step answered most periods itself


# ------------------------------------------------------------- a faulty or failing target process
def _emulator(faults: str) -> tuple[subprocess.Popen[bytes], str]:
    """The AN1017 emulator as its own process on a pty whose own link (the target's end) has
    ``faults`` (the link spec's query); returns it and the pty path the host opens."""
    process = spawn([sys.executable, "-P", "-m", "hilbench.targets.emulator", "an1017", "--port", f"pty?{faults}",
                     "--mode", "lockstep"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                    stderr=subprocess.DEVNULL, start_new_session=True)
    assert process.stdout is not None
    path = process.stdout.readline().decode().strip()  # announced once it answers
    if not path.startswith("/dev/"):
        reap(process)
        pytest.fail(f"the emulator announced {path!r}")
    return process, path


def test_a_target_that_corrupts_and_repeats_frames_gets_the_same_answers_from_both_paths() -> None:
    """Bad frames (its Drive's bits flipped) and Drives sent twice (a stale seq in the next period),
    from the target's own seeded injector: the C step hands each to the Python reference."""
    runs = []
    for mode in ("c", "python"):
        process, path = _emulator("corrupt=5e-5&corrupt_dir=tx&dup=0.003&fault_seed=5")
        try:  # a lost Drive costs a retry: 20 ms here, not the default 100
            runs.append(_run(mode, path, None, None, 0.4, ("link.timeout_ms=2000", "link.retry_ms=20")))
        finally:
            reap(process)
    (c, c_events, c_stats, c_spans), (py, py_events, py_stats, _) = runs
    assert not _same(c, py)
    assert c_events == py_events
    assert c_stats["crc_errors"] + c_stats["cobs_errors"] + c_stats["length_errors"] > 0
    assert c_stats["stale_frames"] > 0 and c_stats["retries"] > 0
    assert any(span is not None and span.k > 0 for span in c_spans)
    assert c_stats["c_steps"] > c_stats["frames_tx"] / 2 and py_stats["c_steps"] == 0  # C answered most periods
    # (the counters themselves may differ: a retry sent because the loaded machine delayed an answer
    # past retry_ms is one more frame through the target's injector, which moves its later faults)
    assert py_stats["crc_errors"] + py_stats["cobs_errors"] + py_stats["length_errors"] > 0


def _failing(mode: str, faults: str, kill_after: int | None) -> tuple[type, str, int, bytes]:
    """A lockstep run against an emulator with ``faults`` on its own link, killed after
    ``kill_after`` periods when given: the error, its message, the period and the rows recorded."""
    process, path = _emulator(faults)
    try:
        cfg = hilbench.load_config(None, [f'link.target="{path}"', "run.duration_s=0.5", "link.timeout_ms=300"])
        with hilbench.Bench(cfg, scenario=True) as bench:
            session = bench.session
            assert isinstance(session, Session)
            session.c_span = mode == "c"  # type: ignore[misc]
            session.begin()
            with pytest.raises(HilbenchError) as caught:
                if kill_after is not None:
                    session.advance(kill_after)
                    os.kill(process.pid, signal.SIGKILL)
                    process.wait(timeout=10)
                session.advance(session.planned_periods)
            recorder = session.recorder
            rows = bytes(recorder.rows.data) if recorder is not None and hasattr(recorder, "rows") else b""
            return type(caught.value), str(caught.value), session.periods_done, rows
    finally:
        reap(process)


@pytest.mark.parametrize("faults, kill_after", [
    ("silent_after=1500&fault_seed=1", None),  # the target stops answering: a timeout
    ("fault_seed=1", 1200),  # the target process dies: the far end hung up
])
def test_a_silent_or_dead_target_ends_both_paths_with_the_same_error(faults: str, kill_after: int | None) -> None:
    c = _failing("c", faults, kill_after)
    py = _failing("python", faults, kill_after)
    assert c[0] is py[0] and issubclass(c[0], HilbenchError)
    pty_name = re.compile(r"/dev/pts/\d+")  # each run gets its own pty: the message names it
    assert pty_name.sub("/dev/pts/N", c[1]) == pty_name.sub("/dev/pts/N", py[1])
    assert c[2:] == py[2:]
    assert c[2] > 1000


# ------------------------------------------------------------------------ serve's loop, in a thread
def count_c_calls(monkeypatch: pytest.MonkeyPatch, name: str) -> list[int]:
    """How often the server's loop calls `_remotestep.<name>` (a serve loop in C), in the list's one
    item as the test goes on: a spy, not a stand-in."""
    calls = [0]
    real = getattr(remote._remotestep, name)

    def counted(*args: Any) -> Any:
        calls[0] += 1
        return real(*args)

    monkeypatch.setattr(remote._remotestep, name, counted)
    return calls


def _served_an1017(loop: str, stream: list[Sensors], monkeypatch: pytest.MonkeyPatch,
                   sequenced: tuple[type, ...] = (Sensors, Drive)) -> tuple[list[Drive], Any]:
    """serve(AN1017 with its C core) in a thread on a pty, its loop in C or Python (``loop``), its
    link keeping a running seq of the ``sequenced`` types; the host steps ``stream`` (a Sensors
    twice in a row: a repeated seq), a ParamGet every 500 Sensors and a Status at the end. Returns
    the Drives and the server's report."""
    from hilbench.protocol import MODE_LOCKSTEP
    from hilbench.targets import make_target

    monkeypatch.setenv("HILBENCH_SERVE_LOOP", loop)
    calls = count_c_calls(monkeypatch, "serve_lockstep")
    target = make_target("an1017")
    assert getattr(target, "span_core", None) is not None, "the AN1017 C core is not built"
    with served_on_a_pty(target, sequenced) as (host_link, reports):
        # no retries: a pty loses nothing, and a retry under load would count a request (and frames) twice
        host = remote.RemoteTarget(host_link, timeout_s=20.0, retry_s=10.0)
        host.handshake(50, MODE_LOCKSTEP, 100)  # a watchdog: serve waits with a timeout (its C loop's case)
        drives = []
        for i, s in enumerate(stream):
            if i % 500 == 499:
                host.get_param(0)
            drives.append(host.step(s))
        host.status()
    reports[0].c_calls = calls[0]
    return drives, reports[0]


@contextlib.contextmanager
def served_on_a_pty(target: Any, sequenced: tuple[type, ...] = (Sensors, Drive)) -> Iterator[tuple[Link, list[Any]]]:
    """``target`` served (`serve`) by a thread on the far end of a new pty, its link keeping a running
    seq of the ``sequenced`` types: yields the host's end and the list the server's report lands in
    (there once the block has left and the server ended)."""
    import threading

    from hilbench.link import open_link
    from hilbench.targets.serve import serve

    host_link = open_link("pty", timeout_s=2.0)
    far_link = open_link(host_link.peer_path, timeout_s=2.0)
    if sequenced != (Sensors, Drive):
        far_link = Link(far_link.transport, far_link.name, timeout_s=2.0, sequenced_types=sequenced)
    reports: list[Any] = []
    thread = threading.Thread(target=lambda: reports.append(serve(target, far_link)), daemon=True)
    thread.start()
    try:
        yield host_link, reports
    finally:
        host_link.close()
        thread.join(timeout=20)
        far_link.close()
    assert not thread.is_alive() and reports


def test_serves_c_loop_answers_what_its_python_loop_answers(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = random.Random(30)
    halls = (1, 3, 2, 6, 4, 5)
    stream: list[Sensors] = []
    for k in range(3000):
        s = Sensors(k & 0xFF, halls[(k // 40) % 6] | (0x08 if 20 <= k < 30 else 0), (), 0, (700 + k // 20, 512, 640))
        stream.append(s)
        if rng.random() < 0.02:
            stream.append(s)  # sent again: answered with the last Drive, no step
    c_drives, c_report = _served_an1017("c", stream, monkeypatch)
    py_drives, py_report = _served_an1017("python", stream, monkeypatch)
    assert py_report.c_calls == 0
    assert 0 < c_report.c_calls < len(stream) / 10  # C answered most Sensors, many per call
    assert c_drives == py_drives
    assert [type(d) for d in c_drives] == [Drive] * len(stream)
    assert c_report.duplicates == py_report.duplicates > 0
    assert (c_report.sensors, c_report.requests, c_report.handler_faults) == (
        py_report.sensors, py_report.requests, py_report.handler_faults)
    for key in ("frames_rx", "frames_tx", "bytes_rx", "bytes_tx", "seq_gaps", "frame_errors"):
        assert c_report.link_stats[key] == py_report.link_stats[key], key


@pytest.mark.parametrize("sequenced", [(), (Drive,)])
def test_serves_c_loop_on_a_link_that_keeps_no_sensors_seq_answers_as_its_python_loop(
        sequenced: tuple[type, ...], monkeypatch: pytest.MonkeyPatch) -> None:
    """A Link that sequences no Sensors (Link's sequenced_types): no gap is counted for the seqs the
    host skips, in C as in Python (C used to raise a RuntimeError there)."""
    halls = (1, 3, 2, 6, 4, 5)
    stream = [Sensors(k & 0xFF, halls[(k // 40) % 6], (), 0, (700, 512, 640)) for k in range(1200) if k % 97 != 50]
    c_drives, c_report = _served_an1017("c", stream, monkeypatch, sequenced)
    py_drives, py_report = _served_an1017("python", stream, monkeypatch, sequenced)
    assert 0 < c_report.c_calls < len(stream) / 10 and py_report.c_calls == 0
    assert c_drives == py_drives
    assert c_report.link_stats == py_report.link_stats
    assert c_report.link_stats["seq_gaps"] == 0


# ------------------------------------------------------------------- signals in serve's C loop
def _serve_in_main_thread(host: Any, loop: str, monkeypatch: pytest.MonkeyPatch, timeout_s: float = 2.0,
                          target: Any = None) -> Any:
    """serve() of ``target`` (default: the AN1017 C core) in this (the main) thread, the only one
    Python signal handlers run in, while ``host(remote_target)`` runs in a thread; returns serve's
    report, or raises what serve raised. The host's link closes when host returns (serve's end
    when it still serves)."""
    from hilbench.link import open_link
    from hilbench.protocol import MODE_LOCKSTEP
    from hilbench.targets import make_target
    from hilbench.targets.serve import serve
    import threading

    monkeypatch.setenv("HILBENCH_SERVE_LOOP", loop)
    target = make_target("an1017") if target is None else target
    assert getattr(target, "span_core", None) is not None, "the target's C step is not built"
    host_link = open_link("pty", timeout_s=2.0)
    far_link = open_link(host_link.peer_path, timeout_s=2.0)

    def run_host() -> None:
        try:
            remote_target = remote.RemoteTarget(host_link, timeout_s=timeout_s)
            remote_target.handshake(50, MODE_LOCKSTEP, 100)  # a watchdog: serve's C loop polls with a timeout
            host(remote_target)
        except HilbenchError:
            pass  # serve stopped answering
        finally:
            host_link.close()

    thread = threading.Thread(target=run_host, daemon=True)
    thread.start()
    try:
        return serve(target, far_link)
    finally:
        thread.join(timeout=20)
        far_link.close()
        assert not thread.is_alive()


def _stream(remote_target: Any, stop: Any, limit: int) -> int:
    """Sensors one period after another until stop is set or ``limit`` periods; the count."""
    halls = (1, 3, 2, 6, 4, 5)
    k = 0
    while not stop.is_set() and k < limit:
        remote_target.step(Sensors(k & 0xFF, halls[(k // 40) % 6], (), 0, (700, 512, 640)))
        k += 1
    return k


@pytest.mark.parametrize("loop", ["c", "python"])
def test_ctrl_c_stops_serve_while_a_host_keeps_sending(loop: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGINT taken by another thread (the C handler notes it; serve's poll is not interrupted and
    finds data every period): serve still raises KeyboardInterrupt before the host stops sending."""
    import threading

    stop, done = threading.Event(), threading.Event()

    def host(remote_target: Any) -> None:
        _stream(remote_target, stop, 200)
        signal.pthread_kill(threading.get_ident(), signal.SIGINT)  # this thread's, not serve's
        _stream(remote_target, stop, 5000)
        done.set()

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            _serve_in_main_thread(host, loop, monkeypatch)
        assert not done.is_set()  # the host was still sending
    finally:
        stop.set()
        signal.signal(signal.SIGINT, previous)


def test_a_poll_interrupted_by_signals_still_times_out(monkeypatch: pytest.MonkeyPatch) -> None:
    """A host that falls silent while signals keep interrupting serve's poll (a handler that does
    nothing, every couple of ms): the poll's timeout still runs out, so the watchdog trips (each
    signal used to restart the poll with its whole timeout, and the watchdog never came)."""
    import threading

    main = threading.get_ident()
    tripped, signalling = threading.Event(), threading.Event()
    trips: list[Any] = []

    def signaller() -> None:
        signalling.set()
        for _ in range(6000):  # >= 12 s of signals; the watchdog is due after 1 s of silence
            if tripped.is_set():
                return
            signal.pthread_kill(main, signal.SIGUSR1)
            tripped.wait(0.002)
        signalling.clear()

    def host(remote_target: Any) -> None:
        _stream(remote_target, threading.Event(), 50)
        feeder = threading.Thread(target=signaller, daemon=True)
        feeder.start()
        try:
            trips.append(remote_target.watchdog_trip())  # waits timeout_s (10 s) past the watchdog
            trips.append(signalling.is_set())
        finally:
            tripped.set()
            feeder.join(timeout=20)

    noted = [0]
    previous = signal.signal(signal.SIGUSR1, lambda *_: noted.__setitem__(0, noted[0] + 1))
    try:
        report = _serve_in_main_thread(host, "c", monkeypatch, timeout_s=10.0)
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert noted[0] > 0
    assert len(trips) == 2 and trips[0].fault and trips[1]  # the watchdog Drive while the signals still came
    assert report.sensors == 50


@pytest.mark.parametrize("loop", ["c", "python"])
def test_ctrl_c_inside_the_targets_step_stops_serve(loop: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A KeyboardInterrupt out of the target's step is not a model fault to answer BAD_REQUEST to: it
    ends serve, in C as in Python. The target is a RemoteTarget (its step in C) relaying to an
    AN1017 served in a thread, held inside one step while SIGINT comes to serve's thread."""
    from hilbench.link import open_link
    from hilbench.targets import make_target
    from hilbench.targets.serve import serve
    import threading

    main = threading.get_ident()
    armed, entered, release = threading.Event(), threading.Event(), threading.Event()
    inner = make_target("an1017")
    inner_step = inner.step

    def held_step(sensors: Sensors) -> Drive:  # the far target answers this Sensors only once released
        if armed.is_set():
            entered.set()
            release.wait(20)
        return inner_step(sensors)

    inner.step = held_step  # type: ignore[method-assign]
    relay_link = open_link("pty", timeout_s=2.0)
    inner_link = open_link(relay_link.peer_path, timeout_s=2.0)
    inner_thread = threading.Thread(target=lambda: serve(inner, inner_link), daemon=True)
    inner_thread.start()

    def host(remote_target: Any) -> None:
        _stream(remote_target, threading.Event(), 30)
        armed.set()
        killer = threading.Thread(target=lambda: entered.wait(20) and signal.pthread_kill(main, signal.SIGINT))
        killer.start()
        try:
            _stream(remote_target, threading.Event(), 1)
        finally:
            killer.join(timeout=20)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        relay = remote.RemoteTarget(relay_link, timeout_s=10.0)
        with pytest.raises(KeyboardInterrupt):
            _serve_in_main_thread(host, loop, monkeypatch, target=relay)
        assert entered.is_set()
    finally:
        signal.signal(signal.SIGINT, previous)
        release.set()
        relay_link.close()
        inner_thread.join(timeout=20)
        inner_link.close()
    assert not inner_thread.is_alive()


def test_a_command_waits_for_a_probe_answered_without_a_resend() -> None:
    """Start and Stop have no reply, and a frame arriving while one is still in hand in the target's
    receiver is dropped: StatusRequests before the command until one goes without a resend."""
    resends = [3]
    probes: list[int] = []

    def probe() -> None:  # the first probe is itself resent once, the second goes clean
        probes.append(1)
        resends[0] += 1 if len(probes) == 1 else 0

    remote.settle(lambda: resends[0], probe)
    assert len(probes) == 2
    endless = iter(range(100))
    remote.settle(lambda: next(endless), lambda: probes.append(1))  # every probe resent: then sent anyway
    assert len(probes) == 2 + remote.SETTLE_PROBES


def test_a_stop_goes_out_even_when_the_target_does_not_answer_the_probe() -> None:
    from hilbench.errors import LinkTimeout
    from hilbench.link import open_link

    host = open_link("pty", timeout_s=1.0)
    far = open_link(host.peer_path, timeout_s=1.0)
    try:
        target = remote.RemoteTarget(host, timeout_s=0.2, retry_s=0.05)
        with pytest.raises(LinkTimeout, match="^Stop sent, unconfirmed: the StatusRequest before it failed: "):
            target.stop()
        got = []
        while (msg := far.recv_or_none(1.0)) is not None:
            got.append(type(msg).__name__)
        assert got[-1] == "Stop" and set(got[:-1]) == {"StatusRequest"}, got
    finally:
        far.close()
        host.close()


def test_a_monitor_press_goes_on_when_the_board_does_not_answer_the_probe() -> None:
    """S2 on a board that answers no StatusRequest (one busy sending): the Start went out, and the
    run goes on with a note (it raised out of the run), its Start resent if the stream says stopped."""
    from hilbench.bench.monitor import MonitorSession
    from hilbench.link import open_link
    from hilbench.protocol import Start

    host = open_link("pty", timeout_s=1.0)
    far = open_link(host.peer_path, timeout_s=1.0)
    try:
        session = MonitorSession(remote.RemoteTarget(host, timeout_s=0.2, retry_s=0.05), [])
        session.press("s2", 1.5)
        got = []
        while (msg := far.recv_or_none(1.0)) is not None:
            got.append(type(msg).__name__)
        assert got[-1] == "Start" and set(got[:-1]) == {"StatusRequest"}, got
        assert session.messages[-1].startswith("1.500 s: Start sent, unconfirmed: "), session.messages
        assert session._pending is Start and session._pending_rx == session._drives_rx
    finally:
        far.close()
        host.close()


def test_a_monitor_command_is_judged_on_the_drives_received_after_it() -> None:
    """The Drives parked while a Start's probe waited all say STOPPED and predate it: working through
    them must not count as the Start going unseen (it sent a second Start, and a second probe). A
    Stop not seen taken is sent again as a Start is (a ctl or dashboard press went unchecked)."""
    from hilbench.bench.monitor import COMMAND_SEEN_S, MonitorSession
    from hilbench.link import open_link
    from hilbench.protocol import State

    host = open_link("pty", timeout_s=1.0)
    try:
        session = MonitorSession(remote.RemoteTarget(host, timeout_s=0.2, retry_s=0.05), [])
        sent: list[tuple[str, float]] = []
        session.target.start = lambda: sent.append(("start", session.t_s))  # type: ignore[method-assign]
        session.target.stop = lambda: sent.append(("stop", session.t_s))  # type: ignore[method-assign]
        stopped = Drive(0, 0, 0, 0, 0, int(State.STOPPED), 0, False, False, 0, (0, 0, 0))
        running = stopped._replace(state=int(State.RUNNING))
        session.drive = stopped
        session._drives_rx = 10
        session.press("s2", 0.0)
        assert sent == [("start", 0.0)] and session._pending_rx == 10
        session._drives_rx, session._inbox = 16, [stopped] * 6  # 6 parked, 4 new: rows of old Drives
        session.t_s = 1.0
        session._check_command()
        assert sent == [("start", 0.0)]
        session._inbox = []  # every Drive now a row, the last ones after the Start
        session.t_s = 1.0 + COMMAND_SEEN_S / 2
        session._check_command()
        assert len(sent) == 1
        session.t_s = 1.0 + COMMAND_SEEN_S
        session._check_command()
        assert sent[1] == ("start", 1.0 + COMMAND_SEEN_S)
        session.drive, session._drives_rx = running, 17
        session._check_command()
        assert session._pending is None
        session.press("s2", 2.0)  # running: a Stop, sent again while the stream says running
        session._drives_rx, session.t_s = 18, 2.0 + COMMAND_SEEN_S
        session._check_command()
        assert sent[2:] == [("stop", 1.0 + COMMAND_SEEN_S), ("stop", 2.0 + COMMAND_SEEN_S)]
        session.drive, session._drives_rx = stopped, 19
        session._check_command()
        assert session._pending is None and len(sent) == 4
        session.press("s2", 3.0)  # a Start the stream shows ending in a fault was taken: not sent again
        session.drive, session._drives_rx = stopped._replace(state=int(State.FAULT)), 20
        session.t_s += 2 * COMMAND_SEEN_S
        session._check_command()
        assert session._pending is None and [kind for kind, _ in sent] == ["start", "start", "stop", "stop", "start"]
    finally:
        host.close()


def test_ctl_start_in_monitor_mode_is_sent_again_while_the_stream_says_stopped() -> None:
    """`ctl start` on a monitor session goes through the same Start as a press: checked against the
    stream and sent again (it called the target's start once, unchecked)."""
    from hilbench.bench.control import COMMANDS, ControlRequest
    from hilbench.bench.monitor import COMMAND_SEEN_S, MonitorSession
    from hilbench.link import open_link
    from hilbench.protocol import State

    host = open_link("pty", timeout_s=1.0)
    try:
        session = MonitorSession(remote.RemoteTarget(host, timeout_s=0.2, retry_s=0.05), [])
        sent: list[float] = []
        session.target.start = lambda: sent.append(session.t_s)  # type: ignore[method-assign]
        session.drive = Drive(0, 0, 0, 0, 0, int(State.STOPPED), 0, False, False, 0, (0, 0, 0))
        session._drives_rx = 3
        request = ControlRequest("start", {}, 0.0)
        COMMANDS["start"].act(session, request, 0.0)
        assert request.replied and sent == [0.0]
        session._drives_rx, session.t_s = 5, COMMAND_SEEN_S
        session._check_command()
        assert sent == [0.0, COMMAND_SEEN_S]
    finally:
        host.close()


def test_a_reworded_error_keeps_its_class_and_what_it_carries() -> None:
    """A Start whose probe failed says so in the probe's own error: a divergence keeps its records."""
    from hilbench.errors import DivergenceError

    error = DivergenceError("Drives differ at period 7", records="k  twin  target")
    again = error.reworded(f"Start sent, unconfirmed: {error}")
    assert type(again) is DivergenceError and again.records == "k  twin  target"
    assert str(again) == "Start sent, unconfirmed: Drives differ at period 7" and again.exit_code == 10


def _served_foc_refusal(loop: str, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The FOC target (its C core) served in lockstep by ``loop``: 30 Sensors, then one without ADC
    codes (which the host resends while no Drive comes), then 10 more. What each step got, as text."""
    from hilbench.protocol import MODE_LOCKSTEP
    from hilbench.targets import make_target

    monkeypatch.setenv("HILBENCH_SERVE_LOOP", loop)
    calls = count_c_calls(monkeypatch, "serve_lockstep")
    target = make_target("foc")
    assert getattr(target, "span_core", None) is not None, "the FOC C core is not built"
    got: list[str] = []
    with served_on_a_pty(target) as (host_link, reports):
        host = remote.RemoteTarget(host_link, timeout_s=20.0, retry_s=10.0)
        host.handshake(50, MODE_LOCKSTEP, 10_000)  # a watchdog (serve's C loop's case), longer than the test
        host.start()
        stream = [Sensors(k, 0, (), 4 * k, (2048, 2048, 3100)) for k in range(1, 31)]
        stream += [Sensors(31, 0, (), 124, ())]
        stream += [Sensors(k, 0, (), 4 * k, (2048, 2048, 3100)) for k in range(32, 42)]
        for s in stream:
            host.timeout_s, host.retry_s = (1.5, 0.5) if s.seq == 31 else (20.0, 10.0)
            try:
                got.append(repr(host.step(s)))
            except HilbenchError as e:
                got.append(type(e).__name__)
    assert (calls[0] > 0) == (loop == "c")
    return got


def test_a_resent_sensors_the_foc_core_refused_is_refused_again_in_both_loops(monkeypatch: pytest.MonkeyPatch) -> None:
    """The C core noted a refused Sensors' seq as its last step's before refusing it, so the host's
    resend of it was answered as a repeat, with the duties of the step before (the reference refuses
    it again, and the host's step ends with no Drive)."""
    c = _served_foc_refusal("c", monkeypatch)
    py = _served_foc_refusal("python", monkeypatch)
    assert c == py
    assert py[30] == "LinkTimeout"
    assert py[31].startswith("Drive(seq=32,")
