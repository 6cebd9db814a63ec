"""A fuzz of the C ABI through ctypes, run in a child process by test_fuzz_capi.py (a native crash
ends the child, not pytest). Every entry point declared in native/include/haptic_hand.h is
called many times with arguments drawn by C type: null pointers, valid handles, buffers of
NaN, infinities and out-of-range indices, wrong and negative counts, huge counts (with null
buffers: a count larger than its buffer is the caller's lie, which no C function can see),
parameter structs of the wrong size or with wild fields. Each call must return HH_OK or a
status with a message; HH_ERR_INTERNAL only for "out of memory".

Usage: python capi_fuzz.py [calls per function] [seed]; prints each call before making it."""

import ctypes
import math
import random
import re
import sys
from pathlib import Path

import numpy as np

from haptic_hand.engine import mesh, native

HEADER = Path(__file__).resolve().parents[2] / "native" / "include" / "haptic_hand.h"
INTS = [0, 1, 2, 3, 4, 5, 7, 40, -1, -7, 2**31 - 1, -2**31, 1 << 20]
DOUBLES = [0.0, 1.0, -1.0, 0.03, 1e-3, 1 / 30, math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324]
SMALL = 64          # counts up to this go with real buffers
BUFFER = 64 * 4 * 4  # elements of each buffer: enough for SMALL tets of 4 and vectors of 36
HANDLES = ("hh_model", "hh_data", "hh_world", "hh_session")
FREE = {h: f"{h}_free" for h in HANDLES}
SKIP = {"hh_session_start"}  # live threads: test_haptics and TSan cover them
STRUCT_DEFAULTS = {"hh_params": "hh_default_params", "hh_world_params": "hh_default_world_params",
                   "hh_material": "hh_default_material", "hh_session_params": "hh_default_session_params"}


def declarations():
    """(name, [C type of each parameter]) of every function the header declares."""
    text = re.sub(r"/\*.*?\*/", "", HEADER.read_text(), flags=re.S)
    out = []
    for ret, name, args in re.findall(r"\n(int|void|const char\*)\s+(hh_\w+)\(([^)]*)\);", text):
        types = []
        for arg in filter(None, (a.strip() for a in args.split(","))):
            if arg == "void":
                continue
            pointer = "[" in arg
            arg = re.sub(r"\[\d+\]", "", arg)
            t = arg[: -len(re.findall(r"\w+$", arg)[0])].replace(" ", "") + ("*" if pointer else "")
            types.append(t)
        out.append((name, types))
    return out


class Fixture:
    """A small valid rig (a 4x4x4-cell box), its data, a world holding it, and a session."""

    def __init__(self, lib):
        self.lib = lib
        nodes, tets = mesh.structured_box([0.04] * 3, [4] * 3)
        self.model = native.HandModel(nodes, tets, palm_seed=[0.02] * 3, handle_radius=0.012)
        self.data = native.HandSimulation(self.model)
        from haptic_hand.engine import native_session, native_world

        self.world = native_world.World()
        faces = mesh.tet_boundary_faces(tets)
        sn, sw = native_world.vertex_surface(len(nodes))
        self.hand = self.world.add_hand(self.model, sn, sw, faces)
        self.world.add_plane([0, 0, -0.01], [0, 0, 1])
        self.session = native_session.NativeSession(self.world, self.hand)
        self.handles = {"hh_model": self.model._handle, "hh_data": self.data._handle, "hh_world": self.world._handle,
                        "hh_session": self.session._handle}


def struct_buffer(lib, rng, name):
    raw = (ctypes.c_char * 4096)()
    if name in STRUCT_DEFAULTS:
        fill = getattr(lib, STRUCT_DEFAULTS[name])
        fill.argtypes, fill.restype = [ctypes.c_void_p], None
        fill(raw)
    size = ctypes.c_int()
    sizes = {"hh_params": 1, "hh_world_params": 2, "hh_material": 3, "hh_session_params": 4}
    if name in sizes:
        lib.hh_struct_size(sizes[name], ctypes.byref(size))
    else:
        size.value = 8 * rng.randint(1, 64)  # output structs: their size field is theirs to check
    view = np.frombuffer(raw, dtype=np.uint8)
    view[:4] = np.frombuffer(np.int32(size.value if rng.random() < 0.8 else rng.choice([0, -1, 3, 4096])).tobytes(),
                             np.uint8)
    for _ in range(rng.randint(0, 3)):  # wild fields
        offset = 8 * rng.randint(1, max(1, size.value // 8 - 1))
        view[offset:offset + 8] = np.frombuffer(np.float64(rng.choice(DOUBLES)).tobytes(), np.uint8)
    return raw


def argument(lib, rng, fixture, ctype, keep_alive, created):
    base = ctype.replace("const", "")
    if base == "int":
        return ctypes.c_int(rng.choice(INTS) if rng.random() < 0.5 else rng.randint(-2, 12))
    if base == "double":
        return ctypes.c_double(rng.choice(DOUBLES) if rng.random() < 0.5 else rng.uniform(-0.1, 0.1))
    if rng.random() < 0.25:
        return None
    if base == "double*":
        values = np.array([rng.choice(DOUBLES) if rng.random() < 0.1 else rng.uniform(-0.05, 0.05)
                           for _ in range(BUFFER)])
        buf = (ctypes.c_double * BUFFER)(*values)
    elif base == "int*":
        buf = (ctypes.c_int * BUFFER)(*[rng.choice(INTS) if rng.random() < 0.1 else rng.randint(-1, 70)
                                         for _ in range(BUFFER)])
    elif base == "char*":
        return rng.choice([b"", b"dt", b"material.young_modulus", b"hand.palm_seed", b"x" * 300,
                           b"/nonexistent/libHD.so"])
    elif base.rstrip("*") in HANDLES and base.count("*") == 1:
        return fixture.handles[base.rstrip("*")]
    elif base.rstrip("*") in HANDLES:  # an output handle
        slot = ctypes.c_void_p()
        created.append((base.rstrip("*"), slot))
        return ctypes.pointer(slot)
    elif base.startswith("hh_"):
        buf = struct_buffer(lib, rng, base.rstrip("*"))
    else:
        raise ValueError(f"no generator for C type {ctype}")
    keep_alive.append(buf)
    return ctypes.cast(buf, ctypes.c_void_p)


def fuzz(calls_per_function: int, seed: int) -> int:
    native.library()  # the bindings, for the fixtures; the fuzz calls through its own handle (undeclared)
    lib = ctypes.CDLL(str(next(p for p in native._candidates() if p.is_file())))
    lib.hh_last_error.restype = ctypes.c_char_p
    lib.hh_struct_size.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_int)]
    rng = random.Random(seed)
    failures = 0
    for name, types in declarations():
        fn = getattr(lib, name)
        if name in SKIP or name.endswith("_free") or name.startswith("hh_default_") or not types:
            continue
        fn.argtypes, fn.restype = None, ctypes.c_int
        fixture = Fixture(lib)
        for k in range(calls_per_function):
            keep_alive, created = [], []
            args = [argument(lib, rng, fixture, t, keep_alive, created) for t in types]
            counts = [a.value for a in args if isinstance(a, ctypes.c_int)]
            if name == "hh_session_run_offline":
                args[1] = ctypes.c_int(min(max(args[1].value, -3), 3))
            elif any(c > SMALL for c in counts):  # huge counts only with null buffers
                args = [None if isinstance(a, ctypes.c_void_p) and t.replace("const", "").rstrip("*")
                        not in HANDLES and not t.startswith(("hh_", "consthh_")) else a
                        for a, t in zip(args, types)]
            print(f"{name} #{k}: {[getattr(a, 'value', a) for a in args]}", file=sys.stderr, flush=True)
            status = fn(*args)
            message = lib.hh_last_error().decode("utf-8", "replace")
            if status not in (0, -1, -2, -3) or (status != 0 and not message) or (
                    status == -3 and not message.startswith("out of memory")):
                print(f"FAIL {name} #{k}: status {status}, message {message!r}", flush=True)
                failures += 1
            for kind, slot in created:
                if slot.value:
                    getattr(lib, FREE[kind])(slot)
    print(f"fuzzed {len(declarations())} entry points, {failures} failures", flush=True)
    return failures


if __name__ == "__main__":
    sys.exit(1 if fuzz(int(sys.argv[1]) if len(sys.argv) > 1 else 40, int(sys.argv[2]) if len(sys.argv) > 2 else 1)
             else 0)
