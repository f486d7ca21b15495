"""The scope from the command line: `run --scope` (ended from the page), `hilbench scope --socket`
attached to a running session, and `report --open` on a recording."""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("aiohttp", reason="the scope extra (aiohttp) is not installed")

import aiohttp  # noqa: E402

import hilbench  # noqa: E402
from _scope_session import running_session  # noqa: E402

URL_RE = re.compile(r"scope: (http://127\.0\.0\.1:\d+/s/[A-Za-z0-9_-]+/)")


class Served:
    """A hilbench command that serves a scope: its URL from stderr; always reaped."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ, BROWSER="true", PYTHONUNBUFFERED="1")  # --open runs `true`, not a browser
        self.proc = subprocess.Popen([sys.executable, "-m", "hilbench", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)
        self.lines: list[str] = []
        self.url_found = threading.Event()
        self.url = ""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            match = URL_RE.search(line)
            if match and not self.url:
                self.url = match.group(1)
                self.url_found.set()

    def wait_url(self, timeout_s: float = 30.0) -> str:
        assert self.url_found.wait(timeout_s), f"no scope URL printed: {''.join(self.lines)[-2000:]}"
        return self.url

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._reader.join(5)


async def first_stream(url: str, then: dict[str, Any] | None = None) -> dict[str, Any]:
    async with aiohttp.ClientSession() as client:
        async with client.ws_connect(url + "ws") as ws:
            while True:
                message = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
                if message["type"] == "stream" and "meta" in message:
                    break
            if then is not None:
                await ws.send_str(json.dumps(then))
                while True:
                    reply = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
                    if reply["type"] == "reply":
                        message["reply"] = reply
                        break
            return message


def test_run_with_scope_ended_from_the_page(tmp_path: Path) -> None:
    served = Served("run", "--target", "inprocess:an1017", "--duration", "600", "--no-ui", "--scope",
                    "--record", str(tmp_path / "run.npz"))
    try:
        url = served.wait_url()
        message = asyncio.run(first_stream(url, {"type": "cmd", "id": 1, "cmd": "stop"}))
        assert message["meta"]["live"] and message["reply"]["ok"], message.get("reply")
        assert served.proc.wait(60) == 0, "".join(served.lines)
    finally:
        served.close()
    assert "stopped by ctl" in served.proc.stdout.read()  # type: ignore[union-attr]


async def frames_of(url: str, column: str, then: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    """Subscribe to ``column``, count the buckets of it that arrive until 200 have, then send ``then``."""
    buckets = 0
    async with aiohttp.ClientSession() as client:
        async with client.ws_connect(url + "ws") as ws:
            await ws.send_str(json.dumps({"type": "subscribe", "columns": ["t_s", column]}))
            while buckets < 200:
                message = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
                if message["type"] == "stream":
                    buckets += sum(f["n"] for f in message["frames"] if column in f["cols"])
            await ws.send_str(json.dumps(then))
            reply: dict[str, Any] | None = None
            closed = False
            while True:  # the reply, then (a stop ends the run) "closed" and a clean close
                received = await asyncio.wait_for(ws.receive(), 30)
                if received.type != aiohttp.WSMsgType.TEXT:
                    assert received.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), received
                    assert reply is not None, f"the page got no reply before {received}"
                    assert closed, f"the connection ended without 'closed': {received}"
                    return buckets, reply
                message = json.loads(received.data)
                if message["type"] == "reply":
                    reply = message
                elif message["type"] == "closed":
                    assert reply is not None, f"'closed' before the reply: {message}"
                    closed = True
                    assert message["reason"] in ("the run has ended", "the session closed its control socket"), message


def test_run_scope_without_a_recording_streams_traces() -> None:
    """Issue 22, item 1: `hilbench run --scope` without --record streamed nothing (an empty page).
    A stop clicked on the page gets its reply, then "closed" (the run has ended) and a clean close:
    the run lets its scope process relay them before it ends it."""
    served = Served("run", "--target", "inprocess:an1017", "--duration", "600", "--no-ui", "--scope")
    try:
        url = served.wait_url()
        buckets, reply = asyncio.run(frames_of(url, "speed_rpm", {"type": "cmd", "id": 1, "cmd": "stop"}))
        assert buckets >= 200 and reply["ok"], reply
        assert served.proc.wait(60) == 0, "".join(served.lines)
    finally:
        served.close()
    out = served.proc.stdout.read()  # type: ignore[union-attr]
    assert "stopped by ctl" in out


def test_scope_attached_to_a_running_session() -> None:
    with running_session() as path:
        served = Served("scope", "--socket", str(path))
        try:
            url = served.wait_url()
            with urllib.request.urlopen(url, timeout=10) as page:
                assert page.status == 200
            message = asyncio.run(first_stream(url))
            assert "kp" in message["meta"]["params"]
        finally:
            served.close()


def test_report_open_serves_the_recording(tmp_path: Path) -> None:
    with hilbench.Bench(target="inprocess:an1017", record=tmp_path / "run.npz") as bench:
        bench.run(0.05)
    served = Served("report", str(tmp_path / "run.npz"), "--open")
    try:
        url = served.wait_url()
        message = asyncio.run(first_stream(url))
        assert message["meta"]["live"] is False
        assert ["speed_rpm", "rpm"] in message["meta"]["columns"]
    finally:
        served.close()
