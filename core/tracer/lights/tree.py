"""The emitters' light tree: median splits of the emitting triangles' centroids into clusters,
and the clusters into a tree of nodes. No bpy."""

from __future__ import annotations

import numpy as np


def cluster_splits(centroids: np.ndarray, most: int) -> np.ndarray:
    """(E,) cluster ids 0..K-1 (K ≤ `most`) of points `centroids` (E, 3): the cluster whose points'
    box has the longest diagonal is split at the middle of its longest axis (both halves keep
    points), until there are `most` clusters or every cluster's points coincide."""
    ids = np.zeros(len(centroids), np.int64)
    extent = [float(np.linalg.norm(np.ptp(centroids, axis=0)))] if len(centroids) else [0.0]
    while len(extent) < most:  # at most `most` splits, each over one cluster's points
        c = int(np.argmax(extent))
        if extent[c] <= 0.0:
            break
        members = np.flatnonzero(ids == c)
        pts = centroids[members]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        axis = int(np.argmax(hi - lo))
        upper = pts[:, axis] >= 0.5 * (lo[axis] + hi[axis])
        if upper.all():  # the middle rounds onto the lowest point: split off the lowest points
            upper = pts[:, axis] > lo[axis]
        ids[members[upper]] = len(extent)
        extent[c] = float(np.linalg.norm(np.ptp(pts[~upper], axis=0)))
        extent.append(float(np.linalg.norm(np.ptp(pts[upper], axis=0))))
    return ids


def light_tree(centroids: np.ndarray, top: int, fanout: int, most_leaves: int):
    """A tree of spatial clusters over points `centroids` (E, 3): at most `top` top clusters
    (`cluster_splits`), each cluster of more than one point split again into at most `fanout`
    (`cluster_splits` of its points), breadth first, until every leaf holds one point (or
    coincident points) or there are `most_leaves` leaves; fanout ≤ 1 splits none: the top
    clusters alone.
    Returns (leaf (E,) each point's leaf, child_first (N + 1,), child_count (N + 1,), parent
    (N,)) over N nodes numbered breadth first, so a node's children are consecutive (0 children:
    a leaf); entry N of the first two is the root above the top clusters, which parent N names."""
    ids = cluster_splits(centroids, top)
    k = int(ids.max()) + 1
    members = [np.flatnonzero(ids == c) for c in range(k)]
    child_first, child_count, parent = [0] * k, [0] * k, [-1] * k  # the root's entry is appended last
    leaves, c = k, 0
    while c < len(members) and leaves < most_leaves:
        m = members[c]
        sub = cluster_splits(centroids[m], min(fanout, most_leaves - leaves + 1)) if len(m) > 1 else ids[:0]
        n = int(sub.max()) + 1 if len(sub) else 1
        if n > 1:
            child_first[c], child_count[c] = len(members), n
            for j in range(n):
                members.append(m[sub == j])
                child_first.append(0)
                child_count.append(0)
                parent.append(c)
            leaves += n - 1
        c += 1
    nodes = len(members)
    leaf = np.zeros(len(centroids), np.int64)
    for c in range(nodes):
        if child_count[c] == 0:
            leaf[members[c]] = c
    parent_of = np.array([nodes if p < 0 else p for p in parent], np.int64)
    return leaf, np.array(child_first + [0], np.int64), np.array(child_count + [k], np.int64), parent_of


def node_sums(lo: np.ndarray, hi: np.ndarray, power: np.ndarray, child_first: np.ndarray, child_count: np.ndarray):
    """Each inner node's box and power from its children's, in place: lo, hi (N, 3) and power (N,)
    filled for the leaves; nodes as `light_tree` numbers them (children after their parent, so
    a reversed pass sees every child before its parent). numpy: the specification of the
    compiled `light_kernels.node_sums`."""
    for node in range(len(power) - 1, -1, -1):
        a, m = child_first[node], child_count[node]
        if m:
            lo[node], hi[node] = lo[a : a + m].min(axis=0), hi[a : a + m].max(axis=0)
            power[node] = power[a : a + m].sum()
