"""Bus recording (MCAP) and its CSV export, over a real zenoh router."""

import time

import numpy as np
import pytest

from control.identification.datafile import read_measurements
from gateway.bus import BusConfig, open_client, open_router
from gateway.errors import DataFileError
from gateway.messages import ControllerState, IoState, encode_json, make_joint_state
from gateway.recorder import BusRecorder, export_csv, iter_mcap


@pytest.fixture
def router(port):
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}")
    session = open_router(bus)
    yield bus
    session.close()


def test_records_every_message_and_exports_the_measurement_csv(router, tmp_path):
    keys = router.keys
    rec = BusRecorder(router, tmp_path / "run.mcap", {"note": "test"})
    rec.start()
    pub = open_client(router)
    try:
        time.sleep(0.5)  # let the subscription reach the router
        pub.put(keys.io_state, IoState(1.0, 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
        for k in range(50):
            q = np.full(6, 0.01 * k)
            st = make_joint_state(100 + k, 1.0, ControllerState.EXTERNAL, 2, q, q * 0 + 0.1,
                                  np.ones(6), q, q * 0, 0.004)  # fmt: skip
            pub.put(keys.joint_state, st.to_bytes())
        pub.put(keys.health("control"), encode_json({"process": "control"}))
        pub.put(keys.joint_state, b"garbage that is not a JointState")
        time.sleep(0.5)
    finally:
        pub.close()
        rec.stop()
    assert rec.error is None
    topics = [topic for topic, _, _ in iter_mcap(tmp_path / "run.mcap")]
    assert topics.count(keys.joint_state) == 51 and keys.health("control") in topics
    gains = [46.21, 66.18, 39.0, 11.15, 11.15, 5.58]
    rows = export_csv(tmp_path / "run.mcap", tmp_path / "run.csv", gains, keys)
    assert rows == 50  # the garbage message is skipped, not exported
    m = read_measurements(tmp_path / "run.csv")  # gains come from the sidecar
    np.testing.assert_allclose(m.t[-1], 49 * 0.004)
    np.testing.assert_allclose(m.tau[0], gains)
    np.testing.assert_allclose(m.p[0], [6.0, 4.0])


def test_missing_or_corrupt_recording_is_a_clear_error(tmp_path):
    with pytest.raises(DataFileError, match="not found"):
        list(iter_mcap(tmp_path / "nope.mcap"))
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n truncated")
    with pytest.raises(DataFileError, match="not a readable MCAP"):
        list(iter_mcap(bad))
