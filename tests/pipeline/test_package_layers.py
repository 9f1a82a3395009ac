"""The pipeline's subpackages follow the data flow, and imports go one way.

files -> points -> tiles -> meshes -> grids -> store, then the run and the
tools around it.  Every import of a pipeline module counts, also one inside a
function or under ``TYPE_CHECKING``: a module may import its own layer or a
lower one, never a higher one, and no modules import each other in a circle.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

import pipeline

ROOT = Path(pipeline.__file__).parent

#: layer of each subpackage and of each module at the package's top level
LAYERS = {
    # the shared basics: errors, parameters, URLs and logging
    "pipeline.errors": 0,
    "pipeline.config": 0,
    "pipeline.urls": 0,
    "pipeline.logs": 0,
    "pipeline.products": 0,  # the layers' declarations, read by every stage
    "pipeline.inputs": 1,  # files -> points
    "pipeline.tiling": 2,  # points -> tiles
    "pipeline.meshing": 3,  # tiles -> meshes -> grids
    "pipeline.store": 4,  # grids and meshes -> the store
    "pipeline.runs": 5,  # the run's plan, stages, resume, workflows, cluster
    "pipeline.tools": 6,
    "pipeline.cli": 6,
    "pipeline.api": 6,
    "pipeline": 6,  # __init__: the public surface
}


def module_name(path: Path) -> str:
    parts = ("pipeline",) + path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path): path for path in sorted(ROOT.rglob("*.py"))}


def imported(name: str, path: Path) -> set[str]:
    """Every pipeline module that ``name`` imports, wherever the import is."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            # ``from .. import urls`` names a module; ``from .grid import TileGrid`` does not
            targets = [f"{source}.{a.name}" if f"{source}.{a.name}" in MODULES else source for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in MODULES and t != name)
    return found


def layer(name: str) -> int:
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        if ".".join(parts[:k]) in LAYERS:
            return LAYERS[".".join(parts[:k])]
    raise KeyError(name)


def upward(edges: dict[str, set[str]]) -> list[str]:
    """The imports that climb from a lower layer to a higher one."""
    return sorted(f"{a} -> {b}" for a, targets in edges.items() for b in targets if layer(a) < layer(b))


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def group_of(name: str) -> str:
    """The subpackage of a module, or the module itself at the top level."""
    parts = name.split(".")
    return ".".join(parts[:2]) if len(parts) > 2 or (ROOT / parts[-1]).is_dir() else name


@pytest.fixture(scope="module")
def edges() -> dict[str, set[str]]:
    return {name: imported(name, path) for name, path in MODULES.items()}


def test_every_module_has_a_layer():
    unplaced = []
    for name in MODULES:
        try:
            layer(name)
        except KeyError:
            unplaced.append(name)
    assert unplaced == [], "place these modules in a subpackage, or give them a layer in LAYERS"


def test_no_import_climbs_to_a_higher_layer(edges):
    assert upward(edges) == []


def test_no_modules_import_each_other_in_a_circle(edges):
    assert circles(edges) == []


def test_no_subpackages_import_each_other_in_a_circle(edges):
    groups: dict[str, set[str]] = {}
    for a, targets in edges.items():
        groups.setdefault(group_of(a), set()).update(group_of(b) for b in targets if group_of(b) != group_of(a))
    assert circles(groups) == []


def test_the_checks_catch_what_they_look_for():
    assert upward({"pipeline.inputs.crs": {"pipeline.runs.plan"}}) == ["pipeline.inputs.crs -> pipeline.runs.plan"]
    assert upward({"pipeline.runs.plan": {"pipeline.inputs.crs"}}) == []
    two = {"pipeline.inputs.crs": {"pipeline.inputs.sources"}, "pipeline.inputs.sources": {"pipeline.inputs.crs"}}
    assert circles(two) == [["pipeline.inputs.crs", "pipeline.inputs.sources"]]
    assert circles({"pipeline.inputs.sources": {"pipeline.inputs.crs"}}) == []
    lazy = imported("pipeline.runs.runner", MODULES["pipeline.runs.runner"])
    assert "pipeline.inputs.sources" in lazy  # imported inside a function only
    assert "pipeline.store.zarr_store" in lazy  # ``from ..store import zarr_store as store``


def test_no_module_shadows_the_standard_library():
    names = {part for name in MODULES for part in name.split(".")[1:]}
    assert sorted(names & set(sys.stdlib_module_names)) == []


def test_no_subpackage_hides_a_public_name():
    # importing ``pipeline.run.x`` would replace the function ``pipeline.run``
    subpackages = {path.name for path in ROOT.iterdir() if (path / "__init__.py").exists()}
    assert sorted(subpackages & set(pipeline.__all__)) == []


def test_every_subpackage_is_installed():
    import tomllib

    listed = tomllib.loads((ROOT.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    subpackages = {name for name, path in MODULES.items() if path.name == "__init__.py"}
    assert sorted(subpackages - set(listed)) == []


def test_the_store_and_its_grid_load_without_the_kernels():
    """Store commands (export, STAC, reading a store) start without numba:
    the grid type needs no compiled kernel until it bins points (meshcore's
    options, which the run's parameters are, load no kernel)."""
    import subprocess

    probe = (
        "import sys\n"
        "from pipeline.store import zarr_store, export, catalog\n"
        "from pipeline.tiling.grid import TileGrid\n"
        "print('numba' in sys.modules, 'meshcore._jit' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=Path(pipeline.__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "False"]
