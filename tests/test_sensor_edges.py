"""Protocol 3's Sensors carry every input edge of the period (hilbench/bench/sensing.py): the plant's
hall edges and index marks, timed in 100 ns units from the period's start, in order; sensor faults
act on every edge; a period with more edges than the target takes stops the run."""

from __future__ import annotations

from hilbench.bench.faults import SensorFaults
from hilbench.bench.sensing import hall_edges, with_index_marks
from hilbench.protocol import INPUT_INDEX, Sensors


def test_hall_edges_in_100ns_units_clipped_to_the_period() -> None:
    assert hall_edges(((12.34e-6, 3),), 9999) == ((123, 3),)
    assert hall_edges(((1e-4, 3), (5.5e-4, 2), (1.2e-3, 6)), 9999) == ((1000, 3), (5500, 2), (9999, 6))


def test_index_marks_join_the_edges_in_time_order_with_the_halls_then_in_force() -> None:
    edges = ((1000, 3), (5500, 2))
    got = with_index_marks(edges, (50.01e-6, 300.01e-6, 550.01e-6, 800.01e-6), 9999, hall_before=1)
    assert got == ((500, 1 | INPUT_INDEX), (1000, 3), (3000, 3 | INPUT_INDEX), (5500, 2), (5500, 2 | INPUT_INDEX),
                   (8000, 2 | INPUT_INDEX))
    assert with_index_marks((), (1e-3,), 9999, hall_before=5) == ((9999, 5 | INPUT_INDEX),)


def _sensors(inputs: int, edges: tuple[tuple[int, int], ...]) -> Sensors:
    return Sensors(7, inputs, edges, 0, ())


def test_forced_hall_lines_read_forced_on_every_edge() -> None:
    faults = SensorFaults()
    faults.apply("hall_b_high", 0.0, None)
    assert faults.filter(_sensors(1, ((10, 1), (20, 5)))) == _sensors(3, ((10, 3), (20, 7)))
    faults.apply("hall_a_low", 0.0, None)
    assert faults.filter(_sensors(3, ((10, 1), (20, 3)))) == _sensors(2, ((10, 0), (20, 2)))


def test_a_missing_edge_drops_the_period_that_changes_the_halls() -> None:
    faults = SensorFaults()
    faults.halls.last = 1
    faults.apply("hall_missing_edge", 0.0, None)
    assert faults.filter(_sensors(1, ())) == _sensors(1, ())  # no change yet: armed
    assert faults.filter(_sensors(3, ((40, 3),))) == _sensors(1, ())  # the edge never reaches the target
    assert not faults.active
