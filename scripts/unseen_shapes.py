"""Write eight test objects that are neither YCB meshes nor the built-in demo primitives, as STL files
in metres, to check the exploration on shapes it was not tuned on (docs/exploration.md, "Unseen
shapes"):

    .venv/bin/python scripts/unseen_shapes.py OUT_DIR
    .venv/bin/palpate eval explore --objects OUT_DIR --runs 1 --strategies igef,gpv,random,tour --json

plate: a 20 x 5 x 1 cm slab; rod: 12 mm across, 20 cm long; capsule: 4 cm across, 12 cm long; cone:
8 cm across, 10 cm high; ring: a torus 12.4 cm across with a 24 mm tube; pea: a 12 mm ball; tube: an
open-ended pipe (inner radius 3 cm, wall 1 cm, 9 cm long); ell: an L-shaped prism (10 x 11 cm, 3 cm
thick) with a concave corner.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh


def ell_prism(
    width_m: float = 0.1, height_m: float = 0.11, bar_m: float = 0.03, depth_m: float = 0.03
) -> trimesh.Trimesh:
    """An L-shaped prism: the polygon (0, 0) (w, 0) (w, b) (b, b) (b, h) (0, h), extruded by depth_m."""
    w, h, b = width_m, height_m, bar_m
    outline = np.array([[0.0, 0.0], [w, 0.0], [w, b], [b, b], [b, h], [0.0, h]])
    triangles = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])  # counter-clockwise, like the outline
    mesh = trimesh.creation.extrude_triangulation(outline, triangles, depth_m)
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def shapes() -> dict[str, trimesh.Trimesh]:
    """The eight test objects by name, centred near the origin."""
    creation = trimesh.creation
    return {
        "plate": creation.box((0.2, 0.05, 0.01)),
        "rod": creation.cylinder(0.006, 0.2, sections=48),
        "capsule": creation.capsule(0.08, 0.02, count=[24, 24]),
        "cone": creation.cone(0.04, 0.1, sections=48),
        "ring": creation.torus(0.05, 0.012, major_sections=64, minor_sections=24),
        "pea": creation.icosphere(3, 0.006),
        "tube": creation.annulus(0.03, 0.04, 0.09, sections=64),
        "ell": ell_prism(),
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("out", type=Path, metavar="OUT_DIR", help="folder to write the eight STL files into")
    out = parser.parse_args(argv).out
    out.mkdir(parents=True, exist_ok=True)
    for name, mesh in shapes().items():
        if not mesh.is_watertight:
            raise SystemExit(f"{name}: the generated mesh is not watertight")
        mesh.export(out / f"{name}.stl")
        print(f"{out / name}.stl: {len(mesh.faces)} faces, {np.round(1000 * mesh.extents).astype(int).tolist()} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
