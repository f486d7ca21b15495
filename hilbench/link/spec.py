"""One grammar for naming a target or a link: what a user types after `--target` or `--port`,
or writes in `[link] target`.

    parse_target_spec("emulator:an1017?corrupt=1e-3&fault_seed=7")
    # TargetSpec(kind="emulator", name="an1017", faults=FaultSpec(seed=7, corrupt_bit_rate=0.001))
    parse_target_spec("socket://127.0.0.1:5000")   # TargetSpec(kind="port", port_kind="url", ...)

The parser only reads text: it opens nothing and does not know which target names exist.
Every malformed spec is one `ConfigError` line that names the spec and lists the accepted forms
(or, for a query key, the known keys with a "did you mean"). `describe_spec_forms()` is the help.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass
from typing import Callable

from hilbench.errors import ConfigError

DEFAULT_BAUD = 250_000

KIND_INPROCESS = "inprocess"  # the model stepped in this process: no link at all
KIND_EMULATOR = "emulator"  # the model as its own Python process, on a pty pair the host makes
KIND_SIL = "sil"  # a host build of the C firmware as its own process, on a pty pair the host makes
KIND_SIMAVR = "simavr"  # an AVR build of the C firmware in the simavr simulator, on the pty it makes
KIND_QEMU = "qemu"  # a Cortex-M build of the C firmware in QEMU
KIND_EXEC = "exec"  # any program given the pty path as its one argument (e.g. the C loopback)
KIND_PORT = "port"  # a port the far end already sits on: a tty, an fd, a pyserial URL
#: kinds that start a build of a target's C firmware (hilbench.targets.starters): NAME or a PATH
FIRMWARE_KINDS = (KIND_SIL, KIND_SIMAVR, KIND_QEMU)
_NAMED_KINDS = (KIND_INPROCESS, KIND_EMULATOR, *FIRMWARE_KINDS)

PORT_PTY = "pty"  # make a pty pair here; link.peer_path is the slave the far end opens
PORT_DEVICE = "device"  # a tty device path (a real board, a pty slave someone else made)
PORT_FD = "fd"  # an open file descriptor (a pty, a socket, a pipe) inherited from a parent
PORT_URL = "url"  # anything pyserial's serial_for_url opens: socket://, rfc2217://, loop://, spy://

_NAME_RE = re.compile(r"[a-z][a-z0-9_]*")
_SCHEME_RE = re.compile(r"([a-z][a-z0-9+.-]*)://")

# pyserial 3.5's own query options per URL scheme (its handlers' from_url); they pass through
_PYSERIAL_OPTIONS: dict[str, tuple[str, ...]] = {
    "alt": ("class",),
    "cp2110": (),
    "hwgrep": ("n", "skip_busy"),
    "loop": ("logging",),
    "rfc2217": ("logging", "ign_set_control", "poll_modem", "timeout"),
    "socket": ("logging",),
    "spy": ("file", "color", "raw", "all"),
}
_NEEDS_HOST_PORT = ("socket", "rfc2217")

FORMS = (
    ("inprocess:NAME", "the target model stepped in this process (no link)"),
    ("emulator:NAME", "the target model as its own process on a virtual serial pair (pty)"),
    ("sil:NAME", "a host build of the target's C firmware as its own process on a pty"),
    ("simavr:NAME", "an AVR build of the target's C firmware in the simavr simulator"),
    ("qemu:NAME", "a Cortex-M4 build of the target's C firmware in QEMU"),
    ("sil:PATH, simavr:PATH, qemu:PATH", "a build of any firmware on hilbench's runtime (it describes itself)"),
    ("exec:PROGRAM", "any program, given the pty path as its argument (e.g. the C loopback)"),
    ("pty", "a virtual serial pair made here; the far end opens the printed path"),
    ("/dev/PATH[?baud=N]", "a serial device (a board, a pty slave)"),
    ("serial:/dev/PATH?baud=N", "the same, spelled as a URL"),
    ("fd:N", "an open file descriptor (pty, socket, pipe)"),
    ("SCHEME://…", "any pyserial URL: socket://HOST:PORT, rfc2217://HOST:PORT, loop://, spy://…"),
)
_FORMS_LINE = ", ".join(form for form, _ in FORMS)


@dataclass(frozen=True)
class FaultSpec:
    """Seeded fault injection asked for in a spec's query; the FaultyLink options, validated."""

    seed: int = 0
    corrupt_bit_rate: float = 0.0  # probability that each wire bit is flipped (a bit error rate)
    corrupt_direction: str = "both"  # rx, tx or both
    drop_rate: float = 0.0  # probability that a frame this end sends is dropped
    duplicate_rate: float = 0.0  # ... is sent twice
    delay_s: float = 0.0  # ... is sent this late
    delay_rate: float = 1.0  # ... of the frames (when delay_s > 0)
    silent_after: int | None = None  # send nothing after this many frames

    def faulty_link_options(self) -> dict[str, float | int | str | None]:
        """The keyword arguments of FaultyLink besides link and seed."""
        return {
            "corrupt_bit_rate": self.corrupt_bit_rate,
            "corrupt_direction": self.corrupt_direction,
            "drop_rate": self.drop_rate,
            "duplicate_rate": self.duplicate_rate,
            "delay_s": self.delay_s,
            "delay_rate": self.delay_rate,
            "silent_after": self.silent_after,
        }


@dataclass(frozen=True)
class TargetSpec:
    """A parsed target spec. `kind` says which fields mean something:

    inprocess / emulator / sil / simavr / qemu: `name` (or, for the firmware kinds, `program`: a
    path to a build); exec: `program`; port: `port`, `port_kind`, `baud`.
    `faults` (any kind with a link, i.e. all but inprocess) asks for a FaultyLink around it.
    """

    text: str  # as the user wrote it, for labels and error lines
    kind: str
    name: str = ""  # the registered target name (the parser does not check that it exists)
    program: str = ""
    port: str = ""  # what to open: "pty", a device path, "fd:N", or a pyserial URL without our keys
    port_kind: str = ""  # PORT_PTY, PORT_DEVICE, PORT_FD or PORT_URL
    baud: int = DEFAULT_BAUD
    faults: FaultSpec | None = None
    wire_baud: int | None = None  # hold the link to this baud's wire time (hilbench.link.throttle)
    twin: str | None = None  # "auto" / "off": twin-speculative lockstep, over [link] twin (hilbench.bench.speculative)

    @property
    def has_link(self) -> bool:
        """False only for inprocess: every other kind talks to its target through a link."""
        return self.kind != KIND_INPROCESS

    @property
    def spawns_process(self) -> bool:
        """True for emulator, the firmware kinds and exec: the host starts the far end as a process."""
        return self.kind in (KIND_EMULATOR, KIND_EXEC, *FIRMWARE_KINDS)


def describe_spec_forms() -> str:
    """The accepted spec forms and the fault keys, one per line (for --help and docs)."""
    width = max(len(form) for form, _ in FORMS)
    lines = ["Target specs:"]
    lines += [f"  {form:<{width}}  {what}" for form, what in FORMS]
    lines.append("Fault injection (any spec with a link; add as query keys, e.g. "
                 "emulator:an1017?corrupt=1e-3&fault_seed=7):")
    width = max(len(key) for key in _FAULT_KEYS)
    lines += [f"  {key:<{width}}  {_FAULT_KEYS[key][1]}" for key in _FAULT_KEYS]
    lines.append(f"Wire time (any spec with a link): {WIRE_BAUD_KEY}=N holds the link to the wire time of an "
                 "8N1 UART at N baud, 10 bits a byte each way (e.g. sil:an1017?wire_baud=250000)")
    lines.append(f"Twin (any spec with a link): {TWIN_KEY}=auto|off, twin-speculative lockstep when the target's "
                 "firmware has a bit-exact host twin (over [link] twin)")
    return "\n".join(lines)


# -- values ------------------------------------------------------------------------------
class _BadValue(ValueError):
    """A query value that does not parse or is out of range (the message says why)."""


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _BadValue("is not a number") from None
    if not math.isfinite(value):
        raise _BadValue("is not finite")
    return value


def _whole(text: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise _BadValue("is not a whole number") from None


def _rate(text: str) -> float:
    value = _number(text)
    if not 0.0 <= value < 1.0:
        raise _BadValue("must be in [0, 1)")
    return value


def _fraction(text: str) -> float:
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise _BadValue("must be in [0, 1]")
    return value


def _delay_s(text: str) -> float:
    value = _number(text)
    if not 0.0 <= value <= 60_000.0:
        raise _BadValue("must be in [0, 60000] ms")
    return value / 1000.0


def _count(text: str) -> int:
    value = _whole(text)
    if value < 0:
        raise _BadValue("must be >= 0")
    return value


def _seed(text: str) -> int:
    value = _whole(text)
    if not 0 <= value < 2**64:
        raise _BadValue("must be in [0, 2**64)")
    return value


def _direction(text: str) -> str:
    if text not in ("rx", "tx", "both"):
        raise _BadValue("must be rx, tx or both")
    return text


def _baud(text: str) -> int:
    value = _whole(text)
    if not 0 < value <= 100_000_000:
        raise _BadValue("must be a positive whole number of bits/s")
    return value


# key -> (FaultSpec field, help, parser)
_FAULT_KEYS: dict[str, tuple[str, str, Callable[[str], object]]] = {
    "corrupt": ("corrupt_bit_rate", "bit error rate: each wire bit flipped with this probability, [0, 1)", _rate),
    "corrupt_dir": ("corrupt_direction", "which bytes corrupt flips: rx, tx or both (default)", _direction),
    "drop": ("drop_rate", "probability that a frame the host sends is dropped, [0, 1)", _rate),
    "dup": ("duplicate_rate", "probability that a frame the host sends goes twice, [0, 1)", _rate),
    "delay_ms": ("delay_s", "hold a frame the host sends this long before sending it", _delay_s),
    "delay_rate": ("delay_rate", "fraction of the frames delay_ms applies to, [0, 1] (default 1)", _fraction),
    "silent_after": ("silent_after", "the host sends nothing after this many frames", _count),
    "fault_seed": ("seed", "seed of the fault generators (default 0): same seed, same faults", _seed),
}
FAULT_KEYS = tuple(_FAULT_KEYS)
#: the keys of any spec with a link: the fault keys and the wire throttle
WIRE_BAUD_KEY = "wire_baud"
TWIN_KEY = "twin"
LINK_KEYS = (*FAULT_KEYS, WIRE_BAUD_KEY, TWIN_KEY)


# -- parsing -----------------------------------------------------------------------------
def _fail(text: str, why: str) -> ConfigError:
    return ConfigError(f"target spec {text!r}: {why} (accepted: {_FORMS_LINE})")


def _did_you_mean(key: str, known: list[str]) -> str:
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _split_query(text: str, query: str, ours: tuple[str, ...],
                 theirs: tuple[str, ...] | None) -> tuple[dict[str, str], list[str]]:
    """Our keys' values, and the raw items left for pyserial (theirs None: any key passes)."""
    values: dict[str, str] = {}
    passed: list[str] = []
    seen: set[str] = set()
    for item in query.split("&"):
        if not item:
            continue
        key, eq, value = item.partition("=")
        if key in seen:
            raise ConfigError(f"target spec {text!r}: key {key!r} given twice")
        seen.add(key)
        if key in ours:
            if not eq:
                raise ConfigError(f"target spec {text!r}: key {key!r} needs a value ({key}=…)")
            values[key] = value
        elif theirs is None or key in theirs:
            passed.append(item)
        else:
            raise ConfigError(f"target spec {text!r}: {_unknown_key(key, ours + (theirs or ()))}")
    return values, passed


def _unknown_key(key: str, known_keys: tuple[str, ...]) -> str:
    """Why key is refused: no link to fault, baud on a port without one, or a plain unknown key."""
    if not known_keys and key in LINK_KEYS:
        return f"{key!r}: an in-process target has no link to inject faults into (use emulator:NAME)"
    if key == "baud":
        return "baud applies only to device paths and pyserial URLs"
    known = sorted(known_keys)
    listed = f"known keys: {', '.join(known)}" if known else "this form takes no keys"
    return f"unknown key {key!r}{_did_you_mean(key, known)}; {listed}"


def _faults(text: str, values: dict[str, str]) -> FaultSpec | None:
    fields: dict[str, object] = {}
    for key, raw in values.items():
        if key not in _FAULT_KEYS:
            continue
        field_name, _, parse = _FAULT_KEYS[key]
        try:
            fields[field_name] = parse(raw)
        except _BadValue as exc:
            raise ConfigError(f"target spec {text!r}: {key}={raw!r} {exc}") from None
    return FaultSpec(**fields) if fields else None  # type: ignore[arg-type]


def _wire_baud_of(text: str, values: dict[str, str]) -> int | None:
    if WIRE_BAUD_KEY not in values:
        return None
    try:
        return _baud(values[WIRE_BAUD_KEY])
    except _BadValue as exc:
        raise ConfigError(f"target spec {text!r}: {WIRE_BAUD_KEY}={values[WIRE_BAUD_KEY]!r} {exc}") from None


def _twin_of(text: str, values: dict[str, str]) -> str | None:
    value = values.get(TWIN_KEY)
    if value is None or value in ("auto", "off"):
        return value
    raise ConfigError(f"target spec {text!r}: {TWIN_KEY}={value!r} must be auto or off")


def _baud_of(text: str, values: dict[str, str]) -> int:
    if "baud" not in values:
        return DEFAULT_BAUD
    try:
        return _baud(values["baud"])
    except _BadValue as exc:
        raise ConfigError(f"target spec {text!r}: baud={values['baud']!r} {exc}") from None


def _url_scheme_known(scheme: str) -> list[str] | None:
    """None when pyserial can open scheme://, else the schemes it can (for the error line)."""
    import importlib.util

    import serial  # pyserial

    for package in serial.protocol_handler_packages:
        try:
            if importlib.util.find_spec(f"{package}.protocol_{scheme}") is not None:
                return None
        except (ImportError, ValueError):
            continue
    return sorted(_PYSERIAL_OPTIONS)


def _parse_url(text: str, body: str, scheme: str) -> TargetSpec:
    known_schemes = _url_scheme_known(scheme)
    if known_schemes is not None:
        raise ConfigError(
            f"target spec {text!r}: pyserial knows no URL scheme {scheme!r}"
            f"{_did_you_mean(scheme, known_schemes)}; known: {', '.join(known_schemes)}"
        )
    base, _, query = body.partition("?")
    ours = ("baud", *LINK_KEYS)
    values, passed = _split_query(text, query, ours, _PYSERIAL_OPTIONS.get(scheme))
    if scheme in _NEEDS_HOST_PORT:
        host, colon, port = base[len(scheme) + 3:].rstrip("/").rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ConfigError(f"target spec {text!r}: {scheme}:// needs HOST:PORT, e.g. {scheme}://127.0.0.1:5000")
    url = base + ("?" + "&".join(passed) if passed else "")
    return TargetSpec(text, KIND_PORT, port=url, port_kind=PORT_URL, baud=_baud_of(text, values),
                      faults=_faults(text, values), wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))


def parse_target_spec(text: str) -> TargetSpec:
    """Parse one target spec (see describe_spec_forms); ConfigError names what is wrong."""
    if not isinstance(text, str):
        raise ConfigError(f"target spec {text!r}: must be a string (accepted: {_FORMS_LINE})")
    body = text.strip()
    if not body:
        raise _fail(text, "empty")
    scheme = _SCHEME_RE.match(body)
    if scheme is not None:
        return _parse_url(text, body, scheme.group(1))
    head, _, query = body.partition("?")
    prefix, colon, rest = head.partition(":")
    if colon and prefix in FIRMWARE_KINDS and ("/" in rest or rest.startswith(("~", "."))):
        values, _ = _split_query(text, query, LINK_KEYS, ())  # a path to a build of any firmware
        return TargetSpec(text, prefix, program=rest, faults=_faults(text, values),
                          wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))
    if colon and prefix in _NAMED_KINDS:
        return _parse_named(text, prefix, rest, query)
    if colon and prefix == KIND_EXEC:
        if not rest:
            raise _fail(text, "exec: needs a program path")
        values, _ = _split_query(text, query, LINK_KEYS, ())
        return TargetSpec(text, KIND_EXEC, program=rest, faults=_faults(text, values),
                          wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))
    return _parse_port(text, head, query)


def _parse_named(text: str, kind: str, name: str, query: str) -> TargetSpec:
    """``inprocess:NAME``, ``emulator:NAME``, ``sil:NAME``...: a registered target by name."""
    if not _NAME_RE.fullmatch(name):
        raise _fail(text, f"{kind}: needs a target name (a lowercase identifier, e.g. {kind}:an1017)")
    if kind == KIND_INPROCESS:
        _split_query(text, query, (), ())  # an in-process target has no link to wrap
        return TargetSpec(text, KIND_INPROCESS, name=name)
    values, _ = _split_query(text, query, LINK_KEYS, ())
    return TargetSpec(text, kind, name=name, faults=_faults(text, values), wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))


def _parse_port(text: str, head: str, query: str) -> TargetSpec:
    """``pty``, ``fd:N``, ``serial:/dev/...`` or a bare device path: a port the bench opens."""
    prefix, colon, rest = head.partition(":")
    if head == "pty" or (colon and prefix == "fd"):
        if prefix == "fd" and not (rest.isascii() and rest.isdigit()):
            raise _fail(text, "fd: needs a file descriptor number, e.g. fd:3")
        values, _ = _split_query(text, query, LINK_KEYS, ())
        return TargetSpec(text, KIND_PORT, port=head, port_kind=PORT_FD if colon else PORT_PTY,
                          faults=_faults(text, values), wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))
    if colon and prefix == "serial":
        head = rest
        if not head.startswith("/"):
            raise _fail(text, "serial: needs a device path, e.g. serial:/dev/ttyUSB0?baud=250000")
    if head.startswith("/"):
        values, _ = _split_query(text, query, ("baud", *LINK_KEYS), ())
        return TargetSpec(text, KIND_PORT, port=head, port_kind=PORT_DEVICE, baud=_baud_of(text, values),
                          faults=_faults(text, values), wire_baud=_wire_baud_of(text, values),
                          twin=_twin_of(text, values))
    raise ConfigError(f"unknown target spec {text!r} (accepted: {_FORMS_LINE})")


__all__ = [
    "DEFAULT_BAUD",
    "FAULT_KEYS",
    "LINK_KEYS",
    "TWIN_KEY",
    "WIRE_BAUD_KEY",
    "FaultSpec",
    "KIND_EMULATOR",
    "KIND_EXEC",
    "KIND_INPROCESS",
    "KIND_PORT",
    "KIND_QEMU",
    "KIND_SIL",
    "KIND_SIMAVR",
    "FIRMWARE_KINDS",
    "PORT_DEVICE",
    "PORT_FD",
    "PORT_PTY",
    "PORT_URL",
    "TargetSpec",
    "describe_spec_forms",
    "parse_target_spec",
]
