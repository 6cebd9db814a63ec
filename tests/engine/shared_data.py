"""Where ../shared/data is, and a marker for tests that need it (CI has it beside the
checkout; a user's machine may not)."""

import pathlib

import pytest

SHARED_DATA = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data"
HAND_OBJ = SHARED_DATA / "hand.obj"

needs_shared_hand = pytest.mark.skipif(not HAND_OBJ.is_file(), reason="../shared/data/hand.obj is not beside the checkout")
