"""Control socket: modes, request shape checks, resilience, discovery, cleanup, CLI words.

A "session" thread drives server.poll() (paced by Event.wait, like a session period) and
echoes each request back; every socket read in the tests has a timeout.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest

from hilbench.bench.control import (
    MAX_LINE_BYTES,
    MAX_PENDING,
    ControlClient,
    ControlServer,
    default_discovery_file,
    parse_ctl_args,
)
from hilbench.errors import ConfigError, LinkError, LinkTimeout

TIMEOUT_S = 5.0


class EchoSession:
    """Polls the server on its own thread and replies ok with the request echoed as data."""

    def __init__(self, server: ControlServer) -> None:
        self.server = server
        self.stop = threading.Event()
        self.seen: list[tuple[str, dict]] = []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            for req in self.server.poll():
                self.seen.append((req.cmd, dict(req.args)))
                req.reply(True, f"did {req.cmd}", {"cmd": req.cmd, "args": dict(req.args)})
            self.stop.wait(0.0005)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=TIMEOUT_S)
        assert not self.thread.is_alive()


def poll_until(server: ControlServer, n: int, timeout_s: float = TIMEOUT_S) -> list:
    """Poll (paced like a session period) until n requests arrived; fail after timeout_s."""
    got: list = []
    pace = threading.Event()
    deadline = time.monotonic() + timeout_s
    while len(got) < n:
        assert time.monotonic() < deadline, f"only {len(got)} of {n} requests within {timeout_s} s"
        got += server.poll()
        pace.wait(0.0005)
    return got


@pytest.fixture
def server(tmpdir_short: Path) -> Iterator[ControlServer]:
    srv = ControlServer(discovery_file=tmpdir_short / "current")
    try:
        yield srv
    finally:
        srv.close()


@pytest.fixture
def session(server: ControlServer) -> Iterator[EchoSession]:
    s = EchoSession(server)
    try:
        yield s
    finally:
        s.close()


class Raw:
    """A bare socket client, to send bytes no well-behaved client would."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(TIMEOUT_S)
        self.sock.connect(str(path))
        self.buf = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def reply(self) -> dict:
        while b"\n" not in self.buf:
            chunk = self.sock.recv(65536)  # times out after TIMEOUT_S
            assert chunk, "server closed the connection"
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return json.loads(line)

    def close(self) -> None:
        self.sock.close()


# ---- modes and layout ----------------------------------------------------------------------


def test_directory_0700_socket_0600_owned_by_user(server: ControlServer) -> None:
    dst = os.stat(server.directory)
    sst = os.stat(server.path)
    assert stat.S_ISDIR(dst.st_mode) and stat.S_IMODE(dst.st_mode) == 0o700
    assert stat.S_ISSOCK(sst.st_mode) and stat.S_IMODE(sst.st_mode) == 0o600
    assert dst.st_uid == os.getuid() and sst.st_uid == os.getuid()
    assert stat.S_IMODE(dst.st_mode) & 0o077 == 0  # group and others cannot enter or list
    assert server.path.parent == server.directory


def test_discovery_file_names_socket(server: ControlServer, tmpdir_short: Path) -> None:
    lines = (tmpdir_short / "current").read_text().splitlines()
    assert lines[:2] == [str(server.path), str(os.getpid())]  # then a JSON line (start time, cwd)
    assert stat.S_IMODE(os.stat(tmpdir_short / "current").st_mode) & 0o077 == 0


def test_explicit_path_parent_created_private(tmpdir_short: Path) -> None:
    sock_path = tmpdir_short / "ctl" / "s.sock"
    with ControlServer(sock_path, publish=False) as srv:
        assert stat.S_IMODE(os.stat(sock_path.parent).st_mode) == 0o700
        assert stat.S_IMODE(os.stat(sock_path).st_mode) == 0o600
    assert not sock_path.exists()
    assert sock_path.parent.exists()  # not ours to remove: the caller named it
    assert srv.discovery_file is None


def test_explicit_path_in_open_directory_refused(tmpdir_short: Path) -> None:
    open_dir = tmpdir_short / "open"
    open_dir.mkdir()
    os.chmod(open_dir, 0o755)
    with pytest.raises(ConfigError, match="755"):
        ControlServer(open_dir / "s.sock", publish=False)


def test_default_discovery_file_locations(monkeypatch: pytest.MonkeyPatch, tmpdir_short: Path) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmpdir_short))
    assert default_discovery_file() == tmpdir_short / "hilbench" / "current"
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    monkeypatch.setenv("HOME", str(tmpdir_short / "home"))
    assert default_discovery_file() == tmpdir_short / "home" / ".cache" / "hilbench" / "current-session"


def test_socket_under_xdg_runtime_dir(monkeypatch: pytest.MonkeyPatch, tmpdir_short: Path) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmpdir_short))
    with ControlServer() as srv:  # its own discovery file, inside the fake runtime dir (issue 16, item 13)
        assert srv.directory.parent == tmpdir_short
        assert srv.discovery_file is not None and srv.discovery_file.parent == tmpdir_short / "hilbench" / "sessions"
        assert srv.discovery_file.read_text().splitlines()[0] == str(srv.path)
        assert stat.S_IMODE(os.stat(tmpdir_short / "hilbench" / "sessions").st_mode) == 0o700
    assert not srv.discovery_file.exists()


# ---- requests ----------------------------------------------------------------------------


def test_client_roundtrip_by_discovery(session: EchoSession, tmpdir_short: Path) -> None:
    with ControlClient(discovery_file=tmpdir_short / "current") as client:
        r = client.request({"cmd": "set", "params": {"kp": 0.1, "ki": 0.01}}, timeout_s=TIMEOUT_S)
        assert r == {"ok": True, "message": "did set",
                     "data": {"cmd": "set", "args": {"params": {"kp": 0.1, "ki": 0.01}}}}
        r = client.request({"cmd": "step", "from_rpm": 1000, "to_rpm": 2000}, timeout_s=TIMEOUT_S)
        assert r["data"]["args"] == {"from_rpm": 1000, "to_rpm": 2000}
    assert [c for c, _ in session.seen] == ["set", "step"]


BAD_REQUESTS = [
    (b"{not json\n", "malformed JSON"),
    (b"\xff\xfe\n", "not UTF-8"),
    (b"[1, 2]\n", "JSON object"),
    (b'{"rpm": 5}\n', '"cmd"'),
    (b'{"cmd": "reboot"}\n', "unknown cmd 'reboot'"),
    (b'{"cmd": "ref", "rpm": "fast"}\n', "rpm must be a finite number"),
    (b'{"cmd": "ref", "rpm": true}\n', "rpm must be a finite number"),
    (b'{"cmd": "ref", "rpm": NaN}\n', "rpm must be a finite number"),
    (b'{"cmd": "ref"}\n', "missing field 'rpm'"),
    (b'{"cmd": "get", "x": 1}\n', "unexpected field 'x'"),
    (b'{"cmd": "set", "params": {}}\n', "non-empty"),
    (b'{"cmd": "set", "params": {"kp": "0.1"}}\n', "kp must be a finite number"),
    (b'{"cmd": "set", "params": {"k p": 1}}\n', "bad parameter name"),
    (b'{"cmd": "set", "params": [["kp", 1]]}\n', "params must be"),
    (b'{"cmd": "save", "file": ""}\n', "file must be"),
    (b'{"cmd": "guard", "on": 1}\n', "on must be true or false"),
]


@pytest.mark.parametrize("line,reason", BAD_REQUESTS)
def test_bad_request_gets_reason_then_good_request_works(session: EchoSession, line: bytes, reason: str) -> None:
    raw = Raw(session.server.path)
    try:
        raw.send(line)
        r = raw.reply()
        assert r["ok"] is False and reason in r["message"] and r["data"] is None
        assert "\n" not in r["message"]
        raw.send(b'{"cmd": "get", "id": 7}\n')
        assert raw.reply() == {"ok": True, "message": "did get", "data": {"cmd": "get", "args": {}}, "id": 7}
    finally:
        raw.close()
    assert session.seen == [("get", {})]  # the bad line never reached the session


def test_oversized_line_in_one_piece_and_in_chunks(session: EchoSession) -> None:
    raw = Raw(session.server.path)
    try:
        raw.send(b'{"cmd": "ref", "rpm": ' + b" " * (MAX_LINE_BYTES + 10) + b"1}\n")
        r = raw.reply()
        assert r["ok"] is False and str(MAX_LINE_BYTES) in r["message"]
        # Sent in pieces with no newline for a long time; a valid-looking request hidden in its
        # tail must be discarded with the rest of the line, not executed.
        for _ in range(5):
            raw.send(b"x" * 1500)
        r = raw.reply()  # answered as soon as the line passed the limit
        assert r["ok"] is False and str(MAX_LINE_BYTES) in r["message"]
        raw.send(b'x{"cmd": "load", "nm": 9}\n')
        raw.send(b'{"cmd": "ref", "rpm": 1500}\n')
        r = raw.reply()
        assert r["ok"] is True and r["data"]["args"] == {"rpm": 1500}
    finally:
        raw.close()
    assert session.seen == [("ref", {"rpm": 1500})]
    assert session.server.counters["oversized"] == 2


def test_line_of_exactly_the_limit_is_accepted(session: EchoSession) -> None:
    head = b'{"cmd": "save", "file": "'
    tail = b'"}'
    line = head + b"g" * (MAX_LINE_BYTES - len(head) - len(tail)) + tail
    assert len(line) == MAX_LINE_BYTES
    raw = Raw(session.server.path)
    try:
        raw.send(line + b"\r\n")
        assert raw.reply()["ok"] is True
    finally:
        raw.close()


def test_pipelined_requests_answered_in_order(session: EchoSession) -> None:
    raw = Raw(session.server.path)
    try:
        raw.send(b'{"cmd":"ref","rpm":1000,"id":"a"}\n\n{"cmd":"nope","id":"b"}\n{"cmd":"load","nm":0.02,"id":"c"}\n')
        replies = [raw.reply() for _ in range(3)]
    finally:
        raw.close()
    by_id = {r["id"]: r for r in replies}
    assert by_id["a"]["ok"] and by_id["c"]["ok"] and not by_id["b"]["ok"]
    assert [c for c, _ in session.seen] == ["ref", "load"]


def test_a_client_that_shuts_its_writing_still_gets_its_replies(session: EchoSession) -> None:
    """Repro: `printf '{"cmd":"ref","rpm":1234}\\n' | nc -N -U sock` (a request, then SHUT_WR) got
    nothing back though the session carried the request out: the server closed on the EOF. Now the
    replies come, the last line may lack its newline, and then the server closes."""
    raw = Raw(session.server.path)
    try:
        raw.send(b'{"cmd":"ref","rpm":1234,"id":1}\n{"cmd":"get","id":2}')
        raw.sock.shutdown(socket.SHUT_WR)
        assert [raw.reply()["id"] for _ in range(2)] == [1, 2]
        assert raw.sock.recv(1) == b""  # then closed
    finally:
        raw.close()
    assert [c for c, _ in session.seen] == ["ref", "get"]


def test_server_survives_abrupt_clients_and_serves_new_connection(session: EchoSession) -> None:
    for junk in (b'{"cmd": "ref", "rp', b"\x00\x01\x02", b""):
        raw = Raw(session.server.path)
        raw.send(junk)
        raw.sock.shutdown(socket.SHUT_RDWR)
        raw.close()
    with ControlClient(session.server.path) as client:
        assert client.request({"cmd": "get"}, timeout_s=TIMEOUT_S)["ok"] is True
    assert session.seen == [("get", {})]


def test_many_connections_at_once(session: EchoSession) -> None:
    clients = [ControlClient(session.server.path) for _ in range(8)]
    try:
        for i, c in enumerate(clients):
            r = c.request({"cmd": "ref", "rpm": i}, timeout_s=TIMEOUT_S)
            assert r["data"]["args"]["rpm"] == i
    finally:
        for c in clients:
            c.close()


def test_busy_when_session_does_not_poll(server: ControlServer) -> None:
    raw = Raw(server.path)
    try:
        raw.send(b'{"cmd": "get"}\n' * (MAX_PENDING + 3))
        busy = [raw.reply() for _ in range(3)]  # only the refused ones are answered
        assert all(not r["ok"] and "busy" in r["message"] for r in busy)
        pending = poll_until(server, MAX_PENDING)
        assert len(pending) == MAX_PENDING and server.poll() == []
        for req in pending:
            req.reply(True, "late")
        assert raw.reply()["message"] == "late"
    finally:
        raw.close()


def test_reply_twice_and_bad_data_raise(server: ControlServer) -> None:
    raw = Raw(server.path)
    try:
        raw.send(b'{"cmd": "get"}\n{"cmd": "get"}\n')
        got = poll_until(server, 2)
        first, second = got
        with pytest.raises(ValueError):
            first.reply(True, "x", {"v": float("nan")})  # strict JSON for scripts (jq)
        assert not first.replied
        first.reply(False, "two\nlines")
        with pytest.raises(RuntimeError):
            first.reply(True, "again")
        assert raw.reply() == {"ok": False, "message": "two lines", "data": None}
        second.reply(True, "fine")
        assert raw.reply()["message"] == "fine"
    finally:
        raw.close()


def test_poll_returns_empty_when_idle(server: ControlServer) -> None:
    assert server.poll() == []
    assert server.poll() == []


# ---- client errors -----------------------------------------------------------------------


def test_client_without_session(tmpdir_short: Path) -> None:
    with pytest.raises(LinkError, match="no running session"):
        ControlClient(discovery_file=tmpdir_short / "missing")
    stale = tmpdir_short / "current"
    stale.write_text(f"{tmpdir_short / 'gone.sock'}\n1\n")
    with pytest.raises(LinkError, match="no session listening"):
        ControlClient(discovery_file=stale)


def test_client_times_out_when_nobody_answers(server: ControlServer) -> None:
    with ControlClient(server.path) as client:
        with pytest.raises(LinkTimeout, match="no reply to 'get'"):
            client.request({"cmd": "get"}, timeout_s=0.2)


def test_client_refuses_oversized_request(server: ControlServer) -> None:
    with ControlClient(server.path) as client:
        with pytest.raises(ConfigError):
            client.request({"cmd": "save", "file": "x" * MAX_LINE_BYTES})


# ---- cleanup -----------------------------------------------------------------------------


def test_close_removes_socket_directory_discovery_and_thread(tmpdir_short: Path) -> None:
    srv = ControlServer(discovery_file=tmpdir_short / "current")
    raw = Raw(srv.path)  # an open connection must not keep anything alive
    try:
        srv.close()
        assert not srv.path.exists()
        assert not srv.directory.exists()
        assert not (tmpdir_short / "current").exists()
        assert not srv._thread.is_alive()
        assert raw.sock.recv(10) == b""  # the connection was closed
        srv.close()  # idempotent
    finally:
        raw.close()


def test_newer_session_owns_discovery_file(tmpdir_short: Path) -> None:
    f = tmpdir_short / "current"
    old = ControlServer(discovery_file=f)
    new = ControlServer(discovery_file=f)
    try:
        assert f.read_text().splitlines()[0] == str(new.path)
        old.close()
        assert f.read_text().splitlines()[0] == str(new.path)  # not the old one's to remove
    finally:
        old.close()
        new.close()
    assert not f.exists()


def test_stale_socket_replaced_live_one_refused(tmpdir_short: Path) -> None:
    d = tmpdir_short / "ctl"
    d.mkdir(mode=0o700)
    path = d / "s.sock"
    leftover = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    leftover.bind(str(path))  # bound, never listening: like a crashed session's socket
    leftover.close()
    with ControlServer(path, publish=False) as srv:
        with pytest.raises(ConfigError, match="another session"):
            ControlServer(path, publish=False)
        assert srv.path.exists()  # the refused second server did not remove the live socket


# ---- CLI words -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "words,expected",
    [
        (["get"], {"cmd": "get"}),
        (["set", "kp=0.1", "ki=0.01"], {"cmd": "set", "params": {"kp": 0.1, "ki": 0.01}}),
        (["set", "kd=0"], {"cmd": "set", "params": {"kd": 0}}),
        (["ref", "1500"], {"cmd": "ref", "rpm": 1500}),
        (["ref", "-1500.5"], {"cmd": "ref", "rpm": -1500.5}),
        (["load", "0.02"], {"cmd": "load", "nm": 0.02}),
        (["step", "1000", "2000"], {"cmd": "step", "from_rpm": 1000, "to_rpm": 2000}),
        (["save", "gains.toml"], {"cmd": "save", "file": "gains.toml"}),
        (["guard", "OFF"], {"cmd": "guard", "on": False}),
    ],
)
def test_parse_ctl_args(words: list[str], expected: dict) -> None:
    got = parse_ctl_args(words)
    assert got == expected
    assert json.loads(json.dumps(got)) == expected  # plain JSON data


@pytest.mark.parametrize(
    "words,reason",
    [
        ([], "missing command"),
        (["fly"], "unknown command 'fly'"),
        (["get", "kp"], "expected no arguments"),
        (["set"], "at least one NAME=VALUE"),
        (["set", "kp0.1"], "'kp0.1' is not NAME=VALUE"),
        (["set", "kp="], "is not NAME=VALUE"),
        (["set", "kp=fast"], "'fast' is not a number"),
        (["set", "kp=1", "kp=2"], "kp given twice"),
        (["set", "kp=inf"], "not finite"),
        (["set", "k-p=1"], "bad parameter name"),
        (["ref"], "expected one speed"),
        (["ref", "abc"], "'abc' is not a number"),
        (["step", "1000"], "expected two speeds"),
        (["load", "nan"], "not finite"),
        (["guard", "maybe"], "expected on or off"),
    ],
)
def test_parse_ctl_args_errors(words: list[str], reason: str) -> None:
    with pytest.raises(ConfigError, match=None) as info:
        parse_ctl_args(words)
    assert reason in str(info.value)
    assert "\n" not in str(info.value)
