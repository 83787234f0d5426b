"""The layer rule of docs/design.md §8, checked over the import graph (imports inside functions included).

Modules depend one way, from the bottom up, with no cycle even within a layer; argparse lives in the command line
only. A place where the code breaks the rule would be listed below (the lists are empty): a new violation fails,
and so does a listed one that is gone (take it off the list, so that it cannot come back unnoticed).
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: module -> layer (docs/design.md §8); every module of the package must be here
LAYERS = {
    "errors": 1, "geometry": 1, "files": 1, "factors": 1,
    "camera": 2, "arm": 2, "collisions": 2, "dataset": 2, "measurements": 2, "frames": 2,
    "tracking": 3, "trackparams": 3, "centroids": 3, "trackfilter": 3, "corners": 3, "spinmodel": 3, "spinfilter": 3,
    "meshconfig": 3, "armmeshes": 3, "meshtextures": 3, "meshcast": 3, "patterns": 3, "render": 3, "renderconfig": 3,
    "videos": 2, "meshrender": 3, "stillness": 3,
    "simulate": 3, "recordings": 3, "camerafiles": 2, "bags": 2, "trackrun": 3, "bagdataset": 3,
    "graph": 4, "initialise": 4, "uncertainty": 4,
    "calibration": 5, "estimate": 5, "fits": 5, "planning": 5,
    "report": 6, "diagnosis": 6, "words": 6, "plots": 6, "export": 6, "pixels": 6, "posefiles": 6, "htmlreport": 6,
    "overlays": 6, "planplots": 6,
    "cli": 7, "plancli": 7, "demo": 7, "__main__": 7, "__init__": 8,
}
#: (importer, imported) pairs that break the rule today
KNOWN_UPWARD: set[tuple[str, str]] = set()
KNOWN_ARGPARSE: set[str] = set()


def _imports(path: Path, relative: bool = True, depth: int = 1) -> tuple[set[str], bool]:
    """The package modules ``path`` imports (at any depth of its code), and whether it imports argparse;
    ``relative``: its relative imports name gtsam_rotid's modules (not those of ``factors/``); ``depth``: the
    relative level that names them (2 inside a sub-package, whose own level-1 imports stay inside it)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found, argparse = set(), False
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                argparse |= parts[0] == "argparse"
                if parts[0] == "gtsam_rotid" and len(parts) > 1:
                    found.add(parts[1])
                elif parts[0] == "factors":
                    found.add("factors")
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level == depth and relative:
                found.update([module.split(".")[0]] if module else [a.name for a in node.names])
            elif module.startswith("gtsam_rotid."):
                found.add(module.split(".")[1])
            elif module == "gtsam_rotid":
                found.update(a.name for a in node.names if a.name in LAYERS)
            elif module.split(".")[0] == "factors":
                found.add("factors")
            argparse |= module == "argparse"
    return found, argparse


def _graph() -> dict[str, tuple[set[str], bool]]:
    graph = {p.stem: _imports(p) for p in sorted((ROOT / "gtsam_rotid").glob("*.py"))}
    for package in sorted(p.parent for p in (ROOT / "gtsam_rotid").glob("*/__init__.py")):
        # a sub-package is one node: what its modules import from the rest of gtsam_rotid
        parts = [_imports(p, depth=2) for p in sorted(package.glob("*.py"))]
        graph[package.name] = (set().union(*(d for d, _ in parts)) - {package.name}, any(a for _, a in parts))
    factors = [_imports(p, relative=False) for p in sorted((ROOT / "factors").glob("*.py"))]
    graph["factors"] = (set().union(*(f[0] for f in factors)) - {"factors"}, any(f[1] for f in factors))
    return graph


def test_every_module_has_a_layer():
    assert set(_graph()) <= set(LAYERS), sorted(set(_graph()) - set(LAYERS))


def test_no_module_imports_one_above_it():
    graph = _graph()
    upward = {(m, d) for m, (deps, _) in graph.items() for d in deps
              if d in LAYERS and d != m and LAYERS[d] > LAYERS[m]}
    assert upward - KNOWN_UPWARD == set(), f"imports against the layer rule: {sorted(upward - KNOWN_UPWARD)}"
    assert KNOWN_UPWARD - upward == set(), f"fixed, take off KNOWN_UPWARD: {sorted(KNOWN_UPWARD - upward)}"


def test_the_core_imports_no_package_module_above_it():
    graph = _graph()
    assert graph["factors"][0] == set(), graph["factors"][0]  # numpy and gtsam only
    assert graph["geometry"][0] <= {"errors"}, graph["geometry"][0]


def test_argparse_only_in_the_command_line():
    graph = _graph()
    using = {m for m, (_, argparse) in graph.items() if argparse and LAYERS.get(m) != LAYERS["cli"]}
    assert using - KNOWN_ARGPARSE == set(), f"argparse outside the CLI: {sorted(using - KNOWN_ARGPARSE)}"
    assert KNOWN_ARGPARSE - using == set(), f"fixed, take off KNOWN_ARGPARSE: {sorted(KNOWN_ARGPARSE - using)}"


def _cycle(graph: dict[str, tuple[set[str], bool]]) -> list[str] | None:
    """One import cycle among the package's modules (a list ending where it starts), or None."""
    edges = {m: sorted(d for d in deps if d in graph and d != m) for m, (deps, _) in graph.items()}
    state: dict[str, int] = {}                     # 1: on the current path, 2: done
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for d in edges[m]:
            if state.get(d) == 1:
                return path[path.index(d):] + [d]
            if d not in state and (found := visit(d)):
                return found
        state[m] = 2
        path.pop()
        return None

    for m in sorted(edges):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_no_import_cycles_even_within_a_layer():
    assert _cycle(_graph()) is None, " -> ".join(_cycle(_graph()))


def test_the_cycle_finder_finds_a_cycle():
    graph = {"a": ({"b"}, False), "b": ({"c"}, False), "c": ({"a"}, False), "d": ({"a"}, False)}
    assert _cycle(graph) == ["a", "b", "c", "a"]
    assert _cycle({"a": ({"b"}, False), "b": (set(), False)}) is None


def test_plots_draw_and_never_solve():
    graph = _graph()
    assert "graph" not in graph["plots"][0] and "estimate" not in graph["plots"][0], graph["plots"][0]
    text = (ROOT / "gtsam_rotid" / "plots.py").read_text(encoding="utf-8")
    assert "Optimizer" not in text and "NonlinearFactorGraph" not in text
