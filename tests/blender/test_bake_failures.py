"""A bake that fails at any write leaves the previous bake exactly as it was, and says so
truthfully; a crash or a runaway allocation in the bake's child process ends only the child.

The previous bake here is a point cache (two .pc2 files, the log, keyed forces); the new one
fails at each write in turn: the log, either cache, a shape key, an F-curve, moving the staged
files into place, reading the child's result."""

import hashlib
import json
import os
import signal
import sys

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import bake_store, ops_bake, runtime
from haptic_hand.engine import bake_formats, child

from blender_helpers import open_copy


def snapshot(context) -> dict:
    """Everything a bake writes, as it stands: keys and their positions, modifiers, actions,
    transforms, custom properties, the scene's bake settings, and every file of the bake."""
    out = {}
    for obj in sorted(context.scene.objects, key=lambda o: o.name):
        state = {"matrix": tuple(map(tuple, obj.matrix_world)), "baked": obj.haptic_hand.baked,
                 "props": sorted(obj.keys()), "modifiers": [(m.type, getattr(m, "filepath", "")) for m in obj.modifiers],
                 "action": obj.animation_data.action.name if obj.animation_data and obj.animation_data.action else None}
        if obj.type == "MESH" and obj.data.shape_keys is not None:
            key = obj.data.shape_keys
            state["keys"] = {}
            for b in key.key_blocks:
                co = np.empty(len(b.data) * 3, dtype=np.float32)
                b.data.foreach_get("co", co)
                state["keys"][b.name] = hashlib.sha1(co.tobytes()).hexdigest()
            state["key_action"] = key.animation_data.action.name if key.animation_data and key.animation_data.action \
                else None
        out[obj.name] = state
    s = context.scene.haptic_hand
    out["scene"] = (s.baked, s.baked_format, s.baked_range, s.bake_log)
    out["actions"] = sorted(a.name for a in bpy.data.actions)
    folder = bake_store.cache_dir()
    out["files"] = {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())} \
        if folder.exists() else {}
    return out


class Fail:
    """Replaces a function by one that raises on its n-th call (counting every call)."""

    def __init__(self, monkeypatch, owner, name, nth, error):
        self.real, self.nth, self.calls, self.error = getattr(owner, name), nth, 0, error
        monkeypatch.setattr(owner, name, self)

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.nth:
            raise self.error
        return self.real(*args, **kwargs)


@pytest.fixture
def baked(addon, built_scenes, tmp_path):
    """The bunny scene with a 6-frame point-cache bake stored: the previous bake."""
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 6, "PC2"
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    assert sorted(p.name for p in bake_store.cache_dir().iterdir()) == ["Hand.pc2", "bunny.pc2", "haptic_log.npz"]
    s.bake_frame_end = 8  # the new bake: longer, so every file it writes differs
    return context


FULL_DISK = OSError(28, "No space left on device")
INJECTIONS = [
    # (new bake's format, where, function, n-th call, error)
    ("PC2", "log", (bake_formats, "write_log"), 1, FULL_DISK),
    ("PC2", "first cache", (bake_formats, "write_pc2"), 1, FULL_DISK),
    ("PC2", "second cache", (bake_formats, "write_pc2"), 2, FULL_DISK),
    ("KEYS", "a shape key", (bake_store, "fill_key"), 5, RuntimeError("internal error setting the array")),
    ("KEYS", "an F-curve", (bake_store, "fcurve"), 9, RuntimeError("F-Curve already exists")),
    ("PC2", "moving the files into place", (bake_store, "move"), 2, OSError(13, "Permission denied")),
    ("KEYS", "moving the files into place", (bake_store, "move"), 1, OSError(18, "Invalid cross-device link")),
    ("PC2", "reading the result", (child, "load_result"), 1, ValueError("truncated file")),
]


@pytest.mark.parametrize("fmt, where, target, nth, error", INJECTIONS, ids=[f"{f}-{w}-{n}" for f, w, _, n, _ in
                                                                           INJECTIONS])
def test_a_failed_write_leaves_the_previous_bake(baked, monkeypatch, fmt, where, target, nth, error):
    context = baked
    s = context.scene.haptic_hand
    s.bake_format = fmt
    before = snapshot(context)
    fail = Fail(monkeypatch, *target, nth, error)
    job = ops_bake.prepare(context)
    runtime.state.bake = job.start()
    job.child.wait()
    state = ops_bake.poll_job(context, job)  # must not raise, whatever failed
    assert fail.calls >= nth, f"the bake never reached {where}"
    assert state == "FAILED"
    level, message = ops_bake.end_message(job, state)
    assert level == "ERROR" and "Writing the bake failed" in message and str(error.args[-1]) in message
    assert message.endswith("the previous bake is unchanged")
    assert snapshot(context) == before, "the previous bake changed"
    assert not list(bake_store.cache_dir().glob(".staging-*")), "no staging folder left behind"
    assert bpy.ops.haptic_hand.free_bake.poll() and runtime.state.bake is None
    if where == "a shape key":  # the next bake goes through and replaces the previous one
        monkeypatch.setattr(*target, fail.real)
        assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
        assert s.baked_range == "1-8" and s.baked_format == fmt


def crashing_child(*lines) -> list:
    """A child that reports progress lines, then runs the given Python lines."""
    progress = json.dumps({"progress": 0.3, "message": "frame 3/9"})
    code = [f"import os, signal, sys", f"sys.stdout.write({child.EVENT + progress!r} + '\\n')", "sys.stdout.flush()",
            *lines]
    return [sys.executable, "-c", "\n".join(code)]


@pytest.mark.parametrize("kind", ["segfault", "killed", "runaway allocation", "exit without result"])
def test_a_crashing_child_ends_only_the_child(baked, kind):
    """A native crash, a kill by the OOM killer, an allocation past the child's limit: Blender
    (this process) lives on, reports why, and keeps the previous bake."""
    context = baked
    before = snapshot(context)
    body = {"segfault": ["os.kill(os.getpid(), signal.SIGSEGV)"],
            "killed": ["os.kill(os.getpid(), signal.SIGKILL)"],
            # past the limit the host sets on the child (waited for): fails at once, touches nothing
            "runaway allocation": ["import resource, time",
                                   "for _ in range(500):",
                                   "    if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY: break",
                                   "    time.sleep(0.01)",
                                   "else: sys.exit(5)",
                                   "x = bytearray(resource.getrlimit(resource.RLIMIT_AS)[0] + (1 << 30))"],
            "exit without result": ["sys.exit(3)"]}[kind]
    job = ops_bake.prepare(context)
    job.child = child.Child(job.child.args, what="The bake's engine process", argv=crashing_child(*body))
    runtime.state.bake = job.start()
    assert job.child.wait(timeout=60) == "FAILED"
    assert job.progress == pytest.approx(0.3), "its progress reached the host before it died"
    state = ops_bake.poll_job(context, job)
    assert state == "FAILED"
    expected = {"segfault": "crashed (SIGSEGV)", "killed": "running out of memory",
                "runaway allocation": "ran out of memory", "exit without result": "exit status 3"}[kind]
    assert expected in job.error and "Blender is unaffected" in job.error, job.error
    assert snapshot(context) == before


def test_the_child_is_contained(baked):
    """The child's address space is limited and the OOM killer takes it first."""
    job = ops_bake.prepare(bpy.context)
    job.child = child.Child(job.child.args, argv=crashing_child("import time", "time.sleep(30)"))
    job.start()
    try:
        pid = job.child.process.pid
        import resource

        assert resource.prlimit(pid, resource.RLIMIT_AS)[0] == child.memory_limit() > 0
        assert open(f"/proc/{pid}/oom_score_adj").read().strip() == "1000"
        job.cancel()
        assert job.child.poll() == "CANCELLED" and job.child.process.returncode == -signal.SIGTERM
    finally:
        job.release()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
