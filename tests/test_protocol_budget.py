"""PROTOCOL.md's wire budget table agrees with the sizes of actually encoded frames."""

from __future__ import annotations

import re
from pathlib import Path

from hilbench.protocol import Drive, Sensors, encode_frame

DOC = Path(__file__).resolve().parent.parent / "firmware_protocol" / "PROTOCOL.md"


def _sizes(n_adc: int, n_telemetry: int, n_edges: int = 1) -> tuple[int, int]:
    s = encode_frame(Sensors(255, 0x3F, ((0xFFFF, 7),) * n_edges, 0xFFFF, (1023,) * n_adc))
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
    assert (an_req, an_rsp) == (22, 23)
    assert _sizes(3, 3, 0)[0] == 19 and _sizes(3, 3, 2)[0] == 25  # an edge is 3 bytes
    for baud, row in rows.items():
        assert row == [baud // (10 * (an_req + an_rsp)), baud // (10 * max(an_req, an_rsp)),
                       baud // (10 * (big_req + big_rsp)), baud // (10 * max(big_req, big_rsp))], baud
    # 1 kHz full duplex at 250 000 baud with a hall edge in the period: 92 % of the line
    assert max(an_req, an_rsp) <= 0.92 * 250_000 / 10 / 1000
