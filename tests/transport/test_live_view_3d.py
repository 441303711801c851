"""`leadthrough view` with the cell's robot and its page (gateway/live_view.py,
gateway/view_page/): a WebSocket client, as Foxglove connects, gets ``/tf``, ``/arm``,
``/arm/points`` and ``/robot_description``, and the tool they place is where an independent
forward kinematics of the same URDF (pinocchio, and the plain DH chain) puts it at the joint
state on the bus; the page is served, and headless Chromium (where installed) draws from it."""

from __future__ import annotations

import base64
import json
import re
import struct
import subprocess
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from test_live_view import SUBPROTOCOLS, _recv_json
from websockets.sync.client import connect

from gateway.bus import open_client
from gateway.live_view import ARM_RATE_HZ, LiveView
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState, Lifecycle, LifecycleMsg
from gateway.robot.description import DEFAULT_DESCRIPTION_PATH, load_description
from gateway.robot.kinematics import dh_world_T_tool
from gateway.robot.urdf import TOOL_LINK, to_urdf
from gateway.view_page.arm import cell_description

#: a different angle on every joint, so that a joint order mix-up moves the tool [rad]
Q_TEST_RAD = np.array([0.31, -0.42, 0.57, 0.26, -0.63, 0.74])
ARM_TOPICS = ("/tf", "/arm", "/arm/points", "/robot_description")
CHROMIUM = Path("/usr/bin/chromium")


def _advertised(ws, topics: set[str], put=None, timeout_s: float = 5.0) -> dict[str, dict]:
    """The channels advertised until all of ``topics`` are (``put()`` between reads)."""
    channels: dict[str, dict] = {}
    deadline = time.monotonic() + timeout_s
    while not topics <= channels.keys():
        assert time.monotonic() < deadline, f"not advertised: {topics - channels.keys()}"
        if put is not None:
            put()
        try:
            msg = ws.recv(timeout=0.1)
        except TimeoutError:
            continue
        if isinstance(msg, str) and json.loads(msg).get("op") == "advertise":
            channels.update({ch["topic"]: ch for ch in json.loads(msg)["channels"]})
    return channels


# --- protobuf, decoded with the descriptors the server advertises (no protobuf package) ------

_DOUBLE, _FLOAT, _MESSAGE = 1, 2, 11
_REPEATED = 3


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    out = shift = 0
    while True:
        byte = buf[i]
        i += 1
        out |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return out, i


def _wire_fields(buf: bytes) -> list[tuple[int, object]]:
    """(field number, raw value) pairs of one protobuf message."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i : i + 8], i + 8
        elif wire == 5:
            value, i = buf[i : i + 4], i + 4
        elif wire == 2:
            size, i = _varint(buf, i)
            value, i = buf[i : i + size], i + size
        else:
            raise AssertionError(f"wire type {wire}")
        out.append((number, value))
    return out


def _descriptors(schema_b64: str) -> dict[str, dict[int, tuple[str, int, int, str]]]:
    """message full name → field number → (name, type, label, type name), from a
    FileDescriptorSet (descriptor.proto's field numbers)."""
    messages = {}
    for _, file_bytes in _wire_fields(base64.b64decode(schema_b64)):
        file = _wire_fields(file_bytes)
        package = next((v.decode() for n, v in file if n == 2), "")
        for _, msg_bytes in (f for f in file if f[0] == 4):
            msg = _wire_fields(msg_bytes)
            name = next(v.decode() for n, v in msg if n == 1)
            fields = {}
            for _, field_bytes in (f for f in msg if f[0] == 2):
                fd = dict(_wire_fields(field_bytes))
                type_name = fd.get(6, b"").decode().lstrip(".")
                fields[fd[3]] = (fd[1].decode(), fd.get(5, 0), fd.get(4, 1), type_name)
            messages[f"{package}.{name}"] = fields
    return messages


def _decode(descriptors: dict, name: str, buf: bytes) -> dict:
    fields = descriptors[name]
    out: dict = {fname: [] for fname, _, label, _ in fields.values() if label == _REPEATED}
    for number, raw in _wire_fields(buf):
        fname, ftype, label, type_name = fields[number]
        if ftype == _MESSAGE:
            value = _decode(descriptors, type_name, raw)
        elif ftype == _DOUBLE:
            value = struct.unpack("<d", raw)[0]
        elif ftype == _FLOAT:
            value = struct.unpack("<f", raw)[0]
        else:
            value = raw.decode() if isinstance(raw, bytes) else raw
        if label == _REPEATED:
            out[fname].append(value)
        else:
            out[fname] = value
    return out


def _xyz(msg: dict) -> np.ndarray:
    return np.array([msg.get(k, 0.0) for k in "xyz"])  # proto3 leaves zeros out


def _homogeneous(translation: dict, rotation: dict) -> np.ndarray:
    xyzw = [rotation.get(k, 0.0) for k in "xyzw"]
    out = np.eye(4)
    out[:3, :3] = pin.Quaternion(np.array(xyzw)).toRotationMatrix()
    out[:3, 3] = _xyz(translation)
    return out


def _world_T(transforms: list[dict], frame: str) -> np.ndarray:
    """``world_T_frame`` composed from parent → child transforms."""
    by_child = {t["child_frame_id"]: t for t in transforms}
    out = np.eye(4)
    while frame != "world":
        t = by_child[frame]
        out = _homogeneous(t["translation"], t["rotation"]) @ out
        frame = t["parent_frame_id"]
    return out


def _put_state(pub, keys, cycle: int, q_rad: np.ndarray) -> None:
    state = make_joint_state(cycle, 0.008 * cycle, ControllerState.EXTERNAL, 2, q_rad, q_rad * 0,
                             np.ones(6), q_rad, q_rad * 0, 0.008)  # fmt: skip
    pub.put(keys.joint_state, state.to_bytes())


def test_the_arm_is_the_robot_the_cells_model_names(tmp_path):
    """As the control loads it (control/declared_model.py): a TOML model's ``robot``, relative
    to the model; the packaged GR630ST without a model."""
    text = DEFAULT_DESCRIPTION_PATH.read_text()
    assert 'name = "GR630ST"' in text
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "arm.toml").write_text(text.replace('"GR630ST"', '"GR630ST-B"', 1))
    (tmp_path / "model.toml").write_text(
        'format = "leadthrough-model"\nversion = 1\nrobot = "robots/arm.toml"\n'
    )
    cell = tmp_path / "cell.toml"
    cell.write_text('[control]\nmodel = "model.toml"\n')
    assert cell_description(cell).name == "GR630ST-B"
    cell.write_text("[bus]\n")
    assert cell_description(cell).name == "GR630ST"


def test_a_websocket_client_gets_the_arm_where_forward_kinematics_puts_it(router):
    keys = router.keys
    desc = load_description()
    urdf = to_urdf(desc)
    # The independent reference: our own pinocchio model and data of the same URDF, and the
    # plain standard-DH chain of the description.
    model = pin.buildModelFromXML(urdf)
    data = model.createData()
    pin.framesForwardKinematics(model, data, Q_TEST_RAD)
    world_T_tool = data.oMf[model.getFrameId(TOOL_LINK)].homogeneous
    np.testing.assert_allclose(world_T_tool, dh_world_T_tool(desc, Q_TEST_RAD), atol=1e-9)

    view = LiveView(router, port=0, robot=desc)
    view.start()
    pub = open_client(router)
    cycle = 0

    def put() -> None:
        nonlocal cycle
        cycle += 1
        _put_state(pub, keys, cycle, Q_TEST_RAD)

    try:
        time.sleep(0.5)  # the view's subscription reaches the router
        with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as ws:
            _recv_json(ws, "serverInfo")
            channels = _advertised(ws, {*ARM_TOPICS, keys.joint_state}, put)
            assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            assert channels["/arm"]["schemaName"] == "foxglove.SceneUpdate"
            assert {channels[t]["encoding"] for t in ("/tf", "/arm")} == {"protobuf"}
            described = channels["/robot_description"]
            assert described["encoding"] == "json"
            assert json.loads(described["schema"])["properties"]["data"]["type"] == "string"
            by_id = {}
            subscriptions = []
            for sub_id, topic in enumerate(ARM_TOPICS, start=1):
                by_id[sub_id] = topic
                subscriptions.append({"id": sub_id, "channelId": channels[topic]["id"]})
            ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
            got: dict[str, bytes] = {}
            deadline = time.monotonic() + 5.0
            while got.keys() != set(ARM_TOPICS) and time.monotonic() < deadline:
                put()
                try:
                    msg = ws.recv(timeout=0.02)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes) and msg[0] == 1:  # MessageData
                    got[by_id[struct.unpack_from("<I", msg, 1)[0]]] = msg[13:]
            assert got.keys() == set(ARM_TOPICS), f"missing {set(ARM_TOPICS) - got.keys()}"

            assert json.loads(got["/robot_description"])["data"] == urdf
            tf = _decode(
                _descriptors(channels["/tf"]["schema"]), "foxglove.FrameTransforms", got["/tf"]
            )["transforms"]
            links = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
            assert sorted(t["child_frame_id"] for t in tf) == sorted(links)
            np.testing.assert_allclose(_world_T(tf, TOOL_LINK), world_T_tool, atol=1e-9)

            scene = _decode(
                _descriptors(channels["/arm"]["schema"]), "foxglove.SceneUpdate", got["/arm"]
            )
            (entity,) = scene["entities"]
            assert entity["frame_id"] == "world" and len(entity["cylinders"]) >= 4
            spheres_m = [_xyz(s["pose"]["position"]) for s in entity["spheres"]]
            assert min(np.linalg.norm(p - world_T_tool[:3, 3]) for p in spheres_m) < 1e-9

            points = json.loads(got["/arm/points"])
            np.testing.assert_allclose(points["q_rad"], Q_TEST_RAD)
            np.testing.assert_allclose(points["tool_m"], world_T_tool[:3, 3], atol=1e-6)

            # At most ARM_RATE_HZ: one second of the bus's 125 Hz gives about 30 arms.
            arms = 0
            t_end = time.monotonic() + 1.0
            while time.monotonic() < t_end:
                put()
                time.sleep(0.008)
                while True:
                    try:
                        msg = ws.recv(timeout=0)
                    except TimeoutError:
                        break
                    arms += isinstance(msg, bytes) and struct.unpack_from("<I", msg, 1)[0] == 1
            assert 1 <= arms <= ARM_RATE_HZ + 3

            # The protocol has no latched channels: a client that comes later gets it anew.
            with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as late:
                _recv_json(late, "serverInfo")
                channel_id = _advertised(late, {"/robot_description"})["/robot_description"]["id"]
                subscribe = {"id": 9, "channelId": channel_id}
                late.send(json.dumps({"op": "subscribe", "subscriptions": [subscribe]}))
                msg = late.recv(timeout=5.0)
                while not isinstance(msg, bytes):
                    msg = late.recv(timeout=5.0)
                assert json.loads(msg[13:])["data"] == urdf
    finally:
        pub.close()
        view.stop()
    assert view.arm_count >= 2


def test_without_a_robot_the_view_serves_the_page_and_no_arm(router):
    view = LiveView(router, port=0, http_port=0)
    view.start()
    try:
        base = f"http://127.0.0.1:{view.http_port}"
        with urllib.request.urlopen(f"{base}/", timeout=5) as reply:
            html = reply.read().decode()
            assert reply.headers["Content-Type"].startswith("text/html")
        assert 'data-subprotocols="foxglove.sdk.v1 foxglove.websocket.v1"' in html
        assert f'data-ws-port="{view.port}"' in html and 'src="live_view.js"' in html
        with urllib.request.urlopen(f"{base}/live_view.js", timeout=5) as reply:
            assert "leadthrough.JointState" in reply.read().decode()
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f"{base}/../pyproject.toml", timeout=5)
        assert refused.value.code == 404
        refused.value.close()
        with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as ws:
            _recv_json(ws, "serverInfo")
            with pytest.raises(TimeoutError):
                ws.recv(timeout=0.5)  # nothing on the bus, no arm: nothing advertised
    finally:
        view.stop()


@pytest.mark.skipif(not CHROMIUM.exists(), reason=f"needs {CHROMIUM}")
def test_headless_chromium_shows_the_joint_states_the_lifecycle_and_the_arm(router, tmp_path):
    keys = router.keys
    view = LiveView(router, port=0, robot=load_description(), http_port=0)
    view.start()
    pub = open_client(router)
    stop = threading.Event()

    def feed() -> None:
        cycle = 0
        while not stop.wait(0.008):
            cycle += 1
            _put_state(pub, keys, cycle, Q_TEST_RAD * np.sin(0.01 * cycle))
            if cycle % 10 == 0:
                pub.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, cycle, 0.0).to_bytes())

    feeder = threading.Thread(target=feed, name="test-feed")
    feeder.start()
    try:
        time.sleep(0.5)  # the view's subscription reaches the router, the channels appear
        command = [
            str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
            "--no-first-run", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", f"--user-data-dir={tmp_path / 'chromium'}",
            "--virtual-time-budget=10000", "--dump-dom",
            f"http://127.0.0.1:{view.http_port}/",
        ]  # fmt: skip
        dom = subprocess.run(command, capture_output=True, text=True, timeout=60).stdout
    finally:
        stop.set()
        feeder.join()
        pub.close()
        view.stop()

    def shown(element_id: str) -> str:
        found = re.search(rf'id="{element_id}"[^>]*>([^<]*)<', dom)
        assert found, f"no #{element_id} in the page:\n{dom[:2000]}"
        return found.group(1)

    assert int(shown("joint-states")) > 0
    assert int(shown("arm-updates")) > 0
    assert shown("lifecycle") == "TEACHING"
