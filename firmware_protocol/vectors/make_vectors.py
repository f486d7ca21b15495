#!/usr/bin/env python3
"""Write vectors.txt: golden frames for the Python and C decoders.

Deliberately independent of the codec: every frame is laid out here by hand from the byte layout in
PROTOCOL.md, the framing (lengths, COBS, check bytes) is reference_codec.py's bitwise CRC-16/CCITT-FALSE
and byte-by-byte COBS. The schema fingerprint is computed here from schema.toml by the recipe in
PROTOCOL.md.

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

import hashlib
import json
import struct
import tomllib
from pathlib import Path

from reference_codec import check_bytes, cobs, crc16  # the independent CRC/COBS beside this script
from reference_codec import wire as ref_wire

HERE = Path(__file__).resolve().parent
OUT = HERE / "vectors.txt"


def _strip(value: object) -> object:
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if k not in ("doc", "hot", "hot_n", "default", "py_order")}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


# PROTOCOL.md: SHA-256 of the schema's JSON (non-wire keys dropped, sorted keys, no spaces), first 4 bytes
FP = int.from_bytes(hashlib.sha256(json.dumps(
    _strip(tomllib.loads((HERE.parent / "schema.toml").read_text(encoding="utf-8"))),
    sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode("ascii")).digest()[:4], "big")
OTHER_FP = FP ^ 0x00010000  # a firmware built from another schema


def wire(raw: bytes, flip: int = 0) -> bytes:
    return ref_wire(raw, flip)


VECTORS: list[tuple[str, bytes, list[str], str | None]] = []


def add(name: str, data: bytes, expects: list[str], hello: str | None = None) -> None:
    VECTORS.append((name, data, expects, hello))


def drive(seq: int, duties: tuple[int, int, int], mode: int, state: int, sector: int, ccw: int, req: int,
          fault: int, telemetry: tuple[int, ...]) -> bytes:
    """Drive: duty_a/b/c u16; u16 = mode bits 0-1, state 2-4, sector 5-7, ccw 8, required 9, fault 10-15."""
    flags = mode | state << 2 | sector << 5 | ccw << 8 | req << 9 | fault << 10
    return bytes([0x11, seq]) + struct.pack(f"<3HH{len(telemetry)}h", *duties, flags, *telemetry)


def hello_tail(name: bytes, roles: bytes, telemetry: bytes) -> bytes:
    """TargetHello's name and ADC roles (count-prefixed) and telemetry ids (the rest)."""
    return bytes([len(name)]) + name + bytes([len(roles)]) + roles + telemetry


# TargetHello: version u8, fingerprint u32, fw version u16, pwm counts u16, pwm Hz u32, n_params u8, adc_bits u8,
# then hello_tail
HELLO = "<BIHHIBB"


def build() -> None:
    # HostHello: version u8, period_us u16, mode u8, watchdog_ms u16, schema fingerprint u32
    add("host_hello_v3", wire(bytes([0x01, 0]) + struct.pack("<BHBHI", 3, 1000, 0, 100, FP)),
        [f"HostHello seq=0 protocol_version=3 period_us=1000 mode=0 watchdog_ms=100 schema_fingerprint={FP}"],
        "accept")
    add("host_hello_wrong_version", wire(bytes([0x01, 7]) + struct.pack("<BHBHI", 4, 50, 1, 0, FP)),
        [f"HostHello seq=7 protocol_version=4 period_us=50 mode=1 watchdog_ms=0 schema_fingerprint={FP}"], "reject")
    add("host_hello_other_schema", wire(bytes([0x01, 8]) + struct.pack("<BHBHI", 3, 50, 0, 0, OTHER_FP)),
        [f"HostHello seq=8 protocol_version=3 period_us=50 mode=0 watchdog_ms=0 schema_fingerprint={OTHER_FP}"],
        "reject")
    add("target_hello_loopback",
        wire(bytes([0x02, 0]) + struct.pack(HELLO, 3, FP, 1, 1000, 20000, 3, 10)
             + hello_tail(b"loopback", bytes([1, 2, 3]), bytes([10, 11, 12]))),
        [f"TargetHello seq=0 protocol_version=3 schema_fingerprint={FP} firmware_version=1 pwm_period_counts=1000 "
         "pwm_freq_hz=20000 n_params=3 adc_bits=10 firmware_name=loopback adc_roles=1,2,3 telemetry_ids=10,11,12"])
    add("target_hello_an1017",
        wire(bytes([0x02, 1]) + struct.pack(HELLO, 3, FP, 0x0101, 1000, 20000, 8, 10)
             + hello_tail(b"AN1017", bytes([1, 2, 3]), bytes([1, 2, 3]))),
        [f"TargetHello seq=1 protocol_version=3 schema_fingerprint={FP} firmware_version=257 "
         "pwm_period_counts=1000 pwm_freq_hz=20000 n_params=8 adc_bits=10 firmware_name=AN1017 adc_roles=1,2,3 "
         "telemetry_ids=1,2,3"])
    add("target_hello_foc",
        wire(bytes([0x02, 2]) + struct.pack(HELLO, 3, FP, 0x0200, 7500, 10000, 16, 12)
             + hello_tail(b"f2812_foc_1", bytes([4, 5, 3]), bytes([1, 2, 8, 5, 6, 9, 0x80, 0xFE]))),
        [f"TargetHello seq=2 protocol_version=3 schema_fingerprint={FP} firmware_version=512 "
         "pwm_period_counts=7500 pwm_freq_hz=10000 n_params=16 adc_bits=12 firmware_name=f2812_foc_1 "
         "adc_roles=4,5,3 telemetry_ids=1,2,8,5,6,9,128,254"])
    add("target_hello_empty_lists",
        wire(bytes([0x02, 255]) + struct.pack(HELLO, 3, 0xFFFFFFFF, 65535, 0, 4294967295, 0, 0)
             + hello_tail(b"", b"", b"")),
        ["TargetHello seq=255 protocol_version=3 schema_fingerprint=4294967295 firmware_version=65535 "
         "pwm_period_counts=0 pwm_freq_hz=4294967295 n_params=0 adc_bits=0 firmware_name= adc_roles= telemetry_ids="])
    add("target_describe", wire(bytes([0x52, 9])), ["TargetDescribe seq=9"])
    # TargetInfo: duty_timing u8, duty_report u8, inputs u8, encoder_counts u16, max_edges u8
    add("target_info_an1017", wire(bytes([0x53, 9]) + struct.pack("<BBBHB", 1, 0, 0x2F, 0, 3)),
        ["TargetInfo seq=9 duty_timing=1 duty_report=0 inputs=47 encoder_counts=0 max_edges=3"])
    add("target_info_foc", wire(bytes([0x53, 10]) + struct.pack("<BBBHB", 2, 1, 0x48, 10000, 16)),
        ["TargetInfo seq=10 duty_timing=2 duty_report=1 inputs=72 encoder_counts=10000 max_edges=16"])
    # Sensors: inputs u8, encoder u16, adc (count u8, u16 each), edges (u16 time in 100 ns, u8 lines) to the end
    add("sensors_an1017_one_edge",
        wire(bytes([0x10, 5]) + struct.pack("<BHB3HHB", 0x0B, 0xFFFF, 3, 512, 0, 1023, 1234, 0x03)),
        ["Sensors seq=5 inputs=11 edges=1234,3 encoder=65535 adc=512,0,1023"])
    add("sensors_three_edges",
        wire(bytes([0x10, 6]) + struct.pack("<BHB3H" + "HB" * 3, 0x06, 0, 3, 700, 1, 2, 10, 0x04, 4000, 0x06, 9999,
                                           0x02)),
        ["Sensors seq=6 inputs=6 edges=10,4,4000,6,9999,2 encoder=0 adc=700,1,2"])
    add("sensors_foc_index", wire(bytes([0x10, 7]) + struct.pack("<BHB3H", 0x40, 9999, 3, 4095, 2048, 0)),
        ["Sensors seq=7 inputs=64 edges= encoder=9999 adc=4095,2048,0"])
    add("sensors_index_edge", wire(bytes([0x10, 8]) + struct.pack("<BHBHB", 0x41, 3, 0, 250, 0x41)),
        ["Sensors seq=8 inputs=65 edges=250,65 encoder=3 adc="])
    add("sensors_no_edge_no_adc", wire(bytes([0x10, 0]) + struct.pack("<BHB", 0, 0, 0)),
        ["Sensors seq=0 inputs=0 edges= encoder=0 adc="])
    add("drive_an1017", wire(drive(5, (1000, 512, 1), 1, 2, 4, 1, 0, 0, (-2, 32767, -32768))),
        ["Drive seq=5 duty_a=1000 duty_b=512 duty_c=1 output_mode=1 state=2 sector=4 direction_ccw=1 "
         "required_ccw=0 fault=0 telemetry=-2,32767,-32768"])
    add("drive_foc_full_counts", wire(drive(6, (7500, 65535, 3750), 1, 2, 7, 0, 1, 63, (1, -1))),
        ["Drive seq=6 duty_a=7500 duty_b=65535 duty_c=3750 output_mode=1 state=2 sector=7 direction_ccw=0 "
         "required_ccw=1 fault=63 telemetry=1,-1"])
    add("drive_zeros_low_side", wire(drive(0, (0, 0, 0), 2, 1, 7, 0, 1, 1, (0, 0, 0))),
        ["Drive seq=0 duty_a=0 duty_b=0 duty_c=0 output_mode=2 state=1 sector=7 direction_ccw=0 "
         "required_ccw=1 fault=1 telemetry=0,0,0"])
    # SensorsBatch: first_seq u16, count u8, records to the end (PROTOCOL.md "Batches": a first period with the
    # inputs and three ADC codes, a tiny ADC record, a run of 3, a period with one hall edge)
    records = (bytes([0x21, 0x05, 3]) + struct.pack("<3H", 600, 512, 700) + bytes([0xC0 | 1 | 3 << 2, 0x82])
               + bytes([0x41, 0x01, 1]) + struct.pack("<HB", 123, 0x01))
    add("sensors_batch", wire(bytes([0x12, 40]) + struct.pack("<HB", 65535, 6) + records),
        ["SensorsBatch seq=40 first_seq=65535 count=6 records=" + ",".join(str(b) for b in records)])
    # BatchDigest: first_seq u16, count u8, next_seq u16, room u8, digest u32, then a Drive's fields
    add("batch_digest", wire(bytes([0x13, 40]) + struct.pack("<HBHBI", 65535, 6, 5, 57, 0xCBF43926)
                             + drive(0, (1000, 512, 1), 1, 2, 4, 1, 0, 0, (-2, 32767, -32768))[2:]),
        ["BatchDigest seq=40 first_seq=65535 count=6 next_seq=5 room=57 digest=3421780262 duty_a=1000 duty_b=512 "
         "duty_c=1 output_mode=1 state=2 sector=4 direction_ccw=1 required_ccw=0 fault=0 telemetry=-2,32767,-32768"])
    add("batch_refused", wire(bytes([0x13, 41]) + struct.pack("<HBHBI", 100, 0, 90, 17, 0)
                              + drive(0, (0, 0, 0), 0, 0, 7, 0, 0, 0, ())[2:]),
        ["BatchDigest seq=41 first_seq=100 count=0 next_seq=90 room=17 digest=0 duty_a=0 duty_b=0 duty_c=0 "
         "output_mode=0 state=0 sector=7 direction_ccw=0 required_ccw=0 fault=0 telemetry="])
    add("param_describe", wire(bytes([0x20, 3, 1])), ["ParamDescribe seq=3 param_id=1"])
    # ParamInfo: id u8, ptype u8, access u8, min i32, max i32, value i32, name (count-prefixed), unit (the rest)
    add("param_info_kp", wire(bytes([0x21, 3]) + struct.pack("<BBBiii", 0, 0, 1, 0, 32767, 3277) + b"\x02kp"),
        ["ParamInfo seq=3 param_id=0 ptype=0 access=1 min_value=0 max_value=32767 value=3277 name=kp unit="])
    add("param_info_stall_ms", wire(bytes([0x21, 9]) + struct.pack("<BBBiii", 7, 1, 1, 10, 30000, 100)
                                    + b"\x08stall_msms"),
        ["ParamInfo seq=9 param_id=7 ptype=1 access=1 min_value=10 max_value=30000 value=100 name=stall_ms unit=ms"])
    # an IQ24 gain: 0.75 = 12582912, range [0, 127.99...]
    add("param_info_iq24", wire(bytes([0x21, 4]) + struct.pack("<BBBiii", 5, 3, 1, -2**31, 2**31 - 1, 12582912)
                                + b"\x05iq_kp"),
        ["ParamInfo seq=4 param_id=5 ptype=3 access=1 min_value=-2147483648 max_value=2147483647 value=12582912 "
         "name=iq_kp unit="])
    add("param_get", wire(bytes([0x22, 4, 2])), ["ParamGet seq=4 param_id=2"])
    add("param_value_unknown", wire(bytes([0x23, 4]) + struct.pack("<BBi", 9, 1, 0)),
        ["ParamValue seq=4 param_id=9 result=1 value=0"])
    add("param_value_iq24", wire(bytes([0x23, 5]) + struct.pack("<BBi", 5, 0, -16777216)),
        ["ParamValue seq=5 param_id=5 result=0 value=-16777216"])
    add("param_set_two", wire(bytes([0x24, 6]) + struct.pack("<BiBi", 0, 16000, 1, -1)),
        ["ParamSet seq=6 pairs=0,16000,1,-1"])
    add("param_set_four", wire(bytes([0x24, 7]) + struct.pack("<BiBiBiBi", 0, 2**31 - 1, 1, -2**31, 2, 1677722,
                                                              3, 0)),
        ["ParamSet seq=7 pairs=0,2147483647,1,-2147483648,2,1677722,3,0"])
    add("param_set_result_constraint", wire(bytes([0x25, 6, 4, 0, 1])),
        ["ParamSetResult seq=6 result=4 param_id=0 detail=1"])
    add("start", wire(bytes([0x30, 1])), ["Start seq=1"])
    add("stop", wire(bytes([0x31, 2])), ["Stop seq=2"])
    add("status_request", wire(bytes([0x40, 3])), ["StatusRequest seq=3"])
    add("status", wire(bytes([0x41, 3]) + struct.pack("<6HB", 10000, 3, 2, 1, 0, 65535, 2)),
        ["Status seq=3 rx_frames=10000 rx_errors=3 resyncs=2 unknown=1 overruns=0 watchdog_trips=65535 "
         "last_error=2"])
    # ErrorReport: code u8, detail u8, the sender's schema fingerprint u32
    add("error_report_version", wire(bytes([0x42, 7, 1, 3]) + struct.pack("<I", FP)),
        [f"ErrorReport seq=7 code=1 detail=3 schema_fingerprint={FP}"])
    add("telemetry_describe", wire(bytes([0x50, 4, 1])), ["TelemetryDescribe seq=4 index=1"])
    # TelemetryInfo: index u8, id u8, ptype u8, scale_num i32, scale_den i32, name (count-prefixed), unit (the rest)
    add("telemetry_info_speed", wire(bytes([0x51, 4]) + struct.pack("<BBBii", 1, 2, 0, 9375000, 51118080)
                                     + b"\x0emeasured_speedrpm"),
        ["TelemetryInfo seq=4 index=1 telemetry_id=2 ptype=0 scale_num=9375000 scale_den=51118080 "
         "name=measured_speed unit=rpm"])
    # ---- malformed
    sensors = bytes([0x10, 5]) + struct.pack("<BHB3HHB", 0x0B, 0xFFFF, 3, 512, 0, 1023, 1234, 0x03)
    add("bad_crc", wire(sensors, flip=0x0001), ["error crc"])
    good = wire(bytes([0x30, 0x11]))
    add("check_top_bit_clear", good[:-4] + bytes((good[-4] & 0x7F,)) + good[-3:], ["error crc"])
    add("check_reserved_bit_set", good[:-2] + bytes((good[-2] | 0x01,)) + good[-1:], ["error crc"])
    # the v2 weakness: the delimiter turned into 0x01 and idle filler after it; and a frame that lost its end
    add("delimiter_flipped_then_idle", good[:-1] + b"\x01\x00", ["error crc"])  # the 0x01 is read as a check byte
    add("leading_length_wrong", ref_wire(bytes([0x30, 0x11]), lengths=(9, 8)), ["error length"])
    add("trailing_length_wrong", ref_wire(bytes([0x30, 0x11]), lengths=(8, 7)), ["error length"])
    add("truncated", good[:-3] + b"\x00", ["error length"])
    cobs_bad = bytes([0x09, 8, 0x30, 0x11, 8])  # its first block runs past the end; the CRC covers it
    add("cobs_block_past_end", cobs_bad + check_bytes(crc16(cobs_bad)) + b"\x00", ["error cobs"])
    add("too_short", bytes([0x02, 0x30, 0x00]), ["error length"])
    add("oversized", bytes([0x01] * 80) + b"\x00", ["error oversized"])
    add("oversized_block", bytes([0x50]) + bytes(range(1, 80)) + b"\x00", ["error oversized"])
    add("unknown_type", wire(bytes([0x7E, 9, 1, 2])), ["error unknown_type"])
    add("start_with_payload", wire(bytes([0x30, 1, 0x55])), ["error length"])
    add("sensors_partial_edge", wire(bytes([0x10, 1]) + struct.pack("<BHB", 0, 0, 0) + b"\x01"), ["error length"])
    add("sensors_adc_count_past_end", wire(bytes([0x10, 1]) + struct.pack("<BHBH", 0, 0, 4, 7)), ["error length"])
    add("drive_too_many_telemetry", wire(drive(1, (0, 0, 0), 0, 0, 0, 0, 0, 0, tuple(range(9)))), ["error length"])
    add("param_set_partial_pair", wire(bytes([0x24, 1, 0, 1, 2, 3])), ["error length"])
    add("error_report_v1_layout", wire(bytes([0x42, 7, 1, 1])), ["error length"])
    add("target_hello_name_past_end",
        wire(bytes([0x02, 0]) + struct.pack(HELLO, 3, FP, 1, 1000, 20000, 3, 10) + bytes([20]) + b"abc"),
        ["error length"])
    add("param_info_name_not_ascii",
        wire(bytes([0x21, 3]) + struct.pack("<BBBiii", 0, 0, 1, 0, 1, 0) + b"\x02k\x01"), ["error length"])
    s = wire(bytes([0x10, 9]) + struct.pack("<BHB3H", 0x08, 7, 3, 1, 2, 3))
    d = wire(drive(9, (5, 6, 7), 1, 2, 0, 0, 0, 0, (7, -1, 9)))
    add("garbage_between_frames", b"\xde\xad\xbe\xef\x00" + s + b"\xff\xff\x00\x00" + d + b"\x00\x00",
        ["error length", "Sensors seq=9 inputs=8 edges= encoder=7 adc=1,2,3",
         "error length", "Drive seq=9 duty_a=5 duty_b=6 duty_c=7 output_mode=1 state=2 sector=0 direction_ccw=0 "
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
