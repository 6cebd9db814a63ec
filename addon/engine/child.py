"""Long work in a child process: tetrahedralizing and baking, off the host's process (the
Blender add-on), as FLIP Fluids does. A native fault or a runaway allocation ends the child,
never the host; a cancel is a signal; progress streams back line by line.

The child (this module run as a program, by `command`):

    python -m haptic_hand.engine.child tetrahedralize <in.npz> <out.npz>
    python -m haptic_hand.engine.child bake <scene.json> <out.npz>

writes its events on stdout as lines that start with EVENT (JSON objects: {"progress": f,
"message": m}, then {"done": {...}} or {"error": message}); every other line is fTetWild's own
log, which the host reads for the tetrahedralization's stages (TetwildLog), since fTetWild
holds Python's GIL for its whole call and cannot report anything itself.

The host side (`Child`) starts the process, reads its lines on a thread, limits its address
space and makes it the OOM killer's first choice, and turns a crash, a signal or an exit
without a result into a message. Never imports bpy.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import types
from pathlib import Path

import numpy as np

EVENT = "\x1ehaptic_hand "  # starts the child's own lines (fTetWild's log lines do not)
# fTetWild's tet counts, measured on a cube, two scanned hands, a bunny and the procedural
# hand (10 runs, 800 to 49k tets): one tet per L^3 / 6.7 of volume for edge length L, plus
# about 6.5 sqrt(area) / envelope tets along the surface, whatever the edge length
TETS_PER_EDGE_CUBE = 6.7
SURFACE_TETS = 6.5


class ChildError(RuntimeError):
    """The child failed; the message says why and what to do."""


# --------------------------------------------------------------------------------------------
# The child
# --------------------------------------------------------------------------------------------


def emit(**event) -> None:
    sys.stdout.write(EVENT + json.dumps(event) + "\n")
    sys.stdout.flush()


def _progress(fraction: float, message: str) -> None:
    emit(progress=float(fraction), message=str(message))


def _pytetwild_without_pyvista() -> None:
    """Makes `import pytetwild` give its numpy API without importing pyvista and vtk.

    pytetwild's package __init__ imports pyvista (for an accessor on pyvista meshes), though
    `tetrahedralize` needs only its compiled wrapper and numpy; so the package is stood in by
    a module holding that one function, loaded from pytetwild's own files. fTetWild is asked
    for its log (quiet=False), which the host reads as progress."""
    if "pytetwild" in sys.modules:
        return
    spec = importlib.util.find_spec("pytetwild")
    if spec is None or not spec.submodule_search_locations:
        return  # mesh.tetrahedralize then says pytetwild is missing
    package = types.ModuleType("pytetwild")
    package.__path__ = list(spec.submodule_search_locations)
    sys.modules["pytetwild"] = package
    core = importlib.import_module("pytetwild.pytetwild")

    def tetrahedralize(*args, **kwargs):
        kwargs.update(quiet=False, loglevel=2)
        return core.tetrahedralize(*args, **kwargs)

    package.tetrahedralize = tetrahedralize


def _line_buffered_c_stdout() -> None:
    """fTetWild writes its log through C's stdout, block-buffered into a pipe: make it
    line-buffered so each stage reaches the host when it happens."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        stream = ctypes.c_void_p.in_dll(libc, "stdout")
        libc.setvbuf(stream, None, 1, 0)  # _IOLBF
    except (OSError, ValueError, AttributeError):
        pass


def run_tetrahedralize(in_path: str, out_path: str) -> dict:
    from . import mesh as meshing

    with np.load(in_path) as given:
        V, F = given["vertices"], given["faces"]
        options = dict(edge_length_fac=float(given["edge_length_fac"]), coarsen=bool(given["coarsen"]),
                       epsilon=float(given["epsilon"]))
    _pytetwild_without_pyvista()
    _line_buffered_c_stdout()
    nodes, tets = meshing.tetrahedralize(V, F, progress=lambda f, m: _progress(0.95 * f, m), **options)
    _progress(0.96, "measuring how far the surface lies outside the tets")
    gap = surface_gap(nodes, tets, V)
    np.savez(out_path, nodes=nodes, tets=tets, gap=gap)
    return {"tets": int(len(tets)), "nodes": int(len(nodes)), "gap_max": float(gap.max(initial=0.0)),
            "outside": int((gap > 0).sum()), "vertices": int(len(V))}


def run_bake(scene_path: str, out_path: str) -> dict:
    from . import scene as scenes
    from . import simulate

    scene = scenes.load(scene_path)
    result = simulate.run(scene, progress=_progress)
    save_result(result, out_path)
    return {"frames": int(len(result["time"]) - 1)}


def save_result(result: dict, path) -> None:
    """A simulate.run result as one uncompressed .npz (the haptic log as haptic_*)."""
    flat = {}
    for key, value in result.items():
        if isinstance(value, dict):
            flat.update({f"{key}_{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    np.savez(path, **flat)


def load_result(path) -> dict:
    """The reverse of save_result: the result dict simulate.run returned."""
    out, haptic = {}, {}
    with np.load(path, allow_pickle=False) as data:
        for key in data.files:
            if key.startswith("haptic_"):
                haptic[key[len("haptic_"):]] = data[key]
            else:
                out[key] = data[key]
    if haptic:
        out["haptic"] = haptic
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m haptic_hand.engine.child",
                                     description="Haptic Hand's child process (started by the Blender add-on)")
    sub = parser.add_subparsers(dest="command", required=True)
    tet = sub.add_parser("tetrahedralize", help="tetrahedralize a surface (.npz: vertices, faces, settings)")
    tet.add_argument("input")
    tet.add_argument("output")
    bake = sub.add_parser("bake", help="simulate a scene file")
    bake.add_argument("scene")
    bake.add_argument("output")
    args = parser.parse_args(argv)
    limit_memory()
    try:
        if args.command == "tetrahedralize":
            done = run_tetrahedralize(args.input, args.output)
        else:
            done = run_bake(args.scene, args.output)
    except MemoryError:
        emit(error="ran out of memory: use fewer tets (a larger edge length) or fewer frames")
        return 1
    except (ValueError, RuntimeError, OSError, KeyError) as e:  # the engine's errors carry their fix
        emit(error=str(e))
        return 1
    except Exception as e:
        emit(error=f"unexpected {type(e).__name__}: {e}; please report it")
        return 1
    emit(done=done)
    return 0


# --------------------------------------------------------------------------------------------
# Geometry the child measures
# --------------------------------------------------------------------------------------------


def surface_gap(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each point, how far it lies outside the tet mesh (m): its distance to the tets'
    boundary when it is outside, 0 inside. The render surface rides along by extrapolation
    where it is outside, so this is the distance that matters."""
    from scipy.spatial import cKDTree

    from . import mesh as meshing

    points = np.asarray(points, dtype=np.float64)
    _, weights = meshing.embed_points(nodes, tets, points)
    gap = np.zeros(len(points))
    outside = np.flatnonzero(weights.min(axis=1) < -1e-9)
    if len(outside) == 0:
        return gap
    tri = nodes[meshing.tet_boundary_faces(tets)]
    centres = tri.mean(axis=1)
    reach = np.linalg.norm(tri - centres[:, None], axis=2).max()  # every corner lies within this of its centre
    tree = cKDTree(centres)
    nearest, _ = tree.query(points[outside])
    for i, d in zip(outside, nearest):
        # the nearest triangle is no farther than the nearest centre's (d), so its centre
        # lies within d + reach
        candidates = np.asarray(tree.query_ball_point(points[i], d + reach * (1 + 1e-9)), dtype=np.int64)
        a, b, c = (tri[candidates, k] for k in range(3))
        q = meshing.closest_point_on_triangles(np.broadcast_to(points[i], a.shape), a, b, c)
        gap[i] = np.linalg.norm(q - points[i], axis=1).min()
    return gap


def estimate_tets(vertices: np.ndarray, faces: np.ndarray, edge_length_fac: float, epsilon: float) -> int:
    """About how many tets fTetWild makes of a closed surface (within a factor of 2 on the
    meshes measured, coarsened or not): the volume filled with tets of edge edge_length_fac x
    the bounding-box diagonal, plus those the envelope (epsilon x the diagonal) packs along
    the surface."""
    from . import mesh as meshing

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    edge, envelope = edge_length_fac * diagonal, epsilon * diagonal
    if edge <= 0 or envelope <= 0:
        return 0
    volume = abs(meshing.surface_volume(v, f))
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    return int(round(TETS_PER_EDGE_CUBE * volume / edge ** 3 + SURFACE_TETS * math.sqrt(area) / envelope))


# --------------------------------------------------------------------------------------------
# The host side
# --------------------------------------------------------------------------------------------


def command(*args: str) -> tuple[list[str], dict]:
    """The command line and environment that run this module as a program with `args`, with
    the interpreter the host runs (Blender's own Python inside Blender).

    Inside Blender an extension is the package bl_ext.<repository>.haptic_hand, which exists
    only in Blender's process: the child imports the same folder by its own name, with the
    host's sys.path (where Blender put the extension's wheels)."""
    root = Path(__file__).resolve().parents[1]  # the add-on package's folder
    package = __name__.rsplit(".", 2)[0]
    paths = [p for p in sys.path if p and os.path.isdir(p)]
    if "." in package:
        package = root.name
        paths.insert(0, str(root.parent))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(paths + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["PYTHONUNBUFFERED"] = "1"
    return [sys.executable, "-m", f"{package}.engine.child", *args], env


def memory_limit() -> int:
    """The child's address-space limit (bytes): three quarters of the machine's memory, so a
    runaway allocation fails in the child (MemoryError, std::bad_alloc) before the machine
    runs out."""
    try:
        pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
        return int(0.75 * pages * size)
    except (ValueError, OSError, AttributeError):
        return 0


def limit_memory(pid: int = 0) -> None:
    """Limits a process's address space (0: this one) to memory_limit()."""
    try:
        import resource

        limit = memory_limit()
        if limit > 0:
            resource.prlimit(pid, resource.RLIMIT_AS, (limit, limit))
    except (ImportError, OSError, ValueError, AttributeError):
        pass


class TetwildLog:
    """Progress of a tetrahedralization from fTetWild's log lines: its stages in order, then
    the optimization passes, whose worst element quality falls towards the stop energy (10)."""

    STAGES = (("Loading mesh", 0.05, "reading the surface"),
              ("remove duplicates", 0.08, "simplifying the surface"),
              ("Tetrahedralization performed", 0.2, "Delaunay tets made"),
              ("triangle insertion start", 0.25, "inserting the surface"),
              ("mark_surface_fs done", 0.35, "optimizing"),
              ("postprocessing", 0.9, "coarsening and cleaning up"),
              ("Tetrahedralization completed", 0.93, "reading the tets back"))
    OPTIMIZE = (0.35, 0.9)
    STOP_ENERGY = 10.0

    def __init__(self):
        self.fraction, self.message = 0.0, ""
        self.tets = None
        self.passes = 0
        self._energy0 = None
        self._optimizing = False

    def feed(self, line: str) -> bool:
        """Reads one log line; True when the progress changed."""
        before = (self.fraction, self.message)
        for marker, fraction, message in self.STAGES:
            if marker in line:
                self._optimizing = marker == "mark_surface_fs done"
                self._set(fraction, message)
        m = re.match(r"^#t = (\d+)", line)
        if m:
            self.tets = int(m.group(1))
        m = re.search(r"pass (\d+) /", line)
        if m:
            self.passes = int(m.group(1)) + 1
        m = re.match(r"^max_energy = ([0-9.eE+-]+)", line)
        if m and self._optimizing:
            self._optimized(float(m.group(1)))
        return (self.fraction, self.message) != before

    def _optimized(self, energy: float) -> None:
        if not math.isfinite(energy) or energy <= 0:
            return
        if self._energy0 is None:
            self._energy0 = max(energy, self.STOP_ENERGY * 1.01)
        span = math.log(self._energy0 / self.STOP_ENERGY)
        done = min(max(math.log(self._energy0 / max(energy, self.STOP_ENERGY)) / span, 0.0), 1.0)
        lo, hi = self.OPTIMIZE
        tets = f", {self.tets} tets" if self.tets else ""
        self._set(lo + (hi - lo) * done, f"optimizing (pass {max(self.passes, 1)}{tets})")

    def _set(self, fraction: float, message: str) -> None:
        self.fraction = max(self.fraction, fraction)
        self.message = message


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(code).name
    except ValueError:
        return f"signal {code}"


class Child:
    """One child process of this module: start(), then poll() from the host's loop (or wait()).

    state: RUNNING, FINISHED (result holds the child's "done" payload), FAILED (error says why)
    or CANCELLED. progress / message follow the child's events (and fTetWild's log)."""

    def __init__(self, args, what: str = "the engine", parse_log: bool = False, argv=None, env=None):
        self.args = [str(a) for a in args]
        self.what = what
        self.log = TetwildLog() if parse_log else None
        self._argv, self._env = argv, env  # a command of the tests' own instead of this module
        self.progress, self.message = 0.0, "starting"
        self.result = None
        self.error = None
        self.state = "RUNNING"
        self.process = None
        self._reader = None
        self._cancelled = False
        self._stderr = None
        self._cwd = self.workdir = None
        self._lock = threading.Lock()
        self.started_at = None

    # --- starting and stopping ---
    def start(self) -> "Child":
        argv, env = command(*self.args)
        argv, env = self._argv or argv, self._env or env
        self._stderr = tempfile.TemporaryFile()
        # a folder of its own: fTetWild leaves debug files (__cutting.stl, ...) where it runs
        self._cwd = self.workdir = tempfile.mkdtemp(prefix="haptic_hand_child_")
        self.started_at = time.monotonic()
        self.process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._stderr,
                                        env=env, cwd=self._cwd, start_new_session=True)
        self._contain(self.process.pid)
        self._reader = threading.Thread(target=self._read, name="haptic_hand child reader", daemon=True)
        self._reader.start()
        return self

    @staticmethod
    def _contain(pid: int) -> None:
        """Limit the child's address space (the child limits itself too, first thing), and make
        it the OOM killer's first choice, so a runaway allocation ends the child and never the
        host."""
        limit_memory(pid)
        try:
            Path(f"/proc/{pid}/oom_score_adj").write_text("1000")
        except OSError:
            pass

    def cancel(self) -> None:
        """Stops the child (SIGTERM, then SIGKILL after a second); the state becomes CANCELLED."""
        self._cancelled = True
        p = self.process
        if p is None or p.poll() is not None:
            return
        for sig, wait in ((signal.SIGTERM, 1.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(p.pid, sig)
            except (ProcessLookupError, PermissionError):
                break
            try:
                p.wait(timeout=wait)
                break
            except subprocess.TimeoutExpired:
                continue
        if self._reader is not None:
            self._reader.join(timeout=2.0)  # its pipe closed with the child: poll() is final now

    # --- reading ---
    def _read(self) -> None:
        for raw in self.process.stdout:
            line = raw.decode("utf-8", "replace").rstrip("\n")
            if line.startswith(EVENT):
                try:
                    event = json.loads(line[len(EVENT):])
                except json.JSONDecodeError:
                    continue
                with self._lock:
                    if "progress" in event:
                        self._set_progress(event["progress"], event.get("message", ""))
                    if "done" in event:
                        self.result = event["done"]
                    if "error" in event:
                        self.error = event["error"]
            elif self.log is not None and self.log.feed(line):
                with self._lock:
                    self._set_progress(self.log.fraction * 0.95 + 0.0, self.log.message)
        self.process.stdout.close()

    def _set_progress(self, fraction: float, message: str) -> None:
        if self.log is not None and message.startswith("tetrahedralizing"):
            return  # fTetWild's own log says more than the wrapper's one line
        self.progress = max(self.progress, float(fraction))
        self.message = message

    def poll(self) -> str:
        """RUNNING while the child runs; then its final state (never raises)."""
        if self.state != "RUNNING":
            return self.state
        p = self.process
        if p is None or p.poll() is None or self._reader.is_alive():
            return "RUNNING"
        self._reader.join()
        self.state = self._final(p.returncode)
        return self.state

    def wait(self, timeout: float | None = None, on_progress=None) -> str:
        """Polls until the child ends (or timeout s pass: then RUNNING)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() == "RUNNING":
            if deadline is not None and time.monotonic() > deadline:
                break
            if on_progress is not None:
                on_progress(self.progress, self.message)
            time.sleep(0.02)
        return self.state

    def _final(self, code: int) -> str:
        if self._cancelled:
            return "CANCELLED"
        if code == 0 and self.result is not None:
            return "FINISHED"
        if self.error is None:
            self.error = self._crash_message(code)
        return "FAILED"

    def _crash_message(self, code: int) -> str:
        tail = self.stderr_tail()
        if code < 0:
            what = f"{self.what} crashed ({_signal_name(-code)})"
            if -code == signal.SIGKILL:
                what += ": it was killed, most likely for running out of memory"
        else:
            what = f"{self.what} stopped (exit status {code}) without a result"
        if "MemoryError" in tail or "bad_alloc" in tail:
            what += ": it ran out of memory; use fewer tets (a larger edge length) or fewer frames"
        hint = f"; its last words: {tail.splitlines()[-1][:300]}" if tail.strip() else ""
        return f"{what}{hint}. Blender is unaffected; please report it if it happens again"

    def stderr_tail(self, size: int = 4000) -> str:
        f = self._stderr
        if f is None:
            return ""
        try:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - size))
            return f.read().decode("utf-8", "replace")
        except (OSError, ValueError):
            return ""

    def close(self) -> None:
        """Ends the child if it still runs and frees what it held."""
        if self.process is not None and self.process.poll() is None:
            self.cancel()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        if self._cwd is not None:
            shutil.rmtree(self._cwd, ignore_errors=True)
            self._cwd = None


if __name__ == "__main__":
    sys.exit(main())
