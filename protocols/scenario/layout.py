"""Where a generated swarm starts, and its radio graph there. Pure, I/O-free.

Layouts put N drones on the ground (z = 0, NED m) no two closer than ``spacing_m``, with the
corner of their bounding box at the origin and the longer extent along north, so that a formation
of yaw 0 is the layout itself:

- ``grid``: rows along east, as many rows (north) as columns or one more; a last, short row is
  centred, so that the grid's principal axes are north and east (rows and columns swap where
  the short row would leave the grid wider than long);
- ``line``: one row along north, every other drone half a spacing to the east (a staggered
  line: a straight one has no width, and the swarm's roll about it is undefined);
- ``circle``: a ring whose neighbouring drones are ``spacing_m`` apart (a chord);
- ``random``: a Poisson-disc blob grown from one seed drone (Bridson's dart throwing in an annulus
  of ``spacing_m`` to ``min(2 spacing_m, reach)`` around an already placed drone), so that it is
  connected within ``reach`` by construction, turned onto its principal axes. Seeded by ``rng``.

:func:`radio_graph` says who hears whom (strictly closer than the range, as the in-process radio
and the Zenoh link decide) and sums the graph up: components and degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray
from protocols.scenario.layout_names import LAYOUTS

#: A line's drones alternate this share of the spacing to the east: a straight line has no width
#: (two flat axes), and the swarm's roll about it is undefined: the controller cannot hold it.
LINE_STAGGER = 0.5
#: Candidates thrown around an active drone before it is retired (Bridson's k).
_CANDIDATES = 30


class LayoutError(ValueError):
    """Layout options that cannot be met; the message names the option."""


def layout_positions(
    layout: str, n: int, spacing_m: float, rng: np.random.Generator, reach_m: float | None = None
) -> FloatArray:
    """Initial positions (n, 3), NED m, z = 0, of ``layout`` (one of :data:`LAYOUTS`).

    ``reach_m`` (random only): new drones are placed within this distance of one already placed
    (default 2 ``spacing_m``), so the blob is connected at any radio range above it.
    """
    if n < 1:
        raise LayoutError(f"drones: need at least 1, got {n}")
    if not spacing_m > 0:
        raise LayoutError(f"spacing_m: must be > 0, got {spacing_m:g}")
    if layout == "grid":
        xy = _grid(n, spacing_m)
    elif layout == "line":
        k = np.arange(n, dtype=float)
        xy = spacing_m * np.column_stack([k, LINE_STAGGER * (k % 2)])
    elif layout == "circle":
        xy = _circle(n, spacing_m)
    elif layout == "random":
        reach = 2.0 * spacing_m if reach_m is None else min(reach_m, 2.0 * spacing_m)
        xy = _principal(_poisson_blob(n, spacing_m, reach, rng))
    else:
        raise LayoutError(f"layout: '{layout}' is not a layout (one of: {', '.join(LAYOUTS)})")
    if np.var(xy[:, 1]) > np.var(xy[:, 0]):  # a grid whose short row made it wider than long
        xy = xy[:, ::-1]
    xy = xy - xy.min(axis=0)
    return np.column_stack([np.round(xy, 6), np.zeros(n)])


def _grid(n: int, spacing_m: float) -> FloatArray:
    n_north = math.ceil(math.sqrt(n))
    n_east = math.ceil(n / n_north)
    k = np.arange(n)
    row, col = k // n_east, (k % n_east).astype(float)
    short = n - n_east * (n // n_east)  # drones in a last, short row (0: none)
    if short:
        col[row == n // n_east] += 0.5 * (n_east - short)  # centred: the axes stay north, east
    return spacing_m * np.column_stack([row, col]).astype(float)


def _circle(n: int, spacing_m: float) -> FloatArray:
    radius = spacing_m / 2.0 if n <= 2 else spacing_m / (2.0 * math.sin(math.pi / n))
    theta = 2.0 * math.pi * np.arange(n) / n
    return radius * np.column_stack([np.cos(theta), np.sin(theta)])


def _poisson_blob(n: int, spacing_m: float, reach_m: float, rng: np.random.Generator) -> FloatArray:
    """Bridson's algorithm without a boundary, stopped at ``n`` points; grows outwards."""
    if reach_m <= spacing_m:
        raise LayoutError(
            f"range_m: a random layout needs a radio range above the spacing ({spacing_m:g} m)"
        )
    points = [np.zeros(2)]
    active = [0]
    while len(points) < n:
        if not active:  # cannot happen without a boundary; kept as a guard
            raise LayoutError("layout: the random layout could not place every drone")
        a = active[int(rng.integers(len(active)))]
        placed = False
        for _ in range(_CANDIDATES):
            r = rng.uniform(spacing_m, reach_m)
            phi = rng.uniform(0.0, 2.0 * math.pi)
            c = points[a] + r * np.array([math.cos(phi), math.sin(phi)])
            if min(float(np.linalg.norm(c - p)) for p in points) >= spacing_m:
                points.append(c)
                active.append(len(points) - 1)
                placed = True
                break
        if not placed:
            active.remove(a)
    return np.array(points)


def _principal(xy: FloatArray) -> FloatArray:
    """``xy`` turned about its centroid so that its larger spread lies along north."""
    p = xy - xy.mean(axis=0)
    if p.shape[0] < 2:
        return p
    _, vecs = np.linalg.eigh(p.T @ p)
    length = vecs[:, 1]  # eigenvector of the larger eigenvalue
    c, s = float(length[0]), float(length[1])
    turn = np.array([[c, s], [-s, c]])  # takes ``length`` onto north
    return p @ turn.T


@dataclass(frozen=True)
class RadioGraph:
    """Who hears whom at given positions: ``adjacency`` (N, N) bool, and its summary."""

    adjacency: np.ndarray
    components: int
    degree_min: int
    degree_mean: float
    degree_max: int

    @property
    def connected(self) -> bool:
        """Whether every drone can reach every other over one or more links."""
        return self.components == 1


def radio_graph(positions_ned_m: FloatArray, range_m: float) -> RadioGraph:
    """The radio graph of drones at ``positions_ned_m`` (N, 3): links strictly shorter than
    ``range_m`` (m), as gcs/reference/network.py and the Zenoh link decide."""
    x = np.asarray(positions_ned_m, dtype=float)
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
    adjacency = d < range_m
    np.fill_diagonal(adjacency, False)
    from scipy.sparse.csgraph import connected_components  # scipy: only when checking a layout

    components, _ = connected_components(adjacency, directed=False)
    degree = adjacency.sum(axis=1)
    return RadioGraph(
        adjacency,
        int(components),
        int(degree.min()),
        float(degree.mean()),
        int(degree.max()),
    )


def min_spacing(positions_ned_m: FloatArray) -> float:
    """The smallest distance (m) between two of the positions (N, 3); inf for one drone."""
    x = np.asarray(positions_ned_m, dtype=float)
    if x.shape[0] < 2:
        return math.inf
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(d.min())


def is_cut_free(adjacency: np.ndarray, removed: set[int]) -> bool:
    """Whether the drones not in ``removed`` still form one connected radio graph."""
    keep = np.array([i for i in range(adjacency.shape[0]) if i not in removed])
    if keep.size <= 1:
        return True
    from scipy.sparse.csgraph import connected_components

    components, _ = connected_components(adjacency[np.ix_(keep, keep)], directed=False)
    return int(components) == 1
