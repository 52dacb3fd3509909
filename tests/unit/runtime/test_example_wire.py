"""The example drivers' socket layer (examples/drivers/wire.py, no palpate import): what its manifest says."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

from palpate.paths import REPO_ROOT


def _wire() -> Any:
    spec = importlib.util.spec_from_file_location("wire", REPO_ROOT / "examples" / "drivers" / "wire.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_drivers_manifest_names_what_it_reads_and_publishes(tmp_path: Path) -> None:
    wire = _wire()
    spec = {
        "name": "noise",
        "mode": "lockstep",
        "endpoint": f"ipc://{tmp_path}/noise.pub",
        "subscribes": {"contacts": "sensors/contacts"},
        "connect": [],
        "bus_dir": str(tmp_path),
        "topic_types": {"sensors/contacts": "ContactSet", "sensors/contacts_noisy": "ContactSet"},
    }
    node = wire.Node(spec, {"sensors/contacts_noisy": "ContactSet"})
    try:
        manifest = json.loads((tmp_path / "noise.json").read_text())
    finally:
        node.close()
    assert manifest["subscribes"] == {"sensors/contacts": "ContactSet"}  # palpate node list shows it
    assert manifest["publishes"] == {"sensors/contacts_noisy": "ContactSet"}
    assert not (tmp_path / "noise.json").exists()


def test_what_arrives_while_a_driver_waits_for_its_subscribers_is_kept(tmp_path: Path) -> None:
    """An outside driver author: wait_for_subscribers dropped every frame received meanwhile (the list it
    extended was the one receive had just replaced), so a peer's acknowledgement of tick -1 was lost and
    the graph hung at tick 0."""
    import threading
    import time

    import zmq

    wire = _wire()
    context = zmq.Context.instance()
    upstream = context.socket(zmq.XPUB)
    upstream.bind(f"ipc://{tmp_path}/up.pub")
    spec = {
        "name": "drv",
        "mode": "lockstep",
        "endpoint": f"ipc://{tmp_path}/drv.pub",
        "connect": [f"ipc://{tmp_path}/up.pub"],
        "subscribes": {},
        "expected_subscribers": {"out": 1},
        "bus_dir": str(tmp_path),
        "topic_types": {},
    }
    node = wire.Node(spec, {"out": "Clock"})
    reader = context.socket(zmq.SUB)
    try:
        upstream.recv()  # the driver subscribed
        time.sleep(0.1)
        ack = wire.encode("LockstepAck", {"stamp_ns": 0, "node": "up", "tick": -1})
        upstream.send_multipart([b"lockstep/ack", ack])

        def connect_late() -> None:
            time.sleep(0.3)
            reader.setsockopt(zmq.SUBSCRIBE, b"out")
            reader.connect(spec["endpoint"])

        threading.Thread(target=connect_late, daemon=True).start()
        node.wait_for_subscribers(5.0)
        assert node.receive(200) == [("lockstep/ack", ack)]
    finally:
        node.close()
        reader.close(0)
        upstream.close(0)
