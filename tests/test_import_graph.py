"""The layers hold by test: the import graph of every hilbench module (built from the source, lazy
and TYPE_CHECKING imports included) against the layer table of docs/architecture.md — no upward
import, no import cycle between modules of different packages — and the check fails when an
upward import is added."""

from __future__ import annotations

import pytest
from _import_graph import cross_package_cycles, import_graph, layer_of, layer_table, module_sources, upward_imports


@pytest.fixture(scope="module")
def sources() -> dict[str, str]:
    return module_sources()


def test_every_module_is_in_a_layer_of_the_table(sources: dict[str, str]) -> None:
    layers = layer_table()
    assert [layer.name for layer in layers][:6] == ["common", "wire format", "link", "plant", "targets",
                                                    "config and bench"]
    lost = [m for m in sources if layer_of(m, layers) is None]
    assert not lost, f"modules in no layer of docs/architecture.md: {lost}"


def test_no_module_imports_a_layer_it_may_not(sources: dict[str, str]) -> None:
    found = upward_imports(import_graph(sources), layer_table())
    assert not found, "imports against the layer table:\n" + "\n".join(found)


def test_no_import_cycle_joins_two_packages(sources: dict[str, str]) -> None:
    found = cross_package_cycles(import_graph(sources))
    assert not found, "import cycles across packages:\n" + "\n".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize("added, module", [
    ("from hilbench.cli import main\n", "hilbench.plant.model"),  # at the top
    ("def _later():\n    from hilbench.bench.session import Session\n", "hilbench.targets.registry"),  # lazy
    ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from hilbench.link import open_link\n",
     "hilbench.plant.params"),  # for the type checker only: still an import of the link from the plant
    ("from ..bench import run\n", "hilbench.protocol.codec"),  # relative
])
def test_an_added_upward_import_is_found(sources: dict[str, str], added: str, module: str) -> None:
    changed = dict(sources, **{module: sources[module] + "\n" + added})
    found = upward_imports(import_graph(changed), layer_table())
    assert len(found) == 1 and found[0].startswith(f"{module} ("), found


def test_an_added_cycle_between_packages_is_found(sources: dict[str, str]) -> None:
    """config imports the bench's settings for their side effect and the settings import config:
    the cycle the explicit registry removed."""
    changed = dict(sources, **{"hilbench.config": sources["hilbench.config"] + "\nimport hilbench.bench.settings\n"})
    cycles = cross_package_cycles(import_graph(changed))
    assert any("hilbench.config" in c and "hilbench.bench.settings" in c for c in cycles), cycles
