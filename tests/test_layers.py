"""The package's layers point one way: geometry <- data <- network <- sfm <- slam <- eval / recon / report <- cli.

The import graph is read from the source with ``ast`` (every ``import`` statement, those inside functions and
``if TYPE_CHECKING:`` blocks included, since a lazy import is still a dependency), one node per module. It must
have no arrow from the core (geometry, data, network, sfm, slam) into eval, no arrow up the layer order, and no
circle, neither between modules nor between the package's parts (``codeslam.slam``, ``codeslam.viz``, ...).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "codeslam"

#: Lowest first; the parts on one rung may import each other only without a circle.
LAYERS = [("geometry",), ("data",), ("network",), ("sfm",), ("slam",), ("eval", "recon", "report"), ("cli",)]
RANK = {part: rank for rank, parts in enumerate(LAYERS) for part in parts}
CORE = ("geometry", "data", "network", "sfm", "slam")
#: Arrows up the layer order that are known and named. The SLAM runner (slam/pipeline.py) writes the fused map
#: with recon; it is the tools layer around the SLAM core and belongs above eval and recon, not in slam/.
KNOWN_UPWARD = {
    ("codeslam.slam.pipeline", "codeslam.recon"),
    ("codeslam.slam.pipeline", "codeslam.recon.ply"),
}


def _modules(package: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package (a package is its ``__init__.py``)."""
    out = {}
    for path in package.rglob("*.py"):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports. ``from a.b import c`` counts as importing ``a.b.c`` when that
    is a module, else ``a.b``; a name that is no module of the package resolves to its nearest enclosing one."""
    modules = _modules(package)
    root = package.name

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets: set[str | None] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets.update(resolve(a.name) for a in node.names if a.name.split(".")[0] == root)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                if node.module.split(".")[0] == root:
                    for a in node.names:
                        full = f"{node.module}.{a.name}"
                        targets.add(full if full in modules else resolve(node.module))
            elif isinstance(node, ast.ImportFrom) and node.level > 0:
                raise AssertionError(f"{path}: relative import; the package imports itself absolutely")
        graph[name] = {t for t in targets if t is not None and t != name}
    return graph


def part(module: str) -> str:
    """``codeslam.slam.window`` -> ``slam``; ``codeslam.io`` -> ``io``; ``codeslam`` -> ``codeslam``."""
    names = module.split(".")
    return names[1] if len(names) > 1 else names[0]


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def _arrows(graph):
    return sorted((a, b) for a, targets in graph.items() for b in targets)


def test_the_graph_sees_the_imports(graph):
    """Not vacuous: arrows written at module level, inside functions and through a package all show."""
    assert "codeslam.data.trajectory" in graph["codeslam.data.tum"]  # module level
    assert "codeslam.eval.slam_run" in graph["codeslam.cli.slam"]  # inside the command function
    assert "codeslam.eval.metrics" in graph["codeslam.eval.slam_run"]  # `from codeslam.eval import metrics`
    assert "codeslam.viz.rerun_viewer" in graph["codeslam.viz.registry"]  # lazy import of the optional viewer
    assert len(graph) > 50


def test_circles_are_found():
    toy = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(toy) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_the_core_never_imports_eval(graph):
    bad = [(a, b) for a, b in _arrows(graph) if part(a) in CORE and part(b) == "eval"]
    assert not bad, f"arrows from the core into eval: {bad}"


def test_layers_point_down(graph):
    up = [(a, b) for a, b in _arrows(graph)
          if part(a) in RANK and part(b) in RANK and RANK[part(b)] > RANK[part(a)] and (a, b) not in KNOWN_UPWARD]
    assert not up, f"imports up the layer order {' <- '.join('/'.join(p) for p in LAYERS)}: {up}"


def test_known_upward_arrows_still_exist(graph):
    """An exception that was mended leaves the list, so the list cannot hide a new arrow of the same name."""
    gone = [(a, b) for a, b in KNOWN_UPWARD if b not in graph.get(a, ())]
    assert not gone, f"remove from KNOWN_UPWARD: {gone}"


def test_no_circle_between_modules(graph):
    assert circles(graph) == []


def test_no_circle_between_parts(graph):
    parts: dict[str, set[str]] = {}
    for a, b in _arrows(graph):
        if part(a) != part(b):
            parts.setdefault(part(a), set()).add(part(b))
    assert circles(parts) == []
