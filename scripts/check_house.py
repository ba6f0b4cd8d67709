#!/usr/bin/env python3
"""Check the house rules of the package (docs/developing.md) by reading its source; exits 1 on a breach.

    python scripts/check_house.py            # every rule, one line per breach
    python scripts/check_house.py --rule cycles

Rules:
  cycles        no import cycle between the package's modules (imports inside functions count; a package's
                ``__init__`` is not counted as imported by its own submodules)
  module-size   no module over 600 lines
  private       no private name (``_x``) imported from another pcdof module
  function-size no function over 80 lines, numba kernels (decorated with njit/jit/vectorize) excepted
  positional    no ``ThinLens(...)`` built from positional arguments
  threads       no thread-count setter or pool outside ``pcdof/runtime/``
  numba-attrs   nothing assigns to an attribute of a numba module
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "pcdof"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
KERNEL_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "stencil", "cfunc"}
THREAD_CALLS = {"set_num_threads", "setNumThreads", "ThreadPoolExecutor", "ProcessPoolExecutor", "Pool"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        out[module_name(path)] = (path, ast.parse(path.read_text(), str(path)))
    return out


def resolve(name: str, node: ast.ImportFrom, path: Path) -> str:
    """The absolute module an ``ImportFrom`` in module *name* (file *path*) names."""
    if not node.level:
        return node.module or ""
    base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(mods) -> dict[str, set[str]]:
    """module -> the pcdof modules it imports (at any depth of its code)."""
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, (path, tree) in mods.items():
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = resolve(name, node, path)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            for target in targets:
                while target and target not in mods:
                    target = target.rpartition(".")[0]
                if target and target != name and not name.startswith(target + "."):
                    graph[name].add(target)
    return graph


def check_cycles(mods) -> list[str]:
    graph = imports(mods)
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append("import cycle: " + " <-> ".join(sorted(comp)))

    sys.setrecursionlimit(10_000)
    for v in graph:
        if v not in index:
            strong(v)
    return out


def check_module_size(mods) -> list[str]:
    return [f"{path.relative_to(PACKAGE.parent)}: {n} lines (> {MAX_MODULE_LINES})"
            for path, _ in mods.values() if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES]


def check_private(mods) -> list[str]:
    out = []
    for name, (path, tree) in mods.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = resolve(name, node, path)
                if not (source == "pcdof" or source.startswith("pcdof.")) or source == name:
                    continue
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: imports private "
                                   f"{source}.{alias.name}")
    return out


def _decorator_names(fn) -> set[str]:
    names = set()
    for d in fn.decorator_list:
        d = d.func if isinstance(d, ast.Call) else d
        names.add(d.attr if isinstance(d, ast.Attribute) else getattr(d, "id", ""))
    return names


def check_function_size(mods) -> list[str]:
    out = []
    for path, tree in mods.values():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not (
                    _decorator_names(node) & KERNEL_DECORATORS):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {node.name} is {n} lines "
                               f"(> {MAX_FUNCTION_LINES})")
    return out


def check_positional(mods) -> list[str]:
    out = []
    for path, tree in mods.values():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == "ThinLens" \
                    and node.args:
                out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: ThinLens(...) with positional arguments")
    return out


def check_threads(mods) -> list[str]:
    out = []
    for name, (path, tree) in mods.items():
        if name.startswith("pcdof.runtime"):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                called = getattr(node.func, "attr", getattr(node.func, "id", ""))
                if called in THREAD_CALLS:
                    out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {called}(...) outside pcdof.runtime")
    return out


def check_numba_attrs(mods) -> list[str]:
    out = []
    for path, tree in mods.values():
        for node in ast.walk(tree):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, (ast.AugAssign, ast.AnnAssign)) else []
            for t in targets:
                root = t
                while isinstance(root, ast.Attribute):
                    root = root.value
                if isinstance(t, ast.Attribute) and getattr(root, "id", "") == "numba":
                    out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: assigns to a numba attribute")
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setattr" and node.args \
                    and "numba" in ast.unparse(node.args[0]):
                out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: setattr on a numba module")
    return out


RULES = {"cycles": check_cycles, "module-size": check_module_size, "private": check_private,
         "function-size": check_function_size, "positional": check_positional, "threads": check_threads,
         "numba-attrs": check_numba_attrs}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rule", choices=sorted(RULES), action="append", help="check only these rules")
    args = ap.parse_args(argv)
    mods = modules()
    breaches = 0
    for rule in args.rule or RULES:
        found = RULES[rule](mods)
        breaches += len(found)
        print(f"{rule}: {'ok' if not found else f'{len(found)} breach(es)'}")
        for line in found:
            print(f"  {line}")
    return 1 if breaches else 0


if __name__ == "__main__":
    sys.exit(main())
