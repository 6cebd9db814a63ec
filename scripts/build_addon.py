"""`make addon`: the installable Blender extension zip.

Stages a copy of addon/ in build/addon/ with the native library in lib/ (where
engine/native.py looks inside an installed extension) and the Python wheels the add-on imports
at run time in wheels/, lists the wheels in the staged manifest, then builds and validates the
zip with Blender's own extension tool (bl_pkg/cli/blender_ext.py, shipped in the bpy wheel).

The wheels: scipy, pytetwild and hidapi, without their dependencies (numpy comes with
Blender). pyvista and vtk (140 MB) stay out: pytetwild's package imports pyvista, but its
numpy API needs only its own compiled wrapper, which the tetrahedralizing child process loads
without pyvista (engine/child.py); and the procedural shapes of the sample scenes (marching
cubes by vtk) are written into the staged sample scenes as .obj meshes and .npz tets here, so
File > Import brings them in without vtk. A scene of the user's own with procedural meshes
needs pyvista installed into Blender's Python (the importer says so).

    python scripts/build_addon.py [--out out] [--no-wheels]
"""

from __future__ import annotations

import argparse
import glob
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ("scipy", "pytetwild", "hidapi")  # pinned in requirements.txt; their only dependency is numpy
BLENDER_HAS = ("numpy",)
# Bundled versions other than the venv's: each wheel must import on the numpy of every Blender
# the manifest names. Blender 4.2 LTS ships numpy 1.24.3; scipy 1.16 and newer need numpy 1.25 or
# newer (scipy 1.17.1, the venv's, fails at `from numpy.exceptions import AxisError`), while
# scipy 1.15.3 imports and runs the engine on numpy 1.24.3 and on 1.26.4 (Blender 4.4 to 5.0).
BUNDLE_PINS = {"scipy": "1.15.3"}
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64", "linux_x86_64")


def pins() -> list[str]:
    wanted = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.-]+)==([^\s#]+)", line.strip())
        if m and m.group(1).lower() in BUNDLED + BLENDER_HAS:
            name = m.group(1).lower()
            wanted[name] = f"{m.group(1)}=={BUNDLE_PINS.get(name, m.group(2))}"
    missing = [p for p in BUNDLED if p not in wanted]
    if missing:
        sys.exit(f"requirements.txt pins no version of {', '.join(missing)}: pin them (name==version)")
    return list(wanted.values())


def download_wheels(cache: Path) -> list[Path]:
    cache.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--python-version",
           "3.11", "--implementation", "cp", "-d", str(cache)]
    for p in PLATFORMS:
        cmd += ["--platform", p]
    subprocess.run(cmd + pins(), check=True)
    # the pinned file of each distribution (a cache filled by an older build may hold others),
    # numpy left to Blender
    pinned = {pin.lower().replace("==", "-") for pin in pins()}
    chosen = {}
    for whl in sorted(cache.glob("*.whl")):
        dist, version = whl.name.split("-")[:2]
        if dist.lower() in BUNDLED and f"{dist.lower()}-{version}" in pinned:
            chosen[dist.lower()] = whl
    return sorted(chosen.values())


def stage_sample_scenes(folder: Path) -> None:
    """Writes the sample scenes' procedural meshes (and their tets, when a scene does not
    store them) as files beside the staged scenes, so importing them needs no pyvista or vtk.
    The shapes are the engine's own, at full precision: the scenes are the same."""
    sys.path.insert(0, str(ROOT / "tests"))
    import conftest  # noqa: F401  (addon/ as the package haptic_hand)
    import numpy as np

    from haptic_hand.engine import mesh, shapes

    def write_obj(name, surface):
        mesh.save_obj(folder / name, *surface)
        return name

    written = {}
    for path in sorted(folder.glob("*.json")):
        data = json.loads(path.read_text())
        hand = data["hand"]
        if hand.get("mesh") == "procedural":
            hand["mesh"] = written.get("hand") or write_obj("procedural_hand.obj", mesh.procedural_hand())
            written["hand"] = hand["mesh"]
            hand.setdefault("palm_seed", mesh.procedural_hand_palm_seed().tolist())
        for body in data.get("bodies", []):
            source = body.get("mesh")
            if not (isinstance(source, str) and source.startswith("procedural:")):
                continue
            name = source.split(":", 1)[1].replace(":", "_")
            if source == "procedural:bunny":
                surface, tets = shapes.procedural_bunny, shapes.procedural_bunny_coarse_tets
            else:
                letter = source.split(":", 2)[2]
                surface, tets = (lambda ch=letter: shapes.procedural_letter(ch)), (lambda ch=letter: shapes.letter_tets(ch))
            if name not in written:
                written[name] = write_obj(f"procedural_{name}.obj", surface())
            body["mesh"] = written[name]
            if not body.get("tets"):
                nodes, t = tets()
                np.savez(folder / f"procedural_{name}_tets.npz", nodes=nodes, tets=t)
                body["tets"] = f"procedural_{name}_tets.npz"
        path.write_text(json.dumps(data, indent=2))


def extension_tool() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    roots = [Path(p) for p in (spec.submodule_search_locations or [])] if spec else []
    for root in roots:
        found = glob.glob(str(root / "**" / "bl_pkg" / "cli" / "blender_ext.py"), recursive=True)
        if found:
            return Path(found[0])
    sys.exit("Blender's extension tool (bl_pkg/cli/blender_ext.py) was not found: install the bpy wheel "
             "(make venv)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "out"))
    parser.add_argument("--no-wheels", action="store_true",
                        help="leave the wheels out (a small zip for a Blender whose Python has them already)")
    args = parser.parse_args(argv)
    lib = ROOT / "build" / "native" / "libhaptic_hand.so"
    if not lib.is_file():
        sys.exit(f"{lib} is missing: run `make native` first")
    stage = ROOT / "build" / "addon"
    shutil.rmtree(stage, ignore_errors=True)
    shutil.copytree(ROOT / "addon", stage, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "lib", "wheels",
                                                                        "*.partial*"))
    (stage / "lib").mkdir()
    shutil.copy2(lib, stage / "lib" / lib.name)
    stage_sample_scenes(stage / "engine" / "sample_scenes")
    wheels = [] if args.no_wheels else download_wheels(ROOT / "build" / "addon_wheels")
    if wheels:
        (stage / "wheels").mkdir()
        for whl in wheels:
            shutil.copy2(whl, stage / "wheels" / whl.name)
        manifest = stage / "blender_manifest.toml"
        listed = ",\n".join(f'  "./wheels/{w.name}"' for w in wheels)
        text = manifest.read_text().replace("# wheels = [...]  (written into the staged copy by `make addon`)",
                                            f"wheels = [\n{listed},\n]")
        manifest.write_text(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tool = extension_tool()
    version = re.search(r'^version = "([^"]+)"', (stage / "blender_manifest.toml").read_text(), re.M).group(1)
    zip_path = out / f"haptic_hand-{version}{'-nowheels' if args.no_wheels else ''}.zip"
    subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(stage), "--output-filepath",
                    str(zip_path)], check=True)
    subprocess.run([sys.executable, str(tool), "validate", str(zip_path)], check=True)
    print(f"extension: {zip_path} ({zip_path.stat().st_size / 1e6:.0f} MB, {len(wheels)} wheels, native library "
          f"{lib.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
