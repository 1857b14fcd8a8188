"""The documentation: the site builds strictly, its code runs, its references match the code.

* ``mkdocs build --strict`` (broken links, missing pages or anchors fail) into a temp dir;
  the built site holds no pickle or zip and no file that no page links, and its API
  reference documents each object once;
* every Python block of the README and of the getting-started page runs;
* every tutorial (``docs/tutorials/*.py``) runs with ``ELASTIC_GYM_TUTORIAL_QUICK=1``;
* the scenario file reference documents every field the scenario loader knows, and the
  YAML blocks of the docs are valid scenarios;
* the version, the changelog and the citation agree; the README is a front page.
"""

from __future__ import annotations

import importlib.util
import posixpath
import re
import runpy
import subprocess
import sys
import tempfile
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
import yaml
from helpers import ROOT
from rich.console import Console

import elastic_gym
from elastic_gym.evaluation import Scenario, compare
from elastic_gym.evaluation.grid import plan_runs

DOCS = ROOT / "docs"
TUTORIALS = sorted((DOCS / "tutorials").glob("*.py"))


def code_blocks(path: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", path.read_text(), flags=re.DOTALL)


@pytest.mark.slow  # a whole site build: about a minute
def test_mkdocs_build_is_strict_and_clean(tmp_path):
    pytest.importorskip("mkdocs")
    site = tmp_path / "site"
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={"NO_MKDOCS_2_WARNING": "1", **__import__("os").environ},
    )
    assert done.returncode == 0, done.stdout + done.stderr
    for page in ("index.html", "getting-started/index.html", "api/observers/index.html"):
        assert (site / page).is_file(), page
    for tutorial in TUTORIALS:
        html = (site / "tutorials" / tutorial.stem / "index.html").read_text()
        assert "<code>" in html and tutorial.name in html
    assert (
        "elastic_gym.observers.deluca.DeLucaObserver"
        in (site / "api/observers/index.html").read_text()
    )
    # one build, several checks (a second build would cost a minute of both cores)
    check_site_holds_only_linked_files(site)
    check_api_documents_each_object_once(site)


THEME_FILES = ("assets/", "search/", "sitemap.xml", "sitemap.xml.gz", "404.html", "objects.inv")


def linked_files(site: Path) -> set[str]:
    """The site's files that some page links (``href``/``src``), as site-relative paths."""
    files = {p.relative_to(site).as_posix() for p in site.rglob("*") if p.is_file()}
    linked = set()
    for page in site.rglob("*.html"):
        folder = page.parent.relative_to(site).as_posix()
        for url in re.findall(r'(?:href|src)="([^"]+)"', page.read_text()):
            parts = urlsplit(url)
            if parts.scheme or parts.netloc or not parts.path:
                continue
            target = posixpath.normpath(posixpath.join(folder, unquote(parts.path)))
            target = "" if target == "." else target
            for name in (target, posixpath.join(target, "index.html")):
                if name in files:
                    linked.add(name)
    return linked


def check_site_holds_only_linked_files(site: Path) -> None:
    """No pickles or zips in the site, and no file that no page links: what is copied into
    the site is what a reader can reach (the theme's and the search's own files aside)."""
    files = {p.relative_to(site).as_posix() for p in site.rglob("*") if p.is_file()}
    assert not [f for f in files if f.endswith((".pkl", ".zip"))]
    unlinked = sorted(files - linked_files(site))
    assert [f for f in unlinked if not f.startswith(THEME_FILES)] == []
    assert "index.html" in linked_files(site) and "api/observers/index.html" in files


def check_api_documents_each_object_once(site: Path) -> None:
    """Each object of the API reference is documented once, in the module that defines it
    (a package's re-exports are not rendered again), and module constants are not listed."""
    griffe = pytest.importorskip("griffe")
    package = griffe.load("elastic_gym", search_paths=[str(ROOT)], allow_inspection=False)
    documented = []
    for page in sorted((site / "api").glob("*/index.html")):
        documented += re.findall(
            r'<div class="doc doc-object doc-\w+">\s*<h\d id="([^"]+)"', page.read_text()
        )
    assert "elastic_gym.observers.base.Observer" in documented
    assert len(documented) == len(set(documented))
    for ident in documented:
        obj = package
        for name in ident.split(".")[1:]:
            obj = obj.members[name]
        assert not obj.is_alias, f"{ident} re-exports {obj.target_path}, documented there"
        assert not re.fullmatch(r"[A-Z][A-Z0-9_]+", obj.name), f"constant {ident} listed"


@pytest.mark.parametrize(
    "page",
    [
        "README.md",
        pytest.param("docs/getting-started.md", marks=pytest.mark.slow),  # a comparison
        "docs/batched.md",
    ],
)
def test_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the comparison writes compare_out/ here
    blocks = code_blocks(ROOT / page, "python")
    assert blocks
    namespace = {"__name__": "docs"}
    for block in blocks:  # one namespace: a page's blocks build on each other
        exec(compile(block, page, "exec"), namespace)


@pytest.mark.slow
@pytest.mark.parametrize("tutorial", TUTORIALS, ids=[t.stem for t in TUTORIALS])
def test_tutorials_run_with_short_settings(tutorial, tmp_path, monkeypatch):
    if tutorial.stem == "ppo_vs_eq13":
        pytest.importorskip("stable_baselines3")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # its work folder, removed with it
    monkeypatch.setenv("ELASTIC_GYM_TUTORIAL_QUICK", "1")
    runpy.run_path(str(tutorial), run_name="__main__")


def test_tutorials_are_jupytext_percent_scripts():
    assert len(TUTORIALS) >= 3
    for tutorial in TUTORIALS:
        text = tutorial.read_text()
        assert text.startswith("# %% [markdown]\n# # "), tutorial.name  # a titled first cell
        assert "ELASTIC_GYM_TUTORIAL_QUICK" in text, tutorial.name


def test_field_references_cover_exactly_the_schemas_fields():
    """docs/scripts/fields.yaml gives a meaning to every field of every rendered schema."""
    from elastic_gym.schemas import json_schema

    spec = importlib.util.spec_from_file_location("hooks", DOCS / "scripts" / "mkdocs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    meanings = hooks.field_meanings()
    rendered = {
        m.group(1) for page in DOCS.rglob("*.md") for m in hooks.MARKER.finditer(page.read_text())
    }
    assert rendered == set(meanings) >= {"scenario", "train"}
    for name, models in meanings.items():
        schema_models = hooks.schema_models(json_schema(name))
        assert set(schema_models) == set(models), name
        for title, (model, _) in schema_models.items():
            assert set(model["properties"]) == set(models[title]) - {"_"}, (name, title)
        text = hooks.schema_markdown(name, json_schema(name), models)
        for title in models:
            assert f"### `{title}` {{ #{title.lower()} }}" in text


@pytest.mark.parametrize("page", ["docs/comparison.md", "docs/scenario-reference.md"])
def test_scenario_yaml_blocks_are_valid(page):
    blocks = [b for b in code_blocks(ROOT / page, "yaml") if "state_sources" in b]
    assert blocks
    for block in blocks:
        runs, _ = plan_runs(Scenario.from_dict(yaml.safe_load(block)))
        assert runs


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


def test_batched_page_lists_every_randomizable_path():
    from elastic_gym.envs.randomization import PATHS

    section = (DOCS / "batched.md").read_text().split("Paths that can be randomized:")[1]
    listed = re.findall(r"`([\w.]+)`", section.split("\n\n")[0])
    assert listed == list(PATHS)


def test_env_kwargs_table_lists_exactly_the_env_kwargs():
    """One table on the environments page, a row per kwarg of the envs, none else."""
    from elastic_gym.envs.config import EnvConfig

    page = (DOCS / "environments" / "index.md").read_text()
    table = page.split("| kwarg | what it sets |\n|---|---|\n")[1].split("\n\n")[0]
    listed = [
        name for row in table.splitlines() for name in re.findall(r"`(\w+)`", row.split("|")[1])
    ]
    assert sorted(listed) == sorted([*EnvConfig.model_fields, "render_mode"])


def interleave(a, b) -> list[float]:
    return [v for pair in zip(a, b, strict=True) for v in pair]


ROBOT_ROWS = {  # first cell of a row of an environment page's robot table -> RobotSpec
    "stiffness K": lambda s: s.stiffness,
    "K (": lambda s: s.stiffness,
    "motor inertia B": lambda s: s.motor_inertia,
    "B (": lambda s: s.motor_inertia,
    "spring damping D": lambda s: s.damping,
    "D (": lambda s: s.damping,
    "torque limit": lambda s: s.torque_limit,
    "viscous friction": lambda s: s.friction.viscous,
    "Coulomb friction": lambda s: interleave(s.friction.coulomb_pos, s.friction.coulomb_neg),
    "workspace": lambda s: interleave(s.workspace_low, s.workspace_high),
}


def test_every_env_has_a_page_with_its_gif_in_the_nav():
    nav = (ROOT / "mkdocs.yml").read_text().split("\nnav:\n")[1]
    titles = {
        re.match(r"# (\S+)\n", page.read_text()).group(1): page
        for page in (DOCS / "environments").glob("*-*.md")
    }
    assert sorted(titles) == sorted(i.split("/")[1] for i in elastic_gym.ENV_IDS)
    for env_id, page in titles.items():
        assert f" environments/{page.name}\n" in nav, page.name
        gif = f"images/envs/{env_id.removesuffix('-v0')}.gif"
        assert f"](../{gif})" in page.read_text() and (DOCS / gif).is_file(), env_id


@pytest.mark.parametrize("page", sorted((DOCS / "environments").glob("*-*.md")), ids=str)
def test_environment_pages_state_the_robots_parameters(page):
    """Every K, B, D, torque limit, friction and workspace an env page shows is its spec's."""
    import gymnasium as gym

    from elastic_gym.robots.catalog import ROBOTS

    env_id = re.match(r"# (\w+-v\d+)\n", page.read_text()).group(1)
    spec = ROBOTS[gym.spec(f"elastic_gym/{env_id}").kwargs["robot"]]()
    section = page.read_text().split("## Robot\n")[1].split("\n## ")[0]
    checked = set()
    for row in section.splitlines():
        cells = [c.strip() for c in row.strip("|").split("|")]
        key = next((k for k in ROBOT_ROWS if cells[0].startswith(k)), None)
        if key is None:
            continue
        shown = [
            float(x.replace("−", "-"))
            for x in re.findall(r"−?\d+(?:\.\d+)?(?:e\d+)?", "|".join(cells[1:]))
        ]
        assert shown == pytest.approx(list(ROBOT_ROWS[key](spec)), rel=1e-12), (page.name, key)
        checked.add(key)
    assert {"torque limit"} <= checked and (not spec.elastic or len(checked) >= 4), checked


def test_module_docstrings_state_contracts_in_at_most_15_lines():
    """Long derivations and measured stories live on the docs' pages, not in modules."""
    import ast

    long = {}
    for path in sorted((ROOT / "elastic_gym").rglob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text()), clean=False)
        assert doc, f"{path.relative_to(ROOT)} has no module docstring"
        if len(doc.strip().splitlines()) > 15:
            long[str(path.relative_to(ROOT))] = len(doc.strip().splitlines())
    assert not long, long


def test_version_changelog_and_citation_agree():
    version = elastic_gym.__version__
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    changelog = (ROOT / "CHANGELOG.md").read_text()
    releases = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", changelog, re.M)
    assert releases[0] == version
    assert f"\nversion: {version}\n" in (ROOT / "CITATION.cff").read_text()
    assert yaml.safe_load((ROOT / "CITATION.cff").read_text())["cff-version"] == "1.2.0"


def test_readme_is_a_front_page_with_the_ci_test_command():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 150
    ci_command = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci_command in readme  # the test command CI runs is the README's, literally
    main = "pip install . && elastic-gym compare"
    assert f"python -m venv .venv && . .venv/bin/activate && {main}" in readme
    assert not re.search(r"load average|issue \d+|#\d+", readme)
    for link in re.findall(r"\]\(((?:docs/|[A-Z]+\.)[^)#]*)", readme):
        assert (ROOT / link).exists(), link
