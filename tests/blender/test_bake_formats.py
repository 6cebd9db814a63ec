"""PC2 files and the haptic log (haptic_hand.engine.bake_formats: numpy only, no bpy)."""

import struct

import numpy as np
import pytest

from haptic_hand.engine import bake_formats


def test_pc2_layout_and_round_trip(tmp_path):
    frames = np.random.default_rng(1).normal(size=(5, 7, 3))
    path = bake_formats.write_pc2(tmp_path / "a.pc2", frames, start_frame=3.0, sample_rate=1.0)
    raw = path.read_bytes()
    # the layout Blender's Mesh Cache modifier reads: 32-byte header, then float32 x, y, z
    assert len(raw) == 32 + 5 * 7 * 3 * 4
    assert raw[:12] == b"POINTCACHE2\0"
    assert struct.unpack("<iiffi", raw[12:32]) == (1, 7, 3.0, 1.0, 5)
    assert struct.unpack("<3f", raw[32:44]) == tuple(np.float32(frames[0, 0]))
    back, start, rate = bake_formats.read_pc2(path)
    assert (start, rate) == (3.0, 1.0)
    np.testing.assert_array_equal(back, frames.astype(np.float32))
    assert not list(tmp_path.glob("*.partial*"))


def test_pc2_refuses_bad_input_and_keeps_the_old_file(tmp_path):
    path = bake_formats.write_pc2(tmp_path / "a.pc2", np.zeros((2, 3, 3)))
    before = path.read_bytes()
    with pytest.raises(bake_formats.BakeFormatError, match="NaN"):
        bake_formats.write_pc2(path, np.full((2, 3, 3), np.nan))
    with pytest.raises(bake_formats.BakeFormatError, match="shape"):
        bake_formats.write_pc2(path, np.zeros((2, 3)))
    assert path.read_bytes() == before
    path.write_bytes(before[:-4])
    with pytest.raises(bake_formats.BakeFormatError, match="truncated"):
        bake_formats.read_pc2(path)


def test_haptic_log_keeps_frames_and_haptic_rows(tmp_path):
    result = {"time": np.arange(3) / 30, "coupling_wrench": np.zeros((3, 6)), "positions": np.zeros((3, 10, 3)),
              "haptic": {"t": np.arange(66) / 1000, "force": np.zeros((66, 3))}}
    log = bake_formats.haptic_log(result)
    assert set(log) == {"time", "coupling_wrench", "haptic_t", "haptic_force"}  # not the positions
    path = bake_formats.write_log(tmp_path / "log.npz", log)
    with np.load(path) as back:
        assert back["haptic_t"].shape == (66,)
