"""`simulate --out` as a user can get it wrong: an output that is an input or a directory, a run
killed while writing, Ctrl-C or SIGTERM. Nothing is lost, nothing is left half-written."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import simulate

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "haptic_hand", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


@pytest.fixture
def scene_dir(tmp_path):
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", tmp_path / "tets.npz")
    (tmp_path / "moves.csv").write_text("0,0,0,0\n1,0.01,0,0\n")
    scene = {"format": "haptic_hand.scene/1", "hand": {"mesh": "procedural", "tets": "tets.npz"}, "frames": 3,
             "haptics": {"enabled": True, "device": "playback:moves.csv"}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    return tmp_path


@pytest.mark.parametrize("out, words", [("scene.json", "the scene file"), ("tets.npz", "hand.tets"),
                                        ("moves.csv", "haptics.device"), ("./sub/../tets.npz", "hand.tets"),
                                        (".", "is a directory")])
def test_an_output_that_is_an_input_or_a_directory_is_refused(scene_dir, out, words):
    before = {p.name: p.read_bytes() for p in scene_dir.iterdir()}
    (scene_dir / "sub").mkdir()
    proc = run_cli("simulate", "scene.json", "--out", out, "--quiet", cwd=scene_dir)
    assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr
    assert {p.name: p.read_bytes() for p in scene_dir.iterdir() if p.is_file()} == before


def test_a_partial_file_left_by_a_killed_run_is_removed_by_the_next(scene_dir):
    stray = simulate.partial_path(scene_dir / "R.npz")
    stray.write_bytes(b"half a zip")
    proc = run_cli("simulate", "scene.json", "--out", "R.npz", "--quiet", cwd=scene_dir)
    assert proc.returncode == 0, proc.stderr
    assert not stray.exists() and len(np.load(scene_dir / "R.npz")["time"]) == 4


def test_an_interrupted_write_leaves_no_partial_file_and_the_earlier_result(tmp_path, monkeypatch):
    out = tmp_path / "R.npz"
    simulate.write({"time": np.arange(3.0)}, out)
    before = out.read_bytes()

    def interrupted(path, **arrays):
        Path(path).write_bytes(b"PK half")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", interrupted)
    with pytest.raises(KeyboardInterrupt):
        simulate.write({"time": np.arange(5.0)}, out)
    assert out.read_bytes() == before and not simulate.partial_path(out).exists()


def test_sigterm_ends_a_run_cleanly(scene_dir):
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["frames"] = 3000
    (scene_dir / "long.json").write_text(json.dumps(scene))
    proc = subprocess.Popen([sys.executable, "-m", "haptic_hand", "simulate", "long.json", "--out", "L.npz",
                             "--quiet"], cwd=scene_dir, stderr=subprocess.PIPE, text=True)
    time.sleep(4)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
    assert not (scene_dir / "L.npz").exists() and not simulate.partial_path(scene_dir / "L.npz").exists()
