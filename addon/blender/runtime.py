"""What runs now in this Blender process: the bake, the tetrahedralization and the live
session, with their progress. Kept in Python, never in the .blend: a file saved during a bake
reopens with nothing running (a setting in the file, even one marked SKIP_SAVE, would be
saved and keep Bake and Live greyed out for good).

Opening or reloading a file stops whatever runs (load_pre: its objects are about to go), and
load_post clears this state and any running-state settings older versions saved.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

# settings older versions of the add-on kept in the scene (and so in saved files)
STALE_KEYS = ("bake_running", "bake_progress", "bake_cancel", "live_running", "live_stop")


class Runtime:
    def __init__(self):
        self.bake = None          # ops_bake.BakeJob running
        self.tetrahedralize = None  # ops_rig.TetJob running
        self.live = None          # live.LiveState running
        self.live_stop = False    # the live session was asked to stop

    def busy(self) -> str:
        """What runs now ('' when nothing)."""
        if self.bake is not None:
            return "A bake is running"
        if self.live is not None:
            return "A live session is running"
        if self.tetrahedralize is not None:
            return "Tetrahedralize is running"
        return ""

    def stop_all(self) -> None:
        """Ends what runs (the child processes are killed, the live session stopped)."""
        job, self.bake = self.bake, None
        if job is not None:
            job.cancel()
            job.release()
        tet, self.tetrahedralize = self.tetrahedralize, None
        if tet is not None:
            tet.cancel()
            tet.release()
        state, self.live = self.live, None
        if state is not None:
            state.end(bpy.context)
        self.live_stop = False


state = Runtime()


def redraw() -> None:
    """Redraw the sidebar and the status bar (no-op headless)."""
    wm = bpy.context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type in ("VIEW_3D", "STATUSBAR"):
                area.tag_redraw()


@persistent
def _load_pre(*_args):
    state.stop_all()


@persistent
def _load_post(*_args):
    state.stop_all()
    for scene in bpy.data.scenes:
        settings = getattr(scene, "haptic_hand", None)
        if settings is None:
            continue
        for key in STALE_KEYS:
            if key in settings.keys():
                del settings[key]


def register():
    bpy.app.handlers.load_pre.append(_load_pre)
    bpy.app.handlers.load_post.append(_load_post)


def unregister():
    state.stop_all()
    for handlers, fn in ((bpy.app.handlers.load_pre, _load_pre), (bpy.app.handlers.load_post, _load_post)):
        while fn in handlers:
            handlers.remove(fn)
