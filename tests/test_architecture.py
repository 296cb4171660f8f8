"""The package layering of docs/architecture.md, checked on the source: no import from a lower
package to a higher one, none between packages of one layer unless listed, and no import circle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "trackflow"

#: layer of every top-level package or module of trackflow (docs/architecture.md)
LAYERS = {
    "errors": 0,
    "optional": 0,
    "math": 0,
    "yamlfile": 1,
    "graph": 1,
    "io": 1,
    "filters": 1,
    "plotting": 3,
    "dataflow": 2,
    "evaluation": 2,
    "demo": 3,
    "trackers": 3,
    "optical": 3,
    "viewer": 3,
    "calibration": 3,
    "distributed": 3,
    "cli": 4,
}
#: imports allowed between packages of one layer (importer -> imported): the error types and
#: the optional-dependency seam sit under everything, math included
SAME_LAYER: set[tuple[str, str]] = {
    ("math", "errors"),
    ("math", "optional"),
    ("optional", "errors"),
}


def _imports(path: Path) -> set[str]:
    """Top-level trackflow packages imported by one module (absolute or relative)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    rel = path.relative_to(SRC).parts
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "trackflow" and len(parts) > 1:
                    out.add(parts[1])
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                parts = (node.module or "").split(".")
                if parts[0] == "trackflow":
                    if len(parts) > 1:
                        out.add(parts[1])
                    else:
                        out.update(a.name for a in node.names)
            else:
                base = list(rel[:-1])[: len(rel) - node.level]
                target = base + (node.module.split(".") if node.module else [])
                if target:
                    out.add(target[0])
                else:
                    out.update(a.name for a in node.names)
    return out


def _package(path: Path) -> str:
    return path.relative_to(SRC).parts[0].removesuffix(".py")


def _graph() -> dict[str, set[str]]:
    deps: dict[str, set[str]] = {}
    for path in SRC.rglob("*.py"):
        pkg = _package(path)
        if pkg == "__init__":
            continue
        deps.setdefault(pkg, set()).update(d for d in _imports(path) if d != pkg)
    return deps


def test_every_package_has_a_layer():
    missing = sorted(set(_graph()) - set(LAYERS))
    assert not missing, f"add {missing} to LAYERS here and to docs/architecture.md"


def test_no_import_upwards_or_sideways():
    bad = []
    for pkg, deps in _graph().items():
        for dep in deps:
            if dep not in LAYERS:
                continue
            if LAYERS[dep] > LAYERS[pkg] or (
                LAYERS[dep] == LAYERS[pkg] and (pkg, dep) not in SAME_LAYER
            ):
                bad.append(f"{pkg} (layer {LAYERS[pkg]}) imports {dep} (layer {LAYERS[dep]})")
    assert not bad, "\n".join(bad)


def _cycle(deps: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}

    def visit(node, stack):
        state[node] = 1
        for nxt in sorted(deps.get(node, ())):
            if state.get(nxt) == 1:
                return stack + [node, nxt]
            if nxt not in state:
                found = visit(nxt, stack + [node])
                if found:
                    return found
        state[node] = 2
        return None

    for node in sorted(deps):
        if node not in state:
            found = visit(node, [])
            if found:
                return found
    return None


def test_no_import_circle_between_packages():
    assert _cycle(_graph()) is None, _cycle(_graph())


def test_the_check_sees_a_circle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) is not None


@pytest.mark.parametrize("pkg", ["filters", "dataflow", "evaluation"])
def test_import_scanner_reads_relative_imports(pkg):
    assert "math" in _graph()[pkg]
