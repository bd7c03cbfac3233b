"""The package's imports run down its layers, and no two folders import each other.

Every module of ``fgcal/`` and ``factors/`` is parsed (``ast``: every import statement, those
inside functions too, relative ones resolved) and each import of a module of this tree becomes an
edge. Layers, top to bottom (docs/DESIGN.md): ``fgcal.cli`` > ``fgcal.api`` > ``fgcal.studies`` >
``fgcal.report`` > ``fgcal.online`` > ``fgcal.estimation`` > ``fgcal.io`` > ``fgcal.measurements`` >
``factors`` > ``fgcal.robots`` > the ground floor (``fgcal.errors``, ``fgcal.util``,
``fgcal._version``), which everyone may import. ``fgcal/__init__.py``, the package's face, hands
the public names on: it may import anything, and nothing of the package imports it.

A module may import modules of its own layer or lower ones only; and the folders (a package's
modules, with its ``__init__.py``) import each other in no loop.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fgcal", "factors")

LAYERS = ("fgcal.cli", "fgcal.api", "fgcal.studies", "fgcal.report", "fgcal.online", "fgcal.estimation", "fgcal.io",
          "fgcal.measurements", "factors", "fgcal.robots")  # top to bottom
GROUND = ("fgcal.errors", "fgcal.util", "fgcal._version")
FACE = "fgcal"


def layer_names() -> list[str]:
    """Layer names bottom to top: the ground floor first, the face last."""
    return ["ground floor", *reversed(LAYERS), "the package's face"]


def layer_of(module: str) -> int:
    """The layer's height (0 = the ground floor); ``ValueError`` for a module on no layer."""
    if module == FACE:
        return len(LAYERS) + 1
    if any(module == g or module.startswith(g + ".") for g in GROUND):
        return 0
    for height, layer in enumerate(reversed(LAYERS), start=1):
        if module == layer or module.startswith(layer + "."):
            return height
    raise ValueError(f"{module} is on no layer: add it to LAYERS or GROUND in {Path(__file__).name}")


def find_modules(root: Path = ROOT, packages=PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every module of ``packages`` under ``root``."""
    out = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _known(name: str, modules) -> str | None:
    """The longest leading part of the dotted ``name`` that is a module of the tree."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_edges(modules: dict[str, Path]) -> list[tuple[str, str, int]]:
    """``(importer, imported, line)`` for every import of one module of ``modules`` by another."""
    edges = []
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module
                # ``from A import b``: the module A.b when it is one, else A itself
                targets = [f"{source}.{alias.name}" for alias in node.names]
            else:
                continue
            for target in targets:
                found = _known(target, modules)
                if found is not None and found != name:
                    edges.append((name, found, node.lineno))
    return sorted(set(edges))


def upward_edges(edges) -> list[str]:
    """Every edge from a module to one of a higher layer, as ``importer:line -> imported (...)``."""
    names = layer_names()
    bad = []
    for a, b, line in edges:
        la, lb = layer_of(a), layer_of(b)
        if lb > la:
            bad.append(f"{a}:{line} -> {b} ({names[la]} imports {names[lb]})")
    return bad


def folder_of(module: str, modules: dict[str, Path]) -> str:
    """The folder a module stands in, as a dotted package name.

    The files directly in ``fgcal/`` (the face and the ground-floor modules) each stand alone:
    the face imports every layer and every layer imports the ground floor, which is no loop.
    """
    path = modules[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    return module if package == FACE else package


def folder_cycles(edges, modules: dict[str, Path]) -> list[str]:
    """Each knot of folders (a strongly connected set of two or more): its shortest loop and the imports along it."""
    graph: dict[str, set[str]] = {}
    ties: dict[tuple[str, str], list[str]] = {}
    for a, b, line in edges:
        fa, fb = folder_of(a, modules), folder_of(b, modules)
        graph.setdefault(fa, set())
        graph.setdefault(fb, set())
        if fa != fb:
            graph[fa].add(fb)
            ties.setdefault((fa, fb), []).append(f"{a}:{line} -> {b}")
    # Tarjan's strongly connected components
    index, low, stack, on_stack, sccs = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                sccs.append(sorted(scc))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    out = []
    for scc in sccs:
        loop = _shortest_loop(graph, set(scc))
        hops = [f"{fa} -> {fb} ({'; '.join(ties[(fa, fb)])})" for fa, fb in zip(loop, loop[1:])]
        out.append(f"folders {', '.join(scc)} import each other, for one: " + ", then ".join(hops))
    return out


def _shortest_loop(graph, scc: set[str]) -> list[str]:
    """The shortest loop of folders inside ``scc``, as ``[a, b, ..., a]`` (breadth first from each)."""
    best = None
    for start in sorted(scc):
        parent, frontier = {start: None}, [start]
        while not any(start in graph[v] for v in frontier):
            nxt = []
            for v in frontier:
                for w in sorted(graph[v] & scc):
                    if w not in parent:
                        parent[w] = v
                        nxt.append(w)
            frontier = nxt
        last = next(v for v in frontier if start in graph[v])
        path = [start]  # walked back: start, last, ..., start
        while last is not None:
            path.append(last)
            last = parent[last]
        if best is None or len(path) < len(best):
            best = path[::-1]
    return best


@pytest.fixture(scope="module")
def graph():
    modules = find_modules()
    return modules, import_edges(modules)


def test_the_tree_is_read(graph):
    modules, edges = graph
    assert len(modules) > 50 and "fgcal.estimation.calibrate" in modules and "factors.errors" in modules
    pairs = {(a, b) for a, b, _ in edges}
    assert ("fgcal.estimation.calibrate", "fgcal.estimation.build") in pairs  # a top-level import
    assert ("factors", "factors.gtsam_factors") in pairs  # a relative import inside a function


def test_every_module_is_on_a_layer(graph):
    modules, _ = graph
    unplaced = []
    for name in modules:
        try:
            layer_of(name)
        except ValueError as exc:
            unplaced.append(str(exc))
    assert not unplaced, "\n".join(unplaced)


def test_imports_run_down_the_layers(graph):
    _, edges = graph
    bad = upward_edges(edges)
    assert not bad, f"{len(bad)} import(s) of a higher layer:\n" + "\n".join(bad)


def test_no_two_folders_import_each_other(graph):
    modules, edges = graph
    loops = folder_cycles(edges, modules)
    assert not loops, "\n".join(loops)


def test_the_checks_find_a_bad_edge(tmp_path):
    """The checker itself, on a small tree with a lazy, relative import up a layer and a loop of folders."""
    files = {
        "fgcal/__init__.py": "",
        "fgcal/errors.py": "",
        "fgcal/robots/__init__.py": "",
        "fgcal/robots/model.py": "from fgcal.errors import x\n\ndef f():\n    from ..estimation import calibrate\n",
        "fgcal/estimation/__init__.py": "",
        "fgcal/estimation/calibrate.py": "import numpy\nfrom fgcal.robots.model import RobotModel\n",
        "fgcal/io/__init__.py": "",
        "fgcal/io/table_io.py": "from fgcal import __version__\nfrom fgcal.measurements import dataset\n",
        "fgcal/measurements/__init__.py": "",
        "fgcal/measurements/dataset.py": "import fgcal.io.table_io\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    modules = find_modules(tmp_path, ("fgcal",))
    edges = import_edges(modules)
    assert ("fgcal.robots.model", "fgcal.estimation.calibrate", 4) in edges
    assert not any(b == "numpy" for _, b, _ in edges)
    bad = upward_edges(edges)
    assert bad == ["fgcal.io.table_io:1 -> fgcal (fgcal.io imports the package's face)",
                   "fgcal.measurements.dataset:1 -> fgcal.io.table_io (fgcal.measurements imports fgcal.io)",
                   "fgcal.robots.model:4 -> fgcal.estimation.calibrate (fgcal.robots imports fgcal.estimation)"]
    loops = folder_cycles(edges, modules)
    assert len(loops) == 2
    assert any("fgcal.estimation, fgcal.robots" in s and "fgcal.robots.model:4 -> fgcal.estimation.calibrate" in s
               for s in loops)
    assert any("fgcal.io, fgcal.measurements" in s for s in loops)
    # the face and the ground floor are no loop though the face imports everyone and everyone the ground
    assert not folder_cycles([("fgcal", "fgcal.robots.model", 1), ("fgcal.robots.model", "fgcal.errors", 1)],
                             modules)
    with pytest.raises(ValueError, match="on no layer"):
        layer_of("fgcal.somewhere")
