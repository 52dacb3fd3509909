"""Objects to touch: generated primitives and meshes from files, posed in the world frame.

A scene's ``object`` section becomes an :class:`ObjectSpec`; :func:`load_object` turns it into an
:class:`ObjectModel` holding the true surface (a ``trimesh.Trimesh`` in the world frame, metres) and
the MJCF text that puts it into a MuJoCo model.

Conventions:
- Primitives are centred on their own origin: box, cube and Rubik's cube on their centre, the
  sphere on its centre, the cylinder on its centre with its axis along z, the torus in the xy plane
  around the z axis. Meshes keep the frame of their file (YCB: x = y = 0 at the bounding-box
  centre, z = 0 the resting plane). ``position_m`` and ``quaternion_wxyz`` then place the object.
- ``path`` may be ``ycb:<id>`` (for example ``ycb:011_banana``), resolved in
  :func:`palpate.paths.ycb_dir`; other relative paths resolve against the current directory.
- MuJoCo collides a mesh geom as its convex hull. ``convex`` says whether that is exact; for the
  other objects the contacts come from :class:`palpate.geometry.mesh_query.ExactContactSensor`,
  and ``mjcf_assets_and_geoms(collision="decomposed")`` gives the physics a convex decomposition.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import tempfile
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import trimesh

from palpate.config import BlankIsDefault, OneOf, PositiveFloat, ScalarIsTuple, Validated
from palpate.errors import ConfigError, MeshError, MeshWarning
from palpate.geometry.mesh_query import MAX_RING_ENTRIES, edge_uses
from palpate.geometry.rotations import quat_to_matrix
from palpate.inputs import MAX_COORDINATE_M
from palpate.paths import YCB_DIR_ENV, cache_dir, ycb_dir

#: Object kinds a scene may name.
KINDS = ("cube", "rubiks_cube", "box", "sphere", "cylinder", "torus", "mesh")
#: Kinds MuJoCo collides exactly with a native geom.
CONVEX_PRIMITIVES = ("cube", "rubiks_cube", "box", "sphere", "cylinder")
#: Number of values ``size_m`` takes per kind, and what they mean.
SIZE_FIELDS: dict[str, tuple[str, ...]] = {
    "cube": ("edge",),
    "rubiks_cube": (),
    "box": ("x", "y", "z"),
    "sphere": ("radius",),
    "cylinder": ("radius", "height"),
    "torus": ("major_radius", "minor_radius"),
    "mesh": (),
}
DEFAULT_CUBE_EDGE_M = 0.05
#: Sizes used when ``size_m`` is not given: hand-sized objects a fingertip can explore.
DEFAULT_SIZES_M: dict[str, tuple[float, ...]] = {
    "cube": (DEFAULT_CUBE_EDGE_M,),
    "box": (0.06, 0.04, 0.03),
    "sphere": (0.03,),
    "cylinder": (0.03, 0.08),
    "torus": (0.04, 0.015),
}
#: A 3x3 speed cube is 57 mm on each side.
RUBIKS_CUBE_EDGE_M = 0.057
#: Objects outside this bounding-box size are refused: most are a unit mistake (mm vs m).
MIN_EXTENT_M = 0.002
MAX_EXTENT_M = 2.0
#: A size outside the range above is called a unit mistake only when a factor of 1000 (a primitive's
#: size_m) or a file unit (a mesh, ``unit_scales``) brings it here.
PLAUSIBLE_EXTENT_M = (0.005, 1.0)
#: The units a mesh file may be in, with the scale (metres per unit) that reads each.
FILE_UNITS = (("metres", 1.0), ("millimetres", 0.001), ("centimetres", 0.01), ("inches", 0.0254))


def unit_mistake(extent_m: float) -> float | None:
    """The factor (0.001 or 1000) that turns an object `extent_m` across outside MIN_EXTENT_M..MAX_EXTENT_M
    into one of a plausible size (PLAUSIBLE_EXTENT_M), or None when neither does (a genuine size)."""
    factor = 0.001 if extent_m > MAX_EXTENT_M else 1000.0
    low, high = PLAUSIBLE_EXTENT_M
    return factor if low <= extent_m * factor <= high else None


#: Tessellation of the generated curved primitives: the icosphere deviates from the true sphere by
#: at most 0.1 % of the radius, the 128-gon cylinder by 0.03 %, the 128 x 64 torus by 0.1 %.
SPHERE_SUBDIVISIONS = 4
CYLINDER_SECTIONS = 128
TORUS_MAJOR_SECTIONS = 128
TORUS_MINOR_SECTIONS = 64


@dataclass(frozen=True, kw_only=True)
class ObjectSpec(Validated):
    """The object of a scene, as written in the scene YAML section ``object``.

    ``size_m`` per kind: cube ``(edge,)`` (default 0.05); rubiks_cube fixed 57 mm (leave empty);
    box ``(x, y, z)``; sphere ``(radius,)``; cylinder ``(radius, height)``; torus ``(major, minor)``;
    mesh: empty, give ``path`` (STL/OBJ/PLY/OFF/GLB in metres, ``ycb:<id>`` for a YCB mesh) and
    optionally ``scale``. The quaternion is normalised; it must have a norm within 1e-3 of 1.
    In YAML, null, [] and "" mean "not given" (launch files pass every argument, empty when unused),
    and a single number is a one-value ``size_m``.
    """

    #: A generated primitive, the 57 mm Rubik's cube, or a mesh read from ``path``.
    kind: Annotated[str, OneOf(KINDS)]
    #: The primitive's dimensions, metres: cube [edge], box [x, y, z], sphere [radius], cylinder [radius,
    #: height], torus [major, minor radius]; empty: the kind's default size (cube 0.05, box 0.06 x 0.04 x
    #: 0.03, sphere 0.03, cylinder 0.03 x 0.08, torus 0.04 x 0.015; rubiks_cube and mesh take none).
    size_m: Annotated[tuple[PositiveFloat, ...], BlankIsDefault, ScalarIsTuple] = ()
    #: Kind mesh only: the mesh file (STL, OBJ, PLY, OFF or GLB, relative to the current directory), or
    #: ``ycb:<id>`` for a YCB object (e.g. ``ycb:011_banana``).
    path: Annotated[str | None, BlankIsDefault] = None
    #: Kind mesh only: multiplies the file's coordinates to give metres (0.001 for a file in millimetres).
    scale: Annotated[PositiveFloat, BlankIsDefault] = 1.0
    #: Where the object's origin goes in the world, metres (primitives: their centre; meshes: their file's origin).
    position_m: Annotated[tuple[float, float, float], BlankIsDefault] = (0.0, 0.0, 0.0)
    #: The object's orientation in the world (w, x, y, z); normalised, its norm must be within 1e-3 of 1.
    quaternion_wxyz: Annotated[tuple[float, float, float, float], BlankIsDefault] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _normalise_spec(self)


def _normalise_spec(spec: ObjectSpec) -> None:
    """Checks across fields, then normalise the (frozen) spec in place: floats, default sizes, unit quaternion."""
    fields = SIZE_FIELDS[spec.kind]
    size = tuple(float(v) for v in spec.size_m)
    if not size and spec.kind in DEFAULT_SIZES_M:
        size = DEFAULT_SIZES_M[spec.kind]
    if spec.kind in ("rubiks_cube", "mesh"):
        if size:
            hint = "its size is fixed at 57 mm" if spec.kind == "rubiks_cube" else "use 'scale' instead"
            raise ConfigError(f"size_m = {list(size)!r}: kind {spec.kind!r} takes no size ({hint})", ("size_m",))
    elif len(size) != len(fields):
        raise ConfigError(
            f"size_m = {list(size)!r}: kind {spec.kind!r} needs {len(fields)} value(s) ({', '.join(fields)}) in metres",
            ("size_m",),
        )
    if spec.kind == "torus" and size[1] >= size[0]:
        raise ConfigError(
            f"size_m = {list(size)!r}: a torus needs minor radius < major radius "
            "(size_m: [major_radius, minor_radius])",
            ("size_m",),
        )
    if size:
        extent = max(size)
        if spec.kind == "sphere":
            extent = 2.0 * size[0]
        elif spec.kind == "cylinder":
            extent = max(2.0 * size[0], size[1])
        elif spec.kind == "torus":
            extent = 2.0 * (size[0] + size[1])
        if not MIN_EXTENT_M <= extent <= MAX_EXTENT_M:
            factor = unit_mistake(extent)
            hint = (
                "sizes are in metres (millimetres given as metres or the reverse?), e.g. size_m: "
                f"{[round(v * factor, 6) for v in size]}"
                if factor
                else "no factor of 1000 makes it 5 mm to 1 m; give a size within that range"
            )
            raise ConfigError(
                f"size_m = {list(size)!r}: the {spec.kind} would be {extent:g} m across, outside "
                f"{MIN_EXTENT_M * 1000:g} mm to {MAX_EXTENT_M:g} m; {hint}",
                ("size_m",),
            )
    if spec.kind == "mesh":
        if not spec.path:
            raise ConfigError(
                "no path given: kind 'mesh' needs a path to a mesh file in metres (or ycb:<id>, e.g. ycb:011_banana)",
                ("path",),
            )
    elif spec.path is not None:
        raise ConfigError(f"path = {spec.path!r}: only kind 'mesh' takes a path (kind is {spec.kind!r})", ("path",))
    scale = float(spec.scale)
    if scale != 1.0 and spec.kind != "mesh":
        raise ConfigError(f"scale = {spec.scale!r}: only kind 'mesh' takes a scale; set size_m", ("scale",))
    position = tuple(float(v) for v in spec.position_m)
    quat = tuple(float(v) for v in spec.quaternion_wxyz)
    norm = math.sqrt(sum(v * v for v in quat))
    if abs(norm - 1.0) > 1e-3:
        raise ConfigError(
            f"quaternion_wxyz = {list(quat)!r}: norm {norm:.6g} is not 1; give a unit quaternion "
            "(w, x, y, z), e.g. [1, 0, 0, 0] for no rotation",
            ("quaternion_wxyz",),
        )
    object.__setattr__(spec, "size_m", size)
    object.__setattr__(spec, "scale", scale)
    object.__setattr__(spec, "position_m", position)
    object.__setattr__(spec, "quaternion_wxyz", tuple(v / norm for v in quat))


def pose_matrix(position_m: Sequence[float], quaternion_wxyz: Sequence[float]) -> np.ndarray:
    """Homogeneous transform (4, 4) from a position (m) and a unit quaternion (w, x, y, z)."""
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(quaternion_wxyz)
    T[:3, 3] = np.asarray(position_m, dtype=np.float64)
    return T


@dataclass(frozen=True, kw_only=True, eq=False)
class ObjectModel:
    """A loaded object: the true surface in the world frame and how MuJoCo should see it.

    ``mesh``: vertices (V, 3) in metres, world frame, outward-wound faces (F, 3).
    ``convex``: True when MuJoCo's collision with it is exact (native primitive or convex mesh).
    """

    name: str
    mesh: trimesh.Trimesh
    convex: bool
    spec: ObjectSpec
    source_path: Path | None = None
    watertight: bool = True
    _mesh_files: dict[str, Path] = field(default_factory=dict, init=False, repr=False)

    def geom_names(self, collision: Literal["hull", "decomposed"] = "hull") -> tuple[str, ...]:
        """Names of the MuJoCo geoms that :meth:`mjcf_assets_and_geoms` creates."""
        if collision == "hull" or self.spec.kind in CONVEX_PRIMITIVES:
            return ("object",)
        parts = self._parts()
        return tuple("object" if k == 0 else f"object_part{k}" for k in range(len(parts)))

    def mjcf_assets_and_geoms(self, collision: Literal["hull", "decomposed"] = "hull") -> tuple[str, str]:
        """MJCF text: the inner text of ``<asset>`` and the ``<geom>`` element(s) for ``<worldbody>``.

        Primitives become native geoms (box, sphere, cylinder) at the object pose. The torus and meshes
        become mesh assets, written once to the palpate cache as binary STL in the world frame.
        ``collision="hull"`` (default): one static geom named ``object``; MuJoCo collides it as its
        convex hull. ``collision="decomposed"``: one geom per CoACD convex part (``object``,
        ``object_part1``, ...), cached on disk (first run: seconds for a torus, about a minute for a
        YCB cup), so that the physics can enter holes and cups.
        """
        kind, size = self.spec.kind, self.spec.size_m
        pose = _mjcf_pose(self.spec.position_m, self.spec.quaternion_wxyz)
        if kind in ("cube", "rubiks_cube", "box"):
            half = [v / 2 for v in self.mesh_extents_local()]
            return "", f'<geom name="object" type="box" size="{_fmt(half)}"{pose}/>'
        if kind == "sphere":
            return "", f'<geom name="object" type="sphere" size="{_fmt([size[0]])}"{pose}/>'
        if kind == "cylinder":
            return "", f'<geom name="object" type="cylinder" size="{_fmt([size[0], size[1] / 2])}"{pose}/>'
        if collision == "hull":
            path = self._mesh_file("object_mesh", self._mujoco_mesh)
            return (
                f'<mesh name="object_mesh" file="{path}"/>',
                '<geom name="object" type="mesh" mesh="object_mesh"/>',
            )
        if collision != "decomposed":
            raise ValueError(f"collision = {collision!r}: use 'hull' or 'decomposed'")
        assets, geoms = [], []
        for k, (part, geom_name) in enumerate(zip(self._parts(), self.geom_names(collision), strict=True)):
            mesh_name = f"object_part{k}_mesh"
            assets.append(f'<mesh name="{mesh_name}" file="{self._mesh_file(mesh_name, part)}"/>')
            geoms.append(f'<geom name="{geom_name}" type="mesh" mesh="{mesh_name}"/>')
        return "\n".join(assets), "\n".join(geoms)

    def mesh_extents_local(self) -> tuple[float, float, float]:
        """Edge lengths (m) of a box-like primitive in its own frame."""
        if self.spec.kind == "cube":
            return (self.spec.size_m[0],) * 3
        if self.spec.kind == "rubiks_cube":
            return (RUBIKS_CUBE_EDGE_M,) * 3
        if self.spec.kind == "box":
            x, y, z = self.spec.size_m
            return (x, y, z)
        raise ValueError(f"{self.spec.kind!r} is not a box")

    @functools.cached_property
    def _mujoco_mesh(self) -> trimesh.Trimesh:
        """What MuJoCo gets for the ``hull`` collision (``mujoco_hull_mesh``), computed once."""
        return mujoco_hull_mesh(self.mesh)

    def _parts(self) -> list[trimesh.Trimesh]:
        from palpate.nodes.sim.decomposition import convex_decomposition

        return convex_decomposition(self.mesh)

    def _mesh_file(self, key: str, mesh: trimesh.Trimesh) -> Path:
        if key not in self._mesh_files:
            self._mesh_files[key] = write_cached_stl(mesh, self.name)
        return self._mesh_files[key]


#: MuJoCo reads at most this many triangles from an STL file.
MUJOCO_MAX_STL_FACES = 200_000
#: Most vertices of the hull MuJoCo gets for a mesh beyond that limit: MuJoCo builds its own hull of them,
#: which took 24 s for 18,000 cocircular vertices and 1 s for 5,000 (a thinned hull lies inside the
#: object by a small fraction of a millimetre on a hand-sized one).
MUJOCO_MAX_HULL_VERTICES = 5_000


def mujoco_hull_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh MuJoCo gets for the ``hull`` collision: ``mesh`` itself, or, beyond MuJoCo's STL limit
    (a dense scan), its convex hull, which is what MuJoCo collides a mesh geom as anyway. A hull of more
    than MUJOCO_MAX_HULL_VERTICES (a densely sampled round object) is taken over a fixed draw of them, so it
    lies slightly inside the object: a hand's MuJoCo contacts on such a convex object are then off by
    that much. The contacts of the probe and of a hand on a non-convex object come from the full mesh
    (``ExactContactSensor``), whatever MuJoCo holds."""
    if len(mesh.faces) <= MUJOCO_MAX_STL_FACES:
        return mesh
    hull = _hull(np.asarray(mesh.vertices))
    most = min(MUJOCO_MAX_HULL_VERTICES, MUJOCO_MAX_STL_FACES // 2)  # a hull of v vertices: 2 v - 4 triangles
    if len(hull.vertices) > most:  # a fixed draw: every k-th vertex of a cylinder's hull lay on one circle
        chosen = np.sort(np.random.default_rng(0).choice(len(hull.vertices), most, replace=False))
        hull = _hull(np.asarray(hull.vertices)[chosen])
    return hull


def _hull(points: np.ndarray) -> trimesh.Trimesh:
    """The convex hull of `points` on the points themselves, from qhull with joggled input (QJ): without it,
    thousands of cocircular points (a finely divided cylinder from CAD) kept its facet merging busy for
    minutes."""
    from scipy.spatial import ConvexHull

    simplices = ConvexHull(points, qhull_options="QbB Pp QJ").simplices
    hull = trimesh.Trimesh(points, simplices, process=True)
    hull.remove_unreferenced_vertices()
    trimesh.repair.fix_normals(hull)
    return hull


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{float(v):.10g}" for v in values)


def _mjcf_pose(position_m: Sequence[float], quaternion_wxyz: Sequence[float]) -> str:
    return f' pos="{_fmt(position_m)}" quat="{_fmt(quaternion_wxyz)}"'


def mesh_digest(mesh: trimesh.Trimesh) -> str:
    """SHA-1 of the vertex and face arrays: identifies a mesh in the on-disk cache."""
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def write_cached_stl(mesh: trimesh.Trimesh, name: str) -> Path:
    """Write ``mesh`` as binary STL into the palpate cache once (atomic rename) and return its path."""
    folder = cache_dir() / "meshes"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{_safe_name(name)}-{mesh_digest(mesh)[:16]}.stl"
    if not path.exists():
        data = mesh.export(file_type="stl")
        assert isinstance(data, bytes)  # binary STL
        with tempfile.NamedTemporaryFile(dir=folder, suffix=".tmp", delete=False) as handle:
            handle.write(data)
        os.replace(handle.name, path)
    return path


def _safe_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "mesh"


# --- loading ---------------------------------------------------------------------------------------
def load_object(spec: ObjectSpec) -> ObjectModel:
    """Generate or read the object's surface and pose it in the world frame.

    Raises MeshError (file missing or unreadable, not a mesh, degenerate, absurd scale, not orientable);
    warns with MeshWarning when it drops repeated triangles, re-winds faces (inconsistent or inward)
    or finds the mesh not watertight.
    """
    if spec.kind == "mesh":
        assert spec.path is not None  # guaranteed by ObjectSpec validation
        path = resolve_mesh_path(spec.path)
        local = read_mesh_file(path, spec.scale)
        name, convex, source = path.stem, bool(local.is_convex), path
    else:
        local = primitive_mesh(spec.kind, spec.size_m)
        name, convex, source = spec.kind, spec.kind in CONVEX_PRIMITIVES, None
    world = local.copy()
    world.apply_transform(pose_matrix(spec.position_m, spec.quaternion_wxyz))
    return ObjectModel(
        name=name,
        mesh=world,
        convex=convex,
        spec=spec,
        source_path=source,
        watertight=bool(world.is_watertight),
    )


def primitive_mesh(kind: str, size_m: Sequence[float]) -> trimesh.Trimesh:
    """Triangle mesh (object frame, metres) of a generated primitive. trimesh merges the vertices of a small
    one (a torus of 1 mm major radius came out without a face, one 11 mm across with holes): such a mesh
    is made with its smallest dimension at 1 m and scaled down, which keeps every face."""
    mesh = _primitive_mesh(kind, size_m)
    if kind in ("sphere", "cylinder", "torus") and (len(mesh.faces) == 0 or not mesh.is_watertight):
        unit = min(size_m[: 2 if kind != "sphere" else 1])  # the smallest dimension at 1 m
        mesh = _primitive_mesh(kind, [v / unit for v in size_m])
        mesh.vertices *= unit
    return mesh


def _primitive_mesh(kind: str, size_m: Sequence[float]) -> trimesh.Trimesh:
    if kind == "cube":
        mesh = trimesh.creation.box(extents=[size_m[0]] * 3)
    elif kind == "rubiks_cube":
        mesh = trimesh.creation.box(extents=[RUBIKS_CUBE_EDGE_M] * 3)
    elif kind == "box":
        mesh = trimesh.creation.box(extents=list(size_m))
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=size_m[0])
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=size_m[0], height=size_m[1], sections=CYLINDER_SECTIONS)
    elif kind == "torus":
        mesh = trimesh.creation.torus(
            major_radius=size_m[0],
            minor_radius=size_m[1],
            major_sections=TORUS_MAJOR_SECTIONS,
            minor_sections=TORUS_MINOR_SECTIONS,
        )
    else:
        raise ValueError(f"{kind!r} is not a primitive; primitives are {KINDS[:-1]}")
    return trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))


def resolve_mesh_path(path: str) -> Path:
    """``ycb:<id>`` -> the YCB folder's ``<id>.stl``; ``~`` and ``$VARS`` expanded; others as given."""
    if path.startswith("ycb:"):
        folder = ycb_dir()
        ident = path[len("ycb:") :]
        if folder is None:
            raise MeshError(
                f"{path}: the YCB mesh folder was not found; set {YCB_DIR_ENV} to the folder holding "
                f"{ident}.stl or give a file path"
            )
        return folder / (ident if ident.endswith(".stl") else f"{ident}.stl")
    return Path(os.path.expandvars(os.path.expanduser(path)))


def read_mesh_file(path: Path, scale: float = 1.0) -> trimesh.Trimesh:
    """Read and check a mesh file (metres after ``scale``); MeshError naming the file on failure."""
    if not path.exists():
        raise MeshError(
            f"{path}: mesh file not found (resolved from {Path.cwd()}); check object.path in the scene, "
            "or use ycb:<id> for a YCB mesh"
        )
    if not path.is_file():
        raise MeshError(f"{path}: cannot read the mesh: it is not a regular file; give the path of a mesh file")
    try:
        with path.open("rb") as handle:
            handle.read(1)
    except OSError as error:
        raise MeshError(
            f"{path}: cannot read the mesh file ({error.strerror or error}); check its permissions"
        ) from error
    ext = path.suffix.lower().lstrip(".")
    formats = sorted(trimesh.available_formats())
    if ext not in formats:
        raise MeshError(
            f"{path}: not a mesh file (extension {path.suffix!r} is not a mesh format); "
            f"convert it to one of {formats} (STL, OBJ or PLY in metres)"
        )
    try:
        loaded = trimesh.load(str(path), process=False)
    except (  # what trimesh's readers raise on a damaged file (AssertionError: a GLB buffer out of range)
        ValueError,
        KeyError,
        IndexError,
        TypeError,
        AssertionError,
        NotImplementedError,
        UnicodeDecodeError,
    ) as error:
        raise MeshError(
            f"{path}: not a readable {ext.upper()} mesh ({type(error).__name__}: {error}); "
            "re-export it as a triangle mesh (binary STL in metres works best)"
        ) from error
    if isinstance(loaded, trimesh.Scene):  # several meshes in one file (OBJ groups, GLB): one surface
        parts = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(parts) if parts else trimesh.Trimesh()
    if isinstance(loaded, trimesh.PointCloud):
        raise MeshError(
            f"{path}: not a mesh: the {ext.upper()} file holds {len(loaded.vertices)} points but no triangles "
            "(a point cloud); reconstruct and export a closed triangle mesh of the object"
        )
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{path}: not a mesh (loaded as {type(loaded).__name__}); re-export it as triangles")
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or (len(faces) and (faces.ndim != 2 or faces.shape[1] != 3)):
        raise MeshError(
            f"{path}: not a 3-D triangle mesh (vertices of shape {vertices.shape}, faces {faces.shape}); "
            "export 3-D vertices (x, y, z) and triangles"
        )
    if len(faces) == 0:
        what = f"{len(vertices)} vertices but no triangles" if len(vertices) else "no vertices and no triangles"
        raise MeshError(
            f"{path}: not a mesh: the {ext.upper()} file holds {what} (empty, corrupt or not this format); "
            "export a closed triangle mesh of the object"
        )
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: degenerate mesh: some vertices are NaN or infinite; repair or re-export it")
    outside = (faces < 0) | (faces >= len(vertices))
    if outside.any():  # PLY's reader keeps them: -1 would silently be the last vertex
        raise MeshError(
            f"{path}: corrupt mesh: {int(outside.any(axis=1).sum())} triangles name a vertex index outside "
            f"0..{len(vertices) - 1} (e.g. {int(faces[outside][0])}); repair or re-export it"
        )
    used = faces.ravel()
    size = float(np.ptp(vertices[used], axis=0).max()) * scale if len(used) else 0.0
    if size > MAX_EXTENT_M:  # checked before trimesh merges vertices, which overflows near 1e30
        _check_scale(size, path, scale)
    mesh = trimesh.Trimesh(vertices * scale, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    unique = mesh.unique_faces()
    if not unique.all():
        warnings.warn(
            f"{path}: {int((~unique).sum())} triangles repeat others (the same three vertices, in either "
            "winding); dropped them, so that they do not count twice in the object's area and coverage. "
            "Re-export the mesh without duplicate faces to silence this warning.",
            MeshWarning,
            stacklevel=2,
        )
        mesh.update_faces(unique)
    mesh.remove_unreferenced_vertices()
    _check_geometry(mesh, path, scale)
    _check_rings(mesh, path)
    return mesh


#: More faces than this at one vertex make a fan (a regular mesh has about six).
FAN_FACES = 12


def _check_rings(mesh: trimesh.Trimesh, path: Path) -> None:
    """MeshError, naming the file, for a mesh whose contact sensor's face rings would not fit
    (``mesh_query.face_rings``: faces x 3 x the most faces at one vertex): said before a run starts."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    most = int(np.bincount(faces.ravel()).max(initial=0))
    entries = len(faces) * 3 * most
    if entries > MAX_RING_ENTRIES:
        if most > FAN_FACES:
            raise MeshError(
                f"{path}: {len(faces):,} faces with a vertex shared by {most} of them (a fan, as CAD tools export "
                f"round caps): the contact sensor's face rings would hold {entries:,} entries, at most "
                f"{MAX_RING_ENTRIES:,}; remesh it (split the fan, or fewer faces)"
            )
        raise MeshError(
            f"{path}: {len(faces):,} faces are too many for the contact sensor: with up to {most} faces at a vertex "
            f"it takes at most {MAX_RING_ENTRIES // (3 * most):,}; simplify the mesh (MeshLab's quadric edge "
            "collapse, or trimesh's simplify_quadric_decimation) to fewer faces"
        )


def _thickness(vertices: np.ndarray) -> float:
    """The vertices' extent along their thinnest principal axis, metres (0 for a plane at any tilt)."""
    centred = vertices - vertices.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][-1]
    along = centred @ axis
    return float(along.max() - along.min())


def unit_scales(file_extent: float) -> list[tuple[str, float, float]]:
    """(unit, scale, extent in metres) of the FILE_UNITS that make a mesh `file_extent` file units across
    an object of a plausible size (PLAUSIBLE_EXTENT_M); else of those that make it one the scenes hold
    (MIN_EXTENT_M..MAX_EXTENT_M); else none."""
    sized = [(unit, scale, file_extent * scale) for unit, scale in FILE_UNITS]
    for low, high in (PLAUSIBLE_EXTENT_M, (MIN_EXTENT_M, MAX_EXTENT_M)):
        fits = [fit for fit in sized if low <= fit[2] <= high]
        if fits:
            return fits
    return []


def _check_scale(size: float, path: Path, scale: float) -> None:
    """MeshError when a mesh `size` metres across (after `scale`) is absurd: a file in one unit read in
    another (the scales of the units that would read it well, from the file's own extent), or no
    object the scenes hold in any unit."""
    if MIN_EXTENT_M <= size <= MAX_EXTENT_M:
        return
    limit = "over 2 m" if size > MAX_EXTENT_M else "under 2 mm"
    held = f"({limit}: the scenes hold objects {MIN_EXTENT_M * 1000:g} mm to {MAX_EXTENT_M:g} m across)"
    fits = unit_scales(size / scale)
    if not fits:
        raise MeshError(
            f"{path}: out of range: the mesh is {size:.6g} m across after scale {scale:g} {held}, and in no "
            f"unit ({', '.join(unit for unit, _ in FILE_UNITS)}) would it be; use an object within that range"
        )
    if len(fits) == 1:
        unit, _, extent_m = fits[0]
        fix = np.format_float_positional(fits[0][1], trim="-")
        raise MeshError(
            f"{path}: absurd scale: the mesh is {size:.6g} m across after scale {scale:g} {held}; a file in "
            f"{unit}? Give it a scale of {fix} ({_across(extent_m)} across): object.scale in a scene, "
            f"scale:={fix} for launch/explore.yaml and launch/probe.yaml, --scale {fix} for palpate eval "
            "explore, sweep explore and bench contacts (or convert the file to metres)"
        )
    choices = ", ".join(
        f"{np.format_float_positional(s, trim='-')} for {unit} ({_across(m)} across)" for unit, s, m in fits
    )
    first_unit, first = fits[0][0], np.format_float_positional(fits[0][1], trim="-")
    raise MeshError(
        f"{path}: absurd scale: the mesh is {size:.6g} m across after scale {scale:g} {held}; which unit is "
        f"the file in? Give it that unit's scale, {choices}: object.scale in a scene, scale:= for "
        "launch/explore.yaml and launch/probe.yaml, --scale for palpate eval explore, sweep explore and bench "
        f"contacts (for {first_unit}: scale:={first}, --scale {first}; or convert the file to metres)"
    )


def _across(extent_m: float) -> str:
    """A size for a message: millimetres below 1 cm, centimetres below 1 m, else metres."""
    if extent_m < 0.01:
        return f"{extent_m * 1000:.3g} mm"
    return f"{extent_m * 100:.3g} cm" if extent_m < 1.0 else f"{extent_m:.3g} m"


#: A mesh's vertices lie at most this far from the origin (per axis): every position in a scene stays
#: within palpate.inputs' MAX_COORDINATE_M, with room for a probe that starts beside the object.
MAX_MESH_COORDINATE_M = MAX_COORDINATE_M - 2.0 * MAX_EXTENT_M


def _check_placement(mesh: trimesh.Trimesh, path: Path) -> None:
    """MeshError for a mesh placed so far from the origin that the positions around it would be refused
    (the probe's start, its contacts: an outside walkthrough saw a mesh at 10 km end as "the effector left
    the world")."""
    far = float(np.abs(mesh.bounds).max())
    if far > MAX_MESH_COORDINATE_M:
        centre = ", ".join(f"{c:.6g}" for c in mesh.bounds.mean(axis=0))
        raise MeshError(
            f"{path}: the mesh lies {far:.6g} m from the origin along an axis (its centre at ({centre}) m); "
            f"scene positions stay within {MAX_COORDINATE_M:g} m of it, so move the mesh within "
            f"{MAX_MESH_COORDINATE_M:g} m (the YCB meshes are centred on it)"
        )


def _check_geometry(mesh: trimesh.Trimesh, path: Path, scale: float) -> None:
    """Degenerate, absurd-scale, inverted and non-watertight checks of a freshly read mesh."""
    if len(mesh.faces) == 0 or mesh.area <= 0.0:
        raise MeshError(
            f"{path}: degenerate mesh: all triangles have zero area (no faces left); export the object's closed surface"
        )
    extents = np.asarray(mesh.extents, dtype=np.float64)
    size = float(extents.max())
    _check_scale(size, path, scale)
    _check_placement(mesh, path)
    if mesh.is_watertight and not mesh.is_winding_consistent:
        _rewind(mesh, path)
    volume = float(mesh.volume) if mesh.is_watertight else 0.0
    # bodies wound both ways cancel in the volume (half of a grid of cubes inverted): their sizes count
    solid = float(np.abs(_Bodies(mesh).volumes).sum()) if mesh.is_watertight and mesh.body_count > 1 else volume
    # across its principal axes (a tilted plane too), with room for a float32 file's rounding
    flat = _thickness(mesh.vertices) <= 1e-6 * size
    if flat or (mesh.is_watertight and abs(solid) <= 1e-6 * float(np.prod(extents))):
        raise MeshError(
            f"{path}: degenerate mesh: zero volume (bounding box {_mm(extents)} mm, volume {solid:.3g} m^3); "
            "the surface is flat or collapsed, export the object's closed 3-D surface"
        )
    if mesh.is_watertight and volume < 0:
        warnings.warn(
            f"{path}: faces are wound inward (volume {volume:.3g} m^3 < 0); inverted them so that normals "
            "point out of the object. Re-export with outward normals to silence this warning.",
            MeshWarning,
            stacklevel=3,
        )
        mesh.invert()
    bodies = int(mesh.body_count)
    if bodies > 1 and mesh.is_watertight:
        _orient_bodies(mesh, path)
    if bodies > 1:
        warnings.warn(
            f"{path}: the mesh holds {bodies} separate bodies (unconnected surfaces); a fingertip explores "
            "what it reaches of them, while coverage and shape scores count all their faces, those hidden "
            "inside another body too (a body never touched, or buried faces, cap the coverage). Join "
            "overlapping bodies into one surface, or give each body a file of its own.",
            MeshWarning,
            stacklevel=3,
        )
    if not mesh.is_watertight:
        warnings.warn(
            f"{path}: mesh is not watertight ({_edge_defects(mesh)}): inside/outside tests and signed "
            "distance (contact penetration sign, occupancy ground truth) and volume-based metrics are "
            "unreliable on it. The probe takes its surface as a two-sided sheet (it passes through the "
            "holes and touches either side); a hand's or finger's contacts near a hole are unreliable. "
            "Close the holes (e.g. trimesh.repair.fill_holes or MeshLab) for reliable results.",
            MeshWarning,
            stacklevel=3,
        )


def _orient_bodies(mesh: trimesh.Trimesh, path: Path) -> None:
    """Turn outward, with a warning, each closed body of `mesh` whose faces are wound inward (negative
    volume), unless it bounds a cavity: a point of it inside the object's material (the other bodies'
    winding numbers summed, a cavity's counting -1) is a cavity's wall, whose faces rightly point into it.
    The whole mesh's volume misses one inverted body among others (its normals then point into the object)."""
    bodies = _Bodies(mesh)
    flip = [
        int(b) for b in np.flatnonzero(bodies.volumes < 0.0) if not bodies.majority_inside(int(b), lambda w: w > 0.5)
    ]
    if not flip:
        return
    bodies.invert(flip)
    warnings.warn(
        f"{path}: {len(flip)} of the mesh's {len(bodies.volumes)} bodies are wound inward (negative volume, not the "
        "wall of a cavity); turned them outward so that their normals point out of the object. Re-export with "
        "outward normals to silence this warning.",
        MeshWarning,
        stacklevel=4,
    )


class _Bodies:
    """The closed bodies (connected components) of a mesh, for telling solids from cavities."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.mesh = mesh
        self.labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
        triangles = mesh.triangles
        signed = np.einsum("ij,ij->i", triangles[:, 0], np.cross(triangles[:, 1], triangles[:, 2])) / 6.0
        self.volumes = np.bincount(self.labels, weights=signed)
        order = np.argsort(self.labels, kind="stable")
        self.triangles = np.split(triangles[order], np.cumsum(np.bincount(self.labels))[:-1])
        self.lows = np.array([b.reshape(-1, 3).min(axis=0) for b in self.triangles])  # bounding boxes (B, 3)
        self.highs = np.array([b.reshape(-1, 3).max(axis=0) for b in self.triangles])

    def majority_inside(self, own: int, inside: Callable[[float], bool]) -> bool:
        """Whether most of three vertices of body ``own`` have ``inside`` of the other bodies' winding
        numbers summed there (a majority, not one vertex: bodies may overlap)."""
        probes = self.triangles[own][:: max(1, len(self.triangles[own]) // 3), 0][:3]
        return sum(inside(self._winding_of_others(p, own)) for p in probes) * 2 > len(probes)

    def enclosed(self, own: int) -> bool:
        """Whether another body's bounding box holds the whole of body ``own``'s (a body that overlaps
        another in part is no cavity)."""
        holds = np.all(self.lows <= self.lows[own], axis=1) & np.all(self.highs[own] <= self.highs, axis=1)
        return int(holds.sum()) > 1  # its own, and another's

    def _winding_of_others(self, point: np.ndarray, own: int) -> float:
        near = np.flatnonzero(np.all(self.lows <= point, axis=1) & np.all(point <= self.highs, axis=1))
        return sum(_winding_number(self.triangles[b], point) for b in near.tolist() if b != own)

    def invert(self, which: Sequence[int]) -> None:
        """Reverse the winding of the bodies ``which``."""
        faces = np.array(self.mesh.faces)
        turned = np.isin(self.labels, which)
        faces[turned] = faces[turned][:, ::-1]
        self.mesh.faces = faces


def _winding_number(triangles: np.ndarray, point: np.ndarray) -> float:
    """How many times the closed, outward-wound surface of `triangles` (F, 3, 3) winds around `point`:
    1 inside, 0 outside (the solid angles of its triangles seen from the point, over 4 pi)."""
    a, b, c = (triangles[:, i] - point for i in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
    den += np.einsum("ij,ij->i", c, a) * lb
    return float(np.arctan2(det, den).sum() / (2.0 * np.pi))


def _rewind(mesh: trimesh.Trimesh, path: Path) -> None:
    """Wind a closed mesh's faces consistently and outward, body by body (a body inside an odd number of
    others is a cavity: its faces point into it), with a warning; MeshError when no consistent winding
    exists (a non-orientable surface)."""
    trimesh.repair.fix_normals(mesh, multibody=True)
    if not mesh.is_winding_consistent:
        raise MeshError(
            f"{path}: faces are wound inconsistently and no consistent winding exists (a non-orientable "
            "surface); export the object's closed, orientable surface"
        )
    if mesh.body_count > 1:  # every body points outward now: one inside an odd number of others is a cavity
        bodies = _Bodies(mesh)
        bodies.invert(
            [
                b
                for b in range(len(bodies.volumes))
                if bodies.enclosed(b) and bodies.majority_inside(b, lambda w: round(w) % 2 == 1)
            ]
        )
    warnings.warn(
        f"{path}: faces are wound inconsistently (some clockwise, some counter-clockwise seen from outside); "
        "re-wound each body's faces consistently and outward (a cavity's into the cavity), so that normals, "
        "volume and inside/outside tests hold. Re-export the mesh with consistent winding to silence this warning.",
        MeshWarning,
        stacklevel=4,
    )


def _edge_defects(mesh: trimesh.Trimesh) -> str:
    """Why a mesh is not watertight: its open edges (on one triangle) and the edges on more than two."""
    counts = edge_uses(mesh.faces)
    return f"{int((counts == 1).sum())} open edges, {int((counts > 2).sum())} edges on more than two triangles"


def _mm(extents: np.ndarray) -> str:
    return " x ".join(f"{1000 * v:.3g}" for v in extents)


# --- sampling --------------------------------------------------------------------------------------
def sample_surface_faces(
    mesh: trimesh.Trimesh, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform-by-area surface samples: points (count, 3) m, outward normals (count, 3), face ids (count,)."""
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    cumulative = np.cumsum(areas)
    faces = np.searchsorted(cumulative, rng.random(count) * cumulative[-1], side="right")
    faces = np.minimum(faces, len(areas) - 1)
    # uniform barycentric coordinates: reflect the unit square's upper half onto the triangle
    uv = rng.random((count, 2))
    flip = uv.sum(axis=1) > 1.0
    uv[flip] = 1.0 - uv[flip]
    a, b, c = triangles[faces, 0], triangles[faces, 1], triangles[faces, 2]
    points = a + uv[:, :1] * (b - a) + uv[:, 1:] * (c - a)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[faces]
    return points, normals, faces.astype(np.int64)


def sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Uniform-by-area surface samples: points (count, 3) in metres and outward unit normals (count, 3)."""
    points, normals, _ = sample_surface_faces(mesh, count, rng)
    return points, normals
