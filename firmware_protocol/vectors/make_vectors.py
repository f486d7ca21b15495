#!/usr/bin/env python3
"""Write vectors.txt: golden frames for the Python and C decoders.

Deliberately independent of the codec: every frame is laid out here by hand from the byte layout in
PROTOCOL.md, the CRC is a bitwise CRC-16/CCITT-FALSE and COBS is a byte-by-byte encoder.

Format, one block per vector:
    vector NAME
    wire HEX BYTES ...                 (everything the receiver gets, delimiters included)
    expect MESSAGE field=value ...     (one line per 0x00-delimited chunk that is not empty, in order;
    expect error KIND                   KIND: crc cobs length unknown_type oversized)
    hello accept|reject                (HostHello vectors: the version check's outcome)
    end
Arrays are comma-separated (empty after '='), bools 0/1, names contain no spaces.
"""

from __future__ import annotations

import struct
from pathlib import Path

from reference_codec import cobs, crc16  # the independent CRC/COBS beside this script

OUT = Path(__file__).resolve().parent / "vectors.txt"


def with_crc(raw: bytes, flip: int = 0) -> bytes:
    c = crc16(raw) ^ flip
    return raw + bytes((c & 0xFF, c >> 8))


def wire(raw: bytes, flip: int = 0) -> bytes:
    return cobs(with_crc(raw, flip)) + b"\x00"


VECTORS: list[tuple[str, bytes, list[str], str | None]] = []


def add(name: str, data: bytes, expects: list[str], hello: str | None = None) -> None:
    VECTORS.append((name, data, expects, hello))


def build() -> None:
    # HostHello: version u8, period_us u16, mode u8, watchdog_ms u16
    add("host_hello_v1", wire(bytes([0x01, 0]) + struct.pack("<BHBH", 1, 1000, 0, 100)),
        ["HostHello seq=0 protocol_version=1 period_us=1000 mode=0 watchdog_ms=100"], "accept")
    add("host_hello_wrong_version", wire(bytes([0x01, 7]) + struct.pack("<BHBH", 2, 50, 1, 0)),
        ["HostHello seq=7 protocol_version=2 period_us=50 mode=1 watchdog_ms=0"], "reject")
    # TargetHello: version, fw version u16, pwm counts u16, pwm Hz u32, n_params, name (count-prefixed),
    # adc roles (count-prefixed), telemetry ids (rest)
    add("target_hello_loopback",
        wire(bytes([0x02, 0]) + struct.pack("<BHHIB", 1, 1, 1000, 20000, 3) + bytes([8]) + b"loopback"
             + bytes([3, 1, 2, 3]) + bytes([10, 11, 12])),
        ["TargetHello seq=0 protocol_version=1 firmware_version=1 pwm_period_counts=1000 pwm_freq_hz=20000 "
         "n_params=3 firmware_name=loopback adc_roles=1,2,3 telemetry_ids=10,11,12"])
    add("target_hello_empty_lists",
        wire(bytes([0x02, 255]) + struct.pack("<BHHIB", 1, 65535, 0, 4294967295, 0) + bytes([0]) + bytes([0])),
        ["TargetHello seq=255 protocol_version=1 firmware_version=65535 pwm_period_counts=0 "
         "pwm_freq_hz=4294967295 n_params=0 firmware_name= adc_roles= telemetry_ids="])
    # Sensors: inputs u8, edge u16, encoder u16, adc u16...
    add("sensors_an1017", wire(bytes([0x10, 5]) + struct.pack("<BHH3H", 0x0B, 1234, 0xFFFF, 512, 0, 1023)),
        ["Sensors seq=5 inputs=11 edge_time_100ns=1234 encoder=65535 adc=512,0,1023"])
    add("sensors_no_edge_no_adc", wire(bytes([0x10, 0]) + struct.pack("<BHH", 0, 0xFFFF, 0)),
        ["Sensors seq=0 inputs=0 edge_time_100ns=65535 encoder=0 adc="])
    # Drive: u32 = duty_a | duty_b<<10 | duty_c<<20 | mode<<30; u8 = state | sector<<3 | dir<<6 | req<<7
    word = 1023 | 512 << 10 | 1 << 20 | 1 << 30
    flags = 2 | 4 << 3 | 1 << 6 | 0 << 7
    add("drive_an1017", wire(bytes([0x11, 5]) + struct.pack("<IBB3h", word, flags, 0, -2, 32767, -32768)),
        ["Drive seq=5 duty_a=1023 duty_b=512 duty_c=1 output_mode=1 state=2 sector=4 direction_ccw=1 "
         "required_ccw=0 fault=0 telemetry=-2,32767,-32768"])
    word = 0 | 0 << 10 | 0 << 20 | 2 << 30
    flags = 1 | 7 << 3 | 0 << 6 | 1 << 7
    add("drive_zeros_low_side", wire(bytes([0x11, 0]) + struct.pack("<IBB3h", word, flags, 1, 0, 0, 0)),
        ["Drive seq=0 duty_a=0 duty_b=0 duty_c=0 output_mode=2 state=1 sector=7 direction_ccw=0 "
         "required_ccw=1 fault=1 telemetry=0,0,0"])
    add("param_describe", wire(bytes([0x20, 3, 1])), ["ParamDescribe seq=3 param_id=1"])
    add("param_info_kp", wire(bytes([0x21, 3]) + struct.pack("<BBBhhh", 0, 0, 1, 0, 32767, 3277) + b"kp"),
        ["ParamInfo seq=3 param_id=0 ptype=0 access=1 min_value=0 max_value=32767 value=3277 name=kp"])
    add("param_get", wire(bytes([0x22, 4, 2])), ["ParamGet seq=4 param_id=2"])
    add("param_value_unknown", wire(bytes([0x23, 4]) + struct.pack("<BBh", 9, 1, 0)),
        ["ParamValue seq=4 param_id=9 result=1 value=0"])
    add("param_set_two", wire(bytes([0x24, 6]) + struct.pack("<BhBh", 0, 16000, 1, -1)),
        ["ParamSet seq=6 pairs=0,16000,1,-1"])
    add("param_set_result_constraint", wire(bytes([0x25, 6, 4, 0, 1])),
        ["ParamSetResult seq=6 result=4 param_id=0 detail=1"])
    add("start", wire(bytes([0x30, 1])), ["Start seq=1"])
    add("stop", wire(bytes([0x31, 2])), ["Stop seq=2"])
    add("status_request", wire(bytes([0x40, 3])), ["StatusRequest seq=3"])
    add("status", wire(bytes([0x41, 3]) + struct.pack("<6HB", 10000, 3, 2, 1, 0, 65535, 2)),
        ["Status seq=3 rx_frames=10000 rx_errors=3 resyncs=2 unknown=1 overruns=0 watchdog_trips=65535 "
         "last_error=2"])
    add("error_report_version", wire(bytes([0x42, 7, 1, 1])), ["ErrorReport seq=7 code=1 detail=1"])
    # ---- malformed
    add("bad_crc", wire(bytes([0x10, 5]) + struct.pack("<BHH3H", 0x0B, 1234, 0xFFFF, 512, 0, 1023), flip=0x0100),
        ["error crc"])
    start = with_crc(bytes([0x30, 0x11]))
    assert 0 not in start, "pick a seq whose frame has no zero byte"
    add("truncated", cobs(start)[:-2] + b"\x00", ["error cobs"])
    add("too_short", bytes([0x02, 0x30, 0x00]), ["error length"])
    add("oversized", bytes([0x01] * 80) + b"\x00", ["error oversized"])
    add("oversized_block", bytes([0x50]) + bytes(range(1, 80)) + b"\x00", ["error oversized"])
    add("unknown_type", wire(bytes([0x7E, 9, 1, 2])), ["error unknown_type"])
    add("start_with_payload", wire(bytes([0x30, 1, 0x55])), ["error length"])
    add("sensors_odd_payload", wire(bytes([0x10, 1]) + struct.pack("<BHH", 0, 0, 0) + b"\x01"), ["error length"])
    add("drive_too_many_telemetry", wire(bytes([0x11, 1]) + struct.pack("<IBB9h", 0, 0, 0, *range(9))),
        ["error length"])
    add("param_set_partial_pair", wire(bytes([0x24, 1, 0, 1])), ["error length"])
    add("target_hello_name_past_end",
        wire(bytes([0x02, 0]) + struct.pack("<BHHIB", 1, 1, 1000, 20000, 3) + bytes([20]) + b"abc"),
        ["error length"])
    add("param_info_name_not_ascii",
        wire(bytes([0x21, 3]) + struct.pack("<BBBhhh", 0, 0, 1, 0, 1, 0) + b"k\x01"), ["error length"])
    s = wire(bytes([0x10, 9]) + struct.pack("<BHH3H", 0x08, 0xFFFF, 7, 1, 2, 3))
    d = wire(bytes([0x11, 9]) + struct.pack("<IBB3h", 5 | 6 << 10 | 7 << 20 | 1 << 30, 2, 0, 7, 0xFFFF - 65536, 9))
    add("garbage_between_frames", b"\xde\xad\xbe\xef\x00" + s + b"\xff\xff\x00\x00" + d + b"\x00\x00",
        ["error cobs", "Sensors seq=9 inputs=8 edge_time_100ns=65535 encoder=7 adc=1,2,3",
         "error cobs", "Drive seq=9 duty_a=5 duty_b=6 duty_c=7 output_mode=1 state=2 sector=0 direction_ccw=0 "
         "required_ccw=0 fault=0 telemetry=7,-1,9"])


def render() -> str:
    lines = ["# hilbench protocol golden vectors: GENERATED by make_vectors.py (independent CRC/COBS).",
             "# Checked by tests/test_protocol_vectors.py and firmware_protocol/tests/test_vectors.c.", ""]
    for name, data, expects, hello in VECTORS:
        lines.append(f"vector {name}")
        lines.append("wire " + " ".join(f"{b:02x}" for b in data))
        for e in expects:
            lines.append(f"expect {e}")
        if hello:
            lines.append(f"hello {hello}")
        lines.append("end")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    build()
    OUT.write_text(render(), encoding="utf-8")
    print(f"wrote {OUT} ({len(VECTORS)} vectors)")


if __name__ == "__main__":
    main()
