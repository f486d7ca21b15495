"""The one target-spec grammar (hilbench.link.spec): every form, every fault key, every error.

Expected values are written out from the grammar in docs/design.md ("Link"), not taken from the
parser: kinds, names, the port URL handed to pyserial (our own keys removed, pyserial's kept in
order), baud (default 250000), and each fault key's FaultyLink option (delay_ms in ms -> delay_s).
"""

from __future__ import annotations

import pytest

from hilbench.errors import ConfigError
from hilbench.link import FaultSpec, TargetSpec, describe_spec_forms, parse_target_spec

D = 250_000  # the default baud


@pytest.mark.parametrize("text, kind, name", [
    ("inprocess:an1017", "inprocess", "an1017"),
    ("emulator:an1017", "emulator", "an1017"),
    ("emulator:loopback", "emulator", "loopback"),
    ("sil:an1017", "sil", "an1017"),
    ("  emulator:foc_f2812  ", "emulator", "foc_f2812"),
])
def test_named_kinds(text: str, kind: str, name: str) -> None:
    spec = parse_target_spec(text)
    assert (spec.kind, spec.name, spec.port, spec.faults, spec.text) == (kind, name, "", None, text)
    assert spec.has_link is (kind != "inprocess")
    assert spec.spawns_process is (kind != "inprocess")


def test_exec_names_a_program() -> None:
    spec = parse_target_spec("exec:/tmp/build/loopback_target")
    assert (spec.kind, spec.program, spec.spawns_process) == ("exec", "/tmp/build/loopback_target", True)


@pytest.mark.parametrize("text, port, port_kind, baud", [
    ("pty", "pty", "pty", D),
    ("/dev/ttyUSB0", "/dev/ttyUSB0", "device", D),
    ("/dev/pts/3", "/dev/pts/3", "device", D),
    ("/dev/ttyUSB0?baud=115200", "/dev/ttyUSB0", "device", 115200),
    ("serial:/dev/ttyUSB0?baud=250000", "/dev/ttyUSB0", "device", 250000),
    ("serial:/dev/ttyACM1", "/dev/ttyACM1", "device", D),
    ("fd:7", "fd:7", "fd", D),
    ("loop://", "loop://", "url", D),
    ("loop://?logging=debug", "loop://?logging=debug", "url", D),
    ("socket://127.0.0.1:5000", "socket://127.0.0.1:5000", "url", D),
    ("socket://bench-host.local:2217?baud=9600", "socket://bench-host.local:2217", "url", 9600),
    ("rfc2217://10.0.0.2:7000", "rfc2217://10.0.0.2:7000", "url", D),
    # pyserial's own keys stay in the URL, in order, flags without values included
    ("rfc2217://h:7000?ign_set_control&baud=57600&timeout=3", "rfc2217://h:7000?ign_set_control&timeout=3", "url", 57600),
    ("spy:///dev/ttyUSB0?file=/tmp/spy.txt&color", "spy:///dev/ttyUSB0?file=/tmp/spy.txt&color", "url", D),
    ("hwgrep://0403:6001?n=1", "hwgrep://0403:6001?n=1", "url", D),
    ("alt:///dev/ttyUSB0?class=PosixPollSerial", "alt:///dev/ttyUSB0?class=PosixPollSerial", "url", D),
])
def test_port_forms(text: str, port: str, port_kind: str, baud: int) -> None:
    spec = parse_target_spec(text)
    assert spec == TargetSpec(text, "port", port=port, port_kind=port_kind, baud=baud)
    assert spec.has_link and not spec.spawns_process


def test_every_fault_key_maps_onto_faulty_link() -> None:
    spec = parse_target_spec("emulator:an1017?corrupt=1e-3&corrupt_dir=rx&drop=1e-4&dup=2e-3"
                             "&delay_ms=2.5&delay_rate=0.25&silent_after=100&fault_seed=7")
    assert spec.faults == FaultSpec(seed=7, corrupt_bit_rate=0.001, corrupt_direction="rx", drop_rate=0.0001,
                                    duplicate_rate=0.002, delay_s=0.0025, delay_rate=0.25, silent_after=100)
    assert spec.faults.faulty_link_options() == {
        "corrupt_bit_rate": 0.001, "corrupt_direction": "rx", "drop_rate": 0.0001, "duplicate_rate": 0.002,
        "delay_s": 0.0025, "delay_rate": 0.25, "silent_after": 100,
    }


@pytest.mark.parametrize("text", [
    "pty?drop=0.5", "fd:3?drop=0.5", "/dev/ttyUSB0?drop=0.5", "serial:/dev/ttyUSB0?baud=9600&drop=0.5",
    "loop://?drop=0.5", "socket://127.0.0.1:1?drop=0.5", "sil:an1017?drop=0.5", "exec:/bin/true?drop=0.5",
])
def test_fault_keys_on_every_kind_with_a_link(text: str) -> None:
    assert parse_target_spec(text).faults == FaultSpec(drop_rate=0.5)


def test_fault_keys_are_not_sent_to_pyserial() -> None:
    spec = parse_target_spec("socket://127.0.0.1:5000?corrupt=0.01&logging=debug&fault_seed=3")
    assert spec.port == "socket://127.0.0.1:5000?logging=debug"
    assert spec.faults == FaultSpec(seed=3, corrupt_bit_rate=0.01)


def test_rate_bounds() -> None:
    assert parse_target_spec("pty?corrupt=0").faults == FaultSpec()
    assert parse_target_spec("pty?corrupt=0.999").faults == FaultSpec(corrupt_bit_rate=0.999)
    assert parse_target_spec("pty?delay_rate=1").faults == FaultSpec(delay_rate=1.0)
    assert parse_target_spec("pty?silent_after=0").faults == FaultSpec(silent_after=0)
    assert parse_target_spec(f"pty?fault_seed={2**64 - 1}").faults == FaultSpec(seed=2**64 - 1)


def _error(text: str) -> str:
    with pytest.raises(ConfigError) as info:
        parse_target_spec(text)
    message = str(info.value)
    assert "\n" not in message
    return message


FORMS = ("inprocess:NAME", "emulator:NAME", "sil:NAME", "pty", "/dev/PATH", "serial:/dev/PATH?baud=N", "fd:N",
         "SCHEME://")


@pytest.mark.parametrize("text, why", [
    ("", "empty"),
    ("   ", "empty"),
    ("bogus", "unknown target spec"),
    ("an1017", "unknown target spec"),
    ("emulator:", "needs a target name"),
    ("emulator:AN1017", "needs a target name"),
    ("inprocess:an-1017", "needs a target name"),
    ("sil:1st", "needs a target name"),
    ("exec:", "needs a program path"),
    ("fd:", "needs a file descriptor number"),
    ("fd:x", "needs a file descriptor number"),
    ("fd:-1", "needs a file descriptor number"),
    ("fd:\u00b2", "needs a file descriptor number"),
    ("serial:", "needs a device path"),
    ("serial:ttyUSB0", "needs a device path"),
    ("pty:3", "unknown target spec"),
    ("tcp:127.0.0.1:5000", "unknown target spec"),
])
def test_malformed_specs_list_the_accepted_forms(text: str, why: str) -> None:
    message = _error(text)
    assert why in message and repr(text) in message
    for form in FORMS:
        assert form in message


@pytest.mark.parametrize("text, needles", [
    ("emulator:an1017?corupt=1e-3", ("'corupt'", "did you mean 'corrupt'", "known keys: corrupt, corrupt_dir")),
    ("pty?fault_sed=1", ("'fault_sed'", "did you mean 'fault_seed'", "silent_after")),
    ("serial:/dev/x?speed=3", ("'speed'", "known keys: baud, corrupt")),
    ("rfc2217://h:1?timeot=3", ("'timeot'", "did you mean 'timeout'", "ign_set_control", "poll_modem")),
    ("socket://h:1?file=x", ("'file'", "known keys: baud", "logging")),
    ("inprocess:an1017?corrupt=0.01", ("in-process target has no link", "emulator:NAME")),
    ("inprocess:an1017?x=1", ("unknown key 'x'", "takes no keys")),
    ("pty?baud=9600", ("baud applies only to device paths and pyserial URLs",)),
    ("emulator:an1017?baud=9600", ("baud applies only",)),
    ("fd:3?baud=9600", ("baud applies only",)),
])
def test_unknown_keys_name_key_spec_and_known_keys(text: str, needles: tuple[str, ...]) -> None:
    message = _error(text)
    assert repr(text) in message
    for needle in needles:
        assert needle in message, message


@pytest.mark.parametrize("text, why", [
    ("pty?corrupt=1", "corrupt='1' must be in [0, 1)"),
    ("pty?corrupt=-0.1", "must be in [0, 1)"),
    ("pty?corrupt=nan", "is not finite"),
    ("pty?drop=inf", "is not finite"),
    ("pty?dup=lots", "is not a number"),
    ("pty?delay_ms=-1", "must be in [0, 60000] ms"),
    ("pty?delay_ms=1e9", "must be in [0, 60000] ms"),
    ("pty?delay_rate=1.5", "must be in [0, 1]"),
    ("pty?silent_after=-1", "must be >= 0"),
    ("pty?silent_after=2.5", "is not a whole number"),
    ("pty?fault_seed=-1", "must be in [0, 2**64)"),
    ("pty?fault_seed=x", "is not a whole number"),
    ("pty?corrupt_dir=up", "must be rx, tx or both"),
    ("/dev/ttyUSB0?baud=0", "must be a positive whole number"),
    ("/dev/ttyUSB0?baud=fast", "is not a whole number"),
    ("pty?drop", "needs a value"),
    ("pty?drop=0.1&drop=0.2", "given twice"),
    ("loop://?baud=9600&baud=9600", "given twice"),
])
def test_bad_values(text: str, why: str) -> None:
    message = _error(text)
    assert why in message and repr(text) in message


@pytest.mark.parametrize("text, needles", [
    ("sockt://127.0.0.1:5000", ("no URL scheme 'sockt'", "did you mean 'socket'", "rfc2217", "loop")),
    ("socket://127.0.0.1", ("socket:// needs HOST:PORT",)),
    ("socket://:5000", ("needs HOST:PORT",)),
    ("rfc2217://h:0", ("needs HOST:PORT",)),
    ("rfc2217://h:70000", ("needs HOST:PORT",)),
])
def test_bad_urls(text: str, needles: tuple[str, ...]) -> None:
    message = _error(text)
    for needle in needles:
        assert needle in message, message


def test_not_a_string() -> None:
    with pytest.raises(ConfigError):
        parse_target_spec(None)  # type: ignore[arg-type]


def test_help_lists_every_form_and_fault_key() -> None:
    text = describe_spec_forms()
    for needle in (*FORMS, "exec:PROGRAM", "socket://HOST:PORT", "rfc2217://HOST:PORT", "loop://",
                   "corrupt", "corrupt_dir", "drop", "dup", "delay_ms", "delay_rate", "silent_after", "fault_seed"):
        assert needle in text
