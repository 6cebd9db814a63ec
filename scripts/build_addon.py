"""`make addon`: the installable Blender extension zip.

Stages a copy of addon/ in build/addon/ with the native library in lib/ (where
engine/native.py looks inside an installed extension) and the Python wheels the add-on needs
in wheels/ (numpy is left out: Blender ships it), lists the wheels in the staged manifest,
then builds and validates the zip with Blender's own extension tool (bl_pkg/cli/blender_ext.py,
shipped in the bpy wheel).

    python scripts/build_addon.py [--out out] [--no-wheels]
"""

from __future__ import annotations

import argparse
import glob
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ("scipy", "pytetwild", "pyvista", "vtk", "hidapi")  # pinned in requirements.txt
BLENDER_HAS = ("numpy",)
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64", "linux_x86_64")


def pins() -> list[str]:
    wanted = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.-]+)==([^\s#]+)", line.strip())
        if m and m.group(1).lower() in BUNDLED + BLENDER_HAS:
            wanted[m.group(1).lower()] = f"{m.group(1)}=={m.group(2)}"
    missing = [p for p in BUNDLED if p not in wanted]
    if missing:
        sys.exit(f"requirements.txt pins no version of {', '.join(missing)}: pin them (name==version)")
    return list(wanted.values())


def download_wheels(cache: Path) -> list[Path]:
    cache.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--only-binary=:all:", "--python-version", "3.11",
           "--implementation", "cp", "-d", str(cache)]
    for p in PLATFORMS:
        cmd += ["--platform", p]
    subprocess.run(cmd + pins(), check=True)
    # only the newest file of each distribution, numpy left to Blender
    chosen = {}
    for whl in sorted(cache.glob("*.whl")):
        dist = whl.name.split("-")[0].lower().replace("-", "_")
        if dist not in BLENDER_HAS:
            chosen[dist] = whl
    return sorted(chosen.values())


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
