"""Every struct the bindings pass to the library is checked against the library's own size of it
when the library is first used, and a stale one is refused naming the struct and the fix; the
haptic log's width comes from the library."""

import ctypes
import re
from pathlib import Path

import pytest

from haptic_hand.engine import native, native_library, native_session, native_skeleton, params

HEADER = Path(__file__).resolve().parents[2] / "native" / "include" / "haptic_hand.h"


def header_struct_ids() -> dict:
    """HH_STRUCT_<NAME> -> id, as the header defines them."""
    return {name: int(i) for name, i in re.findall(r"#define HH_STRUCT_(\w+) (\d+)", HEADER.read_text())}


def test_the_struct_ids_are_the_headers():
    ids = header_struct_ids()
    assert sorted(ids.values()) == list(range(len(native_library.STRUCT_NAMES)))
    for name, i in ids.items():
        assert native_library.STRUCT_NAMES[i] == ("" if name == "NONE" else "hh_" + name.lower())


def test_every_struct_of_the_header_is_checked_by_a_binding_and_matches():
    native.library(), native_session._lib(), native_skeleton.library()  # each checks its layouts on first use
    checked = {}
    for layouts in (native.LAYOUTS, native_session.LAYOUTS, native_skeleton.LAYOUTS):
        checked.update({c_name: structure for structure, c_name in layouts.items()})
    for struct_id in (params.STRUCT_PARAMS, params.STRUCT_WORLD_PARAMS, params.STRUCT_MATERIAL,
                      params.STRUCT_SESSION_PARAMS):
        checked[native_library.STRUCT_NAMES[struct_id]] = params.structure(struct_id)
    assert sorted(checked) == sorted(native_library.STRUCT_NAMES[1:])
    for c_name, structure in checked.items():
        assert ctypes.sizeof(structure) == native_library.struct_size(c_name), c_name


class StaleFrame(ctypes.Structure):
    """hh_session_frame as an older header had it: without its wrench."""
    _fields_ = [(name, ctype) for name, ctype in native_session.SessionFrame._fields_ if name != "wrench"]


def test_a_stale_struct_is_refused_when_the_library_loads_naming_it_and_the_fix():
    # hh_session_frame: 35 doubles (time, visual_steps, 3 poses of 7, 2 wrenches of 6) and 2 ints
    assert native_library.struct_size("hh_session_frame") == 35 * 8 + 2 * 4
    load = native_library.binding({}, {StaleFrame: "hh_session_frame"})
    with pytest.raises(native.NativeError, match=r"hh_session_frame is 288 bytes in the native library and 240 "
                                                 r"bytes in these bindings \(StaleFrame\).*rebuild it with `make native`"):
        load()


def test_a_library_without_a_function_the_bindings_declare_is_refused_with_the_fix():
    with pytest.raises(native.NativeError, match=r"has no hh_not_there: it is older than these bindings; rebuild it "
                                                 r"with `make native`"):
        native_library.declare(native_library.library(), {"hh_not_there": ([], ctypes.c_int)})


def test_the_haptic_log_is_as_wide_as_the_library_writes_it(monkeypatch):
    lib = native_session._lib()
    # time, period, cost; device position and quaternion; proxy position and quaternion; force; torque
    assert native_session.LOG_COLUMNS == lib.hh_log_columns() == 3 + (3 + 4) * 2 + 3 + 3
    monkeypatch.setattr(native_session, "LOG_COLUMNS", 22)
    with pytest.raises(native.NativeError, match=r"rows are 23 numbers wide and these bindings read 22.*make native"):
        native_session._check_log_columns(lib)
