"""Make the add-on source directory `addon/` importable as the package `haptic_hand`, the
name Blender and the CLI know it by, without installing it."""

import importlib.util
import pathlib
import sys

ADDON_DIR = pathlib.Path(__file__).resolve().parents[1] / "addon"

if "haptic_hand" not in sys.modules:
    spec = importlib.util.spec_from_file_location(
        "haptic_hand",
        ADDON_DIR / "__init__.py",
        submodule_search_locations=[str(ADDON_DIR)],
    )
    package = importlib.util.module_from_spec(spec)
    sys.modules["haptic_hand"] = package
    spec.loader.exec_module(package)
