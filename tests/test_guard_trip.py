"""The guard catches a gain change that trips the board (issue 22, item 3): `ctl set kp=0.05 ki=0.9`
then `ctl ref -2000` on the default config. The MCLV's 3 A comparator cuts the current before the
guard's own 3 A look can see it, so a firmware FAULT (overcurrent) inside the window is trouble too;
and gains are tried by stepping the reference, often seconds after the write, so new gains stay on
probation until their first reference change, which watches a window again."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

import hilbench
from hilbench.bench.control import ControlClient, ControlServer
from hilbench.bench.run import RunRequest, load_run_config, run_bench

Q15 = 1 / 32768


class Request:
    """A control request answered in process (what the control socket hands the session)."""

    def __init__(self, cmd: str, **args: Any) -> None:
        self.cmd, self.args = cmd, args
        self.answer: tuple[bool, str, Any] | None = None

    def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
        self.answer = (ok, text, data)


def _ctl(bench: hilbench.Bench, cmd: str, **args: Any) -> tuple[bool, str, Any]:
    request = Request(cmd, **args)
    bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
    assert request.answer is not None
    return request.answer


def _trip(bench: hilbench.Bench, gains: dict[str, float], hold_s: float) -> tuple[dict[str, float], tuple[str, ...], Any]:
    before = bench.get_params()
    bench.set_reference(1500)
    bench.press("s2")
    bench.run(1.0)
    ok, text, _ = _ctl(bench, "set", params=gains)
    assert ok, text
    bench.run(hold_s)
    assert all(bench.get_params()[k] == pytest.approx(v, abs=Q15) for k, v in gains.items())  # not reverted yet
    ok, text, _ = _ctl(bench, "ref", rpm=-2000)
    assert ok and "the guard watches the new gains until" in text
    bench.run(0.5)
    ok, _, state = _ctl(bench, "get")
    assert ok
    return before, bench.events, state


def _assert_reverted(before: dict[str, float], events: tuple[str, ...], state: Any) -> None:
    after = state["params"]
    assert after["kp"] == pytest.approx(before["kp"], abs=Q15) and after["ki"] == pytest.approx(before["ki"], abs=Q15)
    trips = [e for e in events if "guard:" in e]
    assert len(trips) == 1 and "overcurrent" in trips[0] and "restored kp=" in trips[0]
    comparator = next(e for e in events if "comparator tripped" in e)
    assert 0 <= float(trips[0].split()[0][2:]) - float(comparator.split()[0][2:]) < 0.005  # within a few looks
    assert "overcurrent" in state["guard_trips"][-1]


def test_set_then_ref_reverts_and_says_overcurrent() -> None:
    """The acceptance line: `ctl set kp=0.05 ki=0.9`, `ctl ref -2000`, the packaged default config."""
    with hilbench.Bench(target="inprocess:an1017", scenario=False) as bench:
        _assert_reverted(*_trip(bench, {"kp": 0.05, "ki": 0.9}, 0.0))


def test_a_trip_seconds_after_the_write_is_caught_by_probation() -> None:
    """kp=0.05 ki=0.3 holds 1500 rpm for 2 s (longer than the 1 s window); the reference change
    to -2000 rpm then trips the comparator: the probation's window catches it."""
    with hilbench.Bench(target="inprocess:an1017", scenario=False) as bench:
        _assert_reverted(*_trip(bench, {"kp": 0.05, "ki": 0.3}, 2.0))


def test_a_second_reference_change_is_not_watched() -> None:
    """Probation ends with the first reference change: gains that met one are the user's."""
    with hilbench.Bench(target="inprocess:an1017", scenario=False) as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.5)
        _ctl(bench, "set", params={"kp": 0.12})
        bench.run(1.5)
        ok, text, _ = _ctl(bench, "ref", rpm=1800)
        assert ok and "guard watches" in text
        bench.run(1.5)
        ok, text, _ = _ctl(bench, "ref", rpm=2000)
        assert ok and "guard watches" not in text


@pytest.mark.slow
def test_ctl_set_then_ref_over_the_control_socket(tmp_path: Path) -> None:
    """The acceptance line as a user types it: the default config (the emulator process), the control
    socket, `set` then `ref`; `get` shows the previous gains back and the guard's reason."""
    cfg = load_run_config(RunRequest(None, overrides=("run.duration_s=120",)))
    server = ControlServer(tmp_path / "sock" / "ctl.sock", publish=False)
    client = ControlClient(server.path, timeout_s=10.0)
    replies: dict[str, Any] = {}
    failures: list[BaseException] = []

    def script() -> None:
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # the default scenario brings the motor up to speed
                replies["first"] = client.request({"cmd": "get"}, timeout_s=30)
                if replies["first"]["data"]["t_s"] > 1.0:
                    break
            replies["set"] = client.request({"cmd": "set", "params": {"kp": 0.05, "ki": 0.9}}, timeout_s=10)
            replies["ref"] = client.request({"cmd": "ref", "rpm": -2000}, timeout_s=10)
            while time.monotonic() < deadline:
                replies["after"] = client.request({"cmd": "get"}, timeout_s=10)
                if replies["after"]["data"]["guard_trips"]:
                    break
            replies["stop"] = client.request({"cmd": "stop"}, timeout_s=10)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            failures.append(exc)
            client.request({"cmd": "stop"}, timeout_s=10)

    thread = threading.Thread(target=script, daemon=True)
    thread.start()
    try:
        summary = run_bench(cfg, control=server)
    finally:
        thread.join(timeout=90)
        server.close()
    assert not failures, failures
    assert summary.end_reason == "stopped by ctl"
    before = replies["first"]["data"]["params"]
    after = replies["after"]["data"]
    assert replies["set"]["ok"] and replies["ref"]["ok"]
    assert after["params"]["kp"] == pytest.approx(before["kp"], abs=Q15)
    assert after["params"]["ki"] == pytest.approx(before["ki"], abs=Q15)
    assert "overcurrent" in after["guard_trips"][-1]
