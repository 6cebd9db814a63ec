"""Device backends seen from Python: SpaceMouse HID reports decoded into pose increments,
playback files, OpenHaptics absent, and the scene's haptics fields checked."""

import math
import struct

import numpy as np
import pytest

from haptic_hand.engine import devices, native, scene as scenes
from test_haptics import Rig, hand_scene


def report(rid: int, *values: int) -> bytes:
    return bytes([rid]) + struct.pack(f"<{len(values)}h", *values)


def test_spacemouse_reports_decode_into_the_expected_pose_increments():
    state = devices.SpaceMouseState()
    # older devices: translation in report 1, rotation in report 2; buttons in report 3
    devices.decode_spacemouse_report(report(1, 350, 0, -175), state)
    devices.decode_spacemouse_report(report(2, 0, 0, 350), state)
    devices.decode_spacemouse_report(bytes([3, 0b101, 0]), state)
    assert np.allclose(state.translation, [1.0, 0.0, -0.5])
    assert np.allclose(state.rotation, [0.0, 0.0, 1.0])
    assert state.buttons == 0b101
    pose = devices.SpaceMouseIntegrator([0.0, 0.0, 0.0], max_speed=0.1, max_rate=1.0)
    for _ in range(100):  # 1 s in steps of 10 ms
        p, q = pose.advance(state, 0.01)
    # full right for 1 s at 0.1 m/s; half down (device +z is down) -> scene up at 0.05 m/s
    assert np.allclose(p, [0.1, 0.0, 0.05])
    # 1 rad/s about device z (down) for 1 s: -1 rad about scene z
    assert np.allclose(q, [0.0, 0.0, -math.sin(0.5), math.cos(0.5)])
    # newer devices: all six axes in report 1
    state2 = devices.decode_spacemouse_report(report(1, 0, 70, 0, -35, 0, 0), devices.SpaceMouseState())
    assert np.allclose(state2.translation, [0.0, 0.2, 0.0]) and np.allclose(state2.rotation, [-0.1, 0.0, 0.0])


def test_playback_file_replays_through_the_session(tmp_path):
    rig = Rig(hand_scene())
    path = tmp_path / "motion.csv"
    lines = ["t,x,y,z"] + [f"{t},{rig.com[0] + 0.01 * t},{rig.com[1]},{rig.com[2]}" for t in (0.0, 0.5, 1.0)]
    path.write_text("\n".join(lines) + "\n")
    t, p, q = devices.load_recording(path)
    rig.session.device_playback(t, p, q)
    rig.session.run_offline(15)
    log = rig.session.read_log()
    from haptic_hand.engine.native_session import log_arrays
    arrays = log_arrays(log)
    expected = rig.com[0] + 0.01 * arrays["t"]
    assert np.allclose(arrays["device_position"][:, 0], expected, atol=1e-12)


def test_bad_playback_files_are_named(tmp_path):
    with pytest.raises(devices.DeviceError, match="does not exist"):
        devices.load_recording(tmp_path / "missing.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("0,0,0,0\n0,1,1,1\n")
    with pytest.raises(devices.DeviceError, match="increase strictly"):
        devices.load_recording(bad)


def test_openhaptics_without_the_library_is_a_clear_error():
    rig = Rig(hand_scene())
    with pytest.raises(native.InvalidInput, match="OpenHaptics is not installed"):
        rig.session.device_openhaptics("/nonexistent/libHD.so")
    names = [d["name"] for d in devices.discover()]
    assert {"simulated", "playback", "external", "openhaptics"} <= set(names)


@pytest.mark.parametrize("field, value, words", [
    ("rate", 50.0, r"haptics.rate .* in \[100, 10000\]"),
    ("device", "phantom", "unknown"),
    ("max_force", -1.0, "positive"),
])
def test_bad_haptics_fields_are_named(field, value, words):
    data = {"format": scenes.FORMAT, "haptics": {"enabled": True, field: value}}
    with pytest.raises(scenes.SceneError, match=words):
        scenes.from_dict(data)


def test_coupling_stiffer_than_tested_is_refused():
    data = {"format": scenes.FORMAT, "haptics": {"enabled": True}, "coupling": {"stiffness": 1e6}}
    with pytest.raises(scenes.SceneError, match="coupling.stiffness"):
        scenes.from_dict(data)


class FakeHidDevice:
    """Stands in for hidapi's device: plays recorded reports, then fails like an unplugged one."""

    def __init__(self, reports, fail_after: float):
        self.reports, self.fail_after, self.opened = list(reports), fail_after, None

    def open_path(self, path):
        self.opened = path
        import time
        self.t0 = time.monotonic()

    def set_nonblocking(self, on):
        pass

    def read(self, size):
        import time
        if time.monotonic() - self.t0 > self.fail_after:
            raise OSError("read error")
        return self.reports.pop(0) if self.reports else []

    def close(self):
        pass


def test_hid_reader_pushes_integrated_poses_and_reports_an_unplugged_device(monkeypatch):
    import sys
    import time
    import types

    fake = FakeHidDevice([list(report(1, 350, 0, 0, 0, 0, 0))], fail_after=0.3)
    monkeypatch.setitem(sys.modules, "hid", types.SimpleNamespace(device=lambda: fake))
    pushed = []
    reader = devices.HidSpaceMouse(b"/dev/hidraw-test", lambda p, q: pushed.append((time.monotonic(), p)),
                                   np.zeros(3))
    time.sleep(0.6)
    reader.stop()
    assert fake.opened == b"/dev/hidraw-test"
    assert reader.error is not None and "unplugged" in reader.error
    # full right deflection: x grows at 0.1 m/s while the device answers, y and z stay
    (t0, p0), (t1, p1) = pushed[1], pushed[-1]
    assert p1[0] - p0[0] == pytest.approx(0.1 * (t1 - t0), rel=0.2)
    assert abs(p1[1]) < 1e-12 and abs(p1[2]) < 1e-12
