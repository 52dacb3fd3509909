"""A scene: one object and one effector, read from YAML and assembled into a MuJoCo model.

Only the chosen effector is built (no hand when a fingertip will do). Gravity is off by default:
the hand and finger are held by their position actuators and the probe by its velocity command,
and the object is static, so gravity would only bias the joint tracking without adding anything
to the touch experiments of papers 000 and 002.

Placement: when the effector's base pose is not given, the exploring finger's MCP joint is put
``finger_mcp_offset_m`` from the object's bounding box (x from its -x face, y from its centre, z
from its top), fingers pointing +x and palm facing -z, so the fingertip can reach the top face and
the face nearest the hand. The probe starts ``start_clearance_m`` above the object's top, facing
down, over the centre of its bounding box, or where nothing lies under that centre, over the nearest
point that has the object under it (``descent_xy``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any, TypeVar

import mujoco
import numpy as np

from palpate.config import NonNegativeFloat, OneOf, PositiveFloat, Validated
from palpate.description import mount_fact
from palpate.errors import ConfigError
from palpate.geometry.rotations import quat_to_matrix
from palpate.nodes.sim.effectors import (
    LONG_FINGERS,
    OBJECT_CONTYPE,
    EffectorMjcf,
    FingerConfig,
    HandConfig,
    ProbeConfig,
    build_finger_mjcf,
    build_hand_mjcf,
    build_probe_mjcf,
)
from palpate.nodes.sim.objects import ObjectModel, ObjectSpec, load_object

EFFECTORS: tuple[str, ...] = ("hand", "finger", "probe")
#: Name of the static body that holds the object's geoms.
OBJECT_BODY = "object"


def _default_object() -> ObjectSpec:
    return ObjectSpec(kind="rubiks_cube")


@dataclass(frozen=True, kw_only=True)
class SceneConfig(Validated):
    """Object, effector and physics options of one simulated scene (YAML: the sim node's section).

    YAML keys: ``effector`` (hand | finger | probe), ``object`` (see ObjectSpec), an optional section
    named after the effector (``hand:``, ``finger:`` or ``probe:``) with that effector's config, and
    the scalar options below. A section of another effector is refused (it would be ignored). Once
    built, the section of the effector in use is always set (its defaults when not given) and the
    other two are None.
    """

    #: The effector the scene builds: the 21-DoF hand, one finger of it, or the spherical fingertip probe.
    effector: Annotated[str, OneOf(EFFECTORS)] = "finger"
    object: ObjectSpec = field(default_factory=_default_object)
    #: The hand's options; only with ``effector: hand`` (null: its defaults).
    hand: HandConfig | None = None
    #: The single finger's options; only with ``effector: finger`` (null: its defaults).
    finger: FingerConfig | None = None
    #: The probe's options; only with ``effector: probe`` (null: its defaults).
    probe: ProbeConfig | None = None
    #: MuJoCo physics time step, seconds; the sim node's tick_period_s must be a whole multiple of it.
    timestep_s: PositiveFloat = 0.002
    #: Off by default (see the module docstring).
    gravity_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Exploring finger's MCP relative to the object's bounding box (-x face, y centre, top face).
    finger_mcp_offset_m: tuple[float, float, float] = (0.0, 0.035, 0.05)
    #: Exact-mesh contacts: a surface within radius + this distance counts as touched.
    contact_tolerance_m: NonNegativeFloat = 2e-4
    #: Penalty contact of hand/finger on non-convex objects (exact-mesh path), see core.Simulation.
    mesh_contact_stiffness_n_per_m: NonNegativeFloat = 10000.0
    #: Damping b of that penalty contact's force k (r - d) - b v_n (k the stiffness above): newtons per m/s
    #: of a capsule sphere's velocity along the surface normal.
    mesh_contact_damping_n_s_per_m: NonNegativeFloat = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in EFFECTORS:
            if name != self.effector and getattr(self, name) is not None:
                raise ConfigError(
                    f"section {name!r} is not used by effector {self.effector!r}; remove it or set effector: {name}",
                    (name,),
                )
        if getattr(self, self.effector) is None:  # frozen: fill the section in use with its defaults
            object.__setattr__(self, self.effector, _SECTIONS[self.effector]())

    def effector_config(self) -> HandConfig | FingerConfig | ProbeConfig:
        """The config of the chosen effector."""
        cfg: HandConfig | FingerConfig | ProbeConfig = getattr(self, self.effector)
        return cfg

    def finger_config(self) -> FingerConfig:
        """The single finger's config; ConfigError if the scene's effector is not the finger."""
        return self._section("finger", FingerConfig)

    def hand_config(self) -> HandConfig:
        """The hand's config; ConfigError if the scene's effector is not the hand."""
        return self._section("hand", HandConfig)

    def probe_config(self) -> ProbeConfig:
        """The probe's config; ConfigError if the scene's effector is not the probe."""
        return self._section("probe", ProbeConfig)

    def _section(self, name: str, kind: type[_C]) -> _C:
        cfg = getattr(self, name)
        if not isinstance(cfg, kind):
            raise ConfigError(f"the scene's effector is {self.effector!r}, not {name!r}: it has no {name} section")
        return cfg


_C = TypeVar("_C", HandConfig, FingerConfig, ProbeConfig)
_SECTIONS: dict[str, type[HandConfig | FingerConfig | ProbeConfig]] = {
    "hand": HandConfig,
    "finger": FingerConfig,
    "probe": ProbeConfig,
}


# --- placement -------------------------------------------------------------------------------------


def target_mcp_position(scene: SceneConfig, obj: ObjectModel) -> np.ndarray:
    """World position (3,) where the exploring finger's MCP joint goes by default."""
    lo, hi = np.asarray(obj.mesh.bounds, dtype=np.float64)
    anchor = np.array([lo[0], 0.5 * (lo[1] + hi[1]), hi[2]])
    return anchor + np.asarray(scene.finger_mcp_offset_m, dtype=np.float64)


def starts_inside(obj: ObjectModel, point_m: np.ndarray) -> bool:
    """Whether `point_m` (3,) lies inside a watertight object (ray parity); False for an open mesh,
    whose inside is not defined."""
    if not obj.mesh.is_watertight:
        return False
    from palpate.geometry.mesh_query import MeshScene

    lo, hi = np.asarray(obj.mesh.bounds, dtype=np.float64)
    if np.any(point_m < lo) or np.any(point_m > hi):
        return False
    centre = 0.5 * (lo + hi)
    scene = MeshScene(obj.mesh.vertices, obj.mesh.faces, origin_m=centre)
    return bool(scene.occupied((point_m - centre)[None, :])[0])


def descent_xy(obj: ObjectModel, radius_m: float, grid: int = 64) -> tuple[float, float]:
    """Where a probe of ``radius_m`` moving straight down lands on the object: the centre (x, y) of its
    bounding box when the object lies under it, else (under the hole of a torus, between two parts)
    the point nearest that centre, on a ``grid`` x ``grid`` lattice over the box, where the object
    lies under the probe's whole footprint (failing that, under its centre)."""
    from palpate.geometry.mesh_query import MeshScene

    lo, hi = np.asarray(obj.mesh.bounds, dtype=np.float64)
    centre = 0.5 * (lo + hi)
    scene = MeshScene(obj.mesh.vertices, obj.mesh.faces, origin_m=centre)
    above = hi[2] - centre[2] + radius_m
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    footprint = np.vstack([[0.0, 0.0], 0.9 * radius_m * np.column_stack([np.cos(angles), np.sin(angles)])])
    if _under(scene, np.zeros((1, 2)), footprint[:1], above).all():
        return float(centre[0]), float(centre[1])
    u = np.linspace(lo[0], hi[0], grid) - centre[0]
    v = np.linspace(lo[1], hi[1], grid) - centre[1]
    lattice = np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1).reshape(-1, 2)
    under = _under(scene, lattice, footprint, above)
    for landed in (under.all(axis=1), under[:, 0]):  # the whole footprint, else its centre
        if landed.any():
            points = lattice[landed]
            x, y = points[np.argmin(np.einsum("ij,ij->i", points, points))]
            return float(centre[0] + x), float(centre[1] + y)
    return float(centre[0]), float(centre[1])


def _under(scene: Any, xy: np.ndarray, footprint: np.ndarray, height_m: float) -> np.ndarray:
    """(n, k): whether a vertical ray down from (x, y) + footprint[j] at ``height_m`` meets the mesh
    (``MeshScene``'s local frame)."""
    points = (xy[:, None, :] + footprint[None, :, :]).reshape(-1, 2)
    origins = np.column_stack([points, np.full(len(points), height_m)])
    down = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    hit: np.ndarray = np.isfinite(scene.ray_hit_distance(origins, down)).reshape(len(xy), len(footprint))
    return hit


def effector_base_position(scene: SceneConfig, obj: ObjectModel) -> np.ndarray:
    """World position (3,) of the effector's root body (palm, metacarpal base or probe centre)."""
    if scene.effector == "probe":
        cfg = scene.probe_config()
        if cfg.start_position_m is not None:
            start = np.asarray(cfg.start_position_m, dtype=np.float64)
            if starts_inside(obj, start):
                raise ConfigError(
                    f"start_position_m = {start.tolist()} lies inside the object; start the probe outside it "
                    "(launch argument start:=, or start:=null to start 3 cm above it)",
                    ("start_position_m",),
                )
            return start
        x, y = descent_xy(obj, cfg.radius_m)
        return np.array([x, y, obj.mesh.bounds[1][2] + cfg.radius_m + cfg.start_clearance_m])
    if scene.effector == "finger":
        fcfg = scene.finger_config()
        if fcfg.base_position_m is not None:
            return np.asarray(fcfg.base_position_m, dtype=np.float64)
        meta = fcfg.lengths_m(fcfg.finger)[0]
        R = quat_to_matrix(fcfg.base_quaternion_wxyz)
        return target_mcp_position(scene, obj) - R @ np.array([meta, 0.0, 0.0])
    hcfg = scene.hand_config()
    if hcfg.base_position_m is not None:
        return np.asarray(hcfg.base_position_m, dtype=np.float64)
    finger = hcfg.pose_finger if hcfg.pose_finger in LONG_FINGERS else "index"
    R = quat_to_matrix(hcfg.base_quaternion_wxyz)
    return target_mcp_position(scene, obj) - R @ hcfg.mcp_position_m(finger)


def effector_mount(scene: SceneConfig) -> dict[str, Any]:
    """Where the scene fixes its hand or finger, and the finger that taps (``mount_fact``): what a mapper
    of this finger states.

    Loads the object only when the base is placed from it (no ``base_position_m``).
    """
    cfg = scene.effector_config()
    if isinstance(cfg, ProbeConfig):
        return {"effector": "probe"}
    base = cfg.base_position_m
    if base is None:
        base = tuple(effector_base_position(scene, load_object(scene.object)))
    if isinstance(cfg, FingerConfig):
        finger = cfg.finger
    else:  # the hand taps with this finger (``motion``): the one a mapper of its contacts models
        finger = cfg.pose_finger if cfg.pose_finger in LONG_FINGERS else "index"
    return mount_fact(scene.effector, finger, cfg.scale, base, cfg.base_quaternion_wxyz)


def uses_exact_contacts(scene: SceneConfig, obj: ObjectModel) -> bool:
    """True when MuJoCo must not collide effector and object (probe always; hand/finger on non-convex)."""
    return scene.effector == "probe" or not obj.convex


def effector_mjcf(scene: SceneConfig, obj: ObjectModel) -> EffectorMjcf:
    """MJCF fragments of the scene's effector, placed for the object."""
    base = effector_base_position(scene, obj)
    collide = not uses_exact_contacts(scene, obj)
    if scene.effector == "probe":
        return build_probe_mjcf(scene.probe_config(), base)
    if scene.effector == "finger":
        return build_finger_mjcf(scene.finger_config(), base, collide_with_object=collide)
    return build_hand_mjcf(scene.hand_config(), base, collide_with_object=collide)


def scene_mjcf(scene: SceneConfig, obj: ObjectModel) -> str:
    """The whole scene as an MJCF document."""
    assets, geoms = obj.mjcf_assets_and_geoms()
    eff = effector_mjcf(scene, obj)
    gravity = " ".join(f"{g:.9g}" for g in scene.gravity_m_s2)
    return (
        '<mujoco model="palpate_scene">'
        '<compiler angle="radian" autolimits="true"/>'
        f'<option timestep="{scene.timestep_s:.9g}" gravity="{gravity}" integrator="implicitfast"/>'
        '<default><geom solref="0.01 1"/></default>'
        f"<asset>{assets}</asset>"
        "<worldbody>"
        '<light pos="0 0 1" dir="0 0 -1" directional="true"/>'
        f'<body name="{OBJECT_BODY}">{geoms}</body>'
        f"{eff.worldbody}"
        "</worldbody>"
        f"<actuator>{eff.actuators}</actuator>"
        "</mujoco>"
    )


def build_model(scene: SceneConfig, obj: ObjectModel | None = None) -> mujoco.MjModel:
    """Compile the scene (object + effector). Pass ``obj`` to reuse an already loaded object."""
    obj = load_object(scene.object) if obj is None else obj
    xml = scene_mjcf(scene, obj)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as error:
        raise ConfigError(f"the scene does not compile in MuJoCo: {error}") from error
    # The object's geoms collide with effector geoms only on the native path; set their bits here so
    # the result does not depend on what the object's MJCF text says.
    object_body = model.body(OBJECT_BODY).id
    is_object = model.geom_bodyid == object_body
    model.geom_contype[is_object] = OBJECT_CONTYPE
    model.geom_conaffinity[is_object] = OBJECT_CONTYPE
    return model
