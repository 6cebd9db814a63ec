"""Helpers shared by the Blender tests (a module with a unique name: every test folder has a
conftest.py, so `from conftest import ...` would be ambiguous)."""

from __future__ import annotations

import pathlib
import shutil

import haptic_hand

SAMPLES = pathlib.Path(haptic_hand.__file__).resolve().parent / "engine" / "sample_scenes"


def open_copy(path, folder) -> "bpy.types.Context":
    """Open a copy of the .blend at path saved in folder (a bake writes files beside it)."""
    import bpy

    target = pathlib.Path(folder) / pathlib.Path(path).name
    shutil.copy(path, target)
    bpy.ops.wm.open_mainfile(filepath=str(target))
    return bpy.context
