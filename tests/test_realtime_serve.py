"""Real time's serve loop in C (hilbench/targets/_remotestep.c `serve_realtime`) against its Python
reference (`_Server._realtime`): the AN1017 core's C advance equals `An1017Target.advance`, and the
loop answers, counts and keeps the model on the wall clock as the Python loop does."""

from __future__ import annotations

import random
import threading
import time
from typing import Any

import pytest

from hilbench.link import open_link
from hilbench.protocol import MODE_REALTIME, Drive, Sensors
from hilbench.targets import make_target, remote
from hilbench.targets.an1017.target import TCY_PER_US, An1017Target, _CAn1017Target
from hilbench.targets import serve as serve_module
from hilbench.targets.serve import serve

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


def _served_realtime(loop: str, stream: list[Sensors], monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """serve(AN1017, C core) in a thread on a pty in real time, its loop in C or Python (``loop``);
    the host sends ``stream`` (a Sensors twice in a row: a repeated seq) with a ParamGet every 300.
    Returns the Drives, the report, the calls into C, the firmware's time and the bounds the wall
    clock puts on it."""
    monkeypatch.setenv("HILBENCH_SERVE_LOOP", loop)
    calls = [0]
    serve_realtime = remote._remotestep.serve_realtime

    def counted(*args: Any) -> Any:  # how often the server's loop called into C (a spy, not a stand-in)
        calls[0] += 1
        return serve_realtime(*args)

    monkeypatch.setattr(remote._remotestep, "serve_realtime", counted)
    servers: list[Any] = []
    run = serve_module._Server.run

    def kept(self: Any) -> Any:  # the server itself, for its last_sensors_t
        servers.append(self)
        return run(self)

    monkeypatch.setattr(serve_module._Server, "run", kept)
    target = make_target("an1017")
    host_link = open_link("pty", timeout_s=2.0)
    far_link = open_link(host_link.peer_path, timeout_s=2.0)
    reports: list[Any] = []
    thread = threading.Thread(target=lambda: reports.append(serve(target, far_link)), daemon=True)
    thread.start()
    try:
        host = remote.RemoteTarget(host_link, timeout_s=20.0, retry_s=10.0)
        host.handshake(PERIOD_US, MODE_REALTIME, 5000)  # a watchdog the host never lets fire
        t_start_us = target.time_us
        drives, first = [], (0.0, 0.0)
        for i, sensors in enumerate(stream):
            if i % 300 == 299:
                host.get_param(0)
            sent = time.monotonic()
            drives.append(host.step(sensors))
            if i == 0:
                first = (sent, time.monotonic())
        host.status()
    finally:
        host_link.close()
        thread.join(timeout=20)
        far_link.close()
    assert not thread.is_alive() and reports
    return {"drives": drives, "report": reports[0], "c_calls": calls[0], "t_us": target.time_us - t_start_us,
            "first": first, "last_sensors_t": servers[0].last_sensors_t}


def test_serves_c_realtime_loop_answers_and_counts_as_its_python_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = random.Random(31)
    stream: list[Sensors] = []
    for k in range(1500):
        stream.append(_sensors(k, rng))
        if rng.random() < 0.02:
            stream.append(stream[-1])  # sent again: answered with the last Drive, no advance
    c = _served_realtime("c", stream, monkeypatch)
    py = _served_realtime("python", stream, monkeypatch)
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
    run = _served_realtime(loop, stream, monkeypatch)
    last_s = run["last_sensors_t"]
    sent_s, answered_s = run["first"]
    low_us = PERIOD_US + (last_s - answered_s) * 1e6
    high_us = PERIOD_US + (last_s - sent_s) * 1e6
    slack_us = 2.0 / TCY_PER_US  # whole Tcy: the carried fraction
    assert low_us - slack_us <= run["t_us"] <= high_us + slack_us, (low_us, run["t_us"], high_us)
