"""A playback recording that cannot be played (missing, a corrupt zip, NaN, empty, times that do
not increase) stops Bake, Bake Recording and Live Start before anything changes: one ERROR
report in Blender's report area that names the file and the fix, no traceback, the scene and
any earlier bake as they were.

Headless, modal timers never fire and there is no window to invoke an operator in: the tests call
the start functions the operators call (ops_bake.prepare, live.start), the operators (Bake and
Bake Recording run to the end from a script), and their invoke (what a click calls) directly."""

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import live, ops_bake, runtime
from haptic_hand.engine import devices

from blender_helpers import FakeSession, open_copy

# (name, file name, content or None for no file, words of the message)
BAD_RECORDINGS = [
    ("missing", "nope.npz", None, "does not exist"),
    ("corrupt zip", "take.npz", b"PK\x03\x04garbage", "is not a readable .npz recording"),
    ("NaN", "take.csv", b"0,0,0,0\n0.1,nan,0,0\n0.2,0,0,0\n", "must be finite"),
    ("empty", "take.csv", b"", "holds no rows"),
    ("times not increasing", "take.csv", b"0,0,0,0\n0.2,0,0,0\n0.1,0,0,0\n", "times must increase strictly"),
]
IDS = [b[0] for b in BAD_RECORDINGS]


def write(folder, name, content) -> str:
    if content is not None:
        (folder / name).write_bytes(content)
    return str(folder / name)


def snapshot(context) -> tuple:
    """What a refused start must leave as it was: objects, meshes and their vertices, actions,
    the frame, the bake's state and files beside the .blend."""
    s = context.scene.haptic_hand
    vertices = {}
    for me in bpy.data.meshes:
        co = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", co)
        vertices[me.name] = co.tobytes()
    folder = bpy.path.abspath("//")
    import pathlib

    return (sorted(o.name for o in bpy.data.objects), vertices, sorted(a.name for a in bpy.data.actions),
            {o.name: tuple(map(tuple, o.matrix_world)) for o in bpy.data.objects}, context.scene.frame_current,
            (s.baked, s.baked_range, s.bake_log), sorted(p.name for p in pathlib.Path(folder).rglob("*")))


def refused(capfd, run, words, path) -> str:
    """Runs an operator that must be refused: its ERROR report, checked, and no traceback."""
    capfd.readouterr()
    with pytest.raises(RuntimeError) as info:
        run()
    message = str(info.value)
    out, err = capfd.readouterr()
    assert message.startswith("Error: ") and words in message and path in message, message
    assert "Traceback" not in message + out + err
    return message


class Reports:
    """Stands in for an instance of the operator class (headless there is no window to invoke
    it in): its methods, and the reports it makes, recorded."""

    def __init__(self, operator):
        self.operator, self.reports = operator, []

    def report(self, level, message):
        self.reports.append((level, message))

    def __getattr__(self, name):
        value = getattr(self.operator, name)
        return value.__get__(self) if callable(value) else value


def invoke_refused(operator, context, words, path) -> str:
    """The operator's invoke, as a click calls it: CANCELLED with one ERROR report."""
    op = Reports(operator)
    assert operator.invoke(op, context, None) == {"CANCELLED"}
    [(level, message)] = op.reports
    assert level == {"ERROR"} and words in message and path in message, message
    return message


@pytest.fixture
def wave(addon, built_scenes, tmp_path):
    """The hand_wave scene (haptic loop on), 4 frames to bake, saved in tmp_path."""
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 4
    return context


def bake_refused(context, capfd, words, path, recording=None) -> None:
    """prepare() refuses the bake, and so does its operator, run from a script or invoked."""
    with pytest.raises((ops_bake.BakeError, devices.DeviceError), match=words):
        ops_bake.prepare(context, recording=recording)
    name = "bake" if recording is None else "bake_recording"
    if recording is not None and not bpy.ops.haptic_hand.bake_recording.poll():
        # no recording at all: the button is greyed out, its tooltip saying why
        with pytest.raises(RuntimeError, match="Record a live session first"):
            bpy.ops.haptic_hand.bake_recording()
        return
    refused(capfd, getattr(bpy.ops.haptic_hand, name), words, path)
    invoke_refused(getattr(ops_bake, f"HAPTIC_HAND_OT_{name}"), context, words, path)


@pytest.mark.parametrize("haptics", [True, False], ids=["haptic loop", "device trajectory"])
@pytest.mark.parametrize("name, file, content, words", BAD_RECORDINGS, ids=IDS)
def test_bake_refuses_a_bad_playback_file(wave, tmp_path, capfd, haptics, name, file, content, words):
    """With the haptic loop on the recording drives the playback device; with it off it becomes
    the device trajectory. Either way it is read before the bake starts."""
    context = wave
    s = context.scene.haptic_hand
    s.haptics_enabled = haptics
    s.device, s.device_file = "PLAYBACK", write(tmp_path, file, content)
    before = snapshot(context)
    bake_refused(context, capfd, words, s.device_file)
    assert snapshot(context) == before and runtime.state.bake is None


@pytest.mark.parametrize("name, file, content, words", BAD_RECORDINGS, ids=IDS)
def test_bake_recording_refuses_a_bad_recording(wave, tmp_path, capfd, name, file, content, words):
    context = wave
    s = context.scene.haptic_hand
    s.live_recording = write(tmp_path, file, content)
    before = snapshot(context)
    bake_refused(context, capfd, words, s.live_recording, recording=s.live_recording)
    assert bpy.ops.haptic_hand.bake_recording.poll() == (content is not None)
    assert snapshot(context) == before and runtime.state.bake is None


@pytest.mark.parametrize("name, file, content, words", BAD_RECORDINGS, ids=IDS)
def test_live_start_refuses_a_bad_playback_file(wave, tmp_path, capfd, name, file, content, words):
    context = wave
    s = context.scene.haptic_hand
    s.device, s.device_file = "PLAYBACK", write(tmp_path, file, content)
    before = snapshot(context)
    started = []

    def factory(*args, **kwargs):
        started.append(FakeSession(*args, **kwargs))
        return started[-1]

    with pytest.raises(live.LiveError, match=words):
        live.start(context, session_factory=factory)
    assert not started, "the recording is read before a session is made"
    invoke_refused(live.HAPTIC_HAND_OT_live, context, words, s.device_file)
    assert snapshot(context) == before and runtime.state.live is None
