"""Named errors. Each message says what is wrong and what to do about it."""

from __future__ import annotations


class PalpateError(Exception):
    """Base class of every error palpate raises on purpose."""


# --- messages -------------------------------------------------------------------------------------
class MessageError(PalpateError):
    """A message could not be decoded or does not match its schema."""


class MalformedMessageError(MessageError):
    """The bytes are not a palpate envelope, or a field is missing, extra or of the wrong type."""


class UnknownMessageTypeError(MessageError):
    """The envelope names a message type this build does not know."""


class SchemaVersionError(MessageError):
    """The envelope's schema version differs from the version this build speaks."""


class NonFiniteError(MessageError):
    """A field that must be finite holds NaN or infinity."""


class OutputError(MessageError):
    """A node tried to publish a message that breaks its own schema: a bug in that node, not bad input.
    The runtime counts it in ``output_errors`` and lets it end the node (it is never taken for a
    rejected input)."""


class InputError(PalpateError):
    """A message decoded (it matches its schema) but holds values a node cannot use: a zero quaternion,
    a joint state without the joints the node needs, a target farther than any workspace.

    ``field`` names the message field (``quaternion_wxyz``, ``names``), ``reason`` says what is wrong
    with it. The runtime counts the message in the node's ``input_errors``, logs node, topic, field and
    reason, and the node goes on with the state it had before the message.
    """

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


# --- configuration and launch ---------------------------------------------------------------------
class ConfigError(PalpateError):
    """A node's parameters are missing, unknown, of the wrong type or out of range.

    ``path`` is the key path of the offending value (``("scene", "object", "size_m", 0)``) when the
    error came from palpate.config, so that a launch file error can name the line of that key.
    """

    def __init__(self, message: str, path: tuple[str | int, ...] = ()) -> None:
        super().__init__(message)
        self.path = path


class BusError(PalpateError):
    """The bus cannot be used safely: an unsafe bus directory, or an unreadable CurveZMQ key file."""


class LaunchError(PalpateError):
    """A launch file is invalid or a launched graph failed."""


class PeerLostError(PalpateError):
    """A lockstep node the run depends on disconnected without a stop: its process died or closed its sockets."""


# --- simulation and geometry ----------------------------------------------------------------------
class MeshError(PalpateError):
    """A mesh file is missing, unreadable, degenerate or at an absurd scale."""


class SimulationDivergedError(PalpateError):
    """The physics produced non-finite state, usually because the time step is too large."""


# --- estimation -----------------------------------------------------------------------------------
class EstimationError(PalpateError):
    """An estimator was given input it cannot use (for example a zero-length normal)."""


# --- exploration planning and control -------------------------------------------------------------
class PlanningError(PalpateError):
    """The planner or trajectory controller cannot act (no candidate target, degenerate inputs)."""


# --- warnings -------------------------------------------------------------------------------------
class MeshWarning(UserWarning):
    """A mesh loads but some results on it are unreliable (for example it is not watertight)."""


# --- benchmarks -----------------------------------------------------------------------------------
class BenchmarkError(PalpateError):
    """A benchmark could not run to the end (a helper process died, timed out or lost messages)."""


class ClusterError(PalpateError):
    """Runs on Dask cannot go on: the scheduler is unreachable, no worker joined, or runs failed for good."""


# --- message logs ---------------------------------------------------------------------------------
class RecordError(PalpateError):
    """A message log (MCAP) is missing, unreadable, truncated or holds no usable messages."""


# --- viewer ---------------------------------------------------------------------------------------
class ViewerError(PalpateError):
    """`palpate view` cannot run: the viewer extra is missing, there is no display, or the source is unusable."""
