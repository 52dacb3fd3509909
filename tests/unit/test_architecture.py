"""The layers point one way (docs/architecture.md): read every module's imports with ast and check them.

messages <- runtime <- launch <- record <- commands; nodes <- messages, the library layer and the
runtime's node API (palpate.runtime.spec); no node package imports another; zmq only in the runtime
and the nodes' node.py; no symlink in the tree; every package directory is installed by pyproject.toml.
"""

from __future__ import annotations

import ast
import subprocess
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from palpate.paths import REPO_ROOT

PYPROJECT = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
#: Source directory -> installed package name (pyproject.toml's package mapping).
PACKAGE_DIRS: dict[Path, str] = {REPO_ROOT / src: pkg for pkg, src in PYPROJECT["package-dir"].items()}

#: The library layer: shared mathematics and robot facts; it imports nothing above itself.
LIBRARY = (
    "palpate.errors",
    "palpate.paths",
    "palpate.locks",  # exclusive claims between processes (lock files)
    "palpate.text_table",
    "palpate.config",
    "palpate.geometry",
    "palpate.description",
    "palpate.metrics",
    "palpate.inputs",  # the checks of values that arrive in messages
    "palpate.jsonio",  # strict JSON output
    "palpate.argtypes",  # command-line argument types
    "palpate.launch_files",  # data: the shipped YAML launch files
)
#: What each layer may import from palpate (besides itself); a prefix matches its sub-modules.
ALLOWED: dict[str, tuple[str, ...]] = {
    "palpate.messages": ("palpate.errors",),
    "palpate.runtime": (*LIBRARY, "palpate.messages"),
    "palpate.launch": (*LIBRARY, "palpate.messages", "palpate.runtime"),
    "palpate.record": (*LIBRARY, "palpate.messages", "palpate.runtime", "palpate.launch"),
    "palpate.nodes": (*LIBRARY, "palpate.messages", "palpate.runtime.spec"),
}
#: Modules outside the runtime and the node.py files that use zmq, each with its reason.
ZMQ_ALLOWED = {
    "palpate.bench.bus": "measures palpate's bus against raw pyzmq",
}


#: What may be imported from the root package itself: it holds only the version and the
#: environment defaults (BLAS threads, numba's cache where nothing else can be written).
ROOT_NAMES = {"palpate", "palpate.__version__"}
#: The geometry layer is stricter than the library layer: third-party numerics and palpate.errors only.
GEOMETRY_LIBRARIES = {"__future__", "math", "dataclasses", "functools", "typing", "numpy", "scipy", "open3d"}
GEOMETRY_LIBRARIES |= {"trimesh", "skimage", "numba"}


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    target: str  # the imported module (absolute)
    path: Path
    line: int


def module_name(path: Path) -> str:
    """The installed module name of a source file under a mapped package directory."""
    for directory, package in sorted(PACKAGE_DIRS.items(), key=lambda item: -len(item[0].parts)):
        if path.is_relative_to(directory):
            parts = list(path.relative_to(directory).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            return ".".join([package, *parts])
    raise AssertionError(f"{path} is in no package of pyproject.toml")


def source_files() -> Iterator[Path]:
    for directory in PACKAGE_DIRS:
        yield from (p for p in directory.rglob("*.py") if "__pycache__" not in p.parts)


def imports() -> Iterator[Import]:
    """Every import statement (top level or inside functions) of every installed module."""
    for path in source_files():
        module = module_name(path)
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    yield Import(module, alias.name, path, node.lineno)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                yield Import(module, base, path, node.lineno)
                for alias in node.names:  # `from palpate.nodes import controller` imports a module too
                    yield Import(module, f"{base}.{alias.name}", path, node.lineno)


ALL_IMPORTS = list(imports())


def under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def where(imp: Import) -> str:
    return f"{imp.path.relative_to(REPO_ROOT)}:{imp.line}: {imp.module} imports {imp.target}"


def layer_of(module: str) -> str | None:
    return next((layer for layer in ALLOWED if under(module, layer)), None)


def test_the_scan_sees_every_layer() -> None:
    """Guards the test itself: a broken path mapping would find nothing and pass."""
    modules = {imp.module for imp in ALL_IMPORTS}
    for expected in ("palpate.nodes.sim.node", "palpate.messages.codec", "palpate.runtime.node", "palpate.cli"):
        assert expected in modules
    assert any(imp.target == "zmq" for imp in ALL_IMPORTS)


def test_no_node_package_imports_another() -> None:
    bad = []
    for imp in ALL_IMPORTS:
        if under(imp.module, "palpate.nodes") and under(imp.target, "palpate.nodes"):
            own = ".".join(imp.module.split(".")[:3])
            if imp.target != "palpate.nodes" and not under(imp.target, own):
                bad.append(where(imp))
    assert not bad, "node packages share code through the library layer, not each other:\n" + "\n".join(bad)


def test_node_cores_do_not_import_the_runtime() -> None:
    """Pure core, thin node: only a node package's node.py speaks to the runtime (palpate.runtime.spec); its
    core and other modules take arrays and return arrays (an outside walkthrough's strategy module imported
    palpate.runtime.spec and no test said so)."""
    bad = [
        where(imp)
        for imp in ALL_IMPORTS
        if under(imp.module, "palpate.nodes") and under(imp.target, "palpate.runtime") and imp.path.name != "node.py"
    ]
    assert not bad, "only a node package's node.py imports the runtime:\n" + "\n".join(bad)


def test_layers_point_one_way() -> None:
    bad = []
    for imp in ALL_IMPORTS:
        layer = layer_of(imp.module)
        in_library = any(under(imp.module, lib) for lib in LIBRARY)
        if imp.target in ROOT_NAMES or not under(imp.target, "palpate") or (layer and under(imp.target, layer)):
            continue  # the root package holds only the version and the environment defaults
        if in_library and not any(under(imp.target, lib) for lib in LIBRARY):
            bad.append(where(imp) + " (the library layer imports only the library layer)")
        elif layer and not any(under(imp.target, allowed) for allowed in ALLOWED[layer]):
            bad.append(where(imp) + f" ({layer} may import {', '.join(ALLOWED[layer])})")
    assert not bad, "imports against the layering of docs/architecture.md:\n" + "\n".join(bad)


def test_geometry_imports_only_numerics_and_errors() -> None:
    bad = []
    for imp in ALL_IMPORTS:
        if not under(imp.module, "palpate.geometry"):
            continue
        if under(imp.target, "palpate"):
            if not (under(imp.target, "palpate.geometry") or under(imp.target, "palpate.errors")):
                bad.append(where(imp))
        elif imp.target.split(".")[0] not in GEOMETRY_LIBRARIES:
            bad.append(where(imp))
    assert not bad, "the geometry layer uses numerical libraries and palpate.errors only:\n" + "\n".join(bad)


def test_zmq_only_in_the_runtime_and_node_files() -> None:
    bad = []
    for imp in ALL_IMPORTS:
        if not under(imp.target, "zmq") or under(imp.module, "palpate.runtime") or imp.module in ZMQ_ALLOWED:
            continue
        if not (under(imp.module, "palpate.nodes") and imp.path.name == "node.py"):
            bad.append(where(imp))
    assert not bad, "zmq belongs to the runtime (and nodes' node.py):\n" + "\n".join(bad)


def test_no_symlinks_in_the_tree() -> None:
    listing = subprocess.run(["git", "ls-files", "-s"], cwd=REPO_ROOT, capture_output=True, text=True)
    if listing.returncode != 0:
        pytest.skip("not a git checkout")
    links = [line.split("\t", 1)[1] for line in listing.stdout.splitlines() if line.startswith("120000")]
    assert not links, f"symlinks in the tree (install by package mapping instead): {links}"


def test_pyproject_installs_every_package() -> None:
    found = {module_name(p) for p in source_files() if p.name == "__init__.py"}
    assert found == set(PYPROJECT["packages"]), "pyproject.toml [tool.setuptools] packages must list exactly " + str(
        sorted(found)
    )
