"""The geometry layer is a library: it imports no node, runtime, launcher or command code."""

from __future__ import annotations

import ast
from pathlib import Path

import palpate.geometry

ALLOWED = {
    "__future__",
    "math",
    "dataclasses",
    "functools",
    "typing",
    "numpy",
    "scipy",
    "open3d",
    "trimesh",
    "skimage",
    "numba",
}
ALLOWED_PALPATE = {"palpate.errors", "palpate.geometry"}


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module is not None:
            names.add(node.module)
        elif isinstance(node, ast.ImportFrom):
            raise AssertionError(f"{path}: relative import; use absolute palpate.geometry imports")
    return names


def test_geometry_imports_only_libraries_and_errors() -> None:
    files = sorted(Path(palpate.geometry.__file__).parent.glob("*.py"))
    assert len(files) >= 4
    for path in files:
        for name in _imports(path):
            top = name.split(".")[0]
            if top == "palpate":
                assert any(name == p or name.startswith(p + ".") for p in ALLOWED_PALPATE), f"{path.name}: {name}"
            else:
                assert top in ALLOWED, f"{path.name} imports {name}: the geometry layer uses libraries only"
