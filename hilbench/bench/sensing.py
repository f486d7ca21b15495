"""The input edges a Sensors carries (protocol 3): every hall edge and encoder index mark of the
plant's last period, each with its time from the period's start in 100 ns units and the input
lines after it (hall bits; INDEX set on an index mark, an event: a pulse began then).

A period's edges are what the plant listed (`Plant.edges`, one per chunk of at most 50 us, and
`Plant.index_marks`), so no edge is lost at any exchange period; the session asks only when the
plant reported an edge (`advance` returned its time) or a mark (`sense` said so).
"""

from __future__ import annotations

from hilbench.protocol import Input

INPUT_INDEX = int(Input.INDEX)
HALL_MASK = 0x07


def hall_edges(plant_edges: tuple[tuple[float, int], ...], limit: int) -> tuple[tuple[int, int], ...]:
    """(t_s, hall bits) of the plant -> Sensors.edges: (100 ns units, at most ``limit``, lines)."""
    if len(plant_edges) == 1:  # the common case at short periods
        t, bits = plant_edges[0]
        return ((min(int(t * 1e7), limit), bits),)
    return tuple([(min(int(t * 1e7), limit), bits) for t, bits in plant_edges])


def with_index_marks(edges: tuple[tuple[int, int], ...], marks: tuple[float, ...], limit: int,
                     hall_before: int) -> tuple[tuple[int, int], ...]:
    """``edges`` with an INDEX edge at each of ``marks`` (s from the period's start): its lines are the
    hall bits in force then (``hall_before`` until the period's first hall edge) with INDEX set; in
    time order, a hall edge before a mark of the same time."""
    out = list(edges)
    for t_s in marks:
        t = min(int(t_s * 1e7), limit)
        hall = hall_before
        for te, bits in edges:
            if te > t:
                break
            hall = bits & HALL_MASK
        out.append((t, hall | INPUT_INDEX))
    out.sort(key=lambda e: (e[0], e[1] & INPUT_INDEX))  # stable: the plant's order among equal times
    return tuple(out)


__all__ = ["hall_edges", "with_index_marks"]
