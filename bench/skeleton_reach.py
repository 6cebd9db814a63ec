"""How much of the factor of A_t each bone's right-hand sides touch (docs/skeleton.md, Section 3).

A forward substitution L^-1 r with r non-zero only at a bone's nodes touches the columns of L
on the elimination-tree paths from those nodes to the root (their reach). This prints, per bone
of the rigged procedural hand, the reach and the share of L's stored blocks in it, under a
minimum-degree ordering of the node graph (SuperLU's MMD on A^T + A, standing in for the native
AMD). No timing: counts only, the same on any machine.

    .venv/bin/python bench/skeleton_reach.py [--tets file.npz]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from haptic_hand.engine import skeleton

SAMPLE = Path(skeleton.__file__).resolve().parent / "sample_scenes" / "procedural_hand_tets.npz"


def elimination_tree(graph: sp.csr_matrix):
    """Parents and column counts of the Cholesky factor of a symmetric pattern (in its order)."""
    n = graph.shape[0]
    below = [set(int(i) for i in graph.indices[graph.indptr[j]:graph.indptr[j + 1]] if i > j) for j in range(n)]
    parent = np.full(n, -1)
    for j in range(n):
        if below[j]:
            parent[j] = min(below[j])
            below[parent[j]].update(i for i in below[j] if i > parent[j])
    return parent, np.array([len(s) + 1 for s in below])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tets", default=str(SAMPLE), help="an .npz with nodes (n, 3) and tets (m, 4)")
    args = parser.parse_args()
    stored = np.load(args.tets)
    nodes, tets = stored["nodes"], stored["tets"]
    n = len(nodes)
    rows, cols = np.repeat(tets, 4, axis=1).ravel(), np.tile(tets, (1, 4)).ravel()
    graph = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    lu = spla.splu((graph + n * sp.identity(n)).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0,
                   options={"SymmetricMode": True})
    order = lu.perm_c
    position = np.empty(n, dtype=int)
    position[order] = np.arange(n)
    parent, counts = elimination_tree(graph[order][:, order].tocsr())
    rig = skeleton.procedural_hand_skeleton()
    owner = rig.capture(nodes)
    print(f"{len(tets)} tets, {n} nodes, {(owner >= 0).sum()} captured by {len(rig)} bones; "
          f"L has {counts.sum()} node blocks")
    print(f"{'bone':<10} {'nodes':>5} {'reach':>6} {'share of L':>10}")
    shares = []
    for b, name in enumerate(rig.names):
        reach = set()
        for i in np.flatnonzero(owner == b):
            j = position[i]
            while j >= 0 and j not in reach:
                reach.add(j)
                j = parent[j]
        shares.append(counts[list(reach)].sum() / counts.sum())
        print(f"{name:<10} {(owner == b).sum():>5} {len(reach):>6} {shares[-1]:>10.0%}")
    print(f"9 forward lanes per bone over its reach = {9 * sum(shares) / 2:.1f} full one-lane solves "
          f"(the columns path: {1 + 6 * len(rig)})")


if __name__ == "__main__":
    main()
