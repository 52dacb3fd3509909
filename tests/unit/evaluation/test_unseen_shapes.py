"""scripts/unseen_shapes.py: the eight test objects off the YCB set (docs/exploration.md, "Unseen shapes")."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import trimesh

SCRIPT = Path(__file__).resolve().parents[3] / "scripts" / "unseen_shapes.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("unseen_shapes", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_shapes_are_closed_solids_of_the_documented_sizes(tmp_path: Path) -> None:
    assert _script().main([str(tmp_path)]) == 0
    extents_mm = {
        "plate": (200, 50, 10),
        "rod": (12, 12, 200),
        "capsule": (40, 40, 120),
        "cone": (80, 80, 100),
        "ring": (124, 124, 24),
        "pea": (12, 12, 12),
        "tube": (80, 80, 90),
        "ell": (100, 110, 30),
    }
    assert sorted(p.stem for p in tmp_path.glob("*.stl")) == sorted(extents_mm)
    for name, extents in extents_mm.items():
        mesh = trimesh.load(tmp_path / f"{name}.stl")
        assert mesh.is_watertight and mesh.volume > 0, name
        np.testing.assert_allclose(1000 * mesh.extents, extents, atol=1.0, err_msg=name)


def test_the_ell_has_its_concave_corner() -> None:
    """Its volume is the L's (two 3 cm bars, 10 and 11 cm long, 3 cm deep), well below its hull's."""
    ell = _script().ell_prism()
    l_area = 0.1 * 0.03 + (0.11 - 0.03) * 0.03
    assert abs(ell.volume - l_area * 0.03) < 1e-12
    assert ell.volume < 0.7 * ell.convex_hull.volume
