"""The project's habits that code can hold: a quiet start, short commit subjects, a
command that tells its version."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
import yaml
from helpers import ROOT


@pytest.mark.slow
def test_importing_the_simulator_and_listing_presets_print_no_banner():
    code = (
        "import elastic_gym.envs; from elastic_gym.cli import main; "
        "main(['compare', '--list-presets'])"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "pybullet build time" not in done.stdout + done.stderr
    assert done.stdout.splitlines()[0].strip()  # the presets, first


def test_the_commit_msg_hook_refuses_a_subject_over_72_characters():
    config = yaml.safe_load((ROOT / ".pre-commit-config.yaml").read_text())
    assert "commit-msg" in config["default_install_hook_types"]
    (hook,) = [
        h for r in config["repos"] for h in r["hooks"] if "commit-msg" in h.get("stages", [])
    ]
    assert hook["language"] == "pygrep" and "--multiline" in hook["args"]
    refused = re.compile(hook["entry"])  # pygrep: a match anywhere in the file fails the hook
    assert refused.search("x" * 73 + "\n\nbody\n")
    assert not refused.search("x" * 72 + "\n\n" + "a long body line " * 10 + "\n")
    assert not refused.search("short\n")


def test_test_modules_share_helpers_through_helpers_py_only():
    """Shared test code lives in tests/helpers.py; no test module imports another test
    module or conftest (which fails under a bare ``pytest`` run from another folder)."""
    offenders = {}
    for path in sorted((ROOT / "tests").glob("*.py")):
        found = re.findall(
            r"^\s*(?:from|import) (test_\w+|conftest|tests\.\w+)", path.read_text(), re.M
        )
        if found:
            offenders[path.name] = found
    assert not offenders, offenders


def test_docstrings_are_markdown_without_sphinx_roles():
    """mkdocstrings renders Markdown: a `:func:` role would show as raw text in the API pages."""
    role = re.compile(r":(?:py:)?(?:func|class|meth|mod|attr|data|obj|exc|const):`")
    found = [
        f"{path.relative_to(ROOT)}:{n}"
        for path in sorted((ROOT / "elastic_gym").rglob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if role.search(line)
    ]
    assert not found, f"Sphinx roles (write [`name`][elastic_gym.module.name]): {found[:10]}"


def test_the_command_tells_the_installed_version(capsys):
    from importlib.metadata import version

    from elastic_gym.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"elastic-gym {version('elastic-gym')}"
