"""Issue 23: the control socket against clients that misbehave. Scopes cannot take `ctl`'s
connections, a client that does not read its replies is closed and counted (memory bounded), and
a session never talks to another user, whatever the file modes (SO_PEERCRED, both ends)."""

from __future__ import annotations

import json
import os
import pwd
import socket
import stat
import time
from pathlib import Path

import pytest

from _hostile import wait_for
from _scope_session import running_session
from hilbench.bench import control as control_module
from hilbench.bench.control import (MAX_CONNECTIONS, MAX_STREAM_CONNECTIONS, ControlClient, ControlServer,
                                    list_sessions, read_discovery)
from hilbench.errors import LinkError

TIMEOUT_S = 30.0


def _line(sock: socket.socket) -> dict:
    buf = b""
    while not buf.endswith(b"\n"):
        chunk = sock.recv(1 << 20)
        if not chunk:
            break
        buf += chunk
    return json.loads(buf.split(b"\n")[0]) if buf else {}


def test_scopes_cannot_take_the_connections_of_ctl() -> None:
    """Repro: 24 idle scope pages (one stream connection each) locked `ctl get` out (exit 4)."""
    with running_session() as path:
        pages = []
        try:
            answers = []
            for _ in range(24):
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                sock.settimeout(TIMEOUT_S)
                sock.connect(str(path))
                sock.sendall(b'{"cmd":"stream","since":-1,"columns":["speed_rpm"]}\n')
                answers.append(_line(sock))
                pages.append(sock)
            served = [a for a in answers if a.get("ok")]
            refused = [a for a in answers if not a.get("ok")]
            assert len(served) == MAX_STREAM_CONNECTIONS
            assert all("too many scopes" in a["message"] for a in refused)
            ctls = [ControlClient(path, timeout_s=TIMEOUT_S) for _ in range(MAX_CONNECTIONS)]  # every ctl slot
            try:
                assert all(c.request({"cmd": "get"}, timeout_s=TIMEOUT_S)["ok"] for c in ctls)
            finally:
                for c in ctls:
                    c.close()
        finally:
            for sock in pages:
                sock.close()


def test_a_reader_that_does_not_read_is_closed_and_counted(monkeypatch: pytest.MonkeyPatch, tmpdir_short: Path) -> None:
    """Repro: a socket flooded with requests whose replies are never read grew the session from 52
    to 124 MB. Now its requests are no longer read once PAUSE_UNSENT_BYTES of replies wait, and it
    is closed after SLOW_READER_S; others are served meanwhile."""
    monkeypatch.setattr(control_module, "SLOW_READER_S", 1.0)
    folder = tmpdir_short
    server = ControlServer(folder / "s" / "ctl.sock", publish=False)
    try:
        flood = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        flood.connect(str(server.path))
        flood.setblocking(False)
        request = b'{"cmd":"ref","rpm":1e99}\n'  # refused by the I/O thread itself: a reply each
        sent = 0
        stalled_since = None
        while True:  # send until the server stops reading (the kernel's buffers fill up)
            try:
                sent += flood.send(request * 256)
                stalled_since = None
            except BlockingIOError:
                stalled_since = stalled_since or time.monotonic()
                if time.monotonic() - stalled_since > 0.5:
                    break
                time.sleep(0.01)  # polling a non-blocking socket
            except OSError:
                break  # closed already
        unsent = sum(len(c.wbuf) for c in server._conns.values())
        assert unsent <= control_module.PAUSE_UNSENT_BYTES + 2 * 65536 * 8, unsent
        wait_for(lambda: server.counters["slow_readers"] == 1, TIMEOUT_S, "the slow reader closed")
        assert server.counters["dropped_replies"] > 0 and sent > 1_000_000 // 8
        with ControlClient(server.path, timeout_s=TIMEOUT_S) as client:  # the server is fine
            client._sock.sendall(b'{"cmd":"ref","rpm":1e99}\n')
            assert "out of range" in _line(client._sock)["message"]
        flood.close()
    finally:
        server.close()


def _nobody() -> int:
    if os.geteuid() != 0:
        pytest.skip("acting as a second user needs root (the test forks a child that becomes nobody)")
    try:
        return pwd.getpwnam("nobody").pw_uid
    except KeyError:
        pytest.skip("no user nobody on this machine")


def _as_user(uid: int, action) -> bytes:  # type: ignore[no-untyped-def]
    """Fork a child that becomes ``uid`` and runs ``action()`` (socket calls only: nothing that could
    meet a lock another thread held at the fork); returns what it wrote to its pipe."""
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child
        try:
            os.close(read_fd)
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            os.write(write_fd, action())
        except BaseException as exc:  # noqa: BLE001 - told to the parent
            os.write(write_fd, f"child: {exc!r}".encode())
        finally:
            os._exit(0)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as handle:
        out = handle.read()
    os.waitpid(pid, 0)
    return out


def test_a_session_refuses_another_user_whatever_the_file_modes(tmpdir_short: Path) -> None:
    """The socket's directory (0700) keeps other users out; with it opened up (chmod 711), the
    session still refuses their connection: SO_PEERCRED names another uid."""
    uid = _nobody()
    folder = tmpdir_short
    os.chmod(folder, 0o711)
    server = ControlServer(folder / "s" / "ctl.sock", publish=False)
    try:
        def knock() -> bytes:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(TIMEOUT_S)
            try:
                sock.connect(str(server.path))
            except OSError as exc:
                return f"connect: {exc.errno}".encode()
            buf = b""  # the session answers at once, before any request
            while chunk := sock.recv(4096):
                buf += chunk
            return buf or b"closed"

        assert knock_result_is_errno(_as_user(uid, knock))  # the 0700 directory: EACCES
        os.chmod(server.directory, 0o711)
        os.chmod(server.path, 0o777)
        reply = _as_user(uid, knock)
        assert reply.startswith(b"{"), reply
        assert json.loads(reply)["message"] == f"refused: this session belongs to uid {os.getuid()}"
        assert server.counters["refused_users"] == 1 and server.counters["requests"] == 0
    finally:
        server.close()


def knock_result_is_errno(out: bytes) -> bool:
    return out.startswith(b"connect: ")


def test_ctl_refuses_a_session_of_another_user(tmpdir_short: Path) -> None:
    """`hilbench ctl --socket PATH` where another user listens: the client checks the peer too."""
    uid = _nobody()
    folder = tmpdir_short
    os.chmod(folder, 0o777)
    path = folder / "ctl.sock"
    ready_r, ready_w = os.pipe()

    def listen() -> bytes:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.bind(str(path))
        os.chmod(path, 0o777)
        sock.listen(1)
        os.write(ready_w, b"x")
        conn, _ = sock.accept()
        conn.recv(4096)
        return b"done"

    pid = os.fork()
    if pid == 0:
        try:
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            listen()
        finally:
            os._exit(0)
    try:
        os.close(ready_w)
        assert os.read(ready_r, 1) == b"x"
        with pytest.raises(LinkError, match=f"the session there runs as uid {uid}, not as this user"):
            ControlClient(path, timeout_s=TIMEOUT_S)
    finally:
        os.close(ready_r)
        try:
            socket.socket(socket.AF_UNIX, socket.SOCK_STREAM).connect(str(path))  # let the child end
        except OSError:
            pass
        os.waitpid(pid, 0)


def test_discovery_files_others_may_write_are_not_believed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A session's discovery file is 0600 in a 0700 directory; a file others may write (or a
    directory they may write into) is skipped, never used to pick a socket."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    os.chmod(tmp_path, 0o700)
    server = ControlServer()
    try:
        sessions = list_sessions()
        assert [s.socket_path for s in sessions] == [server.path]
        f = sessions[0].file
        assert stat.S_IMODE(f.stat().st_mode) == 0o600 and stat.S_IMODE(f.parent.stat().st_mode) == 0o700
        os.chmod(f, 0o622)
        assert list_sessions() == []
        os.chmod(f, 0o600)
        os.chmod(f.parent, 0o733)
        assert list_sessions() == []
        os.chmod(f.parent, 0o700)
        assert read_discovery() == server.path
        named = tmp_path / "named"
        named.write_text(f"{server.path}\n")
        os.chmod(named, 0o666)
        with pytest.raises(LinkError, match="not believed"):
            read_discovery(named)
    finally:
        server.close()


def test_a_peer_whose_credentials_cannot_be_read_is_not_taken_for_ours() -> None:
    """peer_uid fails closed: an unreadable SO_PEERCRED is uid -1 (refused), not None (accepted)."""
    import socket as _socket

    from hilbench.bench.control import peer_uid

    class Unreadable(_socket.socket):
        def getsockopt(self, *args):  # type: ignore[no-untyped-def, override]
            raise OSError("no credentials")

    sock = Unreadable(_socket.AF_UNIX, _socket.SOCK_STREAM)
    try:
        assert peer_uid(sock) == -1
    finally:
        sock.close()
