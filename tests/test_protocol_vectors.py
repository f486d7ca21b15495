"""Golden vectors (firmware_protocol/vectors/vectors.txt) checked by the Python codec and by C.

The vectors are laid out by make_vectors.py with its own CRC/COBS, not by the codec.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, build_c
from hilbench.errors import DecodeError
from hilbench.protocol import FrameDecoder, decode_frame, encode_frame, host_hello_mismatch, messages

VECTORS = FIRMWARE_DIR / "vectors" / "vectors.txt"
KIND_COUNTER = {"crc": "crc_errors", "cobs": "cobs_errors", "length": "length_errors",
                "unknown_type": "unknown_type", "oversized": "oversized"}


@dataclass(frozen=True)
class Vector:
    name: str
    wire: bytes
    expects: tuple[str, ...]
    hello: str | None


def load_vectors() -> list[Vector]:
    out, cur = [], {}
    for line in VECTORS.read_text(encoding="utf-8").splitlines():
        if not line or line.startswith("#"):
            continue
        key, _, rest = line.partition(" ")
        if key == "vector":
            cur = {"name": rest, "wire": b"", "expects": [], "hello": None}
        elif key == "wire":
            cur["wire"] = bytes.fromhex(rest)
        elif key == "expect":
            cur["expects"].append(rest)
        elif key == "hello":
            cur["hello"] = rest
        elif key == "end":
            out.append(Vector(cur["name"], cur["wire"], tuple(cur["expects"]), cur["hello"]))
    return out


def build_expected(text: str):
    """'Sensors seq=5 adc=1,2' -> Sensors(...) from the field list of the message class."""
    cls_name, *pairs = text.split(" ")
    cls = getattr(messages, cls_name)
    fields = dict(p.split("=", 1) for p in pairs)
    assert list(fields) == list(cls._fields), text
    values = []
    for name in cls._fields:
        raw = fields[name]
        hint = cls.__annotations__[name]
        hint = getattr(hint, "__forward_arg__", hint)
        if hint == "str":
            values.append(raw)
        elif hint == "bool":
            values.append(raw == "1")
        elif "tuple[tuple" in hint:
            nums = [int(v) for v in raw.split(",")] if raw else []
            values.append(tuple(zip(nums[0::2], nums[1::2])))
        elif hint.startswith("tuple"):
            values.append(tuple(int(v) for v in raw.split(",")) if raw else ())
        else:
            values.append(int(raw))
    return cls(*values)


ALL = load_vectors()


def test_vector_file_is_fresh_and_complete(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, str(FIRMWARE_DIR / "vectors" / "make_vectors.py")],
                            capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    kinds = {e.split()[1] for v in ALL for e in v.expects if e.startswith("error")}
    assert kinds == set(KIND_COUNTER)
    assert any(v.hello == "reject" for v in ALL)
    assert any(v.name == "garbage_between_frames" for v in ALL)


@pytest.mark.parametrize("vec", ALL, ids=[v.name for v in ALL])
def test_vector_python(vec: Vector) -> None:
    chunks = [c for c in vec.wire.split(b"\x00")[:-1] if c]
    assert len(chunks) == len(vec.expects)
    expected_msgs = []
    for chunk, expect in zip(chunks, vec.expects):
        if expect.startswith("error "):
            kind = expect.split()[1]
            with pytest.raises(DecodeError) as info:
                decode_frame(chunk)
            assert info.value.counter == KIND_COUNTER[kind]
        else:
            msg = build_expected(expect)
            assert decode_frame(chunk) == msg
            assert encode_frame(msg) == chunk + b"\x00"
            expected_msgs.append(msg)
            if vec.hello:
                assert (host_hello_mismatch(msg) is None) == (vec.hello == "accept")
    # the stream decoder agrees, byte by byte and all at once
    for step in (1, len(vec.wire)):
        decoder = FrameDecoder()
        got = []
        for i in range(0, len(vec.wire), step):
            got += decoder.feed(vec.wire[i:i + step])
        assert got == expected_msgs
        for kind, counter in KIND_COUNTER.items():
            assert decoder.counters[counter] == sum(e == f"error {kind}" for e in vec.expects)


@pytest.fixture(scope="module")
def c_vector_programs(tmp_path_factory, gcc: str) -> list[Path]:
    out = tmp_path_factory.mktemp("cvec")
    sources = [FIRMWARE_DIR / "tests" / "test_vectors.c", *LIBRARY_SOURCES]
    flags = ("-DHBP_RX_MAX=63u", f"-I{FIRMWARE_DIR / 'tests'}")
    return [build_c(sources, out / "test_vectors", extra_flags=flags),
            build_c(sources, out / "test_vectors_san", extra_flags=flags, sanitize=True)]


@pytest.mark.slow
def test_vectors_c(c_vector_programs: list[Path]) -> None:
    for exe in c_vector_programs:
        result = subprocess.run([str(exe), str(VECTORS)], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stdout + result.stderr
        assert f"{len(ALL)} vectors ok" in result.stdout, result.stdout
