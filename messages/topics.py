"""Topic names. Nodes use these constants (or their remapped names from the launch file), never literals.

Topics under `truth/` carry ground truth from the simulator; the launch validator refuses to wire them
into a node unless the launch file marks that node as an evaluator.
"""

CLOCK = "clock"
LOCKSTEP_ACK = "lockstep/ack"
NODE_STATUS = "status"
GRAPH_CONTROL = "graph/control"
#: The runtime's own topics (lockstep, stop, status): no node port is wired to them, a replay never
#: republishes them.
RUNTIME_TOPICS = (CLOCK, LOCKSTEP_ACK, NODE_STATUS, GRAPH_CONTROL)
#: Prefix of hello/<node>, the topic each node subscribes to on every publisher it connects to.
HELLO_PREFIX = "hello/"

JOINT_STATES = "sensors/joint_states"
JOINT_COMMANDS = "commands/joints"
EFFECTOR_POSE = "sensors/effector_pose"
VELOCITY_COMMANDS = "commands/velocity"
CONTACTS = "sensors/contacts"

NOISY_JOINT_STATES = "sensors/joint_states_noisy"
NOISY_CONTACTS = "sensors/contacts_noisy"

TRUTH_PREFIX = "truth/"
TRUTH_JOINT_STATES = "truth/joint_states"
TRUTH_OBJECT = "truth/object"

OCCUPANCY_GRID = "map/occupancy"
WEIGHTED_OCCUPANCY_GRID = "map/occupancy_weighted"
PARTICLES = "map/particles"

SURFACE_MESH = "surface/mesh"
SURFACE_REQUEST = "surface/request"
TOUCH_TARGET = "planner/target"
TRAJECTORY = "controller/trajectory"
EXPLORATION_EVENT = "controller/events"


def is_truth(topic: str) -> bool:
    """True for ground-truth topics, which only evaluator nodes may subscribe to."""
    return topic.lstrip("/").startswith(TRUTH_PREFIX)
