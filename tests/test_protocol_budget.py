"""PROTOCOL.md's wire budget table agrees with the sizes of actually encoded frames."""

from __future__ import annotations

import re
from pathlib import Path

from hilbench.protocol import Drive, Sensors, encode_frame

DOC = Path(__file__).resolve().parent.parent / "firmware_protocol" / "PROTOCOL.md"


def _sizes(n_adc: int, n_telemetry: int) -> tuple[int, int]:
    s = encode_frame(Sensors(255, 0x3F, 0xFFFF, 0xFFFF, (1023,) * n_adc))
    d = encode_frame(Drive(255, 1000, 1000, 1000, 1, 2, 5, True, True, 0, (-1,) * n_telemetry))
    return len(s), len(d)


def test_budget_table_matches_encoded_sizes() -> None:
    rows = {}
    for line in DOC.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^\| ([\d ]+) \| ([\d ]+) \| ([\d ]+) \| ([\d ]+) \| ([\d ]+) \|$", line)
        if m:
            rows[int(m.group(1).replace(" ", ""))] = [int(g.replace(" ", "")) for g in m.groups()[1:]]
    assert sorted(rows) == [115_200, 250_000, 460_800, 921_600, 1_250_000]
    an_req, an_rsp = _sizes(3, 3)
    big_req, big_rsp = _sizes(4, 6)
    assert (an_req, an_rsp) == (17, 20)
    for baud, row in rows.items():
        assert row == [baud // (10 * (an_req + an_rsp)), baud // (10 * max(an_req, an_rsp)),
                       baud // (10 * (big_req + big_rsp)), baud // (10 * max(big_req, big_rsp))], baud
    # 1 kHz full duplex at 250 000 baud: protocol 2's u16 duties leave 20 % to spare (1 had 28 %)
    assert max(an_req, an_rsp) <= 0.8 * 250_000 / 10 / 1000
