"""A griffe extension for the API reference: each object is documented once, where defined.

A package's `__all__` re-exports names of its modules (`from elastic_gym.observers import
Observer`), and mkdocstrings renders the public names a module imports: the package's
block and the defining module's block would both document `Observer`. This extension
marks every re-export of an object of the package as not public, so that it is rendered
only in the module that defines it; a reference to the package path (`[Observer]
[elastic_gym.observers.Observer]`) still resolves to that documentation.
"""

from __future__ import annotations

from typing import Any

import griffe


class DocumentOnce(griffe.Extension):
    """Hide re-exports (aliases to objects of the same package) from the rendering."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        self._hide_reexports(pkg, pkg.path + ".")

    def _hide_reexports(self, module: griffe.Module, prefix: str) -> None:
        for member in module.members.values():
            if member.is_alias:
                if member.target_path.startswith(prefix):
                    member.public = False
            elif member.is_module:
                self._hide_reexports(member, prefix)
