"""The scope's server: the token, another local user refused, the WebSocket relay to a running
session (frames, a guarded parameter write applied and one refused), and a recording's viewer."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Callable

import pytest

pytest.importorskip("aiohttp", reason="the scope extra (aiohttp) is not installed")

import aiohttp  # noqa: E402

import hilbench  # noqa: E402
from _scope_session import running_session  # noqa: E402
from hilbench.scope.server import ControlSource, RecordingSource, ScopeServer, socket_owner  # noqa: E402


class QuietSource:
    """A source that sends one message and then only answers commands (no session needed)."""

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[dict[str, Any]]") -> None:
        await send({"type": "stream", "seq": 0, "frames": [], "markers": [], "status": {}})
        while True:
            await inbox.get()


def fetch(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def test_socket_owner_names_this_user() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server, socket.create_connection(server.getsockname(), timeout=5) as client:
        peer, _ = server.accept()
        with peer:
            assert socket_owner(client.getsockname()[1], server.getsockname()[1]) == os.getuid()
    assert socket_owner(1, 2, tables=("/nonexistent",)) is None


def test_page_needs_the_token() -> None:
    with ScopeServer(QuietSource()) as server:
        assert server.url.startswith("http://127.0.0.1:") and len(server.token) >= 20
        status, body = fetch(server.url)
        assert status == 200 and "hilbench scope" in body
        assert fetch(server.url + "scope.js")[0] == 200
        base = f"http://127.0.0.1:{server.port}"
        for url in (f"{base}/", f"{base}/s/{server.token[:-1]}x/", f"{base}/s//", f"{base}/s/{server.token}x/scope.js",
                    f"{base}/s/wrong/ws", f"{base}/favicon.ico"):
            status, body = fetch(url)
            assert status == 403 and "token" in body, url
        assert server.refused["token"] >= 6 and server.refused["user"] == 0


def test_websocket_with_a_wrong_token_is_refused() -> None:
    async def attempt(url: str) -> int:
        async with aiohttp.ClientSession() as client:
            try:
                async with client.ws_connect(url, timeout=aiohttp.ClientWSTimeout(ws_close=5)):
                    return 101
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status

    with ScopeServer(QuietSource()) as server:
        assert asyncio.run(attempt(f"ws://127.0.0.1:{server.port}/s/not-the-token/ws")) == 403
        assert asyncio.run(attempt(server.url + "ws")) == 101


SYSTEM_PYTHON = "/usr/bin/python3"  # the other user cannot reach this test's virtual environment


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to run a client as another user (nobody)")
@pytest.mark.skipif(not os.path.exists(SYSTEM_PYTHON), reason=f"no {SYSTEM_PYTHON} for the other user's client")
def test_another_local_user_with_the_url_is_refused() -> None:
    client = ("import sys, urllib.request, urllib.error\n"
              "try:\n    urllib.request.urlopen(sys.argv[1], timeout=10); print(200)\n"
              "except urllib.error.HTTPError as e:\n    print(e.code, e.read().decode().strip())\n")
    with ScopeServer(QuietSource()) as server:
        other = subprocess.run([SYSTEM_PYTHON, "-I", "-S", "-c", client, server.url], user=65534, group=65534,
                               capture_output=True, text=True, timeout=30, cwd="/")
        assert other.stdout.startswith("403") and "not from the bench's user" in other.stdout, other
        assert server.refused["user"] == 1
        assert fetch(server.url)[0] == 200  # the same URL from this user


async def _talk(url: str, steps: Callable[[Any, list[dict[str, Any]]], Any]) -> list[dict[str, Any]]:
    seen: list[dict[str, Any]] = []
    async with aiohttp.ClientSession() as client:
        async with client.ws_connect(url) as ws:
            await asyncio.wait_for(steps(ws, seen), timeout=30)
    return seen


async def _until(ws: Any, seen: list[dict[str, Any]], done: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
    while True:
        message = json.loads((await ws.receive()).data)
        seen.append(message)
        if done(message):
            return message


def test_live_frames_and_guarded_writes_through_the_websocket() -> None:
    async def steps(ws: Any, seen: list[dict[str, Any]]) -> None:
        meta = await _until(ws, seen, lambda m: m["type"] == "stream" and "meta" in m)
        assert ["speed_rpm", "rpm"] in meta["meta"]["columns"] and "kp" in meta["meta"]["params"]
        await ws.send_str(json.dumps({"type": "subscribe", "columns": ["t_s", "speed_rpm", "hall_a"]}))
        first = await _until(ws, seen, lambda m: m["type"] == "stream" and m["frames"])
        t_first = first["frames"][-1]["t0"]
        later = await _until(ws, seen, lambda m: m["type"] == "stream" and m["frames"] and m["frames"][-1]["t0"] > t_first)
        assert set(later["frames"][-1]["cols"]) == {"t_s", "speed_rpm", "hall_a"}
        await ws.send_str(json.dumps({"type": "cmd", "id": 7, "cmd": "set", "params": {"kp": 0.15}}))
        applied = await _until(ws, seen, lambda m: m["type"] == "reply" and m["id"] == 7)
        assert applied["ok"] and applied["message"].startswith("applied at t=")
        await _until(ws, seen, lambda m: m["type"] == "stream" and any(k == "param" and "kp=0.15" in x for _, k, x in m["markers"]))
        await ws.send_str(json.dumps({"type": "cmd", "id": 8, "cmd": "set", "params": {"kp": 0.99, "ki": 0.02}}))
        refused = await _until(ws, seen, lambda m: m["type"] == "reply" and m["id"] == 8)
        assert not refused["ok"] and "break the firmware" in refused["message"]  # Kp + Ki + Kd < 0.9999

    with running_session() as path, ScopeServer(ControlSource(path)) as server:
        asyncio.run(_talk(server.url + "ws", steps))


def test_a_recording_in_the_same_viewer(tmp_path: Path) -> None:
    with hilbench.Bench(target="inprocess:an1017", record=tmp_path / "run.npz") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.2)
        bench.set_params(kp=0.2)
        bench.run(0.1)

    async def steps(ws: Any, seen: list[dict[str, Any]]) -> None:
        meta = await _until(ws, seen, lambda m: m["type"] == "stream")
        assert not meta["meta"]["live"] and [0.2, "param", "set kp=0.2"] in meta["markers"]
        await ws.send_str(json.dumps({"type": "subscribe", "columns": ["t_s", "speed_rpm", "hall_b"]}))
        whole = await _until(ws, seen, lambda m: m["type"] == "stream" and m["frames"])
        frame = whole["frames"][0]
        assert frame["t0"] == 0.0 and frame["n"] * frame["dt"] == pytest.approx(0.3, abs=1e-6)
        await ws.send_str(json.dumps({"type": "cmd", "id": 1, "cmd": "set", "params": {"kp": 0.1}}))
        reply = await _until(ws, seen, lambda m: m["type"] == "reply")
        assert not reply["ok"]

    with ScopeServer(RecordingSource(tmp_path / "run.npz")) as server:
        asyncio.run(_talk(server.url + "ws", steps))
