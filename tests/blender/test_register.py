"""The add-on registers and unregisters twice in a row without errors or leftovers."""

import pytest

bpy = pytest.importorskip("bpy")

import haptic_hand


def snapshot():
    """Everything an add-on can leave behind in Blender's Python state."""
    handlers = {name: len(getattr(bpy.app.handlers, name)) for name in dir(bpy.app.handlers)
                if isinstance(getattr(bpy.app.handlers, name), list)}
    menu = bpy.types.TOPBAR_MT_file_import
    menu_draws = len(menu._dyn_ui_initialize()) if hasattr(menu, "_dyn_ui_initialize") else 0
    return {
        "types": sorted(n for n in dir(bpy.types) if "HAPTIC_HAND" in n.upper() or n.startswith("Haptic")),
        "ops": sorted(dir(bpy.ops.haptic_hand)),
        "scene_prop": hasattr(bpy.types.Scene, "haptic_hand"),
        "object_prop": hasattr(bpy.types.Object, "haptic_hand"),
        "bone_prop": hasattr(bpy.types.Bone, "haptic_hand"),
        "handlers": handlers,
        "menu_draws": menu_draws,
    }


def handlers_added(during, before) -> dict:
    return {k: during["handlers"][k] - before["handlers"][k] for k in before["handlers"]
            if during["handlers"][k] != before["handlers"][k]}


def test_register_unregister_twice_leaves_nothing():
    from haptic_hand.blender import draw, runtime

    bpy.ops.wm.read_factory_settings(use_empty=True)
    before = snapshot()
    assert before["types"] == [] and before["ops"] == [] and not before["scene_prop"], \
        "the add-on is registered before the test: another test leaked it"
    for _ in range(2):
        haptic_hand.register()
        during = snapshot()
        # what registering adds, so the "after" comparison below can fail
        assert during["scene_prop"] and during["object_prop"] and during["bone_prop"]
        assert {"bake", "tetrahedralize", "place_seed", "live", "mark_body", "free_bake", "use_armature"} <= \
            set(during["ops"])
        assert "HAPTIC_HAND_PT_main" in during["types"]
        assert during["menu_draws"] == before["menu_draws"] + 1
        assert len(draw._handles) == 2  # the live session's overlay and the skeleton's capsules
        bpy.context.scene.haptic_hand.handle_radius = 0.02  # the properties work
        haptic_hand.unregister()
        assert snapshot() == before
        assert not draw._handles and draw.overlay is None
        assert not runtime.state.busy()
        assert handlers_added(during, before) == {"load_pre": 1, "load_post": 1}


def test_engine_imports_without_bpy():
    """haptic_hand.engine must not import bpy (it runs outside Blender)."""
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    code = textwrap.dedent(f"""
        import builtins, sys
        real = builtins.__import__
        def guard(name, *a, **k):
            if name == "bpy" or name.startswith("bpy."):
                raise ImportError("bpy imported by the engine")
            return real(name, *a, **k)
        builtins.__import__ = guard
        sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
        import conftest
        from haptic_hand.engine import bake_formats, mesh, scene, simulate, bodies, native
        import haptic_hand
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr
