"""Targets: firmware models, the loopback target and the remote proxy, all one interface.

`make_target(name, **options)` builds a model by name; heavy models are imported only when asked.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

from hilbench.errors import ConfigError


def _make_loopback(**options: Any) -> Any:
    from hilbench.targets.loopback import LoopbackTarget

    if options:
        raise ConfigError(f"target loopback: takes no options, got {', '.join(sorted(options))}")
    return LoopbackTarget()


def _make_an1017(**options: Any) -> Any:
    from hilbench.targets.an1017 import An1017Target

    reference = bool(options.pop("reference", False))
    given = options.pop("options", None)
    if given is None:
        from hilbench.targets.an1017_firmware import An1017Options

        known = {f.name for f in dataclasses.fields(An1017Options)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ConfigError(
                f"target an1017: unknown option {unknown[0]!r} (known: {', '.join(sorted(known | {'reference'}))})"
            )
        given = An1017Options(**options)
    elif options:
        raise ConfigError(f"target an1017: pass either options= or single fields, not both ({', '.join(options)})")
    return An1017Target(given, reference=reference)


def _make_foc(**options: Any) -> Any:
    from hilbench.targets.foc import make_foc_target

    return make_foc_target(**options)


TARGET_FACTORIES: dict[str, Callable[..., Any]] = {
    "loopback": _make_loopback,
    "an1017": _make_an1017,
    "foc": _make_foc,
}


def known_targets() -> tuple[str, ...]:
    """Names make_target accepts."""
    return tuple(sorted(TARGET_FACTORIES))


def make_target(name: str, **options: Any) -> Any:
    """A target model by name (ConfigError listing the known names for anything else)."""
    factory = TARGET_FACTORIES.get(name)
    if factory is None:
        raise ConfigError(f"target {name!r}: unknown target (known: {', '.join(known_targets())})")
    return factory(**options)


__all__ = ["TARGET_FACTORIES", "known_targets", "make_target"]
