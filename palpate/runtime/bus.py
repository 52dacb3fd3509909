"""The bus: brokerless ZeroMQ publish/subscribe with one publisher socket per node.

Why brokerless: every message takes one hop (publisher to subscriber), so latency is that of raw
pyzmq plus the codec, and a dead broker cannot take the graph down. Each node binds one XPUB socket
(at ``ipc://<bus dir>/<node>.pub`` by default, or a TCP address for nodes on other hosts) and
connects one SUB socket to the publishers of the topics it reads. One socket per node means that
everything a node sends to another travels over one connection, in order: the lockstep protocol
relies on that. Frames are ``[topic, payload]``.

Discovery: the launcher wires static graphs. Each running node also writes a manifest
``<bus dir>/<node>.json`` (endpoint, topics, types), so tools started in another terminal
(`palpate topic echo`, `record`, `replay`) find the same bus with or without a launch.

Tools get their sockets here too, so that zmq stays in the runtime: `PublisherTap` (one SUB socket
per publisher, for echo, the viewer and the recorder) and `BlockingPublisher` (the log player).

Security: the default bus directory is private to the user (`default_bus_dir`, `private_dir`); a
CurveZMQ publisher admits only the client keys the launcher lists (`ClientAllowList`, a ZAP handler).
"""

from __future__ import annotations

import contextlib
import difflib
import errno
import hashlib
import json
import logging
import os
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import zmq
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils import z85
from zmq.utils.monitor import recv_monitor_message

from palpate import locks
from palpate.errors import BusError
from palpate.messages import topics as topic_names
from palpate.paths import read_start, why_not

log = logging.getLogger("palpate.bus")

#: Environment variable naming the bus directory (ipc sockets and manifests).
BUS_ENV = "PALPATE_BUS"
#: The XDG base-directory variable of the per-user runtime directory (sockets belong there).
RUNTIME_DIR_ENV = "XDG_RUNTIME_DIR"


def default_bus_dir() -> Path:
    """``$PALPATE_BUS``; else ``$XDG_RUNTIME_DIR/palpate/default`` (the per-user runtime directory, 0700 by
    the XDG specification); else ``<temp dir>/palpate-<uid>/default``. The directory above ``default`` is
    created 0700 or checked to be a directory of this user that no one else can enter (`private_dir`),
    since anyone who can reach the ipc sockets can talk to the graph."""
    configured = os.environ.get(BUS_ENV)
    if configured:
        path = usable_dir(Path(configured))
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BusError(unwritable(path, exc)) from exc
        return path
    runtime = os.environ.get(RUNTIME_DIR_ENV)
    if runtime and Path(runtime).is_absolute() and Path(runtime).is_dir():
        base = Path(runtime) / "palpate"
    else:
        base = Path(tempfile.gettempdir()) / f"palpate-{os.getuid()}"
    path = private_dir(base) / "default"
    path.mkdir(mode=0o700, exist_ok=True)
    return path


#: A relative bus directory is made absolute when a socket of a node name this long still fits there.
ROOM_FOR_NAME = 32


def usable_dir(path: Path) -> Path:
    """`path`, a directory or one that can be made (else BusError naming the file in the way), made
    absolute, so that the ipc endpoints in its manifests and an external node's spec hold from any
    working directory; left relative when the absolute path leaves no room for a socket's name (a short
    relative --bus is the way round the OS's 107-byte limit)."""
    absolute = path.absolute()
    if len(os.fsencode(absolute)) + 1 + ROOM_FOR_NAME + len(".pub") <= zmq.IPC_PATH_MAX_LEN:
        path = absolute
    existing = next(p for p in (path, *path.parents) if p.exists())
    if not existing.is_dir():
        what = f"bus directory {path}" + (f": {existing}" if existing != path else "")
        raise BusError(f"{what} is not a directory; choose a bus directory with --bus DIR or ${BUS_ENV}")
    return path


def limit_hint(exc: OSError) -> str:
    """For an error of a per-process limit, which limit to raise ('' for another error)."""
    if exc.errno in (errno.EMFILE, errno.ENFILE):
        return " (the limit of open files: raise it with `ulimit -n`, each node holds a few dozen)"
    if exc.errno == errno.EAGAIN:
        return " (the limit of processes or threads: raise it with `ulimit -u`)"
    return ""


def unwritable(folder: Path, exc: OSError) -> str:
    """What to tell a user whose bus directory cannot be made or written (another user's folder, a full disk)."""
    return (
        f"cannot write the bus directory {folder} ({why_not(exc)}); give one you can write, "
        f"with room on its disk, with --bus DIR or ${BUS_ENV}"
    )


def private_dir(path: Path) -> Path:
    """Create `path` as a directory only its owner can enter (mode 0700), or check that it already is one:
    a real directory (not a symlink), owned by this user; group and other permissions are removed.

    Raises BusError saying what is wrong and what to do. In a shared temp dir (sticky, like /tmp) no
    other user can replace the directory once it is checked.
    """
    with contextlib.suppress(FileExistsError):
        os.mkdir(path, 0o700)
    info = os.lstat(path)
    fix = f"remove it, or choose a bus directory with --bus DIR or ${BUS_ENV}"
    if stat.S_ISLNK(info.st_mode) or not stat.S_ISDIR(info.st_mode):
        kind = "symlink" if stat.S_ISLNK(info.st_mode) else "file"
        raise BusError(f"bus directory {path} is not a directory but a {kind}; {fix}")
    if info.st_uid != os.getuid():
        raise BusError(f"bus directory {path} belongs to uid {info.st_uid}, not to you (uid {os.getuid()}); {fix}")
    if info.st_mode & 0o077:  # yours, but open (made by an older palpate): close it
        log.warning("bus directory %s had mode %o; setting it to 700", path, stat.S_IMODE(info.st_mode))
        os.chmod(path, 0o700)
    return path


def ipc_path(endpoint: str) -> Path | None:
    """The socket file of an ``ipc://`` endpoint (None for TCP)."""
    return Path(endpoint[len("ipc://") :]) if endpoint.startswith("ipc://") else None


def remove_ipc_file(endpoint: str) -> None:
    """Delete the socket file of a closed ``ipc://`` publisher at once (ZeroMQ unlinks it later, in its
    I/O thread, and not at all when the process exits first); nothing for TCP endpoints."""
    path = ipc_path(endpoint)
    if path is not None:
        with contextlib.suppress(NotADirectoryError):  # no socket file can be there
            path.unlink(missing_ok=True)


def ipc_endpoint(bus_dir: str | Path, name: str) -> str:
    """The loopback-only ipc address of a publisher called `name`; BusError if the OS cannot bind it (the
    path is longer than ``zmq.IPC_PATH_MAX_LEN``, 107 bytes on Linux)."""
    path = Path(bus_dir) / f"{name}.pub"
    if len(os.fsencode(path)) > zmq.IPC_PATH_MAX_LEN:
        raise BusError(
            f"the socket path {path} is {len(os.fsencode(path))} bytes, longer than the {zmq.IPC_PATH_MAX_LEN} the "
            f"OS allows; choose a shorter bus directory (--bus DIR or ${BUS_ENV})"
        )
    return f"ipc://{path}"


@dataclass(frozen=True)
class Manifest:
    """What a running publisher advertises in the bus directory."""

    node: str
    endpoint: str
    pid: int
    publishes: dict[str, str]  # topic -> message type
    subscribes: dict[str, str]
    #: CurveZMQ public key (z85) of the publisher when it is a Curve server, else "": a subscriber
    #: (the recorder) needs it, and any client key pair, to connect.
    curve_public: str = ""

    @staticmethod
    def path(bus_dir: str | Path, node: str) -> Path:
        """Where node ``node`` writes its manifest on the bus ``bus_dir``."""
        return Path(bus_dir) / f"{node}.json"

    def write(self, bus_dir: str | Path) -> Path:
        """Write the manifest (BusError naming the folder when it cannot be written: a full disk)."""
        path = Manifest.path(bus_dir, self.node)
        tmp = path.with_suffix(".json.tmp")
        try:
            Path(bus_dir).mkdir(parents=True, exist_ok=True)  # a graph of TCP nodes only has no ipc socket there
            tmp.write_text(json.dumps(asdict(self), sort_keys=True))
            tmp.replace(path)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise BusError(unwritable(Path(bus_dir), exc)) from exc
        return path


def undeclared(topic: str, manifests: Sequence[Manifest]) -> str | None:
    """What to tell a user who asks for a topic that none of the running publishers declares (a typo
    records, echoes or measures nothing), with the closest declared topic; None when one declares it,
    when it is one of the runtime's own topics, or when no publisher is running yet."""
    if not manifests or topic in topic_names.RUNTIME_TOPICS or topic.startswith(topic_names.HELLO_PREFIX):
        return None
    declared = sorted({t for m in manifests for t in m.publishes})
    if topic in declared:
        return None
    close = difflib.get_close_matches(topic, declared, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"no publisher on the bus declares topic {topic!r}{hint}; see palpate topic list"


class UndeclaredTopics:
    """Tells, once per asked-for topic, that no running publisher declares it (``undeclared``), but only
    once the running publishers have stayed the same for ``settle_s``: a graph that is starting writes
    its nodes' manifests one by one. Given ``bus_dir``, ``empty_bus_note`` tells once that the bus has
    had no publisher at all for ``settle_s``."""

    def __init__(self, wanted: Sequence[str], bus_dir: str | Path | None = None, settle_s: float = 2.0) -> None:
        self.wanted, self.settle_s = list(wanted), settle_s
        self.bus_dir = None if bus_dir is None else Path(bus_dir)
        self.told: set[str] = set()
        self._running: frozenset[str] | None = None
        self._since = 0.0
        self._empty_since: float | None = None  # since when the bus has had no publisher
        self._told_empty = False

    def notes(self, manifests: Sequence[Manifest], now_s: float) -> list[str]:
        """What to tell now, given the manifests read at monotonic time ``now_s``."""
        running = frozenset(m.endpoint for m in manifests)
        if running != self._running:
            self._running, self._since = running, now_s
            return []
        if now_s - self._since < self.settle_s:
            return []
        out = []
        for topic in self.wanted:
            if topic not in self.told and (note := undeclared(topic, manifests)):
                self.told.add(topic)
                out.append(note)
        return out

    def empty_bus_note(self, manifests: Sequence[Manifest], now_s: float) -> str | None:
        """Once, when the bus (``bus_dir``) has had no publisher for ``settle_s``: a wrong --bus waits
        silently otherwise."""
        if manifests or self._told_empty or self.bus_dir is None:
            self._empty_since = None
            return None
        if self._empty_since is None:  # the first look starts the wait
            self._empty_since = now_s
            return None
        if now_s - self._empty_since < self.settle_s:
            return None
        self._told_empty = True
        where = "" if self.bus_dir.is_dir() else ", a folder that does not exist yet"
        return (
            f"no publisher on bus {self.bus_dir}{where}; waiting for a graph launched with --bus {self.bus_dir} "
            "(palpate node list shows a bus's publishers)"
        )


def read_manifests(bus_dir: str | Path) -> list[Manifest]:
    """Manifests of live publishers (entries whose process is gone are skipped)."""
    manifests = []
    try:
        paths = sorted(Path(bus_dir).glob("*.json"))
    except OSError as exc:
        raise BusError(f"cannot read bus directory {bus_dir}: {exc.strerror}{limit_hint(exc)}") from exc
    for path in paths:
        try:
            manifest = Manifest(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError):
            continue
        if alive(manifest.pid):
            manifests.append(manifest)
    return manifests


class NameClaim:
    """This process's exclusive claim on node names in a bus directory: a lock file per name
    (``<name>.lock``, holding the claimant's pid) locked with flock, so that two graphs launched on one
    bus directory cannot bind each other's ipc sockets. The system drops the locks when the process
    ends, however it ends; ``release`` drops them earlier."""

    def __init__(self, bus_dir: str | Path, names: Iterable[str]) -> None:
        self.files: list[Any] = []
        folder = Path(bus_dir)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for name in sorted(set(names)):
                try:
                    self.files.append(locks.hold(folder / f"{name}.lock"))
                except OSError as exc:
                    raise BusError(unwritable(folder, exc)) from exc
                except locks.LockHeldError as held:
                    raise BusError(
                        f"node name {name!r} is in use on the bus directory {folder} by another running graph "
                        f"(process {held.holder}); stop that graph, or give this one its own bus directory with "
                        "--bus DIR (palpate topic, record and the viewer then take --bus DIR too)"
                    ) from None
        except OSError as exc:  # the folder could not be made
            self.release()
            raise BusError(unwritable(folder, exc)) from exc
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Drop every claim (idempotent)."""
        for handle in self.files:
            handle.close()  # closing drops the flock; the file stays for the next claimant
        self.files = []


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def publishers_of(bus_dir: str | Path, topics: list[str] | None = None) -> dict[str, list[Manifest]]:
    """Live publishers by topic, optionally only of `topics`."""
    found: dict[str, list[Manifest]] = {}
    for manifest in read_manifests(bus_dir):
        for topic in manifest.publishes:
            if topics is None or topic in topics:
                found.setdefault(topic, []).append(manifest)
    return found


def make_curve_keys(server_public: str | None = None) -> dict[str, str]:
    """A new CurveZMQ key pair as z85 text, with the publisher key its subscriber will trust
    (`server_public`; default: the new pair's own public key, a graph key)."""
    if not zmq.has("curve"):
        raise RuntimeError("this libzmq was built without CurveZMQ support")
    public, secret = zmq.curve_keypair()
    keys = {"public": public.decode(), "secret": secret.decode()}
    keys["server_public"] = server_public or keys["public"]
    return keys


def derived_curve_keys(label: str, secrets: Sequence[str]) -> dict[str, str]:
    """A CurveZMQ key pair that is a function of ``label`` and the graph's secret keys (z85): the same
    pair wherever the same key files are read (a launch and its ``--spec`` for a remote node agree on
    the recorder's key without exchanging it), unknown to anyone without those secrets."""
    if not zmq.has("curve"):
        raise RuntimeError("this libzmq was built without CurveZMQ support")
    material = "\n".join([label, *sorted(secrets)]).encode()
    secret = z85.encode(hashlib.sha256(material).digest())
    return {"public": zmq.curve_public(secret).decode(), "secret": secret.decode()}


def client_curve(server_public: str, client_keys: Mapping[str, str] | None = None) -> dict[str, str]:
    """Curve keys for a subscriber of a publisher whose server key is ``server_public``: the client key pair
    `client_keys` (``public``, ``secret``; a key file the graph admits), or a fresh pair, which a
    publisher with an allow-list refuses; {} when ``server_public`` is empty (no Curve)."""
    if not server_public:
        return {}
    if client_keys:
        return {"public": client_keys["public"], "secret": client_keys["secret"], "server_public": server_public}
    public, secret = zmq.curve_keypair()
    return {"public": public.decode(), "secret": secret.decode(), "server_public": server_public}


#: A key file is about 150 bytes; one larger than this is refused unread.
MAX_KEY_FILE_BYTES = 65_536


def is_z85_key(text: str) -> bool:
    """Whether `text` is a 32-byte CurveZMQ key in z85 (40 characters of ZeroMQ's alphabet)."""
    try:
        return len(text) == 40 and len(z85.decode(text)) == 32
    except (KeyError, ValueError):  # a character outside the alphabet
        return False


def read_key_file(path: str | Path) -> dict[str, str]:
    """The z85 keys of a key file written by `palpate keys` ({"public", "secret", "server_public"})."""
    try:
        data = read_start(Path(path).expanduser(), MAX_KEY_FILE_BYTES + 1)
        if len(data) > MAX_KEY_FILE_BYTES:
            raise ValueError(f"larger than {MAX_KEY_FILE_BYTES:,} bytes: not a key file")
        keys = json.loads(data)
    except (OSError, ValueError) as exc:
        raise BusError(f"cannot read CurveZMQ key file {str(path)!r}: {exc}") from exc
    if not isinstance(keys, dict) or {"public", "secret"} - set(keys):
        raise BusError(
            f"CurveZMQ key file {str(path)!r} lacks 'public' and 'secret' keys; write one with `palpate keys`"
        )
    return {k: str(v) for k, v in keys.items() if k in ("public", "secret", "server_public")}


def apply_curve(socket: zmq.Socket[Any], curve: dict[str, str], *, server: bool) -> None:
    """Authenticate and encrypt a TCP socket with CurveZMQ keys (z85 text) when `curve` has them.

    Publishers are Curve servers (their `secret`); subscribers are clients that know the
    publisher's `server_public` key. Generate keys with `palpate keys`.
    """
    if not curve:
        return
    socket.curve_secretkey = curve["secret"].encode()
    socket.curve_publickey = curve["public"].encode()
    if server:
        socket.curve_server = True
    else:
        socket.curve_serverkey = curve["server_public"].encode()


class ClientAllowList:
    """The ZAP handler of one zmq context: each Curve publisher of the context admits only the client
    public keys listed for it, and refuses every other client during the Curve handshake.

    Without a ZAP handler a Curve server admits any client that knows its public key. A publisher
    registers with `admit(sock, endpoint, keys)` before it binds; its ZAP domain is its endpoint.
    `close()` stops the handler's thread (before the context is terminated).
    """

    def __init__(self, ctx: zmq.Context[Any]):
        self._allowed: dict[str, frozenset[bytes]] = {}
        self._refused: set[tuple[str, bytes]] = set()
        self._auth = ThreadAuthenticator(ctx, log=logging.getLogger("palpate.bus.zap"))
        self._auth.start()

    def admit(self, sock: zmq.Socket[Any], domain: str, client_keys: Iterable[str]) -> None:
        """Let only `client_keys` (z85 public keys) connect to `sock`, a Curve server not bound yet."""
        sock.zap_domain = domain.encode()
        self._allowed[domain] = frozenset(k.encode() for k in client_keys)
        self._auth.configure_curve_callback(domain, self)

    def callback(self, domain: str, client_key: bytes) -> bool:
        """ZAP's question, in the handler's thread: may the client with this z85 key connect?"""
        if client_key in self._allowed.get(domain, frozenset()):
            return True
        if (domain, client_key) not in self._refused:  # log each refused client once
            self._refused.add((domain, client_key))
            log.warning(
                "publisher %s refused a CurveZMQ client whose key %s it does not list", domain, client_key.decode()
            )
        return False

    def close(self) -> None:
        self._auth.stop()


#: ZMTP heartbeats on the bus's TCP sockets: a PING each interval, and a connection whose peer has not
#: answered for the timeout is closed. A peer whose host vanished (power, cable, a VM gone: no TCP FIN)
#: is then dropped like one that closed its sockets; the publisher sees its subscriptions go, so a
#: lockstep graph notices that the node left (runtime.node.PEER_GRACE_S). ZeroMQ's I/O threads answer
#: the PINGs, so a node busy in Python for longer is not dropped, unless its receive queue is full
#: (a real-time subscriber 1000 messages behind stops reading its socket: it is dropped and reconnects,
#: losing what was queued, as real time drops messages anyway; lockstep queues are unbounded). Over
#: ipc the kernel closes a dead process's sockets itself: no heartbeats there.
HEARTBEAT_INTERVAL_MS = 1000
HEARTBEAT_TIMEOUT_MS = 5000


def keep_alive(
    sock: zmq.Socket[Any], interval_ms: int = HEARTBEAT_INTERVAL_MS, timeout_ms: int = HEARTBEAT_TIMEOUT_MS
) -> None:
    """Turn on ZMTP heartbeats (see HEARTBEAT_TIMEOUT_MS) before `sock` binds or connects over TCP."""
    sock.setsockopt(zmq.HEARTBEAT_IVL, interval_ms)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, timeout_ms)
    sock.setsockopt(zmq.HEARTBEAT_TTL, timeout_ms)


def make_publisher(
    ctx: zmq.Context[Any],
    endpoint: str,
    *,
    lockstep: bool,
    curve: dict[str, str] | None = None,
    send_hwm: int | None = None,
    block_when_full: bool = False,
    linger_ms: int = 2000,
    send_timeout_ms: int | None = None,
    allow: ClientAllowList | None = None,
    curve_clients: Iterable[str] = (),
) -> zmq.Socket[Any]:
    """An XPUB socket bound to `endpoint` that reports every subscription (for start-up counting).

    With `curve` keys it is a Curve server that admits only the client public keys `curve_clients`,
    checked by the context's ZAP handler `allow` (required with `curve`).

    In lockstep the high-water mark is unlimited, so nothing is ever dropped; the protocol bounds
    what is in flight to one tick. Otherwise `send_hwm` messages per subscriber (None: ZeroMQ's
    default) are queued; beyond that a send drops the message, or with `block_when_full`
    (XPUB_NODROP) waits, up to `send_timeout_ms` (None: forever), and then raises zmq.Again.
    `linger_ms`: how long closing waits for queued messages to leave.
    """
    sock = ctx.socket(zmq.XPUB)
    if endpoint.startswith("tcp://"):
        keep_alive(sock)
    sock.setsockopt(zmq.XPUB_VERBOSE, 1)
    sock.setsockopt(zmq.LINGER, linger_ms)
    if lockstep:
        sock.setsockopt(zmq.SNDHWM, 0)
    elif send_hwm is not None:
        sock.setsockopt(zmq.SNDHWM, send_hwm)
    if block_when_full:
        sock.setsockopt(zmq.XPUB_NODROP, 1)
    if send_timeout_ms is not None:
        sock.setsockopt(zmq.SNDTIMEO, send_timeout_ms)
    if curve:
        if allow is None:
            sock.close(linger=0)
            raise ValueError("a CurveZMQ publisher needs a ClientAllowList: publishers admit listed clients only")
        allow.admit(sock, endpoint, curve_clients)
    apply_curve(sock, curve or {}, server=True)
    if endpoint.startswith("ipc://"):
        Path(endpoint[len("ipc://") :]).parent.mkdir(parents=True, exist_ok=True)
    try:
        sock.bind(endpoint)
    except zmq.ZMQError as exc:
        sock.close(linger=0)
        hint = (
            "the host must be an address of this machine and the port free (a node's host: and port: in the "
            "launch file, or the launch file's host arguments)"
            if endpoint.startswith("tcp://")
            else "check the bus directory (--bus)"
        )
        raise BusError(f"cannot bind {endpoint}: {exc.strerror}; {hint}") from exc
    return sock


def make_subscriber(
    ctx: zmq.Context[Any],
    endpoints: list[str],
    topics: list[str],
    *,
    lockstep: bool,
    curve: dict[str, str] | None = None,
) -> zmq.Socket[Any]:
    """A SUB socket connected to `endpoints` and subscribed to `topics` (all when the list is empty)."""
    sock = ctx.socket(zmq.SUB)
    if any(e.startswith("tcp://") for e in endpoints):
        keep_alive(sock)
    sock.setsockopt(zmq.LINGER, 0)
    if lockstep:
        sock.setsockopt(zmq.RCVHWM, 0)
    apply_curve(sock, curve or {}, server=False)
    for topic in topics or [""]:
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
    for endpoint in endpoints:
        sock.connect(endpoint)
    return sock


class TapEvents(NamedTuple):
    """What a `PublisherTap.poll` found: endpoints with messages queued, endpoints whose connection changed."""

    messages: list[str]
    connections: list[str]


#: Messages a never-drop tool (the recorder) queues per publisher. Finite, so that a publisher that waits
#: when its queue is full (``BlockingPublisher``: ``palpate replay --fast``) is held back by the tool: with
#: an unbounded queue on either side ZeroMQ's pipe has no limit, and a fast replay into ``palpate record``
#: piled the whole log up in both processes (1.7 GB for a 242 MB log). A real-time publisher that does not
#: wait drops beyond its own queue and this one (minutes of backlog at the graph's rates).
NEVER_DROP_QUEUE = 100_000


class PublisherTap:
    """For tools that watch a running graph (topic echo/hz, the live viewer, the recorder): one SUB
    socket per publisher, so a message's publisher is known, keyed with the publisher's CurveZMQ
    server key when it has one.

    Tools subscribe to every topic by default (filtering is the caller's: a subscription by name
    would add to the subscriber counts nodes wait for at start-up). With `never_drop` each receive
    queue holds up to NEVER_DROP_QUEUE messages (the recorder must see every message: a lockstep
    publisher's queue is unbounded on its side, and one that waits when full, such as ``palpate replay``,
    waits for the tool instead of filling both processes' memory); with `monitor` each socket reports
    when its publisher connects and disconnects (`connection_changes`).
    """

    def __init__(
        self, *, never_drop: bool = False, monitor: bool = False, client_keys: Mapping[str, str] | None = None
    ) -> None:
        self.context: zmq.Context[Any] = zmq.Context()
        #: the Curve client key pair for keyed publishers (they admit only the keys their launch lists)
        self.client_keys = dict(client_keys or {})
        self.poller = zmq.Poller()
        self.never_drop = never_drop
        self.monitor = monitor
        self.socks: dict[str, zmq.Socket[Any]] = {}
        self.monitors: dict[str, zmq.Socket[Any]] = {}
        self._endpoint_of: dict[zmq.Socket[Any], str] = {}
        self._monitored: dict[zmq.Socket[Any], str] = {}

    @property
    def endpoints(self) -> set[str]:
        """Publisher endpoints connected so far."""
        return set(self.socks)

    def connect(self, manifests: Iterable[Manifest]) -> None:
        """Connect to the publishers of these manifests not connected yet, subscribed to every topic."""
        for m in manifests:
            if m.endpoint not in self.socks:
                self.add(m.endpoint, server_public=m.curve_public)

    def add(self, endpoint: str, topics: Sequence[str] = ("",), *, server_public: str = "") -> None:
        """Connect a new socket to the publisher at `endpoint`, subscribed to `topics` (prefixes; "": all)."""
        sock = self.context.socket(zmq.SUB)
        if server_public and not self.client_keys:
            log.warning(
                "publisher %s uses CurveZMQ and admits only the client keys its launch lists: give this tool "
                "a key file of the graph (--curve-keys FILE) to hear it",
                endpoint,
            )
        apply_curve(sock, client_curve(server_public, self.client_keys), server=False)
        if endpoint.startswith("tcp://"):
            keep_alive(sock)
        sock.setsockopt(zmq.LINGER, 0)
        if self.never_drop:
            sock.setsockopt(zmq.RCVHWM, NEVER_DROP_QUEUE)
        for topic in topics:
            sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
        if self.monitor:  # before connecting, so that the first connection is reported
            monitor = sock.get_monitor_socket(zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED)
            self.monitors[endpoint] = monitor
            self._monitored[monitor] = endpoint
            self.poller.register(monitor, zmq.POLLIN)
        sock.connect(endpoint)
        self.socks[endpoint] = sock
        self._endpoint_of[sock] = endpoint
        self.poller.register(sock, zmq.POLLIN)

    def subscribe(self, endpoint: str, topic: str) -> None:
        """Add a subscription to the socket of the publisher at `endpoint`."""
        self.socks[endpoint].setsockopt(zmq.SUBSCRIBE, topic.encode())

    def poll(self, timeout_s: float) -> TapEvents:
        """Wait up to `timeout_s` for messages or connection changes (sleeps when nothing is connected)."""
        if not self.socks:  # pyzmq returns at once from a poll on no sockets
            time.sleep(timeout_s)
            return TapEvents([], [])
        events = dict(self.poller.poll(int(timeout_s * 1000)))
        messages = [self._endpoint_of[s] for s in events if s in self._endpoint_of]
        connections = [self._monitored[s] for s in events if s in self._monitored]
        return TapEvents(messages, connections)

    def take(self, endpoint: str, limit: int = 1 << 30) -> Iterator[list[bytes]]:
        """The multipart messages queued from the publisher at `endpoint` (at most `limit`), without waiting."""
        sock = self.socks[endpoint]
        for _ in range(limit):
            try:
                yield sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return

    def connection_changes(self, endpoint: str) -> Iterator[bool]:
        """The connection events queued for `endpoint`, oldest first: True connected, False disconnected."""
        monitor = self.monitors[endpoint]
        while monitor.poll(0):
            event = recv_monitor_message(monitor)["event"]
            if event == zmq.EVENT_CONNECTED:
                yield True
            elif event == zmq.EVENT_DISCONNECTED:
                yield False

    def receive(self, timeout_s: float) -> list[list[bytes]]:
        """The multipart messages that arrive within `timeout_s` (and all already queued)."""
        out: list[list[bytes]] = []
        for endpoint in self.poll(timeout_s).messages:
            out.extend(self.take(endpoint))
        return out

    def close(self) -> None:
        """Close the sockets and the context."""
        for endpoint, sock in self.socks.items():
            monitor = self.monitors.get(endpoint)
            if monitor is not None:
                sock.disable_monitor()
                monitor.close(linger=0)
            sock.close(linger=0)
        self.socks.clear()
        self.monitors.clear()
        self.context.term()


class SubscriptionCounter:
    """Counts subscriptions an XPUB socket has seen, per topic, to know when subscribers are there."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def feed(self, frame: bytes) -> None:
        if not frame:
            return
        topic = frame[1:].decode(errors="replace")
        delta = 1 if frame[0] == 1 else -1 if frame[0] == 0 else 0
        self.counts[topic] = self.counts.get(topic, 0) + delta

    def satisfied(self, expected: dict[str, int]) -> bool:
        return all(self.counts.get(topic, 0) >= n for topic, n in expected.items())

    def missing(self, expected: dict[str, int]) -> dict[str, int]:
        return {t: n - self.counts.get(t, 0) for t, n in expected.items() if self.counts.get(t, 0) < n}

    def covering(self, topic: str) -> int:
        """Subscriptions that match `topic`: ZeroMQ subscriptions are prefixes ("" matches every topic)."""
        return sum(n for prefix, n in self.counts.items() if topic.startswith(prefix))


def read_subscriptions(sock: zmq.Socket[Any], counter: SubscriptionCounter, timeout_ms: int) -> None:
    """Wait up to `timeout_ms` for (un)subscriptions on an XPUB socket, then feed all queued to `counter`."""
    if not sock.poll(timeout_ms, zmq.POLLIN):
        return
    while sock.poll(0, zmq.POLLIN):
        counter.feed(sock.recv())


def wait_for_subscribers(
    sock: zmq.Socket[Any], counter: SubscriptionCounter, expected: dict[str, int], timeout_s: float
) -> None:
    """Block until `expected` subscriptions have arrived on an XPUB socket, or raise TimeoutError."""
    deadline = time.monotonic() + timeout_s
    while not counter.satisfied(expected):
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError(f"subscribers still missing after {timeout_s:.0f} s: {counter.missing(expected)}")
        read_subscriptions(sock, counter, int(min(remaining, 0.1) * 1000))


class BlockingPublisher:
    """A publisher for tools that put recorded data on the bus (the log player), with its own context.

    It never drops a message: while a subscriber's queue holds `send_hwm` messages, `send` waits
    (XPUB_NODROP), up to `send_timeout_ms`, so the caller stays responsive to signals and tries
    again. `counter` holds the subscriptions seen (`read_subscriptions`). Closing waits up to
    `linger_ms` for queued messages to leave.
    """

    def __init__(self, endpoint: str, *, send_hwm: int, linger_ms: int = 30_000, send_timeout_ms: int = 100):
        self.context: zmq.Context[Any] = zmq.Context()
        self.counter = SubscriptionCounter()
        self.endpoint = endpoint
        self.sock = make_publisher(
            self.context,
            endpoint,
            lockstep=False,
            send_hwm=send_hwm,
            block_when_full=True,
            linger_ms=linger_ms,
            send_timeout_ms=send_timeout_ms,
        )

    def read_subscriptions(self, timeout_ms: int) -> None:
        """Wait up to `timeout_ms` for subscriptions, then count all that are queued."""
        read_subscriptions(self.sock, self.counter, timeout_ms)

    def send(self, frames: list[bytes]) -> bool:
        """Send a multipart message; False when a subscriber's queue stayed full (nothing sent: try again)."""
        try:
            self.sock.send_multipart(frames)
        except zmq.Again:
            return False
        return True

    def close(self) -> None:
        """Close the socket, wait (up to the linger time) until queued messages have left, delete the socket file."""
        self.sock.close()
        self.context.term()
        remove_ipc_file(self.endpoint)
