"""Does the fast lane exercise every module of the package?

``python tests/lane_coverage.py [PYTEST ARGS]`` runs ``pytest -m "not slow"`` in this one
process under coverage and lists each ``elastic_gym/**/*.py`` module with the share of its
statements that ran. A module counts as exercised when a line inside one of its functions
ran, or when one of its compiled (numba) functions was compiled or loaded for a call (their
lines run as machine code, which coverage cannot see), or, for a module without functions,
when it was imported. Exit status 1 names the modules the lane leaves alone. Subprocesses
are not measured: a module only a subprocess runs counts as not exercised.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import coverage
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "elastic_gym"


def function_lines(path: Path) -> set[int]:
    """The lines of the statements inside the functions of ``path`` (docstrings aside)."""
    lines: set[int] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                body = body[1:]  # the docstring
            for statement in body:
                lines.update(range(statement.lineno, (statement.end_lineno or 0) + 1))
    return lines


class CompiledCalls:
    """A pytest plugin: at the end of the session, the modules with a numba dispatcher
    that holds at least one compiled signature (compiled or loaded from the cache)."""

    def __init__(self) -> None:
        self.modules: set[str] = set()

    def pytest_sessionfinish(self) -> None:
        from numba.core.registry import CPUDispatcher

        for name, module in list(sys.modules.items()):
            if not name.startswith("elastic_gym") or module is None:
                continue
            for value in list(vars(module).values()):
                compiled = isinstance(value, CPUDispatcher) and value.overloads
                if compiled and value.py_func.__module__ == name:
                    self.modules.add(name)
                    break


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def main(arguments: list[str]) -> int:
    measure = coverage.Coverage(data_file=None, source_pkgs=["elastic_gym"], config_file=False)
    probe = CompiledCalls()
    measure.start()
    try:
        code = pytest.main(
            ["-p", "no:xdist", "-o", "addopts=", "-q", "-m", "not slow", *arguments],
            plugins=[probe],
        )
    finally:
        measure.stop()
    data = measure.get_data()
    missing = []
    print(f"\n{'module':<48} {'ran':>6}  exercised by")
    for path in sorted(PACKAGE.rglob("*.py")):
        name = module_name(path)
        ran = set(data.lines(str(path)) or ())
        statements = set(measure.analysis2(str(path))[1]) if ran else set()
        inside = function_lines(path)
        if ran & inside:
            how = "a function ran"
        elif name in probe.modules:
            how = "a compiled function ran"
        elif ran and not inside:
            how = "import (no functions)"
        else:
            how = "NOTHING"
            missing.append(name)
        share = len(ran & statements) / max(1, len(statements))
        print(f"{name:<48} {share:>6.0%}  {how}")
    print(f"\npytest exit status {code}; {len(missing)} module(s) not exercised")
    for name in missing:
        print(f"  {name}")
    return 1 if missing or code not in (0, pytest.ExitCode.NO_TESTS_COLLECTED) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
