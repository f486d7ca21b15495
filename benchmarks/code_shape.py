"""The shape of the code, as the house issue counts it, for one or more trees side by side.

Per tree (a checkout holding `hilbench/`): functions above cyclomatic complexity 20 and above 10
and longer than 60 lines (radon), public annotations that are `Any`/`object` (or hold `Any`),
`type: ignore` comments, lines converting a period in µs by hand (`period_us * 1e-6` and the
like), Drive fields read by position (`drive[N]`). Needs radon (a development tool, not a runtime
dependency: `pip install radon`).

    python benchmarks/code_shape.py . /work/baseline-730876f [--list]
"""

from __future__ import annotations

import argparse
import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

_PERIOD_BY_HAND = re.compile(r"period_us\w*\)?\s*(\*\s*1e-6|/\s*1e6|/\s*1_000_000)|1e-6\s*\*\s*\w*period_us")
_DRIVE_BY_POSITION = re.compile(r"\bdrive\[\d+\]")


def complexity(tree: Path) -> list[tuple[int, int, str]]:
    """(complexity, lines, "file:line name") of every function and method (radon cc)."""
    out = subprocess.run([sys.executable, "-m", "radon", "cc", "-s", "-j", "hilbench"], cwd=tree,
                         capture_output=True, text=True, check=True).stdout
    return [(x["complexity"], x["endline"] - x["lineno"] + 1,
             f"{path}:{x['lineno']} {x['classname'] + '.' if x.get('classname') else ''}{x['name']}")
            for path, blocks in json.loads(out).items() for x in blocks if x["type"] != "class"]


def _loose(annotation: ast.expr) -> bool:
    text = ast.unparse(annotation)
    return text == "object" or re.search(r"\bAny\b", text) is not None


def loose_annotations(tree: Path) -> list[str]:
    """Public functions' parameters and returns annotated `Any`/`object` (or holding `Any`)."""
    found: list[str] = []
    for path in sorted((tree / "hilbench").rglob("*.py")):
        private_module = any(p.startswith("_") and p != "__init__.py" for p in path.relative_to(tree / "hilbench").parts)

        def visit(body: list[ast.stmt], prefix: str, public: bool) -> None:
            for node in body:
                if isinstance(node, ast.ClassDef):
                    visit(node.body, f"{prefix}{node.name}.", public and not node.name.startswith("_"))
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    dunder = node.name.startswith("__") and node.name.endswith("__")
                    if not public or (node.name.startswith("_") and not dunder) or node.name == "__exit__":
                        continue
                    a = node.args
                    params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *(p for p in (a.vararg, a.kwarg) if p)]
                    where = f"{path.relative_to(tree)}:{node.lineno} {prefix}{node.name}"
                    found.extend(f"{where}({p.arg}: {ast.unparse(p.annotation)})" for p in params
                                 if p.annotation is not None and _loose(p.annotation))
                    if node.returns is not None and _loose(node.returns):
                        found.append(f"{where} -> {ast.unparse(node.returns)}")

        visit(ast.parse(path.read_text(encoding="utf-8")).body, "", not private_module)
    return found


def matching_lines(tree: Path, pattern: re.Pattern[str]) -> list[str]:
    return [f"{path.relative_to(tree)}:{i}: {line.strip()}" for path in sorted((tree / "hilbench").rglob("*.py"))
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("trees", nargs="+", type=Path, help="checkouts holding hilbench/")
    parser.add_argument("--list", action="store_true", help="name every function and line counted")
    args = parser.parse_args()
    if shutil.which("radon") is None and subprocess.run([sys.executable, "-m", "radon", "--version"],
                                                        capture_output=True).returncode != 0:
        parser.error("needs radon (pip install radon)")
    for tree in args.trees:
        if not (tree / "hilbench").is_dir():
            parser.error(f"{tree}: no hilbench/ there")
        funcs = complexity(tree)
        loose = loose_annotations(tree)
        ignores = matching_lines(tree, re.compile(r"type:\s*ignore"))
        by_hand = matching_lines(tree, _PERIOD_BY_HAND)
        by_position = matching_lines(tree, _DRIVE_BY_POSITION)
        over20 = sorted((f for f in funcs if f[0] > 20), reverse=True)
        print(f"{tree}: {len(funcs)} functions, {len(over20)} above CC 20, {sum(f[0] > 10 for f in funcs)} above CC 10, "
              f"{sum(f[1] > 60 for f in funcs)} longer than 60 lines (max CC {max(f[0] for f in funcs)}); "
              f"{len(loose)} public Any/object annotations; {len(ignores)} type: ignore; "
              f"{len(by_hand)} period conversions by hand; {len(by_position)} Drive reads by position")
        if args.list:
            for lines in ([f"  CC {c:3d} {n:4d} lines  {name}" for c, n, name in over20], [f"  {x}" for x in loose],
                          [f"  {x}" for x in by_hand], [f"  {x}" for x in by_position]):
                print("\n".join(lines))


if __name__ == "__main__":
    main()
