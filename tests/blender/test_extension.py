"""The extension zip: built by scripts/build_addon.py (make addon), valid for Blender's tool,
installable, and once installed it registers and loads the native library bundled inside."""

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[2]

INSTALL = r"""
import json, sys
import bpy
zip_path = sys.argv[-1]
out = {"install": sorted(bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                                 enable_on_install=True))}
from importlib import import_module
pkg = "bl_ext.user_default.haptic_hand"
native = import_module(pkg + ".engine.native")
native.library()
maps = open("/proc/self/maps").read()
out["lib"] = sorted({line.split()[-1] for line in maps.splitlines() if "libhaptic_hand" in line})
out["registered"] = hasattr(bpy.types.Scene, "haptic_hand") and "tetrahedralize" in dir(bpy.ops.haptic_hand)
import addon_utils
addon_utils.disable(pkg)
out["unregistered"] = not hasattr(bpy.types.Scene, "haptic_hand")
print("RESULT " + json.dumps(out))
"""


def test_extension_zip_installs_and_loads_bundled_library(tmp_path):
    if not (ROOT / "build" / "native" / "libhaptic_hand.so").is_file():
        pytest.skip("the native library is not built (make native)")
    # the small variant (no wheels: this venv has them); `make addon` bundles them too
    subprocess.run([sys.executable, str(ROOT / "scripts" / "build_addon.py"), "--no-wheels", "--out",
                    str(tmp_path)], check=True, capture_output=True)
    zip_path = tmp_path / "haptic_hand-0.1.0-nowheels.zip"
    with zipfile.ZipFile(zip_path) as z:
        names = set(z.namelist())
    assert {"blender_manifest.toml", "__init__.py", "lib/libhaptic_hand.so", "blender/ops_bake.py",
            "engine/native.py", "engine/sample_scenes/procedural_hand_tets.npz"} <= names
    assert not [n for n in names if "__pycache__" in n]
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender_user"))
    script = tmp_path / "install.py"
    script.write_text(INSTALL)
    run = subprocess.run([sys.executable, str(script), str(zip_path)], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=120)
    line = next((l for l in run.stdout.splitlines() if l.startswith("RESULT ")), None)
    assert line, run.stdout + run.stderr
    out = json.loads(line[len("RESULT "):])
    assert out["install"] == ["FINISHED"]
    installed = str(tmp_path / "blender_user" / "extensions" / "user_default" / "haptic_hand" / "lib")
    assert out["lib"] and all(p.startswith(installed) for p in out["lib"]), out["lib"]
    assert out["registered"] and out["unregistered"]
