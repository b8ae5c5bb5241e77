"""No import circle in the package (issue 19): a module never imports, directly or through others, a module that
imports it. Every import counts, also those under ``TYPE_CHECKING`` and those deferred into a function: each of
them is a dependency of the module's code on the other module, whatever the moment Python runs it.

The walk is over the source files' syntax trees (``ast``), not over ``sys.modules``, so it sees imports that a
test run would not execute. Circles are the strongly connected components with more than one module of the
graph module -> imported module (Tarjan's algorithm, written out here rather than taken from the package).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package (a package is its ``__init__``)."""
    out = {}
    for path in sorted((SRC / "reflexarm").rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``name`` imports anywhere in its file."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    deps: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            deps.update(alias.name for alias in node.names if alias.name in modules)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: up from this module's package
                head = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(head + ([base] if base else []))
            for alias in node.names:  # "from pkg import module" depends on the module, else on pkg
                full = f"{base}.{alias.name}"
                deps.add(full if full in modules else base)
    deps.discard(name)
    return {d for d in deps if d in modules}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_the_walk_finds_a_circle_it_is_shown() -> None:
    """The detector itself: a three-module circle and a self-contained tail are told apart."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"a"}}
    assert _circles(graph) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_the_walk_sees_deferred_and_type_checking_imports(tmp_path: Path) -> None:
    source = (
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from reflexarm.x import A\n"
        "def f():\n    from reflexarm import y\n"
    )
    path = tmp_path / "m.py"
    path.write_text(source)
    modules = {"reflexarm.m": path, "reflexarm.x": path, "reflexarm.y": path, "reflexarm": path}
    assert _imported("reflexarm.m", path, modules) == {"reflexarm.x", "reflexarm.y"}


def test_no_import_circle_in_the_package() -> None:
    modules = _modules()
    assert len(modules) > 100, "the walk found too few modules: wrong source folder?"
    graph = {name: _imported(name, path, modules) for name, path in modules.items()}
    circles = _circles(graph)
    if circles:
        pytest.fail("import circles (each a set of modules that import each other):\n" + "\n".join(
            " <-> ".join(c) for c in circles
        ))
