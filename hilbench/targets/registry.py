"""The one registry of target profiles: built-ins and outside packages alike.

A package adds a target by declaring an entry point in the ``hilbench.targets`` group whose object
is a `TargetProfile` (or a function returning one), e.g. in its pyproject.toml::

    [project.entry-points."hilbench.targets"]
    mytarget = "my_package.hil:PROFILE"

It then works in ``--target inprocess:mytarget`` / ``emulator:mytarget``, ``run``, ``step``,
``sweep``, ``ctl`` and the recorder with no edit to hilbench. Built-in targets register the same
way from their own subpackages, imported lazily.
"""

from __future__ import annotations

import importlib
import threading
from typing import TYPE_CHECKING, Any
from importlib.metadata import EntryPoint, entry_points

from hilbench.errors import ConfigError
from hilbench.targets.profile import TargetProfile, generic_profile

if TYPE_CHECKING:
    from hilbench.targets.base import Target

ENTRY_POINT_GROUP = "hilbench.targets"

#: the target a bench uses when the config names none
DEFAULT_TARGET = "emulator:an1017"
#: the target `hilbench link-test` starts when it is given none (its Drives are checked, "link_check")
LINK_TEST_TARGET = "loopback"

#: built-in targets: name -> module whose PROFILE attribute is the profile
_BUILTIN = {
    "an1017": "hilbench.targets.an1017",
    "loopback": "hilbench.targets.loopback",
    "foc": "hilbench.targets.foc",
}

_profiles: dict[str, TargetProfile] = {}
#: plug-ins that could not be registered: entry point name -> why (`hilbench targets` lists them)
_broken: dict[str, str] = {}
_lock = threading.Lock()
_loaded = False


def register(profile: TargetProfile) -> TargetProfile:
    """Add a profile (a later registration of the same name replaces the earlier one)."""
    if not profile.name.isidentifier() or profile.name != profile.name.lower():
        raise ConfigError(f"target profile {profile.name!r}: names are lowercase identifiers")
    _profiles[profile.name] = profile
    return profile


def _load_all() -> None:
    global _loaded
    with _lock:
        if _loaded:
            return
        for name, module in _BUILTIN.items():
            try:
                register(importlib.import_module(module).PROFILE)
            except ModuleNotFoundError as exc:  # a built-in still being written is simply absent
                if exc.name != module:
                    raise
        for entry in entry_points(group=ENTRY_POINT_GROUP):
            problem = _register_plugin(entry)
            if problem is not None:
                _broken[entry.name] = f"target plug-in {entry.name!r} ({entry.value}): {problem}"
        _loaded = True


def _register_plugin(entry: EntryPoint) -> str | None:
    """Register one installed plug-in; what is wrong with it, if anything. A broken plug-in must not
    break the bench: it is left out (and named where it is asked for), and it cannot replace a
    built-in target."""
    try:
        obj = entry.load()
        profile = obj() if callable(obj) and not isinstance(obj, TargetProfile) else obj
    except Exception as exc:  # noqa: BLE001 - the plug-in's own code, whatever it raises
        return f"cannot load: {type(exc).__name__}: {exc}"
    if not isinstance(profile, TargetProfile):
        return "not a TargetProfile"
    if profile.name in _BUILTIN and profile.name in _profiles:
        return f"its name {profile.name!r} is a built-in target's, which it may not replace"
    try:
        register(profile)
    except ConfigError as exc:
        return str(exc)
    return None


def broken_plugins() -> tuple[str, ...]:
    """Why each installed plug-in that could not be registered was left out."""
    _load_all()
    return tuple(_broken.values())


def known_targets() -> tuple[str, ...]:
    """Every registered target name, sorted."""
    _load_all()
    return tuple(sorted(_profiles))


def get_profile(name: str) -> TargetProfile:
    """The profile registered as ``name`` (ConfigError listing the known names otherwise)."""
    _load_all()
    profile = _profiles.get(name)
    if profile is None:
        if name in _broken:
            raise ConfigError(_broken[name])
        raise ConfigError(f"unknown target {name!r} (known: {', '.join(known_targets())})")
    return profile


def registered_for_firmware(firmware_name: str) -> TargetProfile | None:
    """The registered profile of a firmware by the name in its HELLO (None: no module knows it)."""
    _load_all()
    wanted = firmware_name.strip().upper()
    for profile in _profiles.values():
        if profile.firmware_name.upper() == wanted:
            return profile
    return None


def profile_for_firmware(firmware_name: str) -> TargetProfile:
    """The profile of a firmware by the name in its HELLO; a neutral one for unknown firmware (the
    session completes it from the firmware's own description: hilbench.targets.describe)."""
    found = registered_for_firmware(firmware_name)
    return found if found is not None else generic_profile(firmware_name.strip())


def make_target(name: str, options: Any = None) -> "Target":
    """An in-process target by name, with its options dataclass (defaults when None)."""
    profile = get_profile(name)
    return profile.make(profile.default_options() if options is None else options)


__all__ = [
    "DEFAULT_TARGET",
    "broken_plugins",
    "ENTRY_POINT_GROUP",
    "LINK_TEST_TARGET",
    "get_profile",
    "known_targets",
    "make_target",
    "profile_for_firmware",
    "registered_for_firmware",
    "register",
]
