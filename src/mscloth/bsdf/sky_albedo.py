"""The sky albedo table: each texel's directional albedo A(wi) (the integral of f |cos o|
over the outgoing directions, plus what its delta lobe, the gaps, lets through), RGB, for
both sides, at the nodes of :func:`node_coordinates`, as summed-area tables.

What it is for: under a uniform sky of radiance L, the light a first hit receives from the
sky by its sampled direction has the mean c L A(wi) for any share c; ``clothpath`` adds
that mean and leaves Monte Carlo only the rest (docs/performance-log.md L59, L60). A
footprint's A is the mean of its texels' A, one SAT read per bin and corner, as the
BSDF's other footprint means.

Held at the nodes of :func:`node_coordinates`: the centres of the visibility tables'
direction bins, where the fibre-level BSDF's V(wi), bilinear over the same bins, has its
kinks (read 15 degrees apart, A was off by up to 17%; performance log L59),
``NODES_PER_BIN - 1`` between each two (``OUTER_BIN_NODES - 1`` between the outermost
two), and six more rows each side towards the horizon, where the fuzz and the Fresnel
factor raise A steeply (beyond the outermost centres, at 76 degrees for 8 x 8 bins, A
rose from 0.11 to 0.22 on the plane's twill). Read bilinearly between the nodes, times
:func:`shape_ratio`: how the tile's mean A, followed by a cubic, bends between them (read
bilinearly alone, 0.5-1.3% high at 84-89 degrees, where the plane's far pixels see it;
performance log L62). Built by Monte Carlo from the
fibre-level BSDF's own samples (stratified per cell, one random shift per cell kept for
every direction, so that A is smooth in wi and the cells' errors are independent and
average out over a footprint).
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, gather_block, lane_values, opaque
from ..precompute.direction_bins import square_to_hemisphere
from ..precompute.summed_area import build_sat
from .sat_queries import RectUnion, ResidualSATs, hemisphere_to_square, round_box

#: RGB and one zero channel per (side, node): one packet of four per corner read.
CHANNELS_PER_BIN = 4

#: Sample weights per table cell and node direction (a square number: a stratified grid).
SAMPLES = 16

#: The most a table may take: larger tiles get cells of several texels (:func:`cell_blocks`).
#: (A 64^2 tile, the plane's, has cells of one texel within it: 124 MiB.)
MAX_MIB = 128.0

#: The nodes beyond the outermost bin centres, as insets from the square's edge (the
#: horizon) in bins: where the fuzz and the Fresnel factor raise A steeply, at about 80,
#: 83, 85, 87, 88.5 and 89.4 degrees for 8 x 8 bins (the BSDF is not defined at the horizon).
OUTER_INSETS = (0.375, 0.25, 0.178, 0.105, 0.052, 0.02)

#: Nodes per bin along each axis between the outermost bin centres: 2 puts one halfway
#: between neighbouring centres.
NODES_PER_BIN = 2

#: Nodes per bin between the two outermost centres each side (52-76 degrees for 8 x 8
#: bins), where A bends most between centres (a dip near 70 degrees on the plane's twill:
#: read linearly across those 12 degrees, 4% high; performance log L62).
OUTER_BIN_NODES = 4

#: Lay the table out by planes of a node's four channels (``ResidualSATs``'
#: ``packet_planes``) instead of a texel corner's 2 m^2 nodes together: a region's camera
#: rays read the same few nodes (wi varies slowly across it), whose planes then stay in
#: cache, where a corner's record of every node (30 KiB for 8 x 8 bins) was a cache miss at
#: every read. Reads the same values (images identical to the bit).
PACKET_PLANES = True

#: Points per node interval along each axis at which :func:`shape_ratio` is held (read
#: bilinearly between them); 0 reads A bilinearly between the nodes, uncorrected.
SHAPE_STEPS = 8


def nodes_per_axis(n: int) -> int:
    return len(node_coordinates(n))


def node_coordinates(n: int) -> np.ndarray:
    """The node coordinates along each axis of the hemisphere's square (Mitsuba's
    ``uniform_hemisphere_to_square``; its edge is the horizon): the bin centres (k + 1/2)
    / n of an n x n grid and ``NODES_PER_BIN - 1`` evenly between each two
    (``OUTER_BIN_NODES - 1`` between the two outermost each side), then the
    ``OUTER_INSETS`` each side."""
    inner = (0.5 + np.arange(NODES_PER_BIN * (n - 1) + 1) / NODES_PER_BIN) / n
    if n > 1:
        extra = (0.5 + np.arange(1, OUTER_BIN_NODES) / OUTER_BIN_NODES) / n
        inner = np.unique(np.round(np.concatenate([inner, extra, 1.0 - extra]), 12))
    low = np.array(sorted(OUTER_INSETS)) / n
    return np.concatenate([low, inner, 1.0 - low[::-1]])


def node_directions(n: int) -> np.ndarray:
    """The node directions, flat index b m + a (m = :func:`nodes_per_axis`), a along x."""
    c = node_coordinates(n)
    a, b = np.meshgrid(c, c, indexing="xy")
    return square_to_hemisphere(np.stack([a.ravel(), b.ravel()], axis=-1))


def node_interval(p, n: int):
    """(k, f): the node interval [u_k, u_k+1] of square coordinate ``p`` and the fraction
    across it (clamped to [0, 1] beyond the outermost nodes)."""
    c = node_coordinates(n)
    k = mi.Float(0.0)
    for u in c[1:-1]:  # (a few dozen compares: cheaper than a search's dependent reads)
        k += dr.select(p >= float(u), 1.0, 0.0)
    nodes = mi.Float(c.astype(np.float32))  # (evaluated: one array, not literals)
    u0 = dr.gather(mi.Float, nodes, mi.UInt32(k))
    u1 = dr.gather(mi.Float, nodes, mi.UInt32(k) + 1)
    return mi.UInt32(k), dr.clip((p - u0) / (u1 - u0), 0.0, 1.0)


def node_cell(w, n: int):
    """(ka, fx, kb, fy, p): the node intervals along x and y around the upper-hemisphere
    direction ``w``, the fractions across them (:func:`node_interval`) and its square
    coordinates p."""
    p = hemisphere_to_square(w)
    return node_interval(p.x, n) + node_interval(p.y, n) + (p,)


def node_weights(w, n: int, cell=None):
    """The four nodes around the upper-hemisphere direction ``w`` (flat indices) and
    their bilinear weights (``cell``: its :func:`node_cell`, if known)."""
    ka, fx, kb, fy = (node_cell(w, n) if cell is None else cell)[:4]
    m = nodes_per_axis(n)
    nodes = (kb * m + ka, kb * m + ka + 1, (kb + 1) * m + ka, (kb + 1) * m + ka + 1)
    return nodes, ((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy)


def shape_points(n: int, steps: int) -> np.ndarray:
    """Where :func:`shape_ratio` is held along each axis: ``steps`` evenly spaced points in
    every interval between the nodes and between the outermost nodes and the square's
    edges, and the edge 1."""
    c = np.concatenate([[0.0], node_coordinates(n), [1.0]])
    t = np.arange(steps) / steps
    return np.append((c[:-1, None] + (c[1:] - c[:-1])[:, None] * t).ravel(), 1.0)


def _slopes(y: np.ndarray, c: np.ndarray, kinks: np.ndarray):
    """(left, right): the slopes of ``y`` (nodes ``c`` on its last axis) at the start and
    the end of each node interval, by finite differences within the stretch between two
    ``kinks`` (node indices; V(wi) is bilinear between bin centres, so A bends there)
    that holds the interval: a kink has one slope each side."""
    left = np.zeros(y.shape[:-1] + (len(c) - 1,))
    right = np.zeros_like(left)
    bounds = np.unique(np.concatenate([[0], kinks, [len(c) - 1]]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        g = (np.gradient(y[..., a:b + 1], c[a:b + 1], axis=-1, edge_order=2) if b - a >= 2 else
             np.repeat((y[..., b:b + 1] - y[..., a:a + 1]) / (c[b] - c[a]), 2, axis=-1))
        left[..., a:b] = g[..., :-1]
        right[..., a:b] = g[..., 1:]
    return left, right


def _along_axis(y: np.ndarray, c: np.ndarray, kinks: np.ndarray, x: np.ndarray, axis: int):
    """(cubic, linear): ``y``, held at the nodes ``c`` along ``axis``, at ``x``; cubic
    Hermite with :func:`_slopes` (beyond the outermost nodes, their intervals' cubics go
    on), and linear (beyond them, the outermost node's value, as :func:`node_interval`
    reads it)."""
    y = np.moveaxis(y, axis, -1)
    left, right = _slopes(y, c, kinks)
    k = np.clip(np.searchsorted(c, x, side="right") - 1, 0, len(c) - 2)
    h = c[k + 1] - c[k]
    t = (x - c[k]) / h
    y0, y1, m0, m1 = y[..., k], y[..., k + 1], left[..., k] * h, right[..., k] * h
    t2, t3 = t * t, t * t * t
    cubic = (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + t) * m0 + (3 * t2 - 2 * t3) * y1 + (t3 - t2) * m1
    t = np.clip(t, 0.0, 1.0)
    linear = (1 - t) * y0 + t * y1
    return np.moveaxis(cubic, -1, axis), np.moveaxis(linear, -1, axis)


def shape_ratio(means: np.ndarray, n: int, steps: int) -> np.ndarray:
    """The tile mean's A interpolated bicubically over the nodes, over its bilinear
    interpolation, at :func:`shape_points` along each axis: (2, F, F, 3), F = (m + 1) steps
    + 1, from ``means`` (2, m, m, 3), the tile's mean A at the nodes (side, b, a,
    channel). 1 at the nodes; clipped to [0.8, 1.25].

    Why: A is curved between nodes (the fuzz and the Fresnel factor towards the horizon; a
    dip near 70 degrees on twill), and read linearly there it was up to 4% high on the
    plane's twill at 70 degrees and 0.5-0.7% between the outer nodes (performance log L62);
    the tile's mean, whose curve the cubic follows, tells each probe's read how much."""
    c, x = node_coordinates(n), shape_points(n, steps)
    kinks = np.nonzero(np.min(np.abs(c[:, None] - (np.arange(n) + 0.5)[None] / n), axis=1) < 1e-9)[0]
    cubic_x, linear_x = _along_axis(means, c, kinks, x, 2)
    cubic = _along_axis(cubic_x, c, kinks, x, 1)[0]
    linear = _along_axis(linear_x, c, kinks, x, 1)[1]
    ok = linear > 1e-6 * max(float(np.max(np.abs(linear))), 1e-30)
    return np.clip(np.where(ok, cubic / np.where(ok, linear, 1.0), 1.0), 0.8, 1.25)


@dataclass
class SkyAlbedoTable:
    """The SATs of A (:func:`build_sky_albedo_table`) and how to read them.

    Channel ``(side * m^2 + node) * 4 + c`` holds colour channel c of A for incident
    directions at node ``node`` (:func:`node_directions` of ``dv``, the visibility tables'
    bins per side) on side ``side`` (0: front, 1: the mirrored back); its cells are
    ``block`` = (x, y) texels of the tile."""

    sats: ResidualSATs
    dv: int
    block: tuple[int, int]
    #: :func:`shape_ratio` at ``steps`` points per node interval, flat (side, y, x, RGB
    #: and a zero): each read's factor; None: none.
    shape: mi.Float | None = None
    steps: int = 0
    #: Sample weights per cell and direction it was built from, and seconds it took.
    samples: int = 0
    seconds: float = 0.0

    @property
    def nbytes(self) -> int:
        s = self.sats
        return int(s.channels * (s.H + 1) * (s.W + 1) * 4) + (0 if self.shape is None else 4 * dr.width(self.shape))

    def _first_channel(self, cell, back):
        bins, weights = node_weights(None, self.dv, cell)
        side = dr.select(back, mi.UInt32(nodes_per_axis(self.dv) ** 2), mi.UInt32(0))
        return [(side + b) * CHANNELS_PER_BIN for b in bins], weights

    def _shape_factor(self, cell, back):
        """:func:`shape_ratio` at the direction of :func:`node_cell` ``cell`` on side
        ``back``, bilinear between its points (four packet reads of a table of a few MiB)."""
        ka, fx, kb, fy, p = cell
        c = node_coordinates(self.dv)
        m, s = len(c), self.steps
        f = (m + 1) * s + 1

        def position(k, frac, u):  # along one axis, in the table's points
            inner = (mi.Float(k) + 1.0 + frac) * s
            below = u / float(c[0]) * s
            beyond = (m + (u - float(c[-1])) / float(1.0 - c[-1])) * s
            pos = dr.select(u < float(c[0]), below, dr.select(u >= float(c[-1]), beyond, inner))
            return dr.clip(pos, 0.0, float(f - 1))

        x, y = position(ka, fx, p.x), position(kb, fy, p.y)
        x0, y0 = dr.minimum(dr.floor(x), float(f - 2)), dr.minimum(dr.floor(y), float(f - 2))
        tx, ty = x - x0, y - y0
        row = (dr.select(back, mi.UInt32(f), mi.UInt32(0)) + mi.UInt32(y0)) * f + mi.UInt32(x0)
        corners = [gather_block(self.shape, (row + d) * CHANNELS_PER_BIN, 4)[:3] for d in (0, 1, f, f + 1)]
        return mi.Color3f(*((1 - ty) * ((1 - tx) * a + tx * b) + ty * ((1 - tx) * c + tx * d)
                            for a, b, c, d in zip(*corners)))

    def probe_albedo(self, boxes, split, use, x, y, wi_up, back, xi_round) -> mi.Color3f:
        """The mean A over what a shading point samples its direction from, for the
        mirrored-frame direction ``wi_up`` on side ``back``: where ``use``, the probe's
        texel ``boxes`` (x0, y0, x1, y1; several: the parts of a probe ``split`` per lane,
        empty parts adding nothing), else the cell under texel coordinates (x, y) (the
        fibre-level branch's point). The boxes' corners are rounded stochastically to
        whole cells by ``xi_round`` (one read per corner and node, the exact mean in
        expectation); a probe that rounds to nothing reads the cell under (x, y)."""
        # (Opaque: cloths whose tables' cells differ trace the same code, one callable.)
        rx, ry = (opaque(mi.Float, 1.0 / b) for b in self.block)
        cells = [round_box(x0 * rx, y0 * ry, x1 * rx, y1 * ry, xi_round.x, xi_round.y) for x0, y0, x1, y1 in boxes]
        area = sum(((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in cells[1:]),
                   (cells[0][2] - cells[0][0]) * (cells[0][3] - cells[0][1]))
        point = ~mi.Bool(use) | (area < 0.5)
        px, py = dr.floor(x * rx), dr.floor(y * ry)
        first = tuple(dr.select(point, p, c) for p, c in zip((px, py, px + 1.0, py + 1.0), cells[0]))
        rest = [tuple(dr.select(point, px, c) if k % 2 == 0 else dr.select(point, py, c) for k, c in enumerate(box))
                for box in cells[1:]]
        queries = [self.sats.query_on_grid(*box) for box in [first] + rest]
        q = queries[0] if len(queries) == 1 else RectUnion(queries, mi.Bool(split) & ~point)
        cell = node_cell(wi_up, self.dv)
        firsts, weights = self._first_channel(cell, back)
        total = [mi.Float(0.0) for _ in range(3)]
        for channel, w in zip(firsts, weights):
            values = self.sats.integrals(q, channel, CHANNELS_PER_BIN, aligned=True)
            for c in range(3):
                total[c] += w * values[c]
        inv_area = dr.rcp(dr.maximum(q.area, 1e-12))
        albedo = mi.Color3f(*(t * inv_area for t in total))
        return albedo if self.shape is None else albedo * self._shape_factor(cell, back)


#: Tables built in this process, by the cloth's calibration key and the table's size (the
#: same cloth loaded again, as a benchmark or an animation does, builds none): the last
#: ``KEPT_TABLES`` (a cloth can hold a pilot's small table and a full one).
_TABLES: "OrderedDict[str, SkyAlbedoTable]" = OrderedDict()
KEPT_TABLES = 8

def _with_settings(key: str | None, max_mib: float | None) -> str | None:
    """``key``, the table's size and this module's settings (experiments change them)."""
    max_mib = MAX_MIB if max_mib is None else max_mib
    return None if key is None else (f"{key}|{SAMPLES}|{max_mib}|{OUTER_INSETS}|{NODES_PER_BIN}|{OUTER_BIN_NODES}"
                                     f"|{SHAPE_STEPS}|{PACKET_PLANES}")


def cached_table(key: str | None, max_mib: float | None = None) -> SkyAlbedoTable | None:
    """The table of ``max_mib`` (default ``MAX_MIB``) built for ``key`` in this process, if it is kept."""
    key = _with_settings(key, max_mib)
    if key is None or key not in _TABLES:
        return None
    _TABLES.move_to_end(key)
    return _TABLES[key]


def keep_table(key: str | None, table: SkyAlbedoTable, max_mib: float | None = None) -> SkyAlbedoTable:
    """Keep ``table`` (built within ``max_mib``) for ``key`` (dropping the least recently
    used beyond ``KEPT_TABLES``); returns it."""
    key = _with_settings(key, max_mib)
    if key is not None:
        _TABLES[key] = table
        while len(_TABLES) > KEPT_TABLES:
            _TABLES.popitem(last=False)
    return table


#: Lanes of one launch of the build (directions batched up to it).
BATCH_LANES = 1 << 20


def _next_block(n: int, block: int) -> int | None:
    """The smallest multiple of ``block`` above it that divides ``n`` (None: none)."""
    return next((d for d in range(2 * block, n + 1, block) if n % d == 0), None)


def cell_blocks(height: int, width: int, dv: int, max_mib: float) -> tuple[int, int]:
    """(x, y) texels per table cell: square powers of two while both sides halve, the
    smallest whose table (2 m^2 nodes x 4 channels x cells, float32; m =
    :func:`nodes_per_axis`) fits ``max_mib``; past that, cells that divide the tile along
    each axis, the narrower side grown first (a 51 x 64 knit: 17 or 51 texels high)."""
    bx = by = 1
    per_cell = 2 * nodes_per_axis(dv) ** 2 * CHANNELS_PER_BIN * 4
    while (height // by + 1) * (width // bx + 1) * per_cell > max_mib * 2 ** 20:
        nx, ny = _next_block(width, bx), _next_block(height, by)
        if nx == 2 * bx and ny == 2 * by:
            bx, by = nx, ny
        elif nx is not None and (ny is None or bx <= by):
            bx = nx
        elif ny is not None:
            by = ny
        else:
            break
    return bx, by


#: (lanes' uv, lanes' local wi, sample1, sample2) -> (weight RGB as numpy (3, n), kept mask
#: as numpy (n,)): one fibre-level sample per lane, its weight, kept where it is valid.
SampleFn = Callable[..., tuple]


def build_sky_albedo_table(sample: SampleFn, height: int, width: int, uv_scale: tuple[float, float], dv: int,
                           samples: int | None = None, max_mib: float | None = None, seed: int = 7,
                           progress: Callable[[int, int], None] | None = None) -> SkyAlbedoTable:
    """Measure A at every cell of the tile (``height`` x ``width`` texels, texel (ix, iy) at
    uv ((ix + 1/2) / (W uv_scale_u), ...)) for both sides at every node
    (:func:`node_directions` of ``dv``), ``samples`` fibre-level samples per cell and direction: a
    stratified grid in the direction sample, stratified lobe choice, a uniform point of
    the cell, one random shift of all of them per cell (the same for every direction)."""
    import time

    start = time.perf_counter()
    samples = SAMPLES if samples is None else samples
    max_mib = MAX_MIB if max_mib is None else max_mib
    bx, by = cell_blocks(height, width, dv, max_mib)
    rows, cols = height // by, width // bx
    cells = rows * cols
    g = max(1, int(round(math.sqrt(samples))))
    n = g * g
    rng = np.random.default_rng(seed)
    # Per cell: shifts of (sample1, sample2.x, sample2.y, position x, position y).
    shift = rng.random((cells, 5))
    k = np.arange(n)
    # Each cell pairs the lobe choice's strata with the direction's by a permutation of
    # its own: one permutation for all of them ties each direction stratum to one lobe
    # (A was 2-9% off on the plane's twill, performance log L60).
    s1 = (rng.permuted(np.tile(np.arange(n), (cells, 1)), axis=1).ravel() + np.repeat(shift[:, 0], n)) / n
    s2x = (np.tile(k % g, cells) + np.repeat(shift[:, 1], n)) / g
    s2y = (np.tile(k // g, cells) + np.repeat(shift[:, 2], n)) / g
    # The cell's points: a second stratified grid, decorrelated from the direction's.
    perm = rng.permuted(np.tile(np.arange(n), (cells, 1)), axis=1).ravel()
    px = (perm % g + np.repeat(shift[:, 3], n)) / g
    py = (perm // g + np.repeat(shift[:, 4], n)) / g
    ix = np.repeat(np.arange(cells) % cols, n)
    iy = np.repeat(np.arange(cells) // cols, n)
    u = (ix + px) * bx / (width * uv_scale[0])
    v = (iy + py) * by / (height * uv_scale[1])
    uv = mi.Point2f(lane_values(u), lane_values(v))
    sample1 = lane_values(np.fmod(s1, 1.0))
    sample2 = mi.Point2f(lane_values(np.fmod(s2x, 1.0)), lane_values(np.fmod(s2y, 1.0)))
    centres = node_directions(dv)
    n_dirs = len(centres)
    values = np.zeros((2 * n_dirs, CHANNELS_PER_BIN, rows, cols), dtype=np.float64)
    # Directions in batches of about BATCH_LANES lanes: a launch per direction costs more
    # than a small table's samples (a 4 MiB table took 6 s, its 1922 launches).
    lanes = cells * n
    batch = max(1, min(n_dirs, BATCH_LANES // lanes))
    # (The lane count read, not a literal, and every batch traced alike: one compiled
    # kernel builds every cloth's table, 0.14 s of LLVM each otherwise.)
    lanes_read = opaque(mi.UInt32, lanes)
    for side in range(2):
        for b0 in range(0, n_dirs, batch):
            c = centres[b0:b0 + batch] * (1.0, 1.0, 1.0 if side == 0 else -1.0)
            k = len(c)
            wi = mi.Vector3f(*(lane_values(np.repeat(c[:, i], lanes)) for i in range(3)))
            index = dr.arange(mi.UInt32, k * lanes) % lanes_read
            points = tuple(dr.gather(type(a), a, index) for a in (uv, sample1, sample2))
            weight, kept = sample(points[0], wi, *points[1:])
            w = np.where(kept[None], weight, 0.0).reshape(3, k, cells, n).mean(axis=3)
            values[side * n_dirs + b0:side * n_dirs + b0 + k, :3] = w.transpose(1, 0, 2).reshape(k, 3, rows, cols)
            if progress is not None:
                progress(side * n_dirs + b0 + k, 2 * n_dirs)
    sat, mean = build_sat(values.reshape(-1, rows, cols))
    shape = None
    if SHAPE_STEPS:
        m = nodes_per_axis(dv)
        ratio = shape_ratio(values[:, :3].mean(axis=(2, 3)).reshape(2, m, m, 3), dv, SHAPE_STEPS)
        shape = flat_array(np.concatenate([ratio, np.zeros(ratio.shape[:-1] + (1,))], axis=-1).ravel())
    # A node's four channels in one packet (PACKET_PLANES: its plane whole).
    return SkyAlbedoTable(ResidualSATs(sat, mean, packet_planes=PACKET_PLANES), dv, (bx, by), shape, SHAPE_STEPS, n, time.perf_counter() - start)
