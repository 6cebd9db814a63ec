"""Tet meshes written for the C++ drivers of bench/ (compare_builds.cpp, bench_factor.cpp):
int32 node and tet counts, float64 palm seed[3], float64 nodes[3n], int32 tets[4m]."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def write_tet_mesh(path: Path, nodes, tets, seed=(0.0, 0.0, 0.0)) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.array([len(nodes), len(tets)], dtype=np.int32).tofile(f)
        np.asarray(seed, dtype=np.float64).tofile(f)
        np.ascontiguousarray(nodes, dtype=np.float64).tofile(f)
        np.ascontiguousarray(tets, dtype=np.int32).tofile(f)
    return path
