"""The three CPython extensions share one glue (hilbench/_cglue/hbglue.h), and a source
distribution ships it: every header an extension includes is on its include path and in the sdist."""

from __future__ import annotations

import re

from conftest import REPO_ROOT

EXTENSIONS = ("hilbench/plant/_plantcore.c", "hilbench/targets/an1017/_core.c", "hilbench/targets/foc/_core.c")
#: every extension setup.py builds (the sdist test): those above and those with headers of their own
ALL_EXTENSIONS = (*EXTENSIONS, "hilbench/bench/_span.c", "hilbench/targets/_remotestep.c", "hilbench/bench/_npzcolumns.c",
                  "hilbench/bench/_csvrows.c", "hilbench/plant/_switching.c")


def test_every_extension_is_glued_by_the_shared_header() -> None:
    for source in EXTENSIONS:
        text = (REPO_ROOT / source).read_text()
        assert '#include "hbglue.h"' in text, source
        assert "PyModule_Create(" not in text, f"{source}: its module is made by hb_module"
        assert "PyType_IsSubtype" not in text, f"{source}: the Drive type is kept by hb_set_tuple_type"


def test_the_sdist_ships_every_header_the_extensions_include() -> None:
    """Every local `#include` of an extension's glue is found beside it or on an include path of
    setup.py, and MANIFEST.in ships that file."""
    manifest = (REPO_ROOT / "MANIFEST.in").read_text()
    shipped = {word for line in manifest.splitlines() if line.startswith("include ") for word in line.split()[1:]}
    setup = (REPO_ROOT / "setup.py").read_text()
    include_dirs = sorted({d for d in re.findall(r'"([\w/]+)"', setup) if (REPO_ROOT / d).is_dir()})
    assert "hilbench/_cglue" in include_dirs
    built = set(re.findall(r'"(hilbench/[\w/]+\.c)"', setup))
    assert built == set(ALL_EXTENSIONS), f"setup.py builds {sorted(built)}: ALL_EXTENSIONS is out of date"
    for source in ALL_EXTENSIONS:
        here = source.rsplit("/", 1)[0]
        for header in re.findall(r'#include "([^"]+)"', (REPO_ROOT / source).read_text()):
            found = [f"{folder}/{header}" for folder in [here, *include_dirs] if (REPO_ROOT / folder / header).exists()]
            assert found and found[0] in shipped, f"{source} includes {header}: not shipped by MANIFEST.in"
