"""Does the fast lane exercise every module of the package?

``python tests/lane_coverage.py [PYTEST ARGS]`` runs ``pytest -m "not slow"`` under
coverage (in this process, or in each xdist worker with ``-n 2``) and lists each
``elastic_gym/**/*.py`` module with the share of its statements that a test ran (its
setup, call or teardown; imports and collection do not count). A module counts as
exercised when a line inside one of its functions ran so, or when one of its compiled
(numba) functions was compiled or loaded for a call (their lines run as machine code,
which coverage cannot see), or, for a module without functions or whose functions run
at its import (registration), when it was imported.
Exit status 1 names the modules the lane leaves alone. Subprocesses are not measured: a
module only a subprocess runs counts as not exercised.
"""

from __future__ import annotations

import ast
import json
import os
import sys
import tempfile
from pathlib import Path

import coverage
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "elastic_gym"
OUT = "LANE_COVERAGE_DIR"  # where each worker leaves its data (set by `main`)


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


def compiled_and_imported() -> tuple[list[str], list[str]]:
    """The package's modules with a numba dispatcher holding a compiled signature (compiled
    or loaded from the cache), and all the package's modules imported."""
    from numba.core.registry import CPUDispatcher

    compiled, imported = [], []
    for name, module in list(sys.modules.items()):
        if not name.startswith("elastic_gym") or module is None:
            continue
        imported.append(name)
        for value in list(vars(module).values()):
            ran = isinstance(value, CPUDispatcher) and value.overloads
            if ran and value.py_func.__module__ == name:
                compiled.append(name)
                break
    return compiled, imported


_measure: list[coverage.Coverage] = []  # this xdist worker's


def pytest_configure(config) -> None:
    """In an xdist worker (this module is a plugin, ``-p lane_coverage``): coverage from
    here to its end."""
    if hasattr(config, "workerinput"):
        measure = coverage.Coverage(
            data_file=str(Path(os.environ[OUT]) / ".coverage"),
            data_suffix=True,
            source_pkgs=["elastic_gym"],
            config_file=False,
        )
        measure.start()
        _measure.append(measure)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """The lines a test's setup, call and teardown run are recorded under its id; those
    run by imports and collection under no id (and do not count)."""
    measure = coverage.Coverage.current()
    if measure is not None:
        measure.switch_context(item.nodeid)
    yield
    if measure is not None:
        measure.switch_context("")


def pytest_unconfigure(config) -> None:
    """Coverage saved; what `compiled_and_imported` finds written to ``$OUT``."""
    for measure in _measure:
        measure.stop()
        measure.save()
    compiled, imported = compiled_and_imported()
    name = getattr(config, "workerinput", {}).get("workerid", "main")
    path = Path(os.environ[OUT]) / f"modules-{name}.json"
    path.write_text(json.dumps({"compiled": compiled, "imported": imported}))


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def main(arguments: list[str]) -> int:
    with tempfile.TemporaryDirectory() as out:
        os.environ[OUT] = out
        tests = str(Path(__file__).parent)  # this module, importable by the xdist workers
        os.environ["PYTHONPATH"] = os.pathsep.join([tests, os.environ.get("PYTHONPATH", "")])
        sys.path.insert(0, tests)
        measure = coverage.Coverage(
            data_file=str(Path(out) / ".coverage"),
            data_suffix=True,
            source_pkgs=["elastic_gym"],
            config_file=False,
        )
        measure.start()
        try:
            code = pytest.main(
                ["-p", "lane_coverage", "-o", "addopts=", "-q", "-m", "not slow", *arguments]
            )
        finally:
            measure.stop()
            measure.save()
        measure.combine([out])
        data = measure.get_data()
        compiled, imported = set(), set()
        for path in Path(out).glob("modules-*.json"):
            found = json.loads(path.read_text())
            compiled.update(found["compiled"])
            imported.update(found["imported"])
        missing = []
        print(f"\n{'module':<48} {'ran':>6}  exercised by")
        for path in sorted(PACKAGE.rglob("*.py")):
            name = module_name(path)
            by_line = data.contexts_by_lineno(str(path))
            ran = {line for line, contexts in by_line.items() if any(contexts)}
            try:
                statements = set(measure.analysis2(str(path))[1])
            except coverage.CoverageException:
                statements = set()
            inside = function_lines(path)
            if ran & inside:
                how = "a function ran"
            elif name in compiled:
                how = "a compiled function ran"
            elif not inside and (by_line or name in imported):
                how = "import (no functions)"
            elif set(by_line) & inside:
                how = "a function ran at its import"  # registration, the banner silenced
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
