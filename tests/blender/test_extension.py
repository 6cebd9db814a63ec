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
import json, os, sys
# pyvista and vtk are not bundled: make them unimportable here and in the child processes
# (they inherit this sys.path), as in a Blender that never had them
blocker = sys.argv[-2]
sys.path.insert(0, blocker)
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
# a bundled sample scene imports without vtk; its hand tetrahedralizes in a child process run
# from the installed extension's own files
engine_dir = os.path.dirname(native.__file__)
scene_import = import_module(pkg + ".blender.scene_import")
objects = scene_import.build(bpy.context, os.path.join(engine_dir, "sample_scenes", "bunny_press.json"))
out["imported"] = sorted(objects)
hand = objects["hand"]
hand.haptic_hand.edge_length_fac, hand.haptic_hand.coarsen, hand.haptic_hand.epsilon = 0.25, True, 0.005
bpy.context.view_layer.objects.active = hand
hand.select_set(True)
out["tetrahedralize"] = sorted(bpy.ops.haptic_hand.tetrahedralize())
child = import_module(pkg + ".engine.child")
argv, env = child.command("tetrahedralize")
out["child"] = argv[1:3]
import subprocess
out["child_file"] = subprocess.run([argv[0], "-c", "import haptic_hand.engine.child as c; print(c.__file__)"],
                                   env=env, capture_output=True, text=True).stdout.strip()
out["pyvista"] = "pyvista" in sys.modules
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
            "engine/native.py", "engine/child.py", "engine/sample_scenes/procedural_hand_tets.npz",
            "engine/sample_scenes/procedural_hand.obj", "engine/sample_scenes/procedural_bunny.obj"} <= names
    assert not [n for n in names if "__pycache__" in n]
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender_user"))
    script = tmp_path / "install.py"
    script.write_text(INSTALL)
    blocker = tmp_path / "no_vtk"
    for name in ("pyvista", "vtk", "vtkmodules"):
        (blocker / name).mkdir(parents=True)
        (blocker / name / "__init__.py").write_text(f"raise ImportError('{name} is not installed here')\n")
    run = subprocess.run([sys.executable, str(script), str(blocker), str(zip_path)], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=300)
    line = next((l for l in run.stdout.splitlines() if l.startswith("RESULT ")), None)
    assert line, run.stdout + run.stderr
    out = json.loads(line[len("RESULT "):])
    assert out["install"] == ["FINISHED"]
    installed = str(tmp_path / "blender_user" / "extensions" / "user_default" / "haptic_hand" / "lib")
    assert out["lib"] and all(p.startswith(installed) for p in out["lib"]), out["lib"]
    assert out["registered"] and out["unregistered"]
    assert {"hand", "bunny", "ground", "seed", "target"} <= set(out["imported"])
    assert out["tetrahedralize"] == ["FINISHED"], run.stdout[-3000:] + run.stderr[-3000:]
    assert out["child"] == ["-m", "haptic_hand.engine.child"]  # the folder's own name, not bl_ext.*
    assert out["child_file"].startswith(installed.rsplit("/", 1)[0]), out["child_file"]
    assert not out["pyvista"]


def test_extension_wheels_are_the_ones_imported_at_run_time():
    """The full zip bundles scipy, pytetwild and hidapi, never pyvista or vtk (140 MB)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import build_addon

    assert set(build_addon.BUNDLED) == {"scipy", "pytetwild", "hidapi"}
