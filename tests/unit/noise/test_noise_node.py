"""Noise node in-process: sigma 0 is bit-exact, the seed fixes the stream, normals stay unit, and the
node's readings have the configured bias and sigma."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.errors import ConfigError, InputError
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch, parse_cli_args
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet, JointState
from palpate.nodes.noise.node import SPEC, NoiseNode, NoiseNodeConfig
from palpate.paths import REPO_ROOT
from palpate.runtime.inprocess import InProcessGraph

NAMES = ["mcp_flex", "mcp_abd", "pip", "dip"]


class FakeCtx:
    """What NoiseNode sees of the runtime; every published message goes through codec.validate."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.stamp_ns = 0
        self.metrics: dict[str, float] = {}
        self.counters: dict[str, int] = {}
        self.log = logging.getLogger("test.noise")
        self.published: list[tuple[str, Any]] = []

    def publish(self, port: str, message: Message) -> None:
        codec.validate(message)
        self.published.append((port, message))


def _joints(q: np.ndarray, stamp_ns: int = 0) -> JointState:
    return JointState(
        stamp_ns=stamp_ns, names=list(NAMES), positions_rad=q, velocities_rad_s=np.array([1e-300, -0.0, 2.5, np.pi])
    )


def _contacts(n: int, rng: np.random.Generator) -> ContactSet:
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return ContactSet(
        stamp_ns=0,
        positions_m=rng.normal(size=(n, 3)),
        local_positions_m=rng.normal(size=(n, 3)),
        normals=normals,
        forces_n=rng.random(n),
        links=[f"link{i}" for i in range(n)],
    )


def test_ports_follow_the_parameters() -> None:
    joints = SPEC.with_params({})
    assert set(joints.inputs) == {"joint_states"} and set(joints.outputs) == {"noisy_joint_states"}
    assert joints.outputs["noisy_joint_states"].default_topic == "sensors/joint_states_noisy"
    both = SPEC.with_params({"joints": True, "contacts": True})
    assert set(both.inputs) == {"joint_states", "contacts"}
    assert both.outputs["noisy_contacts"].default_topic == "sensors/contacts_noisy"


def test_bad_parameters_are_config_errors() -> None:
    with pytest.raises(ConfigError, match=r"NoiseNodeConfig.sigma_deg: expected a finite number >= 0 and <= 90"):
        NoiseNodeConfig(sigma_deg=-1.0)
    with pytest.raises(ConfigError, match=r"normal_sigma_deg"):
        NoiseNodeConfig(normal_sigma_deg=math.inf)


def test_sigma_zero_passes_joint_states_through_bit_for_bit() -> None:
    ctx = FakeCtx()
    state = ctx.rng.bit_generator.state
    node = NoiseNode(NoiseNodeConfig(sigma_deg=0.0), ctx)
    q = np.array([0.1, -0.0, np.nextafter(0.7, 1.0), 1e-300])
    message = _joints(q, stamp_ns=123)
    node.on_joint_states(message)
    [(port, out)] = ctx.published
    assert port == "noisy_joint_states"
    assert out.positions_rad.tobytes() == q.tobytes()
    assert out.velocities_rad_s.tobytes() == message.velocities_rad_s.tobytes()
    assert (out.stamp_ns, out.names) == (123, NAMES)
    assert ctx.rng.bit_generator.state == state  # nothing drawn


def test_zero_contact_noise_passes_contacts_through_bit_for_bit() -> None:
    ctx = FakeCtx()
    node = NoiseNode(NoiseNodeConfig(joints=False, contacts=True), ctx)
    message = _contacts(5, np.random.default_rng(1))
    node.on_contacts(message)
    [(port, out)] = ctx.published
    assert port == "noisy_contacts"
    for name in ("positions_m", "local_positions_m", "normals", "forces_n"):
        assert getattr(out, name).tobytes() == getattr(message, name).tobytes(), name
    assert out.links == message.links


def test_node_readings_have_the_configured_bias_and_sigma() -> None:
    """10,000 readings: mean within 3 standard errors of q + bias, std within 3 SE of sigma."""
    ctx = FakeCtx(seed=3)
    node = NoiseNode(NoiseNodeConfig(sigma_deg=1.5, bias_deg={"pip": 2.0}, per_joint_sigma_deg={"dip": 3.0}), ctx)
    q = np.array([0.1, 0.2, 0.3, 0.4])
    n = 10_000
    for k in range(n):
        node.on_joint_states(_joints(q, stamp_ns=k))
    samples = np.stack([m.positions_rad for _, m in ctx.published])
    sigma = np.radians([1.5, 1.5, 1.5, 3.0])
    mean = q + np.radians([0.0, 0.0, 2.0, 0.0])
    np.testing.assert_array_less(np.abs(samples.mean(axis=0) - mean), 3 * sigma / math.sqrt(n))
    np.testing.assert_array_less(np.abs(samples.std(axis=0, ddof=1) - sigma), 3 * sigma / math.sqrt(2 * (n - 1)))


def test_contact_noise_keeps_unit_normals_and_moves_them() -> None:
    ctx = FakeCtx(seed=4)
    node = NoiseNode(NoiseNodeConfig(joints=False, contacts=True, position_sigma_m=1e-3, normal_sigma_deg=5.0), ctx)
    message = _contacts(2000, np.random.default_rng(5))
    node.on_contacts(message)
    out = ctx.published[0][1]
    np.testing.assert_allclose(np.linalg.norm(out.normals, axis=1), 1.0, rtol=0, atol=1e-12)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out.normals, message.normals), -1, 1)))
    # Rayleigh with scale 5 deg: mean 5 sqrt(pi / 2) = 6.27 deg
    assert angle.mean() == pytest.approx(5.0 * math.sqrt(math.pi / 2), rel=0.05)
    assert np.std(out.positions_m - message.positions_m) == pytest.approx(1e-3, rel=0.05)
    assert out.forces_n.tobytes() == message.forces_n.tobytes() and out.links == message.links


def _noisy_contacts_of_a_run(tmp_path: Path, *args: str) -> list[np.ndarray]:
    """Run launch/probe.yaml in-process (0.5 s, starting 7 mm above the box); the noisy contact
    positions and normals (n, 6) of every tick with contacts."""
    launch = load_launch(
        REPO_ROOT / "launch" / "probe.yaml", parse_cli_args(["duration_s:=0.5", "start:=[0.0, 0.0, 0.03]", *args])
    )
    seen: list[np.ndarray] = []

    def listen(tick: int, node: str, topic: str, message: Message) -> None:
        if topic == "sensors/contacts_noisy" and isinstance(message, ContactSet) and len(message.links):
            seen.append(np.concatenate([message.positions_m, message.normals], axis=1))

    InProcessGraph(resolve(launch, bus_dir=tmp_path / "bus").in_process_members(), listener=listen).run()
    return seen


def test_same_seed_gives_the_same_stream_in_two_in_process_runs(tmp_path: Path) -> None:
    first = _noisy_contacts_of_a_run(tmp_path, "seed:=7")
    second = _noisy_contacts_of_a_run(tmp_path, "seed:=7")
    other = _noisy_contacts_of_a_run(tmp_path, "seed:=8")
    assert len(first) > 10  # the probe touched the box for a good part of the second
    assert len(first) == len(second)
    for a, b in zip(first, second, strict=True):
        assert a.tobytes() == b.tobytes()
    assert not np.array_equal(np.concatenate(first), np.concatenate(other[: len(first)]))


def test_bad_readings_are_refused_and_do_not_fix_the_joint_list() -> None:
    """The issue's crashes: the noise model came from the first reading, so any later reading with other
    names raised ValueError. Names now travel with every reading; a reading with repeated or empty names
    (or lacking a joint the config names) is refused, and the next good one is handled as usual."""
    ctx = FakeCtx(seed=9)
    node = NoiseNode(NoiseNodeConfig(sigma_deg=1.0, per_joint_sigma_deg={"pip": 0.0}), ctx)
    bad = [
        (["pip", "pip"], r"^names: repeated name\(s\) 'pip'"),
        (["pip", ""], r"^names: entry 1 is an empty name"),
        (["dip"], r"^names: lacks joint\(s\) \['pip'\] that the noise node's per_joint_sigma_deg names"),
    ]
    for names, reason in bad:
        with pytest.raises(InputError, match=reason):
            node.on_joint_states(
                JointState(
                    stamp_ns=0, names=names, positions_rad=np.zeros(len(names)), velocities_rad_s=np.zeros(len(names))
                )
            )
    assert not ctx.published
    node.on_joint_states(_joints(np.array([0.1, 0.2, 0.3, 0.4])))
    many = [f"j{i}" for i in range(50_000)] + ["pip"]
    node.on_joint_states(
        JointState(stamp_ns=1, names=many, positions_rad=np.zeros(len(many)), velocities_rad_s=np.zeros(len(many)))
    )
    node.on_joint_states(_joints(np.array([0.1, 0.2, 0.3, 0.4])))
    assert [len(m.names) for _, m in ctx.published] == [4, 50_001, 4]
    assert ctx.published[1][1].positions_rad[-1] == 0.0  # 'pip' has sigma 0, wherever it sits
    with pytest.raises(InputError, match=r"^normals: row 0 has norm 0, not 1"):
        NoiseNode(NoiseNodeConfig(joints=False, contacts=True), ctx).on_contacts(
            ContactSet(
                stamp_ns=0,
                positions_m=np.zeros((1, 3)),
                local_positions_m=np.zeros((1, 3)),
                normals=np.zeros((1, 3)),
                forces_n=np.ones(1),
                links=["tip"],
            )
        )
