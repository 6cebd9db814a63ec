"""Hand rigs shared by the engine tests: the procedural hand and, when ../shared is beside
the checkout, the real hand.obj. Tetrahedralized once per session (pytetwild is slow and
not deterministic, so every test of a session sees the same tets)."""

import json
from dataclasses import dataclass

import numpy as np
import pytest

from haptic_hand.engine import mesh
from shared_data import HAND_OBJ, SHARED_DATA


@dataclass
class Rig:
    name: str
    nodes: np.ndarray
    tets: np.ndarray
    seed: np.ndarray
    radius: float


@pytest.fixture(scope="session")
def procedural_rig() -> Rig:
    v, f = mesh.procedural_hand()
    nodes, tets = mesh.tetrahedralize(v, f, edge_length_fac=0.1, coarsen=True, epsilon=0.002)
    return Rig("procedural", nodes, tets, mesh.procedural_hand_palm_seed(), 0.03)


@pytest.fixture(scope="session")
def shared_hand_rig() -> Rig:
    v, f = mesh.load_obj(HAND_OBJ)
    nodes, tets = mesh.tetrahedralize(v, f, edge_length_fac=0.2, coarsen=True, epsilon=0.004)
    seed = np.array(json.loads((SHARED_DATA / "mesh_stats.json").read_text())["hand.obj"]["suggested_palm_seed"])
    return Rig("hand.obj", nodes, tets, seed, 0.03)

