"""Control socket: lets another terminal or a script change a running session live.

Protocol: one JSON object per line (UTF-8, at most 4096 bytes before the newline), one JSON
reply line per request ``{"ok": bool, "message": str, "data": object | null}``. An optional
``"id"`` (string or integer) in a request is echoed in its reply. Requests:

    {"cmd": "get"}
    {"cmd": "set",   "params": {"kp": 0.1, "ki": 0.01}}     names → numbers, applied atomically
    {"cmd": "ref",   "rpm": 1500}
    {"cmd": "load",  "nm": 0.02}
    {"cmd": "step",  "from_rpm": 1000, "to_rpm": 2000}
    {"cmd": "save",  "file": "gains.toml"}
    {"cmd": "guard", "on": true}                             guarded tuning on/off
    {"cmd": "start"}                                         the target's Start command
    {"cmd": "press", "button": "s2"}                         press a board button (s2, s3)
    {"cmd": "stream", "since": -1, "columns": ["speed_rpm"]} a scope's decimated frames
    {"cmd": "stop"}                                          end the run

This module checks only the *shape* of a request (known command, the right fields with the
right JSON types, finite numbers); malformed, oversized, unknown or ill-typed lines are answered
here with a one-line reason and never reach the session. Whether a parameter exists, is in
range and meets the firmware's constraints is the session's business.

Where it lives: a fresh directory of mode 0700 (``mkdtemp`` under ``$XDG_RUNTIME_DIR`` when
that is set, else the system temp dir) holding the socket ``ctl.sock`` (mode 0600). The
directory is what keeps other users out (the socket is chmod-ed after bind, and the directory
already forbids entry during that instant).

Discovery: each server writes its own file ``<pid>-<name>.session`` holding
``<socket path>\\n<pid>\\n<JSON: started, cwd>\\n`` into ``$XDG_RUNTIME_DIR/hilbench/sessions/`` (or
``~/.cache/hilbench/sessions/`` without ``XDG_RUNTIME_DIR``; the directory is created 0700), so
every running session can be found (``hilbench ctl list``), not only the newest; ``hilbench ctl``
without ``--socket`` or ``--session`` talks to the only session, else to the only one started in
its working directory (or terminal), else refuses and lists them (`choose_session`). A server starting removes what dead sessions left
(``kill -9``): discovery files whose process is gone and ``hilbench-ctl-*`` directories whose
socket nobody listens on. ``close()`` removes its own file. (An explicit ``discovery_file`` is
written as before: one file naming the newest server.)

Threading: a daemon I/O thread blocks in a selector, accepts connections, splits lines, parses
and validates them and appends ``ControlRequest``s to a deque. ``poll()`` on the session thread
is then a deque truthiness check (well under 1 µs when idle, no system call), and requests are
seen within one poll of arrival however rarely poll is called. Replies are queued back to the
I/O thread (woken through a pipe), so the session never blocks on a slow client. The I/O thread
sleeps in the kernel while idle and holds the GIL only while handling bytes.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import math
import os
import re
import selectors
import socket
import stat
import struct
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, Sequence

from hilbench.errors import ConfigError, LinkClosed, LinkError, LinkTimeout, ProtocolError

if TYPE_CHECKING:
    from hilbench.bench.display import DisplayStream

MAX_LINE_BYTES = 4096
MAX_PENDING = 64  # requests queued for the session before new ones are refused as busy
#: connections for `hilbench ctl` and scripts; a scope's streams have their own (below), so pages
#: can never take these
MAX_CONNECTIONS = 16
#: connections that asked for the `stream` (scopes: a scope process multiplexes its pages on one)
MAX_STREAM_CONNECTIONS = 4
#: the longest reply line a client reads (a stream reply of 20 000 buckets of 48 columns is ~10 MB)
MAX_REPLY_BYTES = 16 * 1024 * 1024
#: replies a connection has not read: past PAUSE_UNSENT_BYTES its requests are not read (the client
#: blocks on its own send), past MAX_UNSENT_BYTES or after SLOW_READER_S without draining the
#: connection is closed and counted (``slow_readers``); its pending replies are dropped
PAUSE_UNSENT_BYTES = 64 * 1024
MAX_UNSENT_BYTES = MAX_REPLY_BYTES
SLOW_READER_S = 10.0
MAX_SET_PARAMS = 16
MAX_STREAM_COLUMNS = 48
SOCKET_NAME = "ctl.sock"
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.]{0,31}$")


# --------------------------------------------------------------------------------------------
# Request shape


#: the limits of a reference and a load, as a scenario's [[scenario]] events have them (settings.py)
MAX_REF_RPM = 20000.0
MAX_LOAD_NM = 1000.0
#: a parameter value beyond this is no parameter any target declares (checked again by the session)
MAX_PARAM_ABS = 1e9


def _is_number(v: Any) -> bool:
    """A JSON number that is finite and fits a float (a 400-digit integer does not: no OverflowError)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    if isinstance(v, int):
        return -(2**63) <= v < 2**63
    return math.isfinite(v)


def _short(v: Any) -> str:
    try:
        return json.dumps(v)[:40]
    except (TypeError, ValueError):
        return repr(v)[:40]


def _number(cmd: str, key: str, limit: float | None = None, unit: str = "") -> Callable[[Any], Any]:
    def check(v: Any) -> Any:
        if not _is_number(v):
            raise ValueError(f"{cmd}: {key} must be a finite number, got {_short(v)}")
        if limit is not None and not -limit <= v <= limit:
            raise ValueError(f"{cmd}: {key} {v:g}{unit} is out of range (-{limit:g} .. {limit:g}{unit})")
        return float(v)

    return check


def _check_params(v: Any) -> dict[str, int | float]:
    if not isinstance(v, dict) or not v:
        raise ValueError("set: params must be a non-empty object of name: number")
    if len(v) > MAX_SET_PARAMS:
        raise ValueError(f"set: at most {MAX_SET_PARAMS} parameters per request, got {len(v)}")
    out: dict[str, int | float] = {}
    for name, value in v.items():
        if not _NAME_RE.match(name):
            raise ValueError(f"set: bad parameter name {name[:40]!r}")
        if not _is_number(value):
            raise ValueError(f"set: {name} must be a finite number, got {_short(value)}")
        if abs(value) > MAX_PARAM_ABS:
            raise ValueError(f"set: {name} = {value:g} is out of any parameter's range (|value| <= {MAX_PARAM_ABS:g})")
        out[name] = value
    return out


def _check_file(v: Any) -> str:
    if not isinstance(v, str) or not v.strip() or "\x00" in v:
        raise ValueError("save: file must be a non-empty path string")
    return v


def _check_columns(v: Any) -> list[str]:
    if not isinstance(v, list) or len(v) > MAX_STREAM_COLUMNS or not all(isinstance(c, str) and _NAME_RE.match(c) for c in v):
        raise ValueError(f"stream: columns must be a list of at most {MAX_STREAM_COLUMNS} column names")
    return v


def _check_since(v: Any) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not -1 <= v < 2**53:
        raise ValueError(f"stream: since must be an integer >= -1, got {json.dumps(v)[:40]}")
    return v


def _check_button(v: Any) -> str:
    if v not in ("s2", "s3"):
        raise ValueError(f"press: button must be \"s2\" or \"s3\", got {_short(v)}")
    return str(v)


def _check_bool(v: Any) -> bool:
    if not isinstance(v, bool):
        raise ValueError(f"guard: on must be true or false, got {_short(v)}")
    return v


class ControlledSession(Protocol):
    """What a command acts on: a running session (hilbench.bench.session.Session)."""

    tuning: Any  # hilbench.bench.livetuning.LiveTuning
    profile: Any  # hilbench.targets.profile.TargetProfile
    target: Any  # hilbench.targets.base.Target
    live: Any  # hilbench.bench.parts.LivePart
    ref_rpm: float
    drive: Any  # the last Drive (hilbench.protocol.Drive), None before the first exchange

    def param_values(self) -> dict[str, float]: ...
    def reference_now(self, rpm: float, t_s: float, note: str) -> None: ...
    def stop_run(self, t_s: float, reason: str, note: str) -> None: ...
    def press(self, button: str, t_s: float) -> None: ...
    def send_start(self, t_s: float) -> None: ...
    def segment(self, kind: str, t_s: float, ref_rpm: float = 0.0, ramp_s: float = 0.0) -> None: ...
    def set_load(self, kind: str, value: float) -> None: ...
    def note(self, t_s: float, text: str) -> None: ...
    def display_stream(self) -> "DisplayStream": ...


def _tuning_state(session: ControlledSession, t_s: float) -> dict[str, Any]:
    return {"params": session.param_values(), "t_s": t_s, "ref_rpm": session.ref_rpm,
            "tunable": list(session.profile.tunable), "guard_trips": list(session.tuning.trips[-4:])}


def _get(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    request.reply(True, "ok", _tuning_state(session, t_s))


def _set(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    session.tuning.set({str(k): float(v) for k, v in request.args["params"].items()}, t_s)
    request.reply(True, f"applied at t={t_s:.4f} s", {"params": session.param_values()})


def _ref(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    rpm = request.args["rpm"]
    session.reference_now(float(rpm), t_s, f"ref {rpm} rpm (ctl)")
    watching = session.tuning.watching
    guard = f"; the guard watches the new gains until t={watching:.4f} s" if watching > t_s else ""
    request.reply(True, f"reference {rpm} rpm at t={t_s:.4f} s{guard}")


def _step(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    """A step needs a running motor: on a stopped (or faulted) one it would measure nothing."""
    from hilbench.protocol import State

    drive = session.drive
    state = None if drive is None else int(drive.state)
    if state is None or state in (State.STOPPED, State.STALLED, State.FAULT):
        name = "not started" if state is None else State(state).name
        request.reply(False, f"step refused: the motor is not running (state {name}); start it first "
                             f"(hilbench ctl press s2)")
        return
    session.live.start_step(request, float(request.args["from_rpm"]), float(request.args["to_rpm"]), t_s)


def _stop(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    session.stop_run(t_s, "stopped by ctl", "stop (ctl)")
    request.reply(True, f"run ends at t={t_s:.4f} s")


def _save(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    """A raw-socket client's save; `hilbench ctl save` writes where the user is."""
    from hilbench.bench.tuning import saved_fragment, write_fragment

    data = _tuning_state(session, t_s)
    path = str(request.args["file"])
    try:
        write_fragment(path, saved_fragment(data), reader_wait_s=0.0)  # (in the control poll: never a wait)
    except OSError as exc:
        request.reply(False, f"save {path}: {exc.strerror or exc}")
    else:
        request.reply(True, f"wrote {path}", data)


def _start(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    session.send_start(t_s)
    session.note(t_s, "start (ctl)")
    request.reply(True, f"start command sent at t={t_s:.4f} s")


def _press(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    button = str(request.args["button"])
    session.press(button, t_s)
    if button == "s2":
        session.segment("press", t_s)
    session.note(t_s, f"press {button} (ctl)")
    request.reply(True, f"{button} pressed at t={t_s:.4f} s")


def _guard(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    session.tuning.guard = dataclasses.replace(session.tuning.guard, enabled=bool(request.args["on"]))
    state = "on" if session.tuning.guard.enabled else "off"
    session.note(t_s, f"guard {state} (ctl)")
    request.reply(True, f"guarded tuning {state}")


def _stream(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    """A scope's decimated view (hilbench.bench.display)."""
    request.reply(True, "stream", session.display_stream().request(int(request.args["since"]), request.args["columns"], t_s))


def _load(session: ControlledSession, request: "ControlRequest", t_s: float) -> None:
    nm = request.args["nm"]
    session.set_load("constant", float(nm))
    session.note(t_s, f"load {nm} N*m (ctl)")
    request.reply(True, f"load {nm} N*m at t={t_s:.4f} s")


@dataclass(frozen=True)
class Command:
    """One control command: its fields, each checked for its shape here (every one required, no
    others), and what it does to the session (`act(session, request, t_s)`, replying)."""

    fields: Mapping[str, Callable[[Any], Any]]
    act: Callable[[ControlledSession, "ControlRequest", float], None]


#: every command a session answers: cmd -> its fields' shape checks and its action
COMMANDS: Mapping[str, Command] = MappingProxyType(
    {
        "get": Command({}, _get),
        "set": Command({"params": _check_params}, _set),
        "ref": Command({"rpm": _number("ref", "rpm", MAX_REF_RPM, " rpm")}, _ref),
        "load": Command({"nm": _number("load", "nm", MAX_LOAD_NM, " N*m")}, _load),
        "step": Command({"from_rpm": _number("step", "from_rpm", MAX_REF_RPM, " rpm"),
                         "to_rpm": _number("step", "to_rpm", MAX_REF_RPM, " rpm")}, _step),
        "save": Command({"file": _check_file}, _save),
        "guard": Command({"on": _check_bool}, _guard),
        "stop": Command({}, _stop),
        "start": Command({}, _start),
        "press": Command({"button": _check_button}, _press),
        "stream": Command({"since": _check_since, "columns": _check_columns}, _stream),  # the scope
    }
)


def validate_request(obj: Any) -> tuple[str, dict[str, Any]]:
    """Check a decoded request's shape; return (cmd, args) or raise ValueError with a one-line reason."""
    if not isinstance(obj, dict):
        raise ValueError("request must be a JSON object")
    cmd = obj.get("cmd")
    if not isinstance(cmd, str):
        raise ValueError('request needs "cmd" (a string)')
    if cmd not in COMMANDS:
        raise ValueError(f"unknown cmd {cmd[:40]!r} (known: {', '.join(COMMANDS)})")
    if "id" in obj and not (isinstance(obj["id"], (str, int)) and not isinstance(obj["id"], bool)):
        raise ValueError("id must be a string or an integer")
    spec = COMMANDS[cmd].fields
    extra = sorted(set(obj) - set(spec) - {"cmd", "id"})
    if extra:
        raise ValueError(f"{cmd}: unexpected field {extra[0][:40]!r} (expected: {', '.join(spec) or 'none'})")
    args: dict[str, Any] = {}
    for key, check in spec.items():
        if key not in obj:
            raise ValueError(f"{cmd}: missing field {key!r}")
        args[key] = check(obj[key])
    return cmd, args


# --------------------------------------------------------------------------------------------
# Discovery


def default_discovery_file() -> Path:
    """The per-user file naming the newest session's socket (see module docstring)."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isdir(runtime):
        return Path(runtime) / "hilbench" / "current"
    return Path.home() / ".cache" / "hilbench" / "current-session"


def _private_dir(path: Path) -> None:
    """Create ``path`` (mode 0700) or check an existing one is ours and closed to others."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if st.st_uid != os.getuid():
        raise ConfigError(f"control directory {path}: owned by uid {st.st_uid}, not by this user")
    if stat.S_IMODE(st.st_mode) & 0o077:
        raise ConfigError(f"control directory {path}: mode {stat.S_IMODE(st.st_mode):o} lets other users in (want 700)")


def sessions_dir() -> Path:
    """The per-user directory of discovery files, one per running session."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isdir(runtime):
        return Path(runtime) / "hilbench" / "sessions"
    return Path.home() / ".cache" / "hilbench" / "sessions"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError):
        return False
    return True


def _listening(path: Path) -> bool:
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(0.5)
        probe.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        probe.close()


@dataclass(frozen=True)
class SessionInfo:
    """One running session as its discovery file names it."""

    socket_path: Path
    pid: int
    started_s: float
    cwd: str
    file: Path
    tty: str = ""  # the terminal the session was started on ("" without one)


def _trusted_file(f: Path) -> bool:
    """A discovery file this user wrote and nobody else may change (a regular file, ours, not
    writable by group or others): anything else is not believed."""
    try:
        st = f.lstat()
    except OSError:
        return False
    return stat.S_ISREG(st.st_mode) and st.st_uid == os.getuid() and not stat.S_IMODE(st.st_mode) & 0o022


def _trusted_dir(d: Path) -> bool:
    """The discovery directory: ours, and nobody else may add or replace files in it."""
    try:
        st = d.stat()
    except OSError:
        return False
    return st.st_uid == os.getuid() and not stat.S_IMODE(st.st_mode) & 0o022


def _read_session_file(f: Path) -> SessionInfo | None:
    if not _trusted_file(f):
        return None
    try:
        lines = f.read_text(encoding="utf-8")[:8192].splitlines()
        extra = json.loads(lines[2]) if len(lines) > 2 else {}
        return SessionInfo(Path(lines[0].strip()), int(lines[1]), float(extra.get("started_s", 0.0)),
                           str(extra.get("cwd", "")), f, str(extra.get("tty", "")))
    except (OSError, IndexError, ValueError, UnicodeDecodeError, AttributeError):
        return None


def list_sessions(directory: Path | None = None) -> list[SessionInfo]:
    """The running sessions (newest first); files of dead ones are skipped (and removed)."""
    d = directory or sessions_dir()
    if not _trusted_dir(d):
        return []
    try:
        files = sorted(d.glob("*.session"))
    except OSError:
        return []
    out = []
    for f in files:
        if not _trusted_file(f):
            continue  # not believed, and not ours to remove
        info = _read_session_file(f)
        if info is None or not _pid_alive(info.pid) or not info.socket_path.exists():
            try:
                if info is None or not _pid_alive(info.pid):
                    f.unlink()
            except OSError:
                pass
            continue
        out.append(info)
    return sorted(out, key=lambda i: (i.started_s, i.pid), reverse=True)


def clean_stale(directory: Path | None = None, temp_base: Path | None = None) -> int:
    """Remove what killed sessions left: discovery files of dead processes and ``hilbench-ctl-*``
    directories (ours) whose socket nobody listens on. Returns how many things were removed."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    bases = {temp_base} if temp_base is not None else {Path(tempfile.gettempdir())} | (
        {Path(runtime)} if runtime and os.path.isdir(runtime) else set())
    return _clean_stale_files(directory or sessions_dir()) + sum(_clean_stale_dirs(base) for base in bases)


def _clean_stale_files(directory: Path) -> int:
    """Discovery files (trusted ones) whose process is gone."""
    try:
        files = list(directory.glob("*.session"))
    except OSError:
        return 0
    removed = 0
    for f in files:
        if not _trusted_file(f):
            continue
        info = _read_session_file(f)
        if info is None or not _pid_alive(info.pid):
            try:
                f.unlink()
                removed += 1
            except OSError:
                pass
    return removed


def _clean_stale_dirs(base: Path) -> int:
    """Our ``hilbench-ctl-*`` directories under ``base`` whose socket nobody listens on."""
    try:
        candidates = list(base.glob("hilbench-ctl-*"))
    except OSError:
        return 0
    removed = 0
    for cand in candidates:
        try:
            if not _stale_ctl_dir(cand):
                continue
            for child in cand.iterdir():
                child.unlink()
            cand.rmdir()
            removed += 1
        except OSError:
            continue
    return removed


def _stale_ctl_dir(cand: Path) -> bool:
    """A directory of ours with no listener on its socket, and not one being set up right now."""
    st = cand.lstat()
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
        return False
    sock = cand / SOCKET_NAME
    if sock.exists() and _listening(sock):
        return False
    return not (time.time() - st.st_mtime < 2.0 and not sock.exists())  # else a server being set up


def _terminal() -> str:
    """The controlling terminal of this process's standard streams ("" without one)."""
    for fd in (0, 1, 2):
        try:
            if os.isatty(fd):
                return os.ttyname(fd)
        except OSError:
            continue
    return ""


def _describe(info: SessionInfo, n: int) -> str:
    return f"#{n} pid {info.pid} in {info.cwd or '?'}" + (f" on {info.tty}" if info.tty else "")


def choose_session(selector: str | None = None, sessions: Sequence[SessionInfo] | None = None, *,
                   cwd: str | None = None, tty: str | None = None) -> SessionInfo:
    """The session a command acts on, never by guess: ``selector`` a pid or the number N of
    `hilbench ctl list` (1: the newest); without one the only session running, else the only one
    started in this working directory, else the only one started on this terminal. Otherwise a
    ConfigError that lists them (LinkError when none runs)."""
    running = list(list_sessions() if sessions is None else sessions)
    listing = "; ".join(_describe(info, n) for n, info in enumerate(running, 1))
    if not running:
        raise LinkError("control socket: no running session found (is `hilbench run` running? `hilbench ctl list`)")
    if selector is not None:
        text = str(selector).strip().lstrip("#")
        if not text.isdigit():
            raise ConfigError(f"--session {selector!r}: expected a pid or a number from `hilbench ctl list` ({listing})")
        value = int(text)
        by_pid = [info for info in running if info.pid == value]
        if by_pid:
            return by_pid[0]
        if 1 <= value <= len(running):
            return running[value - 1]
        raise ConfigError(f"--session {selector}: no such pid or number among the running sessions ({listing})")
    if len(running) == 1:
        return running[0]
    here = os.path.realpath(cwd if cwd is not None else os.getcwd())
    same_dir = [info for info in running if info.cwd and os.path.realpath(info.cwd) == here]
    if len(same_dir) == 1:
        return same_dir[0]
    terminal = _terminal() if tty is None else tty
    same_tty = [info for info in running if terminal and info.tty == terminal]
    if not same_dir and len(same_tty) == 1:
        return same_tty[0]
    why = f"{len(same_dir)} of them were started in {here}" if same_dir else f"none was started in {here}"
    raise ConfigError(f"{len(running)} sessions running and {why}: {listing}; pick one with --session PID or N "
                      f"(or --socket PATH)")


def read_discovery(discovery_file: Path | None = None, selector: str | None = None) -> Path:
    """Socket path of the running session (`choose_session`: never a guess among several), or of
    the named discovery file; LinkError if there is none."""
    if discovery_file is None:
        sessions = list_sessions()
        if sessions or selector is not None:
            return choose_session(selector, sessions).socket_path
    f = discovery_file or default_discovery_file()
    if f.exists() and not _trusted_file(f):
        raise LinkError(f"control socket: discovery file {f} is not this user's own or others may write it; "
                        "not believed (give --socket)")
    try:
        first = f.read_text(encoding="utf-8")[:8192].splitlines()[0].strip()
    except (OSError, IndexError, UnicodeDecodeError):
        raise LinkError(f"control socket: no running session found ({f} missing or empty; is `hilbench run` running?)") from None
    return Path(first)


# --------------------------------------------------------------------------------------------
# Server


@dataclass(eq=False)
class ControlRequest:
    """One validated request from a client; answer it exactly once with ``reply``."""

    cmd: str
    args: Mapping[str, Any]
    received_monotonic_s: float
    request_id: str | int | None = None
    _send: Callable[[bytes], None] | None = field(default=None, repr=False)
    _replied: bool = field(default=False, repr=False)

    def reply(self, ok: bool, message: str, data: dict[str, Any] | None = None) -> None:
        """Queue the reply line; never blocks. JSON-unserialisable data or NaN raises here."""
        if self._replied:
            raise RuntimeError(f"control request {self.cmd!r} already answered")
        line = _reply_line(ok, message, data, self.request_id)
        self._replied = True
        if self._send is not None:
            self._send(line)

    @property
    def replied(self) -> bool:
        return self._replied


def _reply_line(ok: bool, message: str, data: Mapping[str, Any] | None, request_id: str | int | None) -> bytes:
    msg = " ".join(str(message).split())  # one line, always
    obj: dict[str, Any] = {"ok": bool(ok), "message": msg, "data": None if data is None else dict(data)}
    if request_id is not None:
        obj["id"] = request_id
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode("utf-8") + b"\n"


class _Conn:
    __slots__ = ("sock", "cid", "rbuf", "wbuf", "discarding", "closing", "stream", "paused_since", "pending", "eof")

    def __init__(self, sock: socket.socket, cid: int) -> None:
        self.sock = sock
        self.cid = cid
        self.rbuf = bytearray()
        self.wbuf = bytearray()
        self.discarding = False  # inside an oversized line: drop bytes until its newline
        self.closing = False  # close once wbuf is flushed
        self.stream = False  # asked for the stream: counted among MAX_STREAM_CONNECTIONS
        self.paused_since: float | None = None  # reading paused: its replies are not being read
        self.pending = 0  # its requests the session has not answered yet
        self.eof = False  # the client has shut its writing down: answered, then closed


def peer_uid(sock: socket.socket) -> int | None:
    """The uid of the process at the other end of a Unix socket (Linux SO_PEERCRED); None where the
    system has no such option. A peer whose credentials cannot be read is -1, which no user is: it is
    refused (fail closed), never taken for ours."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return None
    try:
        _, uid, _ = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    except OSError:
        return -1
    return uid


class ControlServer:
    """The session's end of the control socket (see module docstring for protocol and layout)."""

    def __init__(
        self,
        path: str | os.PathLike[str] | None = None,
        *,
        discovery_file: str | os.PathLike[str] | None = None,
        publish: bool = True,
    ) -> None:
        self._owns_dir = path is None
        if path is None:
            runtime = os.environ.get("XDG_RUNTIME_DIR")
            base = runtime if runtime and os.path.isdir(runtime) else None
            self.directory = Path(tempfile.mkdtemp(prefix="hilbench-ctl-", dir=base))  # mode 0700
            self.path = self.directory / SOCKET_NAME
        else:
            self.path = Path(path)
            self.directory = self.path.parent
            _private_dir(self.directory)
        os.chmod(self.directory, 0o700)
        self.discovery_file: Path | None = None
        self.uid = os.getuid()
        #: connections, requests, rejected (malformed, invalid, oversized, busy), refused_connections,
        #: refused_users, slow_readers, dropped_replies
        self.counters: collections.Counter[str] = collections.Counter()
        self._inbox: collections.deque[ControlRequest] = collections.deque()
        self._outbox: collections.deque[tuple[int, bytes]] = collections.deque()
        self._conns: dict[int, _Conn] = {}
        self._next_cid = 0
        self._closed = False
        self._stop = threading.Event()
        self._sel = selectors.DefaultSelector()
        self._bound = False
        self._wake_r, self._wake_w = os.pipe()
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            if self.path.exists() or self.path.is_symlink():
                self._remove_stale_socket()
            self._listener.bind(str(self.path))
            self._bound = True
            os.chmod(self.path, 0o600)
            self._listener.listen(64)
            self._listener.setblocking(False)
            os.set_blocking(self._wake_r, False)
            os.set_blocking(self._wake_w, False)
            self._sel.register(self._listener, selectors.EVENT_READ, None)
            self._sel.register(self._wake_r, selectors.EVENT_READ, None)
            if publish:
                if discovery_file is not None:
                    self.discovery_file = Path(discovery_file)
                    self._publish(self.discovery_file)
                else:
                    clean_stale()
                    self.discovery_file = sessions_dir() / f"{os.getpid()}-{self.directory.name}.session"
                    self._publish(self.discovery_file)
        except (OSError, ConfigError) as exc:
            self._listener.close()
            self._sel.close()
            os.close(self._wake_r)
            os.close(self._wake_w)
            self._cleanup_fs()
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"control socket {self.path}: {exc.strerror or exc}") from None
        self._thread = threading.Thread(target=self._run, name="hilbench-ctl", daemon=True)
        self._thread.start()

    # ---- session side ------------------------------------------------------------------

    def poll(self) -> list[ControlRequest]:
        """Requests that arrived since the last call (usually none: then no system call)."""
        inbox = self._inbox
        if not inbox:
            return []
        out: list[ControlRequest] = []
        while inbox:
            out.append(inbox.popleft())
        return out

    def close(self) -> None:
        """Stop the I/O thread; remove the socket, its directory (if ours) and the discovery file."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._wake()
        self._thread.join(timeout=5.0)
        for conn in list(self._conns.values()):
            conn.sock.close()
        self._conns.clear()
        self._sel.close()
        self._listener.close()
        os.close(self._wake_r)
        os.close(self._wake_w)
        self._cleanup_fs()

    def trouble(self) -> str:
        """What clients did wrong, in one line ("" when nothing): the counts a run reports."""
        c = self.counters
        parts = [f"{c[key]} {what}" for key, what in (
            ("slow_readers", "clients closed for not reading their replies"),
            ("dropped_replies", "replies dropped"),
            ("refused_connections", "connections refused (over the limit)"),
            ("refused_users", "connections of another user refused")) if c[key]]
        return ", ".join(parts)

    def __enter__(self) -> "ControlServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- file system -------------------------------------------------------------------

    def _remove_stale_socket(self) -> None:
        st = os.lstat(self.path)
        if not stat.S_ISSOCK(st.st_mode):
            raise ConfigError(f"control socket {self.path}: exists and is not a socket")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.settimeout(0.5)
            probe.connect(str(self.path))
        except OSError:
            os.unlink(self.path)  # nobody listening: left over from a crashed session
        else:
            raise ConfigError(f"control socket {self.path}: another session is listening there")
        finally:
            probe.close()

    def _publish(self, f: Path) -> None:
        _private_dir(f.parent)
        tmp = f.with_name(f".{f.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        info = json.dumps({"started_s": time.time(), "cwd": os.getcwd(), "tty": _terminal()})
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(f"{self.path}\n{os.getpid()}\n{info}\n")
        os.replace(tmp, f)

    def _cleanup_fs(self) -> None:
        if self._bound:  # never remove a socket some other server bound
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
        if self._owns_dir:
            try:
                os.rmdir(self.directory)
            except OSError:
                pass
        f = self.discovery_file
        if f is not None:
            try:
                if f.read_text(encoding="utf-8").splitlines()[0].strip() == str(self.path):
                    os.unlink(f)
            except (OSError, IndexError, UnicodeDecodeError):
                pass

    # ---- I/O thread ---------------------------------------------------------------------

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except (BlockingIOError, OSError):
            pass  # pipe full (a wake-up is already pending) or closing

    def _queue_reply(self, cid: int, line: bytes) -> None:
        """Called from the session thread by ControlRequest.reply."""
        if self._closed:
            return
        self._outbox.append((cid, line))
        self._wake()

    def _run(self) -> None:
        while not self._stop.is_set():
            paused = [c for c in self._conns.values() if c.paused_since is not None]
            try:
                events = self._sel.select(timeout=1.0 if paused else None)
            except OSError:  # selector closed under us
                return
            self._close_slow_readers(paused)
            for key, mask in events:
                obj = key.fileobj
                if obj is self._listener:
                    self._accept()
                elif obj == self._wake_r:
                    try:
                        while os.read(self._wake_r, 4096):
                            pass
                    except (BlockingIOError, OSError):
                        pass
                elif key.data.cid in self._conns:
                    conn: _Conn = key.data
                    if mask & selectors.EVENT_READ:
                        self._read(conn)
                    if mask & selectors.EVENT_WRITE and conn.cid in self._conns:
                        self._flush(conn)
            self._deliver_replies()

    def _close_slow_readers(self, paused: list[_Conn]) -> None:
        now = time.monotonic()
        for conn in paused:
            if conn.paused_since is not None and now - conn.paused_since > SLOW_READER_S:
                self._drop_slow(conn)

    def _deliver_replies(self) -> None:
        """The session's replies to their connections (dropped and counted when the client has gone;
        a client with MAX_UNSENT_BYTES unread is closed)."""
        while self._outbox:
            cid, line = self._outbox.popleft()
            conn = self._conns.get(cid)
            if conn is None:
                self.counters["dropped_replies"] += 1
                continue
            conn.pending -= 1
            if len(conn.wbuf) + len(line) > MAX_UNSENT_BYTES:
                self._drop_slow(conn)
            else:
                conn.wbuf += line
                self._flush(conn)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            uid = peer_uid(sock)
            if uid is not None and uid != self.uid:  # never another user's, whatever the file modes
                self.counters["refused_users"] += 1
                try:
                    sock.setblocking(False)
                    sock.send(_reply_line(False, f"refused: this session belongs to uid {self.uid}", None, None))
                except OSError:
                    pass
                sock.close()
                continue
            sock.setblocking(False)
            self.counters["connections"] += 1
            cid = self._next_cid
            self._next_cid += 1
            conn = _Conn(sock, cid)
            self._conns[cid] = conn
            self._sel.register(sock, selectors.EVENT_READ, conn)
            if sum(1 for c in self._conns.values() if not c.stream) > MAX_CONNECTIONS:
                self._refuse(conn, f"too many control connections (max {MAX_CONNECTIONS})")

    def _refuse(self, conn: _Conn, reason: str) -> None:
        """Answer one line and close (a connection over its class's limit)."""
        self.counters["refused_connections"] += 1
        conn.wbuf += _reply_line(False, reason, None, None)
        conn.closing = True
        conn.rbuf.clear()
        self._flush(conn)

    def _drop_slow(self, conn: _Conn) -> None:
        """A client that does not read its replies: close it, count it and what it did not read."""
        self.counters["slow_readers"] += 1
        self.counters["dropped_replies"] += conn.wbuf.count(b"\n")
        self._drop(conn)

    def _drop(self, conn: _Conn) -> None:
        self._conns.pop(conn.cid, None)
        try:
            self._sel.unregister(conn.sock)
        except (KeyError, ValueError):
            pass
        conn.sock.close()

    def _flush(self, conn: _Conn) -> None:
        """Send what the socket takes; read no more requests from a client that leaves more than
        PAUSE_UNSENT_BYTES of replies unread (it is closed if that lasts SLOW_READER_S)."""
        try:
            while conn.wbuf:
                n = conn.sock.send(conn.wbuf)
                del conn.wbuf[:n]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._drop(conn)
            return
        if not conn.wbuf and (conn.closing or (conn.eof and conn.pending <= 0)):
            self._drop(conn)
            return
        pause = len(conn.wbuf) > PAUSE_UNSENT_BYTES or conn.closing
        if pause and conn.paused_since is None:
            conn.paused_since = time.monotonic()
        elif not pause:
            conn.paused_since = None
        events = (0 if pause or conn.eof else selectors.EVENT_READ) | (selectors.EVENT_WRITE if conn.wbuf else 0)
        if conn.eof and not events:  # (its replies still to come: nothing to wait for on the socket)
            try:
                self._sel.unregister(conn.sock)
            except (KeyError, ValueError):
                pass
            return
        try:
            self._sel.modify(conn.sock, events or selectors.EVENT_READ, conn)
        except KeyError:  # (a half-closed client's, unregistered while its replies were on their way)
            self._sel.register(conn.sock, events or selectors.EVENT_READ, conn)

    def _read(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(conn)
            return
        if not data:  # the client shut its writing (`nc -N`, `socat`): its requests are still answered
            conn.eof = True
            if conn.rbuf and not conn.discarding:
                conn.rbuf += b"\n"  # (its last line, unterminated)
            self._take_lines(conn)
            if conn.cid in self._conns:
                self._flush(conn)
            return
        conn.rbuf += data
        if self._take_lines(conn) and conn.cid in self._conns:
            self._flush(conn)

    def _take_lines(self, conn: _Conn) -> bool:
        """Every whole line in the connection's buffer, handled; True when one was answered here."""
        answered = False
        while True:
            nl = conn.rbuf.find(b"\n")
            if conn.discarding:
                if nl < 0:
                    conn.rbuf.clear()
                    break
                del conn.rbuf[: nl + 1]
                conn.discarding = False
                continue
            if nl < 0:
                if len(conn.rbuf) > MAX_LINE_BYTES:
                    self._reject(conn, None, f"request longer than {MAX_LINE_BYTES} bytes", "oversized")
                    answered = True
                    conn.rbuf.clear()
                    conn.discarding = True
                break
            line = bytes(conn.rbuf[:nl])
            del conn.rbuf[: nl + 1]
            if line.endswith(b"\r"):
                line = line[:-1]
            if len(line) > MAX_LINE_BYTES:
                self._reject(conn, None, f"request longer than {MAX_LINE_BYTES} bytes", "oversized")
                answered = True
                continue
            if not line.strip():
                continue
            answered |= self._handle_line(conn, line)
        return answered

    def _reject(self, conn: _Conn, request_id: Any, reason: str, counter: str) -> None:
        self.counters["rejected"] += 1
        self.counters[counter] += 1
        conn.wbuf += _reply_line(False, reason, None, request_id)

    def _handle_line(self, conn: _Conn, line: bytes) -> bool:
        """Queue a valid request for the session; answer a bad one here. True if answered here.
        Nothing a client sends may end the I/O thread: every failure becomes a one-line reply."""
        try:
            return self._handle_line_unguarded(conn, line)
        except Exception as exc:  # noqa: BLE001 - the thread must survive any request
            self._reject(conn, None, f"request refused: {type(exc).__name__}", "malformed")
            return True

    def _handle_line_unguarded(self, conn: _Conn, line: bytes) -> bool:
        try:
            obj = json.loads(line.decode("utf-8"))
        except UnicodeDecodeError:
            self._reject(conn, None, "request is not UTF-8", "malformed")
            return True
        except json.JSONDecodeError as exc:
            self._reject(conn, None, f"malformed JSON: {exc.msg} at column {exc.colno}", "malformed")
            return True
        except (ValueError, RecursionError) as exc:  # an integer of over 4300 digits, nesting too deep
            self._reject(conn, None, f"malformed JSON: {str(exc).splitlines()[0][:80]}", "malformed")
            return True
        rid = obj.get("id") if isinstance(obj, dict) else None
        if not (isinstance(rid, (str, int)) and not isinstance(rid, bool)):
            rid = None
        try:
            cmd, args = validate_request(obj)
        except ValueError as exc:
            self._reject(conn, rid, str(exc), "invalid")
            return True
        if cmd == "stream" and not conn.stream:
            if sum(1 for c in self._conns.values() if c.stream) >= MAX_STREAM_CONNECTIONS:
                self._refuse(conn, f"too many scopes on this session (max {MAX_STREAM_CONNECTIONS} stream connections)")
                return True
            conn.stream = True  # from now on a scope's connection: it no longer holds one of ctl's
        if len(self._inbox) >= MAX_PENDING:
            self._reject(conn, rid, f"busy: {MAX_PENDING} requests already waiting for the session", "busy")
            return True
        cid = conn.cid
        self.counters["requests"] += 1
        conn.pending += 1
        self._inbox.append(
            ControlRequest(
                cmd=cmd,
                args=MappingProxyType(args),
                received_monotonic_s=time.monotonic(),
                request_id=rid,
                _send=lambda data, cid=cid: self._queue_reply(cid, data),
            )
        )
        return False


# --------------------------------------------------------------------------------------------
# Client


def _connect(sock: socket.socket, path: Path, timeout_s: float) -> None:
    """connect(), again while the listener's backlog is full (EAGAIN: the session's I/O thread is
    accepting others) until ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    delay_s = 0.001
    while True:
        try:
            sock.connect(str(path))
            return
        except BlockingIOError:
            if time.monotonic() + delay_s > deadline:
                raise socket.timeout from None
            time.sleep(delay_s)
            delay_s = min(delay_s * 2, 0.05)


class ControlClient:
    """The `hilbench ctl` end: connect to a session's socket (found by discovery if not given)."""

    def __init__(
        self,
        path: str | os.PathLike[str] | None = None,
        *,
        discovery_file: str | os.PathLike[str] | None = None,
        timeout_s: float = 2.0,
    ) -> None:
        self.path = Path(path) if path is not None else read_discovery(Path(discovery_file) if discovery_file else None)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(timeout_s)
        try:
            _connect(self._sock, self.path, timeout_s)
        except (FileNotFoundError, ConnectionRefusedError):
            self._sock.close()
            raise LinkError(f"control socket {self.path}: no session listening (is `hilbench run` still running?)") from None
        except socket.timeout:
            self._sock.close()
            raise LinkTimeout(f"control socket {self.path}: connect timed out after {timeout_s} s") from None
        except OSError as exc:
            self._sock.close()
            raise LinkError(f"control socket {self.path}: {exc.strerror or exc}") from None
        uid = peer_uid(self._sock)
        if uid is not None and uid != os.getuid():  # another user's session: never talk to it
            self._sock.close()
            raise LinkError(f"control socket {self.path}: the session there runs as uid {uid}, not as this user")
        self._buf = bytearray()

    def request(self, req: Mapping[str, Any], timeout_s: float = 5.0) -> dict[str, Any]:
        """Send one request and wait for its reply line (LinkTimeout after ``timeout_s``)."""
        line = json.dumps(dict(req), allow_nan=False, separators=(",", ":")).encode("utf-8") + b"\n"
        if len(line) > MAX_LINE_BYTES + 1:
            raise ConfigError(f"control request is {len(line) - 1} bytes, more than {MAX_LINE_BYTES}")
        deadline = time.monotonic() + timeout_s
        try:
            self._sock.settimeout(timeout_s)
            self._sock.sendall(line)
            while True:
                nl = self._buf.find(b"\n")
                if nl >= 0:
                    raw = bytes(self._buf[:nl])
                    del self._buf[: nl + 1]
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise socket.timeout
                if len(self._buf) > MAX_REPLY_BYTES:
                    raise ProtocolError(f"control socket {self.path}: a reply longer than {MAX_REPLY_BYTES} bytes")
                self._sock.settimeout(remaining)
                chunk = self._sock.recv(65536)
                if not chunk:
                    raise LinkClosed(f"control socket {self.path}: session closed the connection")
                self._buf += chunk
        except socket.timeout:
            raise LinkTimeout(f"control socket {self.path}: no reply to {req.get('cmd')!r} within {timeout_s} s") from None
        except (BrokenPipeError, ConnectionResetError):
            raise LinkClosed(f"control socket {self.path}: session closed the connection") from None
        try:
            reply = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise ProtocolError(f"control socket {self.path}: reply is not JSON: {raw[:60]!r}") from None
        if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
            raise ProtocolError(f"control socket {self.path}: reply lacks a boolean 'ok': {raw[:60]!r}")
        return reply

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> "ControlClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------------------------
# CLI words


_USAGE = ("get | set NAME=VALUE ... | ref RPM | load NM | step FROM_RPM TO_RPM | save FILE | guard on|off | start | "
          "press s2|s3 | stop | list")


def _parse_number(cmd: str, what: str, word: str) -> int | float:
    shown = word if len(word) <= 24 else word[:20] + "..."
    try:
        value: int | float = int(word, 10)
    except ValueError:
        try:
            value = float(word)
        except ValueError:
            raise ConfigError(f"ctl {cmd}: {what} {shown!r} is not a number") from None
    if not _is_number(value):
        raise ConfigError(f"ctl {cmd}: {what} {shown!r} is not finite or too large")
    return value


def parse_ctl_args(words: Sequence[str]) -> dict[str, Any]:
    """Turn `hilbench ctl` words into a request dict (ConfigError with a one-line reason)."""
    if not words:
        raise ConfigError(f"ctl: missing command (usage: {_USAGE})")
    cmd, rest = words[0], list(words[1:])
    counts = {"get": 0, "ref": 1, "load": 1, "step": 2, "save": 1, "guard": 1, "stop": 0, "start": 0, "press": 1}
    if cmd == "set":
        if not rest:
            raise ConfigError("ctl set: give at least one NAME=VALUE (e.g. set kp=0.1 ki=0.01)")
        params: dict[str, int | float] = {}
        for word in rest:
            name, eq, text = word.partition("=")
            name = name.strip()
            if not eq or not name or not text.strip():
                raise ConfigError(f"ctl set: {word!r} is not NAME=VALUE")
            if not _NAME_RE.match(name):
                raise ConfigError(f"ctl set: bad parameter name {name!r}")
            if name in params:
                raise ConfigError(f"ctl set: {name} given twice")
            params[name] = _parse_number("set", name, text.strip())
        req: dict[str, Any] = {"cmd": "set", "params": params}
    elif cmd in counts:
        if len(rest) != counts[cmd]:
            expected = {"get": "no arguments", "stop": "no arguments", "start": "no arguments", "press": "s2 or s3",
                        "ref": "one speed in rpm", "load": "one torque in N·m",
                        "step": "two speeds in rpm (from, to)", "save": "one file name",
                        "guard": "on or off"}[cmd]
            raise ConfigError(f"ctl {cmd}: expected {expected}, got {len(rest)} word(s)")
        if cmd in ("get", "stop", "start"):
            req = {"cmd": cmd}
        elif cmd == "press":
            req = {"cmd": "press", "button": rest[0].lower()}
        elif cmd == "ref":
            req = {"cmd": "ref", "rpm": _parse_number("ref", "speed", rest[0])}
        elif cmd == "load":
            req = {"cmd": "load", "nm": _parse_number("load", "torque", rest[0])}
        elif cmd == "step":
            req = {"cmd": "step", "from_rpm": _parse_number("step", "from", rest[0]),
                   "to_rpm": _parse_number("step", "to", rest[1])}
        elif cmd == "save":
            req = {"cmd": "save", "file": rest[0]}
        else:
            flag = rest[0].lower()
            if flag not in ("on", "off"):
                raise ConfigError(f"ctl guard: expected on or off, got {rest[0]!r}")
            req = {"cmd": "guard", "on": flag == "on"}
    else:
        raise ConfigError(f"ctl: unknown command {cmd!r} (usage: {_USAGE})")
    try:
        validate_request(req)
    except ValueError as exc:
        raise ConfigError(f"ctl {exc}") from None
    return req


__all__ = [
    "MAX_LINE_BYTES",
    "COMMANDS",
    "Command",
    "ControlledSession",
    "ControlRequest",
    "ControlServer",
    "ControlClient",
    "validate_request",
    "parse_ctl_args",
    "default_discovery_file",
    "read_discovery",
    "choose_session",
    "sessions_dir",
    "list_sessions",
    "clean_stale",
    "SessionInfo",
]
