"""MkDocs hooks for the documentation site (``make docs``).

``docs/api.md`` holds the marker ``<!-- public-api -->``; :func:`on_page_markdown` replaces it with one
mkdocstrings block per public name of :mod:`pcdof`, grouped by the module that defines it. The names and their
modules are read from ``pcdof._EXPORTS`` in ``src/pcdof/__init__.py`` (parsed, not imported), so the reference
follows a module that moves without anyone editing the page.
"""

from __future__ import annotations

import ast
from pathlib import Path

MARKER = "<!-- public-api -->"
PACKAGE_INIT = Path(__file__).resolve().parents[1] / "src" / "pcdof" / "__init__.py"


def public_names(init_path: Path = PACKAGE_INIT) -> dict[str, str]:
    """``{public name: defining module relative to pcdof}`` from the ``_EXPORTS`` dict of *init_path*."""
    tree = ast.parse(Path(init_path).read_text(encoding="utf-8"))
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) \
            else []
        if any(isinstance(t, ast.Name) and t.id == "_EXPORTS" for t in targets):
            exports = ast.literal_eval(node.value)
            if not isinstance(exports, dict) or not exports:
                raise ValueError(f"{init_path}: _EXPORTS must be a non-empty dict literal")
            return exports
    raise ValueError(f"{init_path}: no _EXPORTS dict")


def api_markdown(exports: dict[str, str]) -> str:
    """One section per defining module, one ``::: pcdof.<module>.<name>`` block per name, in _EXPORTS order."""
    modules: dict[str, list[str]] = {}
    for name, module in exports.items():
        modules.setdefault(module, []).append(name)
    parts = []
    for module, names in modules.items():
        parts.append(f"## `pcdof.{module}`\n")
        parts.extend(f"::: pcdof.{module}.{name}\n" for name in names)
    return "\n".join(parts)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, api_markdown(public_names()))
