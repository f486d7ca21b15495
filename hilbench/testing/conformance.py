"""The conformance suite (hilbench.bench.conformance) as pytest tests, for a board in CI or on a desk:

    pytest --pyargs hilbench.testing.conformance --hil-target serial:/dev/ttyUSB0?baud=250000
    pytest --pyargs hilbench.testing.conformance --hil-target sil:firmware/mydrive -m hil_conformance

One test per check and target (marker ``hil_conformance``); one connection per target for the
whole session (a fresh target for the checks that compare with one, where the spec can make it).
"""

from __future__ import annotations

from typing import Any

import pytest

from hilbench.bench.conformance import CHECKS, Connection, ConformanceFailure, NotServed

pytestmark = pytest.mark.hil_conformance
_CONNECTIONS: dict[str, Connection] = {}


@pytest.fixture
def hil_wire(hil_target: str, request: pytest.FixtureRequest) -> Any:
    """The target's Wire (a connection kept for the session, closed at its end)."""
    conn = _CONNECTIONS.get(hil_target)
    if conn is None:
        conn = _CONNECTIONS[hil_target] = Connection(hil_target)

        def close() -> None:
            _CONNECTIONS.pop(hil_target, None)
            conn.close()

        request.config.add_cleanup(close)
    conn.wire.drain()
    return conn.wire


@pytest.mark.parametrize("check", [name for name, _ in CHECKS])
def test_conformance(hil_wire: Any, check: str) -> None:
    run = dict(CHECKS)[check]
    try:
        detail = run(hil_wire)
    except ConformanceFailure as exc:
        pytest.fail(f"{check}: {exc}", pytrace=False)
    except NotServed as exc:  # an optional capability the build leaves out, refused as the protocol says
        pytest.skip(f"{check}: not served: {exc}")
    print(f"{check}: {detail}")
