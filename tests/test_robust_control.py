"""Issue 16, items 1 and 2 and the control-socket fuzz: no request, however hostile, ends a run or
the control thread; the session keeps running and answering."""

from __future__ import annotations

import json
import math
import random
import socket
import tempfile
import threading
from pathlib import Path

import pytest

from hilbench.bench.control import ControlClient, ControlServer, parse_ctl_args, validate_request
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.errors import ConfigError

TIMEOUT_S = 20.0


def _raw_exchange(path: Path, payload: bytes, timeout_s: float = TIMEOUT_S) -> bytes:
    """Send raw bytes (ending with a newline) and read one reply line."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout_s)
        sock.connect(str(path))
        sock.sendall(payload)
        buf = b""
        while b"\n" not in buf:
            chunk = sock.recv(65536)
            if not chunk:
                break
            buf += chunk
        return buf


def test_item2_huge_integer_does_not_kill_the_control_thread() -> None:
    """Item 2: a 400-digit integer raised OverflowError in the I/O thread; every later request hung."""
    with tempfile.TemporaryDirectory(dir="/tmp") as d:
        server = ControlServer(Path(d) / "s" / "ctl.sock", publish=False)
        try:
            reply = json.loads(_raw_exchange(server.path, b'{"cmd":"ref","rpm":' + b"9" * 400 + b"}\n"))
            assert reply["ok"] is False and "finite number" in reply["message"]
            reply = json.loads(_raw_exchange(server.path, b'{"cmd":"ref","rpm":' + b"9" * 5000 + b"}\n"))
            assert reply["ok"] is False
            reply = json.loads(_raw_exchange(server.path, b"[" * 3000 + b"\n"))
            assert reply["ok"] is False
            with ControlClient(server.path, timeout_s=5) as client:  # still served: the thread lives
                client._sock.sendall(b'{"cmd":"get"}\n')
                assert server._thread.is_alive()
        finally:
            server.close()


@pytest.mark.parametrize("words", [["ref", "9" * 400], ["ref", "1e308"], ["ref", "-1e308"], ["step", "1e308", "-1e308"],
                                   ["load", "1e308"], ["load", "1e6"], ["ref", "nan"], ["set", "kp=1e308"]])
def test_item1_cli_words_refused_in_one_line(words: list[str]) -> None:
    """Items 1/2: out-of-range and huge numbers are refused by `hilbench ctl` before they are sent."""
    with pytest.raises(ConfigError) as info:
        parse_ctl_args(words)
    assert "\n" not in str(info.value) and len(str(info.value)) < 200


def test_item1_request_ranges_match_the_scenario_limits() -> None:
    """Item 1: ref, step and load are range-checked as the config limits them (±20000 rpm, ±1000 N*m)."""
    assert validate_request({"cmd": "ref", "rpm": 20000}) == ("ref", {"rpm": 20000.0})
    for bad in ({"cmd": "ref", "rpm": 20001}, {"cmd": "load", "nm": -1001}, {"cmd": "step", "from_rpm": 0, "to_rpm": 1e308}):
        with pytest.raises(ValueError):
            validate_request(bad)
    from hilbench.bench.settings import ScenarioEntry as ScenarioEvent
    import dataclasses

    meta = {f.name: f.metadata for f in dataclasses.fields(ScenarioEvent)}
    assert meta["ref_rpm"]["le"] == 20000 and meta["load_nm"]["le"] == 1000


def _is_finite_in_range(value: object, limit: float) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return abs(value) <= limit if isinstance(value, int) else math.isfinite(value) and abs(value) <= limit


def _fuzz_lines(seed: int) -> list[bytes]:
    """Malformed JSON, huge numbers and lines, binary garbage, every command with bad arguments."""
    rng = random.Random(seed)
    bad_numbers: list[object] = [1e308, -1e308, 10**400, -(10**30), 1e6, -1e6, 0, 3.5, "nan", None, True, [], {}]
    raw_numbers = [b"NaN", b"Infinity", b"-Infinity", b"1e999", b"9" * 400, b"-" + b"9" * 5000]
    lines: list[bytes] = []
    # (in-range loads are left out: a large one legitimately ends the run as a diverging plant)
    for cmd, keys in (("ref", ["rpm"]), ("load", ["nm"]), ("step", ["from_rpm", "to_rpm"])):
        for value in bad_numbers:
            if cmd == "load" and _is_finite_in_range(value, 1000.0) and value != 0:
                continue
            lines.append(json.dumps({"cmd": cmd, **{k: value for k in keys}}).encode())
        for raw in raw_numbers:
            lines.append(b'{"cmd":"' + cmd.encode() + b'",' + b",".join(b'"' + k.encode() + b'":' + raw for k in keys) + b"}")
    for value in bad_numbers:
        lines.append(json.dumps({"cmd": "set", "params": {"kp": value}}).encode())
        lines.append(json.dumps({"cmd": "guard", "on": value}).encode())
        lines.append(json.dumps({"cmd": "save", "file": value}).encode())
    for raw in raw_numbers:
        lines.append(b'{"cmd":"set","params":{"kp":' + raw + b"}}")
    lines += [json.dumps({"cmd": "set", "params": {"kp": 0.5, "ki": 0.6}}).encode(),  # firmware constraint
              json.dumps({"cmd": "set", "params": {"nosuch": 0.1}}).encode(),
              json.dumps({"cmd": "set", "params": {"kp": -5}}).encode(),
              b"{", b"}", b'{"cmd":', b"[" * 5000, b'{"cmd":"get"' * 300, b"null", b"\xff\xfe\x00garbage",
              b'{"cmd":"nosuch"}', b'{"cmd":"get","id":' + b"9" * 400 + b"}", b"x" * 10000]
    for _ in range(60):
        lines.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))).replace(b"\n", b" "))
    rng.shuffle(lines)
    return lines


@pytest.mark.slow
def test_control_socket_fuzz_session_keeps_running_and_answering(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Acceptance: a hostile client against a running in-process session; afterwards `get` is
    answered and `stop` ends the run cleanly (no fault, the control thread alive)."""
    from conftest import hurst_bench_config

    monkeypatch.chdir(tmp_path)  # a fuzzed `save` writes its file here

    cfg = load_run_config(RunRequest(str(hurst_bench_config(tmp_path, 86400.0)), target="inprocess:an1017"))  # ends by ctl stop
    with tempfile.TemporaryDirectory(dir="/tmp") as d:
        server = ControlServer(Path(d) / "s" / "ctl.sock", publish=False)
        answers: list[dict] = []
        failures: list[BaseException] = []
        final: dict[str, dict] = {}

        def client() -> None:
            try:
                for line in _fuzz_lines(16):
                    try:
                        reply = _raw_exchange(server.path, line + b"\n")
                    except TimeoutError:
                        raise AssertionError(f"no reply to {line[:80]!r}") from None
                    for text in reply.splitlines():
                        answers.append(json.loads(text))
                with ControlClient(server.path, timeout_s=TIMEOUT_S) as c:
                    final["get"] = c.request({"cmd": "get"}, timeout_s=TIMEOUT_S)
                    final["ref"] = c.request({"cmd": "ref", "rpm": 1200}, timeout_s=TIMEOUT_S)
                    final["stop"] = c.request({"cmd": "stop"}, timeout_s=TIMEOUT_S)
            except BaseException as exc:  # noqa: BLE001 - reported below
                failures.append(exc)
                try:
                    with ControlClient(server.path, timeout_s=TIMEOUT_S) as c:
                        c.request({"cmd": "stop"}, timeout_s=TIMEOUT_S)
                except BaseException:  # noqa: BLE001
                    pass

        thread = threading.Thread(target=client, daemon=True)
        thread.start()
        try:
            summary = run_bench(cfg, control=server)
        finally:
            thread.join(timeout=120)
            server.close()
    assert not failures, failures
    assert summary.end_reason == "stopped by ctl", summary.fault
    assert final["get"]["ok"] and final["ref"]["ok"] and final["stop"]["ok"]
    assert len(answers) >= 100
    assert all(isinstance(a.get("ok"), bool) and "\n" not in a["message"] for a in answers)
    assert all(not math.isnan(v) for v in final["get"]["data"]["params"].values())


# ---------------------------------------------------------------- item 13: finding sessions, ctl output
def test_item13_every_session_found_stale_ones_cleaned(monkeypatch: pytest.MonkeyPatch) -> None:
    """Item 13: one global pointer file made the older of two sessions unreachable; kill -9 left
    `hilbench-ctl-*` behind. Now: a discovery file per session, `list_sessions` finds both (newest
    first), and a starting server removes dead sessions' files and socket directories. Both started
    here: neither is picked without --session (issue 22)."""
    import os
    import socket as socket_module

    from hilbench.bench.control import clean_stale, list_sessions, read_discovery

    with tempfile.TemporaryDirectory(dir="/tmp") as d:
        runtime = Path(d)
        monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
        sessions = runtime / "hilbench" / "sessions"
        sessions.mkdir(parents=True, mode=0o700)
        dead = sessions / "999999999-hilbench-ctl-dead.session"  # a pid that cannot exist
        dead.write_text("/nowhere/ctl.sock\n999999999\n{}\n")
        leftover = runtime / "hilbench-ctl-leftover"
        leftover.mkdir(mode=0o700)
        sock = socket_module.socket(socket_module.AF_UNIX, socket_module.SOCK_STREAM)
        sock.bind(str(leftover / "ctl.sock"))  # bound, nobody listening: a kill -9 leftover
        sock.close()
        older = ControlServer()
        newer = ControlServer()
        try:
            assert not dead.exists() and not leftover.exists()
            found = list_sessions()
            assert [s.socket_path for s in found] == [newer.path, older.path]
            assert all(s.pid == os.getpid() for s in found)
            with pytest.raises(ConfigError, match="2 of them were started in"):  # issue 22: never the newest by guess
                read_discovery()
            assert read_discovery(selector="2") == older.path  # `ctl list` numbers them, newest first
            with ControlClient(older.path, timeout_s=5) as client:  # the older one stays reachable
                client._sock.sendall(b"{}\n")
                assert b"cmd" in client._sock.recv(4096)
        finally:
            older.close()
            newer.close()
        assert list_sessions() == [] and clean_stale() == 0


def test_item13_ctl_json_list_and_step_timeout(monkeypatch: pytest.MonkeyPatch) -> None:
    """Item 13: `ctl get` printed "ok" before its JSON; no --json; no `ctl list`; the socket path
    never printed; `ctl step` had the 5 s timeout of a quick command."""
    from click.testing import CliRunner

    from hilbench.cli import cli

    with tempfile.TemporaryDirectory(dir="/tmp") as d:
        monkeypatch.setenv("XDG_RUNTIME_DIR", d)
        server = ControlServer()
        stop = threading.Event()
        timeouts: list[float] = []

        def session() -> None:
            while not stop.is_set():
                for request in server.poll():
                    request.reply(True, "done", {"params": {"kp": 0.1}, "t_s": 1.0, "ref_rpm": 0, "tunable": ["kp"]})
                stop.wait(0.001)

        thread = threading.Thread(target=session, daemon=True)
        thread.start()
        real_request = ControlClient.request

        def spy(self: ControlClient, req: dict, timeout_s: float = 5.0) -> dict:
            timeouts.append(timeout_s)
            return real_request(self, req, timeout_s)

        monkeypatch.setattr(ControlClient, "request", spy)
        try:
            runner = CliRunner()
            result = runner.invoke(cli, ["ctl", "get"])
            assert result.exit_code == 0 and json.loads(result.stdout) == {"params": {"kp": 0.1}, "t_s": 1.0,
                                                                            "ref_rpm": 0, "tunable": ["kp"]}
            result = runner.invoke(cli, ["ctl", "--json", "ref", "1000"])
            assert json.loads(result.stdout)["ok"] is True
            result = runner.invoke(cli, ["ctl", "list", "--json"])
            assert [Path(r["socket"]) for r in json.loads(result.stdout)] == [server.path]
            runner.invoke(cli, ["ctl", "step", "1000", "2000"])
            assert timeouts[-1] >= 60
        finally:
            stop.set()
            thread.join(timeout=5)
            server.close()


def test_item13_dashboard_prompt_get_and_help() -> None:
    """Item 13: `get` and `help` at the dashboard prompt printed nothing useful."""
    from hilbench.ui.keys import CommandLine

    with tempfile.TemporaryDirectory(dir="/tmp") as d:
        server = ControlServer(Path(d) / "s" / "ctl.sock", publish=False)
        stop = threading.Event()

        def session() -> None:
            while not stop.is_set():
                for request in server.poll():
                    request.reply(True, "ok", {"params": {"kp": 0.1, "ki": 0.01}, "t_s": 2.5, "ref_rpm": 1500.0})
                stop.wait(0.001)

        thread = threading.Thread(target=session, daemon=True)
        thread.start()
        try:
            line = CommandLine(server.path, on_message=lambda text: None)
            assert line.execute("get") == "> get: kp=0.1 ki=0.01; ref 1500 rpm at t=2.500 s"
            assert "press s2|s3" in line.execute("help") and "\n" not in line.execute("help")
        finally:
            stop.set()
            thread.join(timeout=5)
            server.close()
