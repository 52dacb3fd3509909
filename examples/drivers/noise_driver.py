"""An external lockstep node: the contact noise of palpate's `noise` node, in plain Python.

    palpate launch launch/explore.yaml --external noise --bus /tmp/bus
    python examples/drivers/noise_driver.py /tmp/bus noise

It reads its process spec from <bus dir>/external/<name>.json (the launcher writes it), binds its
publisher where the spec says, subscribes to its input and to the graph topics, waits for its
subscribers, acknowledges tick -1, and then, for every tick, republishes the tick's contact sets with
Gaussian noise on the positions and normals (the spec's params `position_sigma_m`, `normal_sigma_deg`;
0 passes them through unchanged) before acknowledging the tick. It stops on RunControl "stop", and ends
as a failed run (exit code 4) on "fail" or when the clock source leaves without a stop.
Imports pyzmq, msgpack and numpy, never palpate (docs/runtime.md, "External nodes").
"""

from __future__ import annotations

import sys
from collections import deque

import numpy as np
from wire import ACK, CLOCK, CONTROL, Node, decode, read_spec  # wire.py, beside this file


def add_noise(contacts: dict, sigma_m: float, sigma_rad: float, rng: np.random.Generator) -> dict:
    """Noisy copy of a ContactSet's fields: positions + N(0, sigma_m^2) per axis; normals tilted by a
    tangent Gaussian step (sigma_rad per axis) and renormalised. Zero sigma: the arrays unchanged."""
    positions, normals = contacts["positions_m"], contacts["normals"]
    if sigma_m > 0:
        positions = positions + sigma_m * rng.standard_normal(positions.shape)
    if sigma_rad > 0 and len(normals):
        step = sigma_rad * rng.standard_normal(normals.shape)
        step -= np.sum(step * normals, axis=1, keepdims=True) * normals  # tangent part
        normals = normals + step
        normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return {**contacts, "positions_m": positions, "normals": normals}


def main(bus_dir: str, name: str) -> int:
    spec = read_spec(bus_dir, name)
    if spec["mode"] != "lockstep":
        raise SystemExit(f"{name}: this driver speaks the lockstep protocol; the launch file is {spec['mode']}")
    params = spec["params"]
    sigma_m = float(params.get("position_sigma_m", 0.0))
    sigma_rad = np.radians(float(params.get("normal_sigma_deg", 0.0)))
    rng = np.random.default_rng(spec["seed"])
    source, target = spec["subscribes"]["contacts"], spec["publishes"]["noisy_contacts"]
    node = Node(spec, {target: "ContactSet"})
    try:
        node.wait_for_subscribers()
        node.acknowledge(-1, 0)  # start-up done: the clock source starts tick 0 when every node has said so
        print(f"[{name}] started: acknowledged tick -1", flush=True)
        forward, backward = spec["forward_upstream"], spec["backward_upstream"]
        clocks: deque[dict] = deque()
        acks: dict[str, int] = {}
        inputs: list[bytes] = []
        tick, stopping, failed, reason = 0, False, False, ""
        while True:
            for topic, payload in node.receive(100):
                if topic == source:
                    inputs.append(payload)
                elif topic == CLOCK:
                    clocks.append(decode(payload, "Clock"))
                elif topic == ACK:
                    ack = decode(payload, "LockstepAck")
                    acks[ack["node"]] = max(ack["tick"], acks.get(ack["node"], -2))
                elif topic == CONTROL:
                    control = decode(payload, "RunControl")
                    if control["command"] in ("stop", "fail"):
                        stopping, reason = True, reason or control["reason"]
                        failed = failed or control["command"] == "fail"
            if not stopping and node.gone(spec["clock_name"]):
                print(f"[{name}] the clock source {spec['clock_name']!r} left without a stop", file=sys.stderr)
                return 4
            # tick t is ready with Clock(t), acks of t from upstream nodes ranked before this one and of
            # t - 1 from those ranked after it (feedback edges); the clock source's data precede its Clock
            while (
                clocks
                and clocks[0]["tick"] == tick
                and all(acks.get(n, -2) >= tick for n in forward)
                and all(acks.get(n, -2) >= tick - 1 for n in backward)
            ):
                clock = clocks.popleft()
                for payload in inputs:
                    try:
                        contacts = decode(payload, "ContactSet")
                    except ValueError as exc:  # count and skip what cannot be read, as palpate nodes do
                        print(f"[{name}] rejected a message on {source}: {exc}", file=sys.stderr)
                        continue
                    node.send(target, "ContactSet", add_noise(contacts, sigma_m, sigma_rad, rng))
                inputs.clear()
                node.acknowledge(tick, clock["stamp_ns"])
                tick += 1
            if stopping and not clocks:
                how = f": the run failed ({reason or 'no reason given'})" if failed else ""
                print(f"[{name}] stopped after {tick} ticks{how}", flush=True)
                return 4 if failed else 0
    finally:
        node.close()


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: noise_driver.py BUS_DIR NODE_NAME")
    sys.exit(main(sys.argv[1], sys.argv[2]))
