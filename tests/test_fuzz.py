"""Issue 23: seeded fuzz tests (short here; the seeds make every failure a repro) for the surfaces
that had none: the scope's HTTP and WebSocket endpoints, `hilbench report` on mutated recordings,
sweep stores and target specs. Each mutated input must end in the surface's own refusal (one line,
its exit code or error class) or be served; never an exception of another kind, a traceback or a
server that stops answering."""

from __future__ import annotations

import asyncio
import json
import random
import socket
import string
import urllib.request
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from click.testing import CliRunner

import hilbench
from hilbench.cli import cli
from hilbench.errors import ConfigError, HilbenchError, RecordingError

SEED = 23


# ------------------------------------------------------------------------------------ mutations
def mutate_bytes(rng: random.Random, data: bytes, edits: int = 6) -> bytes:
    out = bytearray(data)
    for _ in range(rng.randint(1, edits)):
        if not out:
            out += bytes([rng.randrange(256)])
        i = rng.randrange(len(out))
        op = rng.randrange(4)
        if op == 0:
            out[i] = rng.randrange(256)
        elif op == 1:
            del out[i:i + rng.randrange(1, 64)]
        elif op == 2:
            out[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
        else:
            out[i:i] = out[i:i + rng.randrange(1, 200)] * rng.randrange(1, 50)
    return bytes(out)


NASTY_VALUES: list[Any] = [None, True, -1, 0, 2**64, 1e308, -1e308, float("nan"), float("inf"), "", "x" * 5000, [], {},
                           [1, [2, [3]]], {"a": {"b": None}}, "\x00\x1b[31m", 0.5]


def mutate_json(rng: random.Random, value: Any, depth: int = 0) -> Any:
    """Replace, drop or add pieces of a JSON value."""
    if depth > 3 or rng.random() < 0.25:
        return rng.choice(NASTY_VALUES)
    if isinstance(value, dict):
        out = {k: (mutate_json(rng, v, depth + 1) if rng.random() < 0.4 else v) for k, v in value.items()
               if rng.random() > 0.1}
        if rng.random() < 0.2:
            out[rng.choice(["type", "cmd", "id", "columns", "x", "since", "params"])] = rng.choice(NASTY_VALUES)
        return out
    if isinstance(value, list):
        return [mutate_json(rng, v, depth + 1) for v in value if rng.random() > 0.1]
    return value


# ------------------------------------------------------------------------------------ the scope
class _Quiet:
    """A source that sends one frame and then answers nothing (no session needed)."""

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[Any]") -> None:
        await send({"type": "stream", "seq": 0, "frames": [], "markers": [], "status": {}})
        while True:
            await inbox.get()


GOOD_REQUESTS = [
    b"GET /s/TOKEN/ HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
    b"GET /s/TOKEN/ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
    b"POST /s/TOKEN/ HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\nhello",
    b"GET /o/x HTTP/1.0\r\n\r\n",
]


def _raw(port: int, payload: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=20) as sock:
        try:
            sock.sendall(payload)
            sock.shutdown(socket.SHUT_WR)
            return sock.recv(64)
        except OSError:
            return b""


def test_fuzz_the_scopes_http_endpoint() -> None:
    pytest.importorskip("aiohttp")
    from hilbench.scope.server import ScopeServer

    rng = random.Random(SEED)
    lines: list[str] = []
    with ScopeServer(_Quiet()) as server:
        server.log._write = lines.append  # noqa: SLF001 - collect what it would print
        for _ in range(150):
            # mutated before the server's random token goes in: the same requests every run
            request = mutate_bytes(rng, rng.choice(GOOD_REQUESTS), edits=8).replace(b"TOKEN", server.token.encode())
            # one status line, in the request's own version ("HTTP/0.9 403" to a mutated "HTTP/0.9"), or none
            answer = _raw(server.port, request)
            assert answer == b"" or answer.startswith(b"HTTP/"), answer
        with urllib.request.urlopen(server.url, timeout=20) as page:  # still serving
            assert page.status == 200
    assert all(line.startswith("scope: ") and "\n" not in line and "Traceback" not in line for line in lines), lines
    assert len(lines) <= 2  # rate-limited: one line per 10 s window


def test_fuzz_page_messages_parse_or_refuse() -> None:
    from hilbench.scope.messages import Command, Refused, Subscribe, parse_page_message

    rng = random.Random(SEED)
    seeds = [{"type": "subscribe", "columns": ["speed_rpm", "ia_a"]},
             {"type": "cmd", "id": 1, "cmd": "set", "params": {"kp": 0.1}},
             {"type": "cmd", "id": "x", "cmd": "ref", "rpm": 1000}]
    for _ in range(3000):
        message = mutate_json(rng, rng.choice(seeds))
        text = json.dumps(message) if rng.random() < 0.8 else mutate_bytes(rng, json.dumps(message).encode()).decode(
            "utf-8", "replace")
        try:
            parsed = parse_page_message(text)
        except Refused as exc:
            assert str(exc) and "\n" not in str(exc)
            continue
        assert isinstance(parsed, (Subscribe, Command))
        if isinstance(parsed, Command):
            json.dumps(parsed.request, allow_nan=False)  # what is relayed is valid JSON for the control socket


def test_fuzz_the_websocket_of_a_live_page() -> None:
    """Mutated messages at a page on a running session: each gets a reply or a frame, and a `get`
    sent last is answered (the page's command loop survived everything before it)."""
    pytest.importorskip("aiohttp")
    import aiohttp

    from _scope_session import running_session
    from hilbench.scope.server import ControlSource, ScopeServer

    rng = random.Random(SEED)
    seeds = [{"type": "subscribe", "columns": ["speed_rpm"]}, {"type": "cmd", "id": 1, "cmd": "get"},
             {"type": "cmd", "id": 2, "cmd": "set", "params": {"kp": 0.1}}, {"type": "cmd", "id": 3, "cmd": "guard",
                                                                              "on": True}]
    messages = [json.dumps(mutate_json(rng, rng.choice(seeds))) for _ in range(150)]

    async def exchange(url: str) -> dict[str, Any]:
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(url + "ws", max_msg_size=0) as ws:
                for text in messages:
                    await ws.send_str(text)
                for attempt in range(600):  # a flood may leave the page busy for a moment: ask again
                    await ws.send_str(json.dumps({"type": "cmd", "id": f"last{attempt}", "cmd": "get"}))
                    while True:
                        message = json.loads((await asyncio.wait_for(ws.receive(), 60)).data)
                        if message.get("type") == "reply" and message.get("id") == f"last{attempt}":
                            break
                    if message["ok"] or not message["message"].startswith("busy"):
                        return message
                    await asyncio.sleep(0.1)  # pacing the retries of a condition (the page answers busy at once)
                raise AssertionError("the page stayed busy")

    with running_session() as path, ScopeServer(ControlSource(path)) as server:
        last = asyncio.run(exchange(server.url))
    assert last["ok"] and "kp" in last["data"]["params"], last["message"]


# ------------------------------------------------------------------------------------ report
@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("fuzzrec")
    out = {}
    for suffix in ("csv", "npz"):
        with hilbench.Bench(target="inprocess:an1017", record=folder / f"r.{suffix}") as bench:
            bench.set_reference(800)
            bench.press("s2")
            bench.run(0.01)
        out[suffix] = folder / f"r.{suffix}"
    return out


def _mutated_npz(rng: random.Random, good: Path, out: Path) -> None:
    with np.load(good, allow_pickle=False) as archive:
        arrays = {name: archive[name] for name in archive.files}
    name = rng.choice(list(arrays))
    op = rng.randrange(7)
    if name == "metadata":
        meta = json.loads(str(arrays["metadata"]))
        key = rng.choice(list(meta) + ["columns", "events"])
        meta[key] = mutate_json(rng, meta.get(key))
        arrays["metadata"] = np.asarray(json.dumps(meta))
    elif op == 0:
        arrays[name] = arrays[name].copy()
        arrays[name][rng.randrange(len(arrays[name]))] = rng.choice([np.nan, np.inf, -np.inf, 1e308, -0.0])
    elif op == 1:
        arrays[name] = arrays[name][: rng.randrange(len(arrays[name]))]
    elif op == 2:
        arrays[name] = arrays[name].astype(str)
    elif op == 3:
        arrays[name] = arrays[name].reshape(-1, 1)
    elif op == 4:
        del arrays[name]
    elif op == 5:
        arrays[name] = np.asarray([{"a": 1}] * 3, dtype=object)
    else:
        arrays[name] = arrays[name].astype(np.int8)
    np.savez(out, **arrays, allow_pickle=True) if op == 5 else np.savez(out, **arrays)  # type: ignore[arg-type]


def _mutated_csv(rng: random.Random, good: Path, out: Path) -> None:
    lines = good.read_text().splitlines(keepends=True)
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(lines))
        op = rng.randrange(5)
        if op == 0:
            lines[i] = lines[i].replace(rng.choice("015,"), rng.choice(["nan", "inf", "x", "", ",", "1e400"]), 1)
        elif op == 1:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
        elif op == 2:
            key = rng.choice(["period_us", "target_hello", "config", "events", "history_every_periods", "end", "mode"])
            lines.append(f"# {key}: {json.dumps(mutate_json(rng, 1))}\n")
        elif op == 3:
            del lines[i]
        else:
            lines[i] = "".join(rng.choice(string.printable) if rng.random() < 0.05 else c for c in lines[i])
    out.write_text("".join(lines))


def test_fuzz_report_on_mutated_recordings(recordings: dict[str, Path], tmp_path: Path) -> None:
    """Report (and, for some, its plots and CSV export) on mutated recordings: exit 0, or exit 6
    with one line; never an exception escaping the command."""
    rng = random.Random(SEED)
    runner = CliRunner()
    outcomes = {0: 0, 6: 0}
    for n in range(60):
        kind = rng.choice(["csv", "npz", "npz-bytes"])
        path = tmp_path / f"m{n}.{kind[:3]}"
        if kind == "csv":
            _mutated_csv(rng, recordings["csv"], path)
        elif kind == "npz":
            _mutated_npz(rng, recordings["npz"], path)
        else:
            path.write_bytes(mutate_bytes(rng, recordings["npz"].read_bytes()))
        args = ["report", str(path), "--json"]
        if rng.random() < 0.2:
            args += ["--plot", str(tmp_path / "plots")]
        if rng.random() < 0.2:
            args += ["--csv", str(tmp_path / "out.csv")]
        result = runner.invoke(cli, args)
        assert result.exception is None or isinstance(result.exception, SystemExit), \
            f"case {n} ({kind}): {type(result.exception).__name__}: {result.exception}"
        assert result.exit_code in outcomes, f"case {n}: exit {result.exit_code}: {result.output[-500:]}"
        outcomes[result.exit_code] += 1
        if result.exit_code == 6:
            errors = [line for line in result.output.splitlines() if line.startswith("hilbench: recording error")]
            assert len(errors) == 1, result.output[-500:]
    assert outcomes[6] > 10 and outcomes[0] > 5, outcomes  # the mutations reach both ends


# ------------------------------------------------------------------------------------ sweep stores
def test_fuzz_sweep_stores(tmp_path: Path) -> None:
    from hilbench.bench.metrics import StepMetrics
    from hilbench.bench.sweep import SweepStore

    metrics = StepMetrics(0.0, 1000.0, 1000.0, 0.1, 0.01, 0.11, 2.0, 0.2, 1020.0, 0.3, 0.02, 1.0, 0.1, 2.0, 0.2, 5.0,
                          1.0, None, 0.5, 100).as_dict()
    good = {"key": "K", "index": 1, "params": {"kp": 0.1}, "metrics": metrics, "stalled": False, "cases": 1}
    rng = random.Random(SEED)
    store = tmp_path / "s.jsonl"
    loaded = refused = 0
    for _ in range(400):
        rows = [json.dumps(mutate_json(rng, good) if rng.random() < 0.5 else good) for _ in range(rng.randint(1, 4))]
        text = "\n".join(rows) + "\n"
        store.write_bytes(mutate_bytes(rng, text.encode()) if rng.random() < 0.4 else text.encode())
        try:
            done = SweepStore(store, "K", 4).done
        except (RecordingError, ConfigError) as exc:
            assert "\n" not in str(exc) and str(store) in str(exc)
            refused += 1
            continue
        loaded += 1
        assert all(0 <= i < 4 and isinstance(v[0], StepMetrics) for i, v in done.items())
    assert refused > 100 and loaded > 20, (refused, loaded)


# ------------------------------------------------------------------------------------ target specs
def test_fuzz_target_specs() -> None:
    """Mutated specs: parsed or refused with one ConfigError line, and the plugin's check agrees."""
    from hilbench.link import parse_target_spec
    from hilbench.testing.targets import check_spec

    seeds = ["emulator:an1017", "inprocess:foc", "sil:an1017", "emulator:an1017?corrupt=1e-4&drop=1e-3&fault_seed=7",
             "serial:/dev/ttyUSB0?baud=250000", "socket://127.0.0.1:5000", "rfc2217://host:4000?timeout=2", "loop://",
             "fd:3", "pty", "exec:/bin/true", "/dev/ttyACM0?baud=115200", "emulator:loopback?delay_ms=2&silent_after=5"]
    rng = random.Random(SEED)
    accepted = refused = 0
    for _ in range(3000):
        text = mutate_bytes(rng, rng.choice(seeds).encode(), edits=3).decode("utf-8", "replace")
        try:
            parse_target_spec(text)
        except ConfigError as exc:
            assert str(exc) and "\n" not in str(exc)
            refused += 1
            with pytest.raises(HilbenchError):
                check_spec(text)
            continue
        accepted += 1
        try:
            check_spec(text)
        except ConfigError as exc:
            assert "unknown target" in str(exc) or "has no" in str(exc), exc
    assert refused > 500 and accepted > 100, (refused, accepted)
