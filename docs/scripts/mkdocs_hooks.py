"""mkdocs hooks: the tutorials' jupytext percent scripts become pages.

Each ``docs/tutorials/<name>.py`` (a jupytext ``py:percent`` script: ``# %% [markdown]``
cells of text, ``# %%`` cells of code) is rendered as the page
``tutorials/<name>.md``: its text cells as markdown, its code cells as Python blocks,
with a link to the script itself (copied beside the page). The scripts are the source
of truth; ``tests/test_docs.py`` executes them.
"""

from __future__ import annotations

from pathlib import Path

import jupytext
from mkdocs.structure.files import File, Files

TUTORIALS = "tutorials"


def tutorial_markdown(path: Path) -> str:
    """The markdown page of one jupytext percent script."""
    notebook = jupytext.read(path, fmt="py:percent")
    parts = []
    for cell in notebook.cells:
        if cell.cell_type == "markdown":
            parts.append(cell.source)
        elif cell.source.strip():
            parts.append(f"```python\n{cell.source}\n```")
    parts.append(
        f"---\n\nThis page is the script [`{path.name}`]({path.name}) (jupytext percent "
        f"format): run it with `python docs/tutorials/{path.name}`, or open it as a "
        "notebook with `jupytext --to notebook`."
    )
    return "\n\n".join(parts) + "\n"


def on_files(files: Files, config) -> Files:
    docs_dir = Path(config["docs_dir"])
    for path in sorted((docs_dir / TUTORIALS).glob("*.py")):
        files.append(
            File.generated(config, f"{TUTORIALS}/{path.stem}.md", content=tutorial_markdown(path))
        )
    return files
