"""An external real-time clock source: a stand-in for tactile hardware, in plain Python.

    palpate launch launch/demo_minimal.yaml mode:=realtime --external cube --bus /tmp/bus
    python examples/drivers/contacts_driver.py /tmp/bus cube

It reads its process spec from <bus dir>/external/<name>.json, binds its publisher, connects to every
node of the graph (a clock source reads their stop requests), waits for its subscribers, and then,
every `period_s` of wall time for `duration_s` (its params), publishes a ContactSet of points touched
on the faces of a cube of edge `edge_m` and a Clock. At the end it publishes RunControl "stop" on
graph/control, which ends the run ("fail" when a node asked for that: the run failed). Real-time mode
waits for no acknowledgement. Imports pyzmq, msgpack and numpy, never palpate (docs/runtime.md,
"External nodes").
"""

from __future__ import annotations

import sys
import time

import numpy as np
from wire import CLOCK, CONTROL, Node, decode, read_spec  # wire.py, beside this file


def touches(edge_m: float, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` points on the faces of a cube centred at the origin (n, 3) m, with outward normals (n, 3)."""
    axis = rng.integers(0, 3, count)
    sign = rng.choice([-1.0, 1.0], count)
    points = rng.uniform(-edge_m / 2, edge_m / 2, (count, 3))
    points[np.arange(count), axis] = sign * edge_m / 2
    normals = np.zeros((count, 3))
    normals[np.arange(count), axis] = sign
    return points, normals


def main(bus_dir: str, name: str) -> int:
    spec = read_spec(bus_dir, name)
    if spec["mode"] != "realtime" or not spec["clock_source"]:
        raise SystemExit(f"{name}: this driver is a real-time clock source; the spec says otherwise")
    params = spec["params"]
    edge_m = float(params.get("edge_m", 0.05))
    period_s = float(params.get("period_s", 0.01))
    ticks = round(float(params.get("duration_s", 1.0)) / period_s)
    rng = np.random.default_rng(spec["seed"])
    topic = spec["publishes"]["contacts"]
    node = Node(spec, {topic: "ContactSet", CLOCK: "Clock", CONTROL: "RunControl"})
    try:
        node.wait_for_subscribers()
        start, tick, reason, command = time.monotonic(), 0, "driver finished", "stop"
        while tick < ticks:
            stamp_ns = round(tick * period_s * 1e9)
            points, normals = touches(edge_m, 4, rng)
            node.send(
                topic,
                "ContactSet",
                {
                    "stamp_ns": stamp_ns,
                    "positions_m": points,
                    "local_positions_m": np.zeros_like(points),
                    "normals": normals,
                    "forces_n": np.ones(len(points)),
                    "links": ["probe"] * len(points),
                },
            )
            node.send(
                CLOCK,
                "Clock",
                {"stamp_ns": stamp_ns, "tick": tick, "period_ns": round(period_s * 1e9), "lockstep": False},
            )
            tick += 1
            # pace by wall time; meanwhile read the graph topics (another node may ask to stop)
            while (left := start + tick * period_s - time.monotonic()) > 0:
                for got, payload in node.receive(int(1000 * left) + 1):
                    control = decode(payload, "RunControl") if got == CONTROL else {}
                    if control.get("command") in ("stop", "fail"):
                        reason, ticks = control["reason"], tick
                        command = "fail" if "fail" in (command, control["command"]) else "stop"
        node.send(
            CONTROL, "RunControl", {"stamp_ns": round(tick * period_s * 1e9), "command": command, "reason": reason}
        )
        print(f"[{name}] published {tick} ticks; {reason}", flush=True)
        return 0
    finally:
        node.close()


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: contacts_driver.py BUS_DIR NODE_NAME")
    sys.exit(main(sys.argv[1], sys.argv[2]))
