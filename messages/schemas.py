"""Message schemas: the contract between nodes, and between palpate and hardware drivers.

Each class is frozen and keyword-only; units are in the field names; `TYPE`, `VERSION` and `TOPIC`
are the wire name, the schema version and the default topic. Bump `VERSION` on any change of fields.
`palpate docs messages` renders these into docs/messages.md.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from palpate.messages import topics
from palpate.messages.base import Message, array, scalar, strings


class Clock(Message):
    """One tick of simulated time, published by the clock source after its other messages of the tick."""

    TYPE: ClassVar[str] = "Clock"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.CLOCK

    tick: int = scalar("int", "tick counter, 0 at the first tick")
    period_ns: int = scalar("int", "simulated time between two ticks", "ns")
    lockstep: bool = scalar("bool", "true when the clock source waits for every node's acknowledgement")


class LockstepAck(Message):
    """A node's word that it has handled every input of a tick and published its outputs."""

    TYPE: ClassVar[str] = "LockstepAck"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.LOCKSTEP_ACK

    node: str = scalar("str", "name of the acknowledging node")
    tick: int = scalar("int", "tick being acknowledged")


class RunControl(Message):
    """Ask the graph to stop (for example an exploration that reached its coverage goal)."""

    TYPE: ClassVar[str] = "RunControl"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.GRAPH_CONTROL
    #: The commands that end the run ("stop", and "fail": as a failure); no other is known.
    ENDS_RUN: ClassVar[tuple[str, str]] = ("stop", "fail")

    command: str = scalar("str", "'stop' ends the run after the current tick; 'fail' ends it as a failure")
    reason: str = scalar("str", "human-readable reason")


class JointState(Message):
    """Joint angles (and rates) of a hand or finger."""

    TYPE: ClassVar[str] = "JointState"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.JOINT_STATES

    names: list[str] = strings("joint names, one per angle", "j")
    positions_rad: np.ndarray = array(("j",), "float64", "joint angles", "rad")
    velocities_rad_s: np.ndarray = array(("j",), "float64", "joint angular rates", "rad/s")


class JointCommand(Message):
    """Position targets for the joint actuators."""

    TYPE: ClassVar[str] = "JointCommand"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.JOINT_COMMANDS

    names: list[str] = strings("joint names, one per target", "j")
    positions_rad: np.ndarray = array(("j",), "float64", "target joint angles", "rad")


class Pose(Message):
    """Pose and twist of the exploring end-effector (fingertip) in the world frame."""

    TYPE: ClassVar[str] = "Pose"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.EFFECTOR_POSE

    frame: str = scalar("str", "name of the body this pose belongs to")
    position_m: np.ndarray = array((3,), "float64", "position in the world frame", "m")
    quaternion_wxyz: np.ndarray = array((4,), "float64", "orientation; the body's z axis is the poking axis")
    linear_velocity_m_s: np.ndarray = array((3,), "float64", "linear velocity, world frame", "m/s")
    angular_velocity_rad_s: np.ndarray = array((3,), "float64", "angular velocity, world frame", "rad/s")


class CartesianVelocityCommand(Message):
    """Linear and angular velocity command for a Cartesian-controlled effector (the probe)."""

    TYPE: ClassVar[str] = "CartesianVelocityCommand"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.VELOCITY_COMMANDS

    linear_m_s: np.ndarray = array((3,), "float64", "linear velocity, world frame", "m/s")
    angular_rad_s: np.ndarray = array((3,), "float64", "angular velocity, world frame", "rad/s")


class ContactSet(Message):
    """Contacts between the effector and the object at one instant (n may be 0)."""

    TYPE: ClassVar[str] = "ContactSet"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.CONTACTS

    positions_m: np.ndarray = array(("n", 3), "float64", "contact points, world frame", "m")
    local_positions_m: np.ndarray = array(
        ("n", 3), "float64", "contact points in the frame of the touching link (where the touch is felt)", "m"
    )
    normals: np.ndarray = array(("n", 3), "float64", "unit surface normals, pointing out of the object")
    forces_n: np.ndarray = array(("n",), "float64", "normal contact force", "N")
    links: list[str] = strings("effector link (body) of each contact", "n")


class Trajectory(Message):
    """A cubic Bezier curve for the fingertip (paper 002, Eq. 15 approach or Eq. 17 recovery)."""

    TYPE: ClassVar[str] = "Trajectory"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.TRAJECTORY

    kind: str = scalar(
        "str", "'initial', 'approach' (Eq. 15), 'recovery' (Eq. 17) or 'slide' (a straight line along the surface)"
    )
    control_points_m: np.ndarray = array((4, 3), "float64", "Bezier control points p0..p3, world frame", "m")
    start_quaternion_wxyz: np.ndarray = array((4,), "float64", "fingertip orientation at the start")
    end_quaternion_wxyz: np.ndarray = array((4,), "float64", "fingertip orientation at the target")
    length_m: float = scalar("float", "arc length of the curve", "m")


#: The largest ``TouchTarget.miss_distance_m`` a controller accepts, metres: past it a missed touch would
#: wander far from the object.
MAX_MISS_DISTANCE_M = 0.2


class TouchTarget(Message):
    """The next best touch chosen by the planner, with the candidates it scored."""

    TYPE: ClassVar[str] = "TouchTarget"
    VERSION: ClassVar[int] = 3
    TOPIC: ClassVar[str] = topics.TOUCH_TARGET

    strategy: str = scalar("str", "'igef', 'gpv', 'random', 'area' or 'tour'")
    position_m: np.ndarray = array((3,), "float64", "target point on the estimated surface", "m")
    normal: np.ndarray = array((3,), "float64", "estimated outward surface normal at the target")
    predicted_contact_m: np.ndarray = array((3,), "float64", "where the planner expects the contact", "m")
    score: float = scalar("float", "score of the chosen candidate")
    candidates_m: np.ndarray = array(("m", 3), "float64", "scored candidate points", "m")
    candidate_scores: np.ndarray = array(("m",), "float64", "score of each candidate")
    slide: bool = scalar(
        "bool",
        "reach the target by sliding along the surface from the last contact instead of the Eq. 15 curve "
        "(version 2; not in the paper)",
        default=False,
    )
    miss_distance_m: float = scalar(
        "float",
        "how far past the target the fingertip may go without a contact before the recovery curve "
        "(Delta_m of Algorithm 1 line 26), 0 to 0.2; 0: the controller's own (version 3; not in the paper)",
        "m",
        default=0.0,
    )


class TouchEvent(Message):
    """The controller reached a contact: the contact joins the contact set C of Algorithm 1."""

    TYPE: ClassVar[str] = "TouchEvent"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.EXPLORATION_EVENT

    index: int = scalar("int", "contact number, 0 for the first touch")
    position_m: np.ndarray = array((3,), "float64", "measured contact position", "m")
    normal: np.ndarray = array((3,), "float64", "measured outward unit normal")
    approach_direction: np.ndarray = array((3,), "float64", "unit velocity just before contact (v_n)")
    predicted_contact_m: np.ndarray = array(
        (3,), "float64", "planner's predicted contact (NaN for the first touch)", "m", finite=False
    )
    missed: bool = scalar("bool", "true when the curve ended without contact and recovery was needed")
    travelled_m: float = scalar("float", "fingertip path length since the start of the run", "m")
    rotation_deg: float = scalar("float", "accumulated fingertip rotation since the start", "deg")


class SurfaceMesh(Message):
    """Triangulated estimated surface (marching cubes of the GPIS zero level set)."""

    TYPE: ClassVar[str] = "SurfaceMesh"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 2
    TOPIC: ClassVar[str] = topics.SURFACE_MESH

    region: str = scalar("str", "'local' (near the latest contact) or 'global' (whole object)")
    num_contacts: int = scalar("int", "contacts in the estimate")
    vertices_m: np.ndarray = array(("v", 3), "float64", "vertex positions, world frame", "m")
    faces: np.ndarray = array(("f", 3), "int32", "vertex indices of each triangle, counter-clockwise from outside")
    vertex_normals: np.ndarray = array(("v", 3), "float64", "unit outward normals from the GP gradient")
    variance_vertices: np.ndarray = array(
        ("k",), "int32", "ascending indices of the vertices vertex_variance belongs to (every vertex, or the "
        "planner's candidates near the latest contact, or none)"
    )  # fmt: skip
    vertex_variance: np.ndarray = array(("k",), "float64", "GP posterior variance at those vertices", "m^2")


class SurfaceRequest(Message):
    """Ask the surface estimator for a mesh of a region. The estimator answers each request with one
    SurfaceMesh of that region, in the order asked."""

    TYPE: ClassVar[str] = "SurfaceRequest"
    VERSION: ClassVar[int] = 2
    TOPIC: ClassVar[str] = topics.SURFACE_REQUEST

    region: str = scalar("str", "'global' for the whole object")
    variance: bool = scalar("bool", "true when the mesh must carry the GP variance at every vertex (costly: Eq. 6)")


class OccupancyGrid(Message):
    """Sparse 3D log-odds occupancy grid: only cells that were ever updated travel."""

    TYPE: ClassVar[str] = "OccupancyGrid"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.OCCUPANCY_GRID

    map_kind: str = scalar("str", "'known', 'dead_reckoning', 'best' (best particle) or 'weighted'")
    origin_m: np.ndarray = array((3,), "float64", "world position of the corner of cell (0, 0, 0)", "m")
    resolution_m: float = scalar("float", "cell edge length", "m")
    shape: np.ndarray = array((3,), "int64", "cells along x, y, z")
    cell_indices: np.ndarray = array(("n",), "int64", "flat C-order cell indices of the cells sent")
    log_odds: np.ndarray = array(("n",), "float32", "log-odds of occupancy of each cell sent")


class ParticleSetSummary(Message):
    """State of the FastSLAM particle filter after an update."""

    TYPE: ClassVar[str] = "ParticleSetSummary"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.PARTICLES

    num_particles: int = scalar("int", "K")
    effective_sample_size: float = scalar("float", "1 / sum(w^2) of the normalised weights")
    best_index: int = scalar("int", "index of the particle of largest weight")
    resampled: bool = scalar("bool", "true when this update resampled")
    joint_names: list[str] = strings("finger joints", "j")
    pose_mean_rad: np.ndarray = array(("j",), "float64", "weighted mean joint angles", "rad")
    pose_best_rad: np.ndarray = array(("j",), "float64", "joint angles of the best particle", "rad")
    weights: np.ndarray = array(("k",), "float64", "normalised particle weights")


class ObjectTruth(Message):
    """Ground truth of the object: identity, pose and mesh (published once, at the run's first tick, on a
    truth/ topic; the evaluator ends a run without one after 5 s). The mesh is the object's closed surface
    in the world frame (metres), its triangles wound counter-clockwise seen from outside."""

    TYPE: ClassVar[str] = "ObjectTruth"
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.TRUTH_OBJECT

    name: str = scalar("str", "object name, e.g. 'torus' or '011_banana'")
    source: str = scalar("str", "mesh file path, or 'primitive'")
    position_m: np.ndarray = array((3,), "float64", "object position", "m")
    quaternion_wxyz: np.ndarray = array((4,), "float64", "object orientation")
    vertices_m: np.ndarray = array(("v", 3), "float64", "mesh vertices, world frame", "m")
    faces: np.ndarray = array(("f", 3), "int32", "mesh triangles")


class NodeStatus(Message):
    """Health and counters of a node, published periodically and at exit."""

    TYPE: ClassVar[str] = "NodeStatus"
    STATE: ClassVar[bool] = True
    VERSION: ClassVar[int] = 1
    TOPIC: ClassVar[str] = topics.NODE_STATUS

    node: str = scalar("str", "node name")
    state: str = scalar("str", "'running', 'finished' or 'error'")
    message: str = scalar("str", "last notable event, empty when none")
    counter_names: list[str] = strings("names of the counters", "c")
    counter_values: np.ndarray = array(("c",), "int64", "counter values (messages in, decode errors, ...)")
    metric_names: list[str] = strings("names of the metrics", "q")
    metric_values: np.ndarray = array(("q",), "float64", "metric values, units in their names", finite=False)
