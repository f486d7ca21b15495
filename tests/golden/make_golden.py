"""Write tests/golden/recordings.json from this tree's recordings (see golden.py)."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from golden import CASES, DIGESTS, REPO_ROOT, record  # noqa: E402


def main() -> None:
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=REPO_ROOT).stdout.strip()
    cases = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in (c for c in CASES if c.same_as is None):  # the others are held to these
            cases[case.name] = record(case, Path(tmp))
            print(case.name, len(cases[case.name]), "columns", flush=True)
    DIGESTS.write_text(json.dumps({"commit": commit, "cases": cases}, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
