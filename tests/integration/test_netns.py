"""Hosts and security: a node in its own network namespace talks to the graph over TCP, and CurveZMQ
links work with the right keys and stay silent with the wrong ones.

The namespace test needs root and iproute2. It joins the namespace to the host with a veth pair
carrying loopback-range addresses only (127.77.X.1 on the host side, 127.77.X.2 inside), which Linux
routes over an interface once `route_localnet` is set on it. Everything is removed in a finally.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zmq

from palpate.cli import main
from palpate.commands.introspect import TopicTap
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.messages import codec
from palpate.messages.schemas import RunControl
from palpate.paths import REPO_ROOT
from palpate.record.mcap_io import read_messages
from palpate.runtime import bus
from palpate.runtime.bus import make_curve_keys
from tests.integration.launch_helpers import child_env, free_port, kill_session, launched, text, wait_for


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=10)


@contextmanager
def namespace_link() -> Iterator[tuple[str, str, str]]:
    """A network namespace joined to this one by a veth pair: yields (namespace, host_ip, inner_ip)."""
    if os.geteuid() != 0:
        pytest.skip("network namespaces need root (run the suite as root to test a node on another host)")
    if shutil.which("ip") is None:
        pytest.skip("iproute2's `ip` command is missing (apt-get install iproute2)")
    tag = os.getpid() % 100000
    ns, host_if, inner_if = f"palpate-t{tag}", f"pvh{tag}", f"pvn{tag}"
    used = _ip("-o", "addr", check=False).stdout
    subnet = next(f"127.77.{n}" for n in [tag % 200 + 20, *range(20, 250)] if f"127.77.{n}." not in used)
    created = _ip("netns", "add", ns, check=False)
    if created.returncode != 0:
        pytest.skip(f"cannot create a network namespace here: {created.stderr.strip()}")
    try:
        _ip("link", "add", host_if, "type", "veth", "peer", "name", inner_if, "netns", ns)
        _ip("addr", "add", f"{subnet}.1/24", "dev", host_if)
        _ip("link", "set", host_if, "up")
        _ip("-n", ns, "addr", "add", f"{subnet}.2/24", "dev", inner_if)
        _ip("-n", ns, "link", "set", inner_if, "up")
        _ip("-n", ns, "link", "set", "lo", "up")
        # 127.0.0.0/8 is "martian" on anything but lo unless route_localnet is set on the interface
        subprocess.run(["sysctl", "-qw", f"net.ipv4.conf.{host_if}.route_localnet=1"], check=True, timeout=10)
        subprocess.run(
            ["ip", "netns", "exec", ns, "sysctl", "-qw", f"net.ipv4.conf.{inner_if}.route_localnet=1"],
            check=True,
            timeout=10,
        )
        yield ns, f"{subnet}.1", f"{subnet}.2"
    finally:
        _ip("netns", "del", ns, check=False)  # deletes the veth pair with it
        _ip("link", "del", host_if, check=False)


def test_node_in_another_network_namespace_joins_the_graph_over_tcp(tmp_path: Path) -> None:
    with namespace_link() as (ns, host_ip, inner_ip):
        bus_dir = tmp_path / "bus"
        launch_file = tmp_path / "hosts.yaml"
        launch_file.write_text(
            f"""
mode: lockstep
nodes:
  - name: cube
    type: cube_contacts
    host: {host_ip}
    port: {free_port()}
    params: {{duration_s: 0.3}}
  - name: remote_stats           # started by hand inside the namespace, as on another machine
    type: contact_stats
    external: true
    host: {inner_ip}
    port: {free_port()}
"""
        )
        graph = resolve(load_launch(launch_file), bus_dir=bus_dir)
        remote = next(s for s in graph.process_specs() if s.name == "remote_stats")
        assert remote.endpoint.startswith(f"tcp://{inner_ip}:") and remote.connect[0].startswith(f"tcp://{host_ip}:")
        spec_path = tmp_path / "remote_stats.json"
        spec_path.write_text(remote.to_json())
        node_log, launch_log = tmp_path / "remote.log", tmp_path / "launch.log"
        with node_log.open("wb") as out:
            node = subprocess.Popen(
                ["ip", "netns", "exec", ns, sys.executable, "-m", "palpate.runtime.node", str(spec_path)],
                cwd=REPO_ROOT,
                env=child_env(bus_dir),
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        try:
            with launched(launch_file, bus_dir, launch_log) as launcher:
                # `ip netns exec` execs the node: the pid is the node's, and it lives in the other namespace
                own = _netns_of(os.getpid())
                wait_for(lambda: _netns_of(node.pid) not in ("", own), 10, "the node to enter its namespace", node_log)
                assert launcher.wait(timeout=30) == 0, text(launch_log) + text(node_log)
            assert node.wait(timeout=10) == 0, text(node_log)
        finally:
            kill_session(node)
    out = text(node_log)
    assert "summary: 30 contact sets, 120 contacts" in out and "decode errors 0" in out


def _netns_of(pid: int) -> str:
    try:
        return os.readlink(f"/proc/{pid}/ns/net")
    except OSError:
        return ""


# --- CurveZMQ ----------------------------------------------------------------------------------------------


def _collect(sock: zmq.Socket[Any], pub: zmq.Socket[Any], seconds: float, *, until_heard: bool = False) -> list[bytes]:
    """Publish a RunControl every 20 ms for `seconds` and return what `sock` received (with
    `until_heard`, from the first message on: a handshake on a loaded machine may take long)."""
    got: list[bytes] = []
    payload = codec.encode(RunControl(stamp_ns=1, command="noop", reason="curve test"))
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not (until_heard and got):
        pub.send_multipart([b"graph/control", payload])
        while sock.poll(20):
            got.append(sock.recv_multipart()[1])
    return got


def test_curve_link_with_keys_works_and_a_wrong_server_key_hears_nothing() -> None:
    if not zmq.has("curve"):
        pytest.skip("libzmq was built without CurveZMQ")
    graph_key = make_curve_keys()
    client_key = make_curve_keys(server_public=graph_key["public"])  # a client with its own pair
    impostor = make_curve_keys()  # trusts another server key
    unlisted = make_curve_keys(server_public=graph_key["public"])  # the right server key, but not admitted
    ctx = zmq.Context()
    allow = bus.ClientAllowList(ctx)
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    admitted = [client_key["public"], graph_key["public"]]
    pub = bus.make_publisher(ctx, endpoint, lockstep=False, curve=graph_key, allow=allow, curve_clients=admitted)
    good = bus.make_subscriber(ctx, [endpoint], ["graph/control"], lockstep=False, curve=client_key)
    shared = bus.make_subscriber(ctx, [endpoint], ["graph/control"], lockstep=False, curve=graph_key)
    wrong = bus.make_subscriber(ctx, [endpoint], ["graph/control"], lockstep=False, curve=impostor)
    stranger = bus.make_subscriber(ctx, [endpoint], ["graph/control"], lockstep=False, curve=unlisted)
    plain = bus.make_subscriber(ctx, [endpoint], ["graph/control"], lockstep=False)
    sockets = [pub, good, shared, wrong, stranger, plain]
    try:
        for sock in sockets[1:]:
            sock.setsockopt(zmq.RCVTIMEO, 100)
        heard_good = _collect(good, pub, 30.0, until_heard=True)
        assert heard_good and codec.decode(heard_good[0]).reason == "curve test"  # type: ignore[attr-defined]
        assert _collect(shared, pub, 30.0, until_heard=True)
        assert _collect(wrong, pub, 1.0) == [], "a subscriber with the wrong server key received data"
        assert _collect(stranger, pub, 1.0) == [], "a subscriber whose key the publisher does not list received data"
        assert _collect(plain, pub, 0.5) == [], "a subscriber without keys received data"
        # and a Curve client cannot talk to a publisher without keys either (launch validation refuses it)
        open_endpoint = f"tcp://127.0.0.1:{free_port()}"
        open_pub = bus.make_publisher(ctx, open_endpoint, lockstep=False)
        curious = bus.make_subscriber(ctx, [open_endpoint], ["graph/control"], lockstep=False, curve=client_key)
        sockets += [open_pub, curious]
        assert _collect(curious, open_pub, 0.5) == []
        with pytest.raises(ValueError, match="ClientAllowList"):  # a keyed publisher always checks its clients
            bus.make_publisher(ctx, f"tcp://127.0.0.1:{free_port()}", lockstep=False, curve=graph_key)
    finally:
        for sock in sockets:
            sock.close(linger=0)
        allow.close()
        ctx.term()


def test_topic_tap_reads_a_keyed_and_a_plain_publisher_through_their_manifests(tmp_path: Path) -> None:
    if not zmq.has("curve"):
        pytest.skip("libzmq was built without CurveZMQ")
    graph_key = make_curve_keys()
    ctx = zmq.Context()
    allow = bus.ClientAllowList(ctx)
    keyed_ep, plain_ep = (f"tcp://127.0.0.1:{free_port()}" for _ in range(2))
    keyed = bus.make_publisher(
        ctx, keyed_ep, lockstep=False, curve=graph_key, allow=allow, curve_clients=[graph_key["public"]]
    )
    plain = bus.make_publisher(ctx, plain_ep, lockstep=False)
    for name, endpoint, key in (("keyed", keyed_ep, graph_key["public"]), ("plain", plain_ep, "")):
        bus.Manifest(
            node=name, endpoint=endpoint, pid=os.getpid(), publishes={}, subscribes={}, curve_public=key
        ).write(tmp_path)
    tap = TopicTap(tmp_path, "graph/control", client_keys=graph_key)  # a tool holding the graph's key file
    try:
        tap.discover()
        assert tap.endpoints == {keyed_ep, plain_ep}
        heard: set[str] = set()
        deadline = time.monotonic() + 30.0
        while heard != {"keyed", "plain"} and time.monotonic() < deadline:
            for name, pub in (("keyed", keyed), ("plain", plain)):
                message = RunControl(stamp_ns=1, command="noop", reason=name)
                pub.send_multipart([b"graph/control", codec.encode(message)])
            heard |= {codec.decode(p).reason for _, p in tap.receive(0.05)}  # type: ignore[attr-defined]
        assert heard == {"keyed", "plain"}
    finally:
        tap.close()
        for sock in (keyed, plain):
            sock.close(linger=0)
        allow.close()
        ctx.term()


def test_launch_with_curve_keys_over_tcp(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if not zmq.has("curve"):
        pytest.skip("libzmq was built without CurveZMQ")
    key_file = tmp_path / "graph.key"
    assert main(["keys", "-o", str(key_file)]) == 0
    assert "public key" in capsys.readouterr().out
    keys = json.loads(key_file.read_text())
    assert set(keys) == {"public", "secret", "server_public"} and keys["server_public"] == keys["public"]
    assert len(keys["public"]) == len(keys["secret"]) == 40
    assert key_file.stat().st_mode & 0o777 == 0o600
    assert main(["keys", "-o", str(key_file)]) == 2  # never overwrites a key silently
    launch_file = tmp_path / "curve.yaml"
    launch_file.write_text(
        f"""
nodes:
  - name: cube
    type: cube_contacts
    host: 127.0.0.1
    port: {free_port()}
    curve_keys: {key_file}
    params: {{duration_s: 0.2}}
  - name: stats
    type: contact_stats
    host: 127.0.0.1
    port: {free_port()}
    curve_keys: {key_file}
"""
    )
    specs = resolve(load_launch(launch_file), bus_dir=tmp_path / "bus").process_specs()
    assert [s.curve for s in specs] == [keys, keys]
    assert [s.curve_clients for s in specs] == [[keys["public"]], [keys["public"]]]  # each admits the other
    recorder_key = make_curve_keys()["public"]
    specs = resolve(load_launch(launch_file), bus_dir=tmp_path / "bus").process_specs(
        extra_subscribers=1, extra_curve_clients=[recorder_key]
    )
    assert all(set(s.curve_clients) == {keys["public"], recorder_key} for s in specs)
    log = tmp_path / "launch.log"
    recording = tmp_path / "run.mcap"
    with launched(launch_file, tmp_path / "bus", log, "--record", str(recording)) as proc:
        assert proc.wait(timeout=30) == 0, text(log)
    assert "summary: 20 contact sets, 80 contacts" in text(log)
    # the recorder connects to the keyed publishers with the server keys the launcher passes it, and its
    # own client key pair, which the launcher adds to every publisher's allow-list
    recorded = [m.topic for m in read_messages(recording, ["sensors/contacts"])]
    assert len(recorded) == 20, text(log)
    assert "refused" not in text(log)
