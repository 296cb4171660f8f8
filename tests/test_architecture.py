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
    "_lazy": 0,
    "math": 0,
    "scheduler": 0,
    "timesync": 0,
    "yamlfile": 1,
    "zenohconf": 1,
    "graph": 1,
    "io": 1,
    "filters": 1,
    "plotting": 3,
    "dataflow": 2,
    "evaluation": 2,
    "ros2": 2,
    "demo": 3,
    "trackers": 3,
    "optical": 3,
    "viewer": 3,
    "calibration": 3,
    "distributed": 4,
    "cli": 5,
}
#: imports allowed between packages of one layer (importer -> imported): the error types and
#: the optional-dependency seam sit under everything, math included; timesync builds on math
SAME_LAYER: set[tuple[str, str]] = {
    ("math", "errors"),
    ("math", "optional"),
    ("optional", "errors"),
    ("timesync", "math"),
    ("timesync", "errors"),
    ("scheduler", "errors"),
    ("ros2", "dataflow"),  # the ROS 2 topics build on the setup's specs of them
    ("trackers", "calibration"),  # a live run's online offsets use the offline estimator
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


# --- modules -------------------------------------------------------------------------------
#: the most lines a source file may have
MAX_LINES = 900


def _module_name(path: Path, root: Path) -> str:
    """Dotted name of the module at ``path`` under the package directory ``root`` (a
    package's ``__init__.py`` is the package itself)."""
    parts = (root.name,) + path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_imports(path: Path, root: Path, modules: set[str]) -> set[str]:
    """Modules of ``modules`` that the module at ``path`` imports anywhere in its body
    (inside functions and ``if`` blocks too), absolute or relative. ``from P import x`` is
    the module ``P.x`` where that is a module, else ``P``."""
    name = _module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()

    def module(target: str) -> str | None:  # the longest prefix that is a module
        while target and target not in modules:
            target = target.rpartition(".")[0]
        return target or None

    def add(target: str | None) -> None:
        if target is not None:
            out.add(target)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(module(alias.name))
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                up = package.split(".")
                up = up[: len(up) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                add(sub if sub in modules else module(base))
    out.discard(name)
    return out


def _module_graph(root: Path = SRC) -> dict[str, set[str]]:
    """``{module: modules it imports}`` over every module of the package at ``root``."""
    paths = {_module_name(p, root): p for p in root.rglob("*.py")}
    modules = set(paths)
    return {m: _module_imports(p, root, modules) for m, p in sorted(paths.items())}


def _circles(deps: dict[str, set[str]]) -> list[list[str]]:
    """Every import circle: the strongly connected components of more than one module
    (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(deps.get(v, ())):
            if w not in index:
                visit(w)
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
                out.append(sorted(comp))

    for v in sorted(deps):
        if v not in index:
            visit(v)
    return sorted(out)


def test_no_import_circle_between_modules():
    circles = _circles(_module_graph())
    assert not circles, "import circles between modules:\n" + "\n".join(
        " <-> ".join(c) for c in circles
    )


def test_no_source_file_over_the_line_limit():
    long = {
        str(p.relative_to(SRC)): n
        for p in sorted(SRC.rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"files over {MAX_LINES} lines (split them by what they hold): {long}"


def test_the_module_check_sees_circles_hidden_in_functions(tmp_path):
    """A circle made of a relative import inside a function, ``from . import x`` and an
    absolute import through a package's ``__init__`` is found; a tree without one is not."""
    pkg = tmp_path / "pk"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from .c import C\n")
    (pkg / "a.py").write_text("def f():\n    from .b import g\n    return g\n")
    (pkg / "b.py").write_text("from . import a\n")
    (pkg / "sub" / "c.py").write_text("from .. import other\nC = 1\n")
    (pkg / "other.py").write_text("import pk.sub.c\nfrom pk.sub import C\n")
    (pkg / "free.py").write_text("from .sub.c import C\nfrom . import other, b\n")
    graph = _module_graph(pkg)
    assert graph["pk.a"] == {"pk.b"}
    assert graph["pk.b"] == {"pk.a"}
    assert graph["pk.other"] == {"pk.sub", "pk.sub.c"}
    assert graph["pk.free"] == {"pk.sub.c", "pk.other", "pk.b"}
    assert _circles(graph) == [["pk.a", "pk.b"], ["pk.other", "pk.sub", "pk.sub.c"]]
    (pkg / "b.py").write_text("")
    (pkg / "sub" / "c.py").write_text("C = 1\n")
    assert _circles(_module_graph(pkg)) == []
