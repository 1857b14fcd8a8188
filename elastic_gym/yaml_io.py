"""Loading YAML written by users (scenario files, run folders, hyper-parameter files) safely.

`load_yaml` is ``yaml.safe_load`` with the limits a hostile or broken file needs,
every refusal a `YAMLInputError` (a ``ValueError``) that starts with where it is:
``"<file>: <field path>: <problem>"`` (e.g. ``scenario.yaml: controllers[1]: duplicate
key 'name' (lines 4 and 6)``).

* duplicate keys in one mapping are refused (YAML says keys are unique; PyYAML keeps
  the last one silently);
* nesting deeper than `MAX_DEPTH` is refused before Python's recursion limit;
* the document expanded through its aliases may hold at most `MAX_NODES` nodes
  (an "alias bomb" of a few lines expands to billions), counted without expanding it;
  a self-referencing alias is refused;
* the text may hold at most `MAX_BYTES` bytes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

MAX_BYTES = 1 << 20  # 1 MiB: a scenario is a few kB
MAX_DEPTH = 64  # nesting levels of mappings and sequences
MAX_NODES = 100_000  # nodes of the document with every alias expanded
MERGE_TAG = "tag:yaml.org,2002:merge"


class YAMLInputError(ValueError):
    """Refused YAML; ``where`` is ``"<file>"`` or ``"<file>: <field path>"``."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.problem = problem


class _DepthError(yaml.YAMLError):
    def __init__(self, mark: yaml.Mark | None) -> None:
        super().__init__(f"nesting deeper than {MAX_DEPTH} levels{_at(mark)}")


def _at(mark: yaml.Mark | None) -> str:
    return f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""


class _BoundedLoader(yaml.SafeLoader):
    """``SafeLoader`` whose composer stops at `MAX_DEPTH` levels."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise _DepthError(self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _key(node: yaml.Node) -> object:
    """A comparable identity of a mapping key node (scalars by tag and value)."""
    if isinstance(node, yaml.ScalarNode):
        return (node.tag, node.value)
    return id(node)


def _child(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _check(root: yaml.Node, where: str) -> None:
    """Refuse the first duplicate key, self-reference or excess size (field path first)."""
    sizes: dict[int, int] = {}  # expanded node count of each node seen
    open_nodes: set[int] = set()
    paths: dict[int, str] = {}

    def visit(node: yaml.Node, path: str) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            raise YAMLInputError(
                f"{where}: {path or 'top level'}",
                f"an alias refers to the node that contains it ({paths[key]})",
            )
        open_nodes.add(key)
        paths[key] = path or "top level"
        total = 1
        if isinstance(node, yaml.MappingNode):
            seen: dict[object, int] = {}
            for key_node, value_node in node.value:
                name = str(key_node.value) if isinstance(key_node, yaml.ScalarNode) else "?"
                identity = _key(key_node)
                line = key_node.start_mark.line + 1
                if key_node.tag != MERGE_TAG and identity in seen:
                    raise YAMLInputError(
                        f"{where}: {path or 'top level'}",
                        f"duplicate key {name!r} (lines {seen[identity]} and {line})",
                    )
                seen[identity] = line
                total += visit(key_node, path) + visit(value_node, _child(path, name))
                if total > MAX_NODES:
                    break
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                total += visit(item, f"{path}[{i}]")
                if total > MAX_NODES:
                    break
        if total > MAX_NODES:
            raise YAMLInputError(
                f"{where}: {path or 'top level'}",
                f"expands (through its aliases) to more than {MAX_NODES} values",
            )
        open_nodes.discard(key)
        sizes[key] = total
        return total

    visit(root, "")


def load_yaml(source: str | Path, what: str | None = None) -> Any:
    """The data of a YAML document: a file (a ``Path``) or YAML text (a ``str``).

    ``what`` names the input in errors (default: the file's path; for text give e.g.
    ``"--env-kwargs"``). An empty document gives ``None``. Raises
    `YAMLInputError` for unreadable files, invalid YAML and the limits of the
    module docstring.
    """
    where = what or str(source)
    if isinstance(source, Path):
        try:
            with source.open("rb") as handle:  # a larger file is not read beyond the bound
                raw = handle.read(MAX_BYTES + 1)
            text = raw.decode(errors="replace" if len(raw) > MAX_BYTES else "strict")
        except (OSError, UnicodeDecodeError) as exc:
            raise YAMLInputError(where, f"cannot be read: {exc}") from None
    else:
        text = source
    if len(text.encode(errors="replace")) > MAX_BYTES:  # a file's own bytes too, see above
        raise YAMLInputError(where, f"larger than {MAX_BYTES} bytes")
    loader = _BoundedLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check(node, where)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise YAMLInputError(where, f"invalid YAML: {' '.join(str(exc).split())}") from None
    finally:
        loader.dispose()
