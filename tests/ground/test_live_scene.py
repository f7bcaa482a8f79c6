"""The formation's 3D scene (services.ground.monitoring.scene) in Foxglove's schemas, decoded
with those schemas as the SDK gives them; the recording's scene channels; a state-like
channel's last message sent to a client that subscribes late (the latch)."""

from __future__ import annotations

import base64
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.foxglove_client import FoxgloveClient
from benchmarks.live import layout_topics
from ddvi_core.orbit import hill_frame, mrp_to_dcm
from services.config import deployment_from_table, load_deployment
from services.ground.monitoring.live import LiveServer
from services.ground.monitoring.live_address import LiveAddress
from services.ground.monitoring.scene import (
    BODY_SCALE,
    FORMATION_TOPIC,
    SCENE_FRAME,
    SIGMAS,
    TRANSFORMS_TOPIC,
    Scene,
    estimate_topic,
    hill_axes,
    mrp_dcm,
    quaternion,
)
from services.ground.storage.recording import Recorder, message_json_schema, ns, read_recording
from services.interface import SCHEMAS, decode, encode
from services.model import orbit_period
from tests.support import wait_until

foxglove = pytest.importorskip("foxglove")
message_factory = pytest.importorskip("google.protobuf.message_factory")
from foxglove import messages as fm  # noqa: E402
from google.protobuf import descriptor_pb2, descriptor_pool  # noqa: E402

MISSION = """
[[deputy]]
name = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
y_ref = 500.0
"""


def protobuf_class(schema_name: str, descriptor_set: bytes) -> Any:
    """The message class of ``schema_name`` from a schema's FileDescriptorSet, as a Foxglove
    client builds it from a channel's advertised schema."""
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def decoded(schema_name: str, data: bytes) -> Any:
    kind = getattr(fm, schema_name.removeprefix("foxglove."))
    return protobuf_class(schema_name, kind.get_schema().data).FromString(data)


def rotation(q: Any) -> np.ndarray:
    """The rotation matrix of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def truth(sc: str, t: float, r: Any, v: Any, sigma: Any) -> Any:
    body = {"sc": sc, "r_N": np.asarray(r, float), "v_N": np.asarray(v, float)}
    body["sigma_BN"] = np.asarray(sigma, float)
    return decode(encode("truth", body, seq=0, t=t, src="environment"), "truth")


def nav(sc: str, t: float, x: Any, cov: Any) -> Any:
    body = {"sc": sc, "x_hill": np.asarray(x, float), "z_hill": np.asarray(x, float)}
    body |= {"cov": np.asarray(cov, float), "altitude": 3e5, "valid": True}
    return decode(encode("nav", body, seq=0, t=t, src=f"nav-{sc}"), "nav")


CHIEF_R, CHIEF_V = np.array([6.5e6, 1.2e6, 0.8e6]), np.array([-1.1e3, 6.9e3, 2.9e3])


def step(scene: Scene, t: float, offsets: dict[str, Any], sigma: Any) -> list[Any]:
    """Every craft's truth at t (a deputy at the chief plus its offset in N), chief last."""
    out = []
    for sc, d in offsets.items():
        out += scene.message(f"truth/{sc}", truth(sc, t, CHIEF_R + d, CHIEF_V, sigma))
    out += scene.message("truth/chief", truth("chief", t, CHIEF_R, CHIEF_V, [0.0, 0.0, 0.0]))
    return out


def test_the_scenes_rotations_are_the_attitude_helpers() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):
        sigma = rng.normal(size=3) * 0.7
        C = mrp_to_dcm(sigma)
        assert np.allclose(mrp_dcm(sigma), C)
        # a child frame's quaternion takes its coordinates to the parent's: [child parent]^T
        assert np.allclose(rotation(quaternion(C.tolist())), C.T)
        r, v = rng.normal(size=3) * 7e6, rng.normal(size=3) * 7e3
        assert np.allclose(hill_axes(r, v), hill_frame(r, v))


def test_the_formation_is_each_deputy_in_the_chiefs_hill_frame_at_each_step() -> None:
    dep = deployment_from_table(tomllib.loads(MISSION))
    scene = Scene(dep)
    offsets = {"lqr": np.array([100.0, -2000.0, 30.0]), "ddvi": np.array([-50.0, 400.0, 0.0])}
    sigma = np.array([0.1, -0.05, 0.2])
    assert scene.message("truth/lqr", truth("lqr", 10.0, CHIEF_R, CHIEF_V, sigma)) == []
    out = step(scene, 60.0, offsets, sigma)  # complete once every craft's truth is there
    assert [m.topic for m in out] == [TRANSFORMS_TOPIC, FORMATION_TOPIC]
    assert all(m.log_ns == ns(60.0) for m in out)
    assert out[0].schema.name == "foxglove.FrameTransforms"
    assert out[1].schema.name == "foxglove.SceneUpdate"
    assert out[0].schema.data == fm.FrameTransforms.get_schema().data  # the SDK's schema

    HN = hill_frame(CHIEF_R, CHIEF_V)
    BH = mrp_to_dcm(sigma) @ HN.T
    frames = decoded("foxglove.FrameTransforms", out[0].data).transforms
    assert [(f.parent_frame_id, f.child_frame_id) for f in frames] == [
        (SCENE_FRAME, "lqr"),
        (SCENE_FRAME, "ddvi"),
    ]
    for f in frames:
        assert (f.timestamp.seconds, f.timestamp.nanos) == (60, 0)
        position = np.array([f.translation.x, f.translation.y, f.translation.z])
        assert np.allclose(position, HN @ offsets[f.child_frame_id])
        q = (f.rotation.x, f.rotation.y, f.rotation.z, f.rotation.w)
        assert np.allclose(rotation(q), BH.T)  # the body's axes in the Hill frame

    update = decoded("foxglove.SceneUpdate", out[1].data)
    entities = {e.id: e for e in update.entities}
    assert set(entities) == {
        "chief",
        *(f"{kind}/{sc}" for kind in ("body", "slot", "trail") for sc in ("lqr", "ddvi")),
    }
    assert entities["chief"].frame_id == SCENE_FRAME and entities["chief"].texts[0].text == "chief"
    body = entities["body/ddvi"]
    assert body.frame_id == "ddvi" and body.frame_locked and body.texts[0].text == "ddvi"
    assert body.cubes[0].size.x == pytest.approx(0.3 * BODY_SCALE)
    assert entities["slot/ddvi"].spheres[0].pose.position.y == 500.0  # its y_ref
    trail = entities["trail/lqr"].lines[0]
    assert len(trail.points) == 1 and trail.scale_invariant
    assert np.allclose([trail.points[0].x, trail.points[0].y], (HN @ offsets["lqr"])[:2])


def test_a_trail_is_the_last_orbit_and_an_estimate_its_three_sigma_ellipsoid() -> None:
    dep = deployment_from_table(tomllib.loads(MISSION))
    scene = Scene(dep)
    fsw = dep.run.fsw_period
    steps = math.ceil(orbit_period(dep) / fsw) + 1
    offsets = {"lqr": np.zeros(3), "ddvi": np.zeros(3)}
    for k in range(steps + 5):
        offsets["lqr"] = np.array([0.0, 10.0 * k, 0.0])
        out = step(scene, k * fsw, offsets, np.zeros(3))
    trail = {e.id: e for e in decoded("foxglove.SceneUpdate", out[1].data).entities}
    points = trail["trail/lqr"].lines[0].points
    assert len(points) == steps  # one orbit of steps, the oldest dropped

    P = np.diag([4.0, 100.0, 1.0, 1.0, 1.0, 1.0])  # position sigmas 2, 10 and 1 m
    assert scene.message("nav/lqr/state", nav("lqr", 70.0, np.arange(6.0), P)) == []  # off-step
    (estimate,) = scene.message("nav/lqr/state", nav("lqr", 120.0, np.arange(6.0), P))
    assert estimate.topic == estimate_topic("lqr") and estimate.log_ns == ns(120.0)
    (entity,) = decoded("foxglove.SceneUpdate", estimate.data).entities
    dot, ellipsoid = entity.spheres
    assert (dot.pose.position.x, dot.pose.position.y, dot.pose.position.z) == (0.0, 1.0, 2.0)
    size = np.array([ellipsoid.size.x, ellipsoid.size.y, ellipsoid.size.z])
    q = ellipsoid.pose.orientation
    R = rotation((q.x, q.y, q.z, q.w))
    # the ellipsoid's axes, in the Hill frame, span 2 x 3 sigma of the covariance
    spans = np.abs(R) @ size
    assert np.allclose(sorted(spans), sorted(2 * SIGMAS * np.array([2.0, 10.0, 1.0])))
    # without navigation noise the covariance is zero: the estimate alone, no ellipsoid
    (plain,) = scene.message("nav/lqr/state", nav("lqr", 180.0, np.arange(6.0), np.zeros((6, 6))))
    assert len(decoded("foxglove.SceneUpdate", plain.data).entities[0].spheres) == 1
    # a message of no deputy, or on a topic that is not its own, draws nothing
    assert scene.message("nav/ddvi/state", nav("lqr", 120.0, np.arange(6.0), P)) == []


def test_the_recording_holds_the_scene_beside_the_bus_messages(tmp_path: Path) -> None:
    dep = deployment_from_table(tomllib.loads(MISSION))
    scene = Scene(dep)
    rec = Recorder(tmp_path / "recording.mcap", {"run": "r"}, None)
    msg = truth("chief", 0.0, CHIEF_R, CHIEF_V, [0.0, 0.0, 0.0])
    rec.message("truth/chief", msg, 1)
    for m in step(scene, 0.0, {"lqr": np.ones(3), "ddvi": np.zeros(3)}, np.zeros(3)):
        rec.scene(m.topic, m.schema, m.data, m.log_ns, 2)
    rec.close()
    assert (rec.messages, rec.scenes) == (1, 2)  # the scene is not a bus message
    from mcap.reader import make_reader

    with (tmp_path / "recording.mcap").open("rb") as f:
        reader = make_reader(f)
        found = {
            c.topic: (s.name, s.encoding, c.message_encoding, s.data)
            for s, c, _ in reader.iter_messages()
        }
    assert found[FORMATION_TOPIC] == (
        "foxglove.SceneUpdate",
        "protobuf",
        "protobuf",
        fm.SceneUpdate.get_schema().data,
    )
    records, complete = read_recording(tmp_path / "recording.mcap")
    assert complete and [r.topic for r in records] == ["truth/chief"]


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status(t: float, phase: str) -> Any:
    body = {"sc": "ddvi", "mode": "ddvi", "phase": phase, "samples": 1, "intervals": 0}
    body |= {"rank": 0, "rank_needed": 34, "counters": {}}
    return decode(encode("status", body, seq=int(t), t=t, src="ctrl-ddvi"), "status")


def test_a_client_that_subscribes_late_is_sent_the_last_state_at_once() -> None:
    port = _free_port()
    schemas = {
        "ctrl/ddvi/status": ("ddvi.status", message_json_schema(SCHEMAS["status"])),
        "nav/lqr/state": ("ddvi.nav", message_json_schema(SCHEMAS["nav"])),
    }
    live = LiveServer(LiveAddress("127.0.0.1", port), "test", schemas, {})
    try:
        live.message("ctrl/ddvi/status", status(10.0, "lqr"))
        live.message("ctrl/ddvi/status", status(20.0, "exploring"))  # the last one
        live.message("nav/lqr/state", nav("lqr", 20.0, np.arange(6.0), np.eye(6)))
        live.alive("nav-lqr", True, 0.0)
        assert live.counters["served"] == 0 and not live.watched.is_set()
        client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=10)
        try:
            assert wait_until(lambda: "alive/nav-lqr" in client.counts, timeout=3)
            assert wait_until(lambda: "ctrl/ddvi/status" in client.counts, timeout=3)
            assert wait_until(live.watched.is_set, timeout=3)
            got = next(m for m in client.messages if m.topic == "ctrl/ddvi/status")
            assert got.json()["body"]["phase"] == "exploring" and got.timestamp == ns(20.0)
            assert got.at - client.subscribed["ctrl/ddvi/status"] < 3.0
            assert "nav/lqr/state" not in client.counts  # a sample, not a state: not latched
        finally:
            client.close()
    finally:
        live.close()


def test_a_scene_message_the_live_view_serves_decodes_with_the_advertised_schema() -> None:
    port = _free_port()
    dep = deployment_from_table(tomllib.loads(MISSION))
    scene = Scene(dep)
    channels = {topic: (schema.name, schema) for topic, schema in scene.channels()}
    live = LiveServer(LiveAddress("127.0.0.1", port), "test", channels, {})
    try:
        for m in step(scene, 0.0, {"lqr": np.ones(3), "ddvi": np.zeros(3)}, np.zeros(3)):
            live.scene(m)
        client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=10)
        try:
            assert wait_until(lambda: FORMATION_TOPIC in client.counts, timeout=3)
            advert = client.advertised()[FORMATION_TOPIC]
            assert (advert["encoding"], advert["schemaEncoding"]) == ("protobuf", "protobuf")
            data = base64.b64decode(advert["schema"])
            assert data == fm.SceneUpdate.get_schema().data
            got = next(m for m in client.messages if m.topic == FORMATION_TOPIC)
            update = protobuf_class(advert["schemaName"], data).FromString(got.payload)
            assert "body/lqr" in {e.id for e in update.entities}
        finally:
            client.close()
    finally:
        live.close()


def test_the_layouts_3d_panel_shows_the_scene_of_the_default_mission() -> None:
    root = Path(__file__).resolve().parents[2]
    layout = json.loads((root / "docs" / "foxglove-layout.json").read_text())
    (panel,) = [c for k, c in layout["configById"].items() if k.startswith("3D!")]
    dep = load_deployment(str(root / "deployments" / "rendezvous.toml"))
    channels = dict(Scene(dep).channels())
    assert panel["followTf"] == SCENE_FRAME == panel["layers"]["grid"]["frameId"]
    assert set(panel["topics"]) == {t for t in channels if t != TRANSFORMS_TOPIC}
    assert all(channels[t].name == "foxglove.SceneUpdate" for t in panel["topics"])
    # what a client with the layout subscribes to: the scene and the frames it is placed by
    assert set(channels) <= layout_topics(root / "docs" / "foxglove-layout.json")
