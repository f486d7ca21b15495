"""Protocol 2's handshake check: the schema fingerprint, how it is computed, and who checks it.

The fingerprint is recomputed here from schema.toml by the recipe in PROTOCOL.md (hashlib and
json, not the generator's code). The C side's refusal is in test_c_loopback.py.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import sys
import threading
import tomllib
from pathlib import Path

import pytest

from hilbench.errors import VersionMismatch
from hilbench.link import open_link
from hilbench.protocol import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    ErrorCode,
    ErrorReport,
    HostHello,
    ParamType,
    TargetHello,
    check_target_hello,
    host_hello_mismatch,
    param_scale,
    version_refusal,
)
from hilbench.targets.loopback.target import LoopbackTarget
from hilbench.targets.remote import RemoteTarget
from hilbench.targets.serve import serve

REPO = Path(__file__).resolve().parent.parent
SCHEMA = REPO / "firmware_protocol" / "schema.toml"
OTHER = 0x0BADF00D


def _by_the_recipe(text: str) -> int:
    """PROTOCOL.md: SHA-256 over the parsed schema without doc/hot/hot_n/default/py_order, sorted compact
    ASCII JSON; the first 4 bytes, big-endian."""
    def strip(v):
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if k not in ("doc", "hot", "hot_n", "default", "py_order")}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v

    data = json.dumps(strip(tomllib.loads(text)), sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return int.from_bytes(hashlib.sha256(data.encode("ascii")).digest()[:4], "big")


def _generator():
    spec = importlib.util.spec_from_file_location("hbp_generate", REPO / "firmware_protocol" / "generate.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("hbp_generate", mod)  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_fingerprint_follows_the_documented_recipe() -> None:
    text = SCHEMA.read_text(encoding="utf-8")
    assert SCHEMA_FINGERPRINT == _by_the_recipe(text)
    header = (REPO / "firmware_protocol" / "hbp_messages.h").read_text(encoding="utf-8")
    assert f"#define HBP_SCHEMA_FINGERPRINT {SCHEMA_FINGERPRINT:#010x}UL" in header


def test_fingerprint_ignores_prose_and_sees_the_wire() -> None:
    gen = _generator()
    text = SCHEMA.read_text(encoding="utf-8")
    base = gen.schema_fingerprint(tomllib.loads(text))
    assert base == SCHEMA_FINGERPRINT
    # a comment, a doc string, a Python-only hint: same fingerprint
    prose = "# another comment\n" + text.replace('doc = "Frame type byte"', 'doc = "The frame type byte"')
    prose = prose.replace("hot_n = 3 }", "hot_n = 4 }", 1)
    assert prose != text and gen.schema_fingerprint(tomllib.loads(prose)) == base
    # a field width, a constant, a limit: another fingerprint
    for old, new in (('{ name = "encoder", type = "u16" }', '{ name = "encoder", type = "u32" }'),
                     ('["INDEX", 0x40]', '["INDEX", 0x80]'),
                     ("max_adc = 8", "max_adc = 7")):
        assert old in text
        assert gen.schema_fingerprint(tomllib.loads(text.replace(old, new))) != base, old


def _hello(version: int = PROTOCOL_VERSION, fingerprint: int = SCHEMA_FINGERPRINT) -> TargetHello:
    return TargetHello(0, version, fingerprint, 1, 7500, 10_000, 0, 12, "f2812_foc", (4, 5, 3), (1, 2))


def test_check_target_hello_names_both_fingerprints_and_versions_in_one_line() -> None:
    check_target_hello(_hello(), where="target x")
    for version, fp in ((PROTOCOL_VERSION, OTHER), (PROTOCOL_VERSION + 1, SCHEMA_FINGERPRINT)):
        with pytest.raises(VersionMismatch) as info:
            check_target_hello(_hello(version, fp), where="target serial:/dev/ttyUSB0")
        text = str(info.value)
        assert "\n" not in text and text.startswith("target serial:/dev/ttyUSB0: ")
        assert f"schema {fp:#010x} (protocol version {version})" in text
        assert f"schema {SCHEMA_FINGERPRINT:#010x} (protocol version {PROTOCOL_VERSION})" in text
        assert "rebuild the firmware" in text


def test_defaults_carry_the_real_fingerprint() -> None:
    assert HostHello(0, PROTOCOL_VERSION, 1000, 0, 100).schema_fingerprint == SCHEMA_FINGERPRINT
    assert ErrorReport(0, ErrorCode.VERSION, PROTOCOL_VERSION).schema_fingerprint == SCHEMA_FINGERPRINT
    assert host_hello_mismatch(HostHello(0, PROTOCOL_VERSION, 1000, 0, 100)) is None
    assert "0x0badf00d" in host_hello_mismatch(HostHello(0, PROTOCOL_VERSION, 1000, 0, 100, OTHER))
    err = version_refusal(ErrorReport(1, ErrorCode.VERSION, 2, OTHER), HostHello(1, 2, 1000, 0, 0), where="t")
    assert f"{OTHER:#010x}" in str(err) and f"{SCHEMA_FINGERPRINT:#010x}" in str(err)


def test_python_targets_send_the_real_fingerprint() -> None:
    from hilbench.targets.an1017.target import An1017Target

    for target, adc_bits in ((LoopbackTarget(), 10), (An1017Target(), 10)):
        hello = target.hello(HostHello(3, PROTOCOL_VERSION, 1000, 0, 0))
        check_target_hello(hello, where="in-process")
        assert hello.adc_bits == adc_bits


def test_param_scale() -> None:
    assert param_scale(ParamType.Q15) == 1 / 32768
    assert param_scale(ParamType.IQ24) * 12_582_912 == 0.75  # _IQ24(0.75)
    assert param_scale(ParamType.INT) == param_scale(ParamType.BOOL) == 1.0


def test_serve_refuses_another_schema_like_the_c_target() -> None:
    host_link = open_link("pty", timeout_s=1.0)
    far_link = open_link(host_link.peer_path, timeout_s=1.0)
    stop = threading.Event()
    thread = threading.Thread(target=serve, args=(LoopbackTarget(), far_link), kwargs={"stop_event": stop},
                              daemon=True)
    thread.start()
    try:
        remote = RemoteTarget(host_link, timeout_s=2.0)
        with pytest.raises(VersionMismatch) as info:
            remote.hello(HostHello(7, PROTOCOL_VERSION, 1000, 0, 0, OTHER))
        text = str(info.value)
        assert f"{OTHER:#010x}" in text and f"{SCHEMA_FINGERPRINT:#010x}" in text, text
        assert remote.handshake(1000).schema_fingerprint == SCHEMA_FINGERPRINT  # the real one is accepted
    finally:
        stop.set()
        thread.join(timeout=10)
        host_link.close()
        far_link.close()
    assert not thread.is_alive()


def test_session_handshake_checks_the_target_hello() -> None:
    from hilbench.bench.session import Session

    class OtherSchema(LoopbackTarget):
        def hello(self, host: HostHello) -> TargetHello:
            return super().hello(host)._replace(schema_fingerprint=OTHER)

    with pytest.raises(VersionMismatch) as info:
        Session(OtherSchema(), None, [], target_label="target loopback").handshake()
    assert str(info.value).startswith("target loopback: firmware built from schema 0x0badf00d")
