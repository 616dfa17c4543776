"""Union-find over integer nodes, for compiled loops (numba).

``parent`` ((n,) int64, starting as ``np.arange(n)``) holds each node's parent; a root
is its own parent. :func:`join` makes the smaller of two roots the root of both, so a
node's parent never exceeds the node, and :func:`settle`, one pass in index order, then
points every node at its root.
"""

from __future__ import annotations

from numba import njit

__all__ = ["root", "join", "set_count", "settle"]


@njit(cache=True)
def root(parent, x):
    """The root of node ``x``, halving the path on the way."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit(cache=True)
def join(parent, x, y):
    """Put the nodes ``x`` and ``y`` in one set; the smaller root becomes its root."""
    x, y = root(parent, x), root(parent, y)
    if x != y:
        parent[max(x, y)] = min(x, y)


@njit(cache=True)
def settle(parent):
    """Point every node at its root (roots come first, as :func:`join` keeps them)."""
    for x in range(parent.size):
        parent[x] = parent[parent[x]]


@njit(cache=True)
def set_count(parent):
    """How many sets the nodes form: the roots, nodes that are their own parent."""
    count = 0
    for x in range(parent.size):
        if parent[x] == x:
            count += 1
    return count
