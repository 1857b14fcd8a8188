"""mkdocs hooks: tutorial pages from jupytext scripts, field references from JSON Schemas.

* Each ``docs/tutorials/<name>.py`` (jupytext ``py:percent``: ``# %% [markdown]`` text
  cells, ``# %%`` code cells) becomes the page ``tutorials/<name>.md``, with a link to the
  script (copied beside it). ``tests/test_docs.py`` executes the scripts.
* A line ``<!-- schema: NAME -->`` in a page becomes one section per model of the JSON
  Schema ``elastic_gym.schemas.json_schema(NAME)``: a table of its fields with their type,
  bounds and default read from the schema, and their meaning from ``fields.yaml`` beside
  this file (keyed by schema, model and field; the test checks that it covers exactly the
  schema's fields).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import jupytext
import yaml
from mkdocs.structure.files import File, Files

TUTORIALS = "tutorials"
FIELDS = Path(__file__).with_name("fields.yaml")
MARKER = re.compile(r"^<!-- schema: (\w+) -->$", re.M)
BOUNDS = (("exclusiveMinimum", ">"), ("minimum", "≥"), ("exclusiveMaximum", "<"), ("maximum", "≤"))


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


def type_text(node: dict) -> str:
    """A short reading of a JSON-schema type: ``list of number (at least 1)``, ``> 0``."""
    if "$ref" in node:
        name = node["$ref"].rsplit("/", 1)[1]
        return f"[{name}](#{name.lower()})"
    if "const" in node:
        return f"`{json.dumps(node['const'])}`"
    if "enum" in node:
        return " or ".join(f"`{json.dumps(value)}`" for value in node["enum"])
    if "anyOf" in node:
        options = [n for n in node["anyOf"] if n.get("type") != "null"]
        parts = list(dict.fromkeys(type_text(n) for n in options))
        if "number" in parts and "integer" in parts:  # an int is a number
            parts.remove("integer")
        text = " or ".join(parts)
        return text + (" or `null`" if len(options) < len(node["anyOf"]) else "")
    kind = node.get("type")
    if isinstance(kind, list):
        return " or ".join(kind)
    if kind == "array":
        if "prefixItems" in node:
            return "[" + ", ".join(type_text(n) for n in node["prefixItems"]) + "]"
        notes = [f"at least {node['minItems']}"] if node.get("minItems") else []
        notes += ["distinct"] if node.get("uniqueItems") else []
        item = type_text(node.get("items", {})) or "anything"
        return f"list of {item}" + (f" ({', '.join(notes)})" if notes else "")
    if kind == "object":
        values = node.get("additionalProperties")
        return f"mapping of {type_text(values)}" if isinstance(values, dict) else "mapping"
    if kind in ("integer", "number"):
        bounds = ", ".join(f"{sign} {node[key]:g}" for key, sign in BOUNDS if key in node)
        return f"{kind} {bounds}".strip()
    if kind == "string" and node.get("pattern", "").endswith(":[\\w.]+$"):
        return "`module:Class`"
    return {"boolean": "bool", "string": "string"}.get(kind, kind or "")


def schema_models(schema: dict) -> dict[str, tuple[dict, list[dict]]]:
    """Model title -> (its object schema, the other forms it may take), root model first."""
    models = {}
    for node in (schema, *schema.get("$defs", {}).values()):
        forms = node.get("anyOf", [node])
        objects = [n for n in forms if n.get("type") == "object" and "properties" in n]
        if objects:
            models[node.get("title") or objects[0]["title"]] = (
                objects[0],
                [n for n in forms if n is not objects[0]],
            )
    return models


def default_text(field: dict, required: bool) -> str:
    if required:
        return "required"
    if "default" not in field:
        return "`{}`" if field.get("type") == "object" else "—"
    return f"`{json.dumps(field['default'])}`"


def schema_markdown(name: str, schema: dict, meanings: dict) -> str:
    """One section per model of ``schema``: its fields' type, default and meaning."""
    sections = []
    for title, (model, forms) in schema_models(schema).items():
        text = meanings[title]
        lines = [f"### `{title}` {{ #{title.lower()} }}", "", text.get("_", "").strip(), ""]
        if forms:
            lines += ["Also accepted: " + " or ".join(type_text(f) for f in forms) + ".", ""]
        lines += ["| field | type | default | meaning |", "|---|---|---|---|"]
        required = set(model.get("required", ()))
        for field, node in model["properties"].items():
            row = (f"`{field}`", type_text(node), default_text(node, field in required))
            lines.append("| " + " | ".join((*row, text[field].strip())) + " |")
        sections.append("\n".join(lines))
    return "\n\n".join(sections)


def field_meanings() -> dict:
    return yaml.safe_load(FIELDS.read_text())


def on_files(files: Files, config) -> Files:
    docs_dir = Path(config["docs_dir"])
    for path in sorted((docs_dir / TUTORIALS).glob("*.py")):
        files.append(
            File.generated(config, f"{TUTORIALS}/{path.stem}.md", content=tutorial_markdown(path))
        )
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    if not MARKER.search(markdown):
        return markdown
    from elastic_gym.schemas import json_schema

    meanings = field_meanings()
    return MARKER.sub(
        lambda m: schema_markdown(m.group(1), json_schema(m.group(1)), meanings[m.group(1)]),
        markdown,
    )
