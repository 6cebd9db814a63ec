"""Blender tests: the add-on in the bpy module, headless. Skipped when bpy is not importable.

Timers and modal-operator timer events never fire in the bpy module or in `blender --background`,
so the tests call the step functions the modal operators call (ops_bake.prepare/poll_job,
live.start/update/stop)."""

from __future__ import annotations

import pathlib

import pytest

try:
    import bpy
except ImportError:  # the test modules skip themselves (pytest.importorskip)
    bpy = None

import haptic_hand  # noqa: E402  (tests/conftest.py maps addon/ to this name)
from blender_helpers import SAMPLES  # noqa: E402


@pytest.fixture
def addon():
    """A fresh empty Blender with the add-on registered; unregistered afterwards."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    haptic_hand.register()
    yield bpy.context
    haptic_hand.unregister()
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture(scope="session")
def built_scenes(tmp_path_factory):
    """Sample scenes built once per run into .blend files: {name: path}. Soft bodies' tets are
    made once here (pytetwild is not deterministic) and stored in the .blend."""
    folder = tmp_path_factory.mktemp("blends")
    cache = {}

    def build(name: str) -> pathlib.Path:
        if name not in cache:
            from haptic_hand.blender import scene_import

            registered = hasattr(bpy.types.Scene, "haptic_hand")
            bpy.ops.wm.read_factory_settings(use_empty=True)
            if not registered:
                haptic_hand.register()
            try:
                scene_import.build(bpy.context, SAMPLES / f"{name}.json")
                path = folder / f"{name}.blend"
                bpy.ops.wm.save_as_mainfile(filepath=str(path))
            finally:
                if not registered:
                    haptic_hand.unregister()
            cache[name] = path
        return cache[name]

    return build
