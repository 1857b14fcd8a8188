"""The README's Python snippets and the examples run as documented."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

from rich.console import Console

from elastic_gym.evaluation import compare

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_snippets_run():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert blocks
    for block in blocks:
        exec(compile(block, "README.md", "exec"), {"__name__": "readme"})


def test_custom_controller_and_observer_example(tmp_path):
    path = ROOT / "examples" / "custom_controller_and_observer.py"
    spec = importlib.util.spec_from_file_location("custom_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    result = compare(
        module.scenario(duration=0.3),
        output_dir=tmp_path,
        workers=1,
        progress=False,
        plots=False,
        console=Console(quiet=True),
    )
    labels = {(row["controller"], row["source"]) for row in result.runs.to_dict("records")}
    assert ("torsion-damping", "static") in labels
    assert all(row["status"] == "ok" for row in result.runs.to_dict("records"))


def test_readme_scenario_yaml_is_valid():
    import yaml

    from elastic_gym.evaluation import Scenario
    from elastic_gym.evaluation.runner import plan_runs

    text = (ROOT / "README.md").read_text()
    blocks = [
        b for b in re.findall(r"```yaml\n(.*?)```", text, flags=re.DOTALL) if "state_sources" in b
    ]
    assert blocks
    for block in blocks:
        runs, _ = plan_runs(Scenario.from_dict(yaml.safe_load(block)))
        assert runs
