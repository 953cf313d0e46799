"""Dr.Jit side of the summed-area tables: O(1) integrals over any texel rectangle of a
periodic tile, and the direction-bin lookups that go with them.

Tables come from :mod:`mscloth.precompute` as *residual* SATs on the (H+1) x (W+1) grid
of texel corners: sat[c, y, x] = sum over texels y' < y, x' < x of (v - mean_c). The
integral of a piecewise-constant image over a rectangle with real corners is bilinear in
the corner coordinates, so bilinear lookups give exact fractional-texel integrals.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import Extent, flat_array, gather, gather_block, opaque


class RectQuery:
    """The corner geometry of one texel rectangle, computed once and shared by every
    channel read from any :class:`ResidualSATs` of the same tile size.

    ``on_grid``: the corners are whole texel coordinates, so each corner is one read
    instead of four (see :meth:`ResidualSATs.query_rounded`)."""

    def __init__(self, sats: "ResidualSATs", x0, y0, x1, y1, on_grid=False):
        self.area = (x1 - x0) * (y1 - y0)
        self.on_grid = on_grid
        # The rectangle's integral: S(x1,y1) - S(x0,y1) - S(x1,y0) + S(x0,y0). The caller
        # moved (x0, y0) into the first tile (ResidualSATs._home), so x0 and y0 need no
        # whole tiles: those corners read no last column (x0) or row (y0) at all.
        self.corners = [(1.0, sats._corner(x1, y1, on_grid)),
                        (-1.0, sats._corner(x0, y1, on_grid, home_x=True)),
                        (-1.0, sats._corner(x1, y0, on_grid, home_y=True)),
                        (1.0, sats._corner(x0, y0, on_grid, home_x=True, home_y=True))]
        # Whether a corner lies beyond the first tile, reading the last row or column:
        # (x1, y1) does whenever (x0, y1) or (x1, y0) does (x1 >= x0, y1 >= y0).
        far = self.corners[0][1]
        self.wraps = far.use_col | far.use_row

    def edge_reads(self, read, count: int):
        """``read()`` (a list of ``count`` floats: reads of the SATs' last row and column)
        where some lane of a packet has a corner beyond the first tile, zeros elsewhere.
        Footprints inside one tile are the common case, and their masked reads still cost
        the instructions: 12% of a footprint evaluation, measured."""
        if not dr.is_jit_v(mi.Float):
            return read() if self.wraps else [0.0] * count
        return list(dr.if_stmt(args=(), cond=self.wraps, true_fn=lambda: tuple(read()),
                               false_fn=lambda: tuple(mi.Float(0.0) for _ in range(count)),
                               label="sat_edges"))


class RectUnion:
    """Several texel rectangles read as one: every integral is the sum of the parts'
    (a texel under two parts counts twice, as the residual texels spread over the parts
    by area count it). Lanes where ``used`` is False have their first part alone (the
    others empty), and packets without such a lane skip the other parts' reads."""

    def __init__(self, parts: list[RectQuery], used):
        self.parts = parts
        self.used = used
        self.area = sum((p.area for p in parts[1:]), parts[0].area)

    def sum_over(self, read):
        """The sum over the parts of ``read(part)`` (a list of Floats)."""
        total = list(read(self.parts[0]))
        if len(self.parts) < 2:
            return total

        def rest():
            out = None
            for part in self.parts[1:]:
                values = list(read(part))
                out = values if out is None else [a + b for a, b in zip(out, values)]
            return tuple(out)

        if dr.is_jit_v(mi.Float):
            # Widened to the reads' lanes: from constant footprints (tests) ``used`` is one
            # value, and Dr.Jit 1.5.0's if_stmt then returns one-value outputs.
            cond = self.used & dr.full(mi.Bool, True, dr.width(total))
            more = dr.if_stmt(args=(), cond=cond, true_fn=rest,
                              false_fn=lambda: tuple(mi.Float(0.0) for _ in total), label="sat_parts")
        else:
            more = rest() if self.used else [0.0] * len(total)
        return [a + b for a, b in zip(total, more)]


class _Corner:
    """Where the cumulative integral S(x, y) of the periodically repeated tile reads:
    qx whole tiles along x, qy along y, and the remainder (rx, ry) inside the tile."""

    __slots__ = ("qx", "qy", "cell", "ix", "iy", "fx", "fy", "use_col", "use_row", "home_x", "home_y")


class ResidualSATs:
    """``C`` residual SATs of one tile in Dr.Jit memory, queried per lane.

    Layout: channel-minor, ``data[(y * (W + 1) + x) * C + c]``: the channels of one texel
    corner share cache lines, so the gap/moment/cluster channels (or a rank-K table's
    coefficients) that one footprint reads at a corner, in packets of four, cost a few
    cache misses instead of one per channel. ``channel_major``: one channel's plane whole,
    ``data[c * (H + 1) * (W + 1) + y * (W + 1) + x]``, for the full directional table,
    of which a footprint reads four bins per corner, the same four across a region under
    one sun (docs/decisions.md, "The full directional SAT by planes"). ``packet_planes``:
    the planes of a packet of four channels whole, ``data[((c // 4) * (H + 1) * (W + 1) +
    y * (W + 1) + x) * 4 + c % 4]``, for tables read in packets of four of which a region
    reads the same few (the sky albedo table: four direction nodes at a camera ray's wi).

    Traced code reads the tile's size as opaque values (:class:`.jit_arrays.Extent`), so
    that tables of different tile sizes trace the same code.
    """

    def __init__(self, sat: np.ndarray, mean: np.ndarray, channel_major: bool = False,
                 packet_planes: bool = False):
        sat = np.asarray(sat, dtype=np.float32)
        if sat.ndim == 2:
            sat = sat[None]
        self.channels, rows, cols = sat.shape
        self.H, self.W = rows - 1, cols - 1
        self.width, self.height = Extent(self.W), Extent(self.H)
        self.channel_major = channel_major
        self.packet_planes = packet_planes
        C = self.channels
        # A packet's step from one texel corner to the next (x), and how far apart the
        # packets of the data, the last column and the last row lie per channel of the
        # first (1: together at a corner; a plane each: packet_planes).
        packet_step, planes = C, (1, 1, 1)
        if packet_planes:
            if channel_major or C % 4:
                raise ValueError(f"ResidualSATs: packet planes need whole packets of four channels, got {C}")

            def by_packets(a):  # (C, ...) -> (C / 4, ..., 4): a packet's four channels last
                return np.moveaxis(a.reshape((C // 4, 4) + a.shape[1:]), 1, -1)
            self.data = flat_array(by_packets(sat))
            self.last_col = flat_array(by_packets(sat[:, :, self.W]))
            self.last_row = flat_array(by_packets(sat[:, self.H, :]))
            # (Single channels: integral() adds c % 4 to these.)
            strides = (rows * cols, 4, (self.W + 1) * 4, self.H + 1, 4, self.W + 1, 4)
            packet_step, planes = 4, (rows * cols, rows, cols)
        elif channel_major:
            # data[c * (H + 1) * (W + 1) + y * (W + 1) + x]: one channel's plane whole.
            self.data = flat_array(sat)
            self.last_col = flat_array(sat[:, :, self.W])
            self.last_row = flat_array(sat[:, self.H, :])
            strides = ((self.H + 1) * (self.W + 1), 1, self.W + 1, self.H + 1, 1, self.W + 1, 1)
        else:
            self.data = flat_array(np.moveaxis(sat, 0, -1))
            # The last column (x = W) and last row (y = H) alone: the periodic decomposition
            # reads them at every corner, and 1-D interpolation needs 2 reads instead of 4.
            self.last_col = flat_array(np.moveaxis(sat[:, :, self.W], 0, -1))
            self.last_row = flat_array(np.moveaxis(sat[:, self.H, :], 0, -1))
            strides = (1, C, (self.W + 1) * C, 1, C, 1, C)
        # Index strides: data (channel, x, y); last column (channel, y); last row (channel, x).
        (self.step_c, self.step_x, self.row_stride, self.col_c, self.col_y,
         self.row_c, self.row_x) = (opaque(mi.UInt32, v) for v in strides)
        if packet_planes:
            self.packet_step = opaque(mi.UInt32, packet_step)
            self.packet_row = opaque(mi.UInt32, (self.W + 1) * packet_step)
            self.data_plane, self.col_plane, self.row_plane = (opaque(mi.UInt32, v) for v in planes)
        else:
            # Literal C and no plane offsets: the footprint's hot reads trace as before the
            # packet-plane layout existed (no multiply by an opaque 1, a constant step).
            self.packet_step, self.packet_row = C, self.row_stride
            self.data_plane = self.col_plane = self.row_plane = None
        self.mean = flat_array(np.asarray(mean, dtype=np.float64))
        self.total = flat_array(sat[:, self.H, self.W])  # ~0 by construction

    def _corner(self, x, y, on_grid=False, home_x=False, home_y=False):
        """``home_x`` / ``home_y``: x (y) lies in [0, W] ([0, H]), no whole tiles along it
        (x = W reads the last column itself: the same value, float rounding allowed)."""
        w, h = self.width, self.height
        c = _Corner()
        c.home_x, c.home_y = home_x, home_y
        c.qx = 0.0 if home_x else dr.floor(x * w.rcp)
        c.qy = 0.0 if home_y else dr.floor(y * h.rcp)
        rx = dr.clip(x if home_x else x - c.qx * w.f, 0.0, w.f)
        ry = dr.clip(y if home_y else y - c.qy * h.f, 0.0, h.f)
        if on_grid:  # whole coordinates: the grid point itself, W and H included
            ix = mi.UInt32(dr.round(rx))
            iy = mi.UInt32(dr.round(ry))
        else:
            ix = dr.minimum(mi.UInt32(dr.floor(rx)), w.last_u)
            iy = dr.minimum(mi.UInt32(dr.floor(ry)), h.last_u)
        c.fx = rx - mi.Float(ix)
        c.fy = ry - mi.Float(iy)
        c.ix, c.iy = ix, iy
        c.cell = iy * w.u1 + ix
        # Footprints inside one tile have qx = qy = 0 at every corner: no edge reads.
        c.use_col = c.qx != 0.0
        c.use_row = c.qy != 0.0
        return c

    @staticmethod
    def _edge_terms(c):
        """Which of the last column and last row corner ``c`` can need: (col?, row?)."""
        return not c.home_x, not c.home_y

    def _home(self, x0, y0, x1, y1):
        """The rectangle moved by whole tiles so that (x0, y0) lies in the first tile: the
        same integral (the tile repeats), small tile counts at the corners (texel coordinates
        of a finely tiled surface reach 1e5, and qx * col products of that size lost float32
        precision), and no edge reads for corners inside the first tile."""
        w, h = self.width, self.height
        sx = dr.floor(x0 * w.rcp) * w.f
        sy = dr.floor(y0 * h.rcp) * h.f
        return x0 - sx, y0 - sy, x1 - sx, y1 - sy

    def query(self, x0, y0, x1, y1) -> RectQuery:
        """The corner geometry of the texel rectangle [x0, x1] x [y0, y1] (any size, any
        position: periodic); valid for every table of the same tile size."""
        return RectQuery(self, *self._home(x0, y0, x1, y1))

    def query_rounded(self, x0, y0, x1, y1, xi_x, xi_y) -> RectQuery:
        """The rectangle with its corners rounded stochastically to whole texels
        (:func:`round_box`): one read per corner and channel instead of four."""
        return self.query_on_grid(*round_box(x0, y0, x1, y1, xi_x, xi_y))

    def query_on_grid(self, x0, y0, x1, y1) -> RectQuery:
        """:meth:`query` for corners at whole texel coordinates."""
        return RectQuery(self, *self._home(x0, y0, x1, y1), on_grid=True)

    def integrals(self, q: RectQuery, first, n: int, aligned: bool = False):
        """:meth:`integral` of the ``n`` channels from ``first`` on (Python ints; or
        ``first`` a per-lane UInt32 that the caller knows to be a multiple of four:
        ``aligned``), read in packets where the layout allows (channels in whole fours):
        one packet per corner of a rounded query, four (bilinear) of an exact one."""
        if isinstance(q, RectUnion):
            return q.sum_over(lambda part: self.integrals(part, first, n, aligned))
        C = self.channels
        if not (n % 4 == 0 and (aligned or first % 4 == 0) and C % 4 == 0) or self.channel_major:
            return [self.integral(q, first + j) for j in range(n)]
        if self.packet_planes and n > 4:  # (each packet of four its own plane)
            return [v for k in range(0, n, 4) for v in self.integrals(q, first + k, 4, aligned=True)]
        step = self.packet_step
        totals = gather_block(self.total, mi.UInt32(first), n)
        means = gather_block(self.mean, mi.UInt32(first), n)

        def lerp_blocks(a, b, t):
            return [dr.lerp(u, v, t) for u, v in zip(a, b)]

        def read_edges():  # n of the last column or row for each one a corner can need
            values = []
            for _, c in q.corners:
                col, row = self._edge_terms(c)
                if col:
                    at = c.iy * step + self._plane(first, self.col_plane)
                    block = gather_block(self.last_col, at, n, c.use_col)
                    if not q.on_grid:
                        block = lerp_blocks(block, gather_block(self.last_col, at + step, n, c.use_col), c.fy)
                    values += block
                if row:
                    at = c.ix * step + self._plane(first, self.row_plane)
                    block = gather_block(self.last_row, at, n, c.use_row)
                    if not q.on_grid:
                        block = lerp_blocks(block, gather_block(self.last_row, at + step, n, c.use_row), c.fx)
                    values += block
            return values

        edges = iter(q.edge_reads(read_edges, 4 * n))
        zero = [0.0] * n
        out = [mi.Float(0.0) for _ in range(n)]
        for sign, c in q.corners:
            at = c.cell * step + self._plane(first, self.data_plane)
            inner = gather_block(self.data, at, n)
            if not q.on_grid:
                below = gather_block(self.data, at + self.packet_row, n)
                inner = lerp_blocks(lerp_blocks(inner, gather_block(self.data, at + step, n), c.fx),
                                    lerp_blocks(below, gather_block(self.data, at + self.packet_row + step, n), c.fx),
                                    c.fy)
            has_col, has_row = self._edge_terms(c)
            col = [next(edges) for _ in range(n)] if has_col else zero
            row = [next(edges) for _ in range(n)] if has_row else zero
            for j in range(n):
                out[j] += sign * self._periodic(c, totals[j], col[j], row[j], inner[j])
        return [o + m * q.area for o, m in zip(out, means)]

    @staticmethod
    def _plane(first, plane):
        """Where the packet of channel ``first`` starts (plane ``None``: at the corner)."""
        return first if plane is None else first * plane

    def integral(self, q: RectQuery, channel):
        """Integral of the original values of ``channel`` (int or per-lane UInt32) over the
        rectangle of query ``q`` (made by any table of this tile size; or a
        :class:`RectUnion` of such)."""
        if isinstance(q, RectUnion):
            return q.sum_over(lambda part: [self.integral(part, channel)])[0]
        row_stride, step_x = self.row_stride, self.step_x
        channel = mi.UInt32(channel)
        total = gather(self.total, channel)
        # (packet_planes: the strides place the channel's packet; c % 4 within it.)
        within = None
        if self.packet_planes:
            within = channel & 3
            channel = channel - within

        def place(index):  # (packet_planes: c % 4 within the channel's packet)
            return index if within is None else index + within

        def read_edges():  # per corner: the last-column and last-row values it can need
            values = []
            for _, c in q.corners:
                has_col, has_row = self._edge_terms(c)
                col = place(c.iy * self.col_y + channel * self.col_c)
                row = place(c.ix * self.row_x + channel * self.row_c)
                if q.on_grid:  # fx = fy = 0 up to rounding: the corner's own values
                    values += [gather(self.last_col, col, c.use_col)] if has_col else []
                    values += [gather(self.last_row, row, c.use_row)] if has_row else []
                else:
                    values += [dr.lerp(gather(self.last_col, col, c.use_col),
                                       gather(self.last_col, col + self.col_y, c.use_col), c.fy)] if has_col else []
                    values += [dr.lerp(gather(self.last_row, row, c.use_row),
                                       gather(self.last_row, row + self.row_x, c.use_row), c.fx)] if has_row else []
            return values

        edges = iter(q.edge_reads(read_edges, 4))
        residual = mi.Float(0.0)
        for sign, c in q.corners:
            has_col, has_row = self._edge_terms(c)
            col = next(edges) if has_col else 0.0
            row = next(edges) if has_row else 0.0
            i00 = place(c.ix * step_x + c.iy * row_stride + channel * self.step_c)
            if q.on_grid:
                inner = gather(self.data, i00)
            else:
                v00 = gather(self.data, i00)
                v01 = gather(self.data, i00 + step_x)
                v10 = gather(self.data, i00 + row_stride)
                v11 = gather(self.data, i00 + row_stride + step_x)
                inner = dr.lerp(dr.lerp(v00, v01, c.fx), dr.lerp(v10, v11, c.fx), c.fy)
            residual += sign * self._periodic(c, total, col, row, inner)
        return residual + gather(self.mean, place(channel)) * q.area

    @staticmethod
    def _periodic(c, total, col, row, inner):
        """S at corner ``c`` of the repeated tile: its whole tiles (qx qy of the tile's
        total), whole columns and rows of tiles (the last column / row of S), and the
        remainder inside the tile."""
        return c.qx * c.qy * total + c.qx * col + c.qy * row + inner


def round_box(x0, y0, x1, y1, xi_x, xi_y):
    """The texel rectangle with its corners rounded stochastically to whole texels:
    x -> floor(x + xi_x), y -> floor(y + xi_y), with xi uniform in [0, 1).

    S(x, y) is bilinear inside a texel, and rounding x up with probability frac(x)
    (independently of y) gives the bilinear weights, so the expected integral is the
    exact one. One xi per axis keeps the rounded width within one texel of the true
    width, and its expectation equal to it."""
    return dr.floor(x0 + xi_x), dr.floor(y0 + xi_y), dr.floor(x1 + xi_x), dr.floor(y1 + xi_y)


def hemisphere_to_square(w):
    """``mi.warp.uniform_hemisphere_to_square`` (the same values to the bit), written so that
    LLVM compiles it right when ``w.x`` or ``w.y`` is a literal 0.

    Mitsuba's concentric map takes the signs from ``select(|x| > |y|, x, y)``; with y a
    literal 0, LLVM 19's optimiser folds ``select(|x| > 0, x, 0) < 0`` to false (the
    pass is not located; ``bench/llvm_sign_fold.py`` checks), so a constant direction
    (-0.4, 0, z) with a computed z mapped to y = -0.08 instead of 0.5 and read the wrong
    direction bins (docs/decisions.md, "Constant directions"). Each branch of the select
    takes its own sign here."""
    s = dr.rsqrt(w.z + 1.0)
    p = mi.Point2f(w.x * s, w.y * s)
    x_major = dr.abs(p.x) > dr.abs(p.y)
    norm = dr.norm(p)
    r = dr.select(x_major, dr.copysign(norm, p.x), dr.copysign(norm, p.y))
    phi = dr.atan2(dr.select(x_major, dr.mulsign(p.y, p.x), dr.abs(p.y)),
                   dr.select(x_major, dr.abs(p.x), dr.mulsign(p.x, p.y)))
    t = (4.0 / dr.pi) * phi
    t = dr.select(x_major, t, 2.0 - t) * r
    return mi.Point2f((dr.select(x_major, r, t) + 1.0) * 0.5, (dr.select(x_major, t, r) + 1.0) * 0.5)


def _bin_cell(w, n: int):
    """(the four bins of the cell of bin centres around ``w`` in the order (a0, b0), (a1, b0),
    (a0, b1), (a1, b1), the fractions fx, fy of ``w`` across it)."""
    p = hemisphere_to_square(w)
    x = p.x * n - 0.5
    y = p.y * n - 0.5
    ax = dr.floor(x)
    ay = dr.floor(y)

    def index(v):  # a NaN direction (wi = -wo) reads bin 0: scalar variants raise on UInt32(NaN)
        return mi.UInt32(dr.clip(dr.select(dr.isnan(v), 0.0, v), 0, n - 1))

    a0, a1, b0, b1 = index(ax), index(ax + 1), index(ay), index(ay + 1)
    return (b0 * n + a0, b0 * n + a1, b1 * n + a0, b1 * n + a1), x - ax, y - ay


def hemisphere_bins(w, n: int):
    """Four direction bins around the upper-hemisphere direction ``w`` and their bilinear
    weights, on the n x n equal-area square grid of :mod:`mscloth.precompute.direction_bins`
    (bin (a, b) centred at ((a + .5)/n, (b + .5)/n), flat index b*n + a; edge bins clamp)."""
    bins, fx, fy = _bin_cell(w, n)
    weights = ((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy)
    return bins, weights


def hemisphere_triangle_bins(w, n: int):
    """Three of :func:`hemisphere_bins`' four and their barycentric weights: the cell cut
    along its diagonal, the half that holds ``w``
    (:func:`mscloth.precompute.direction_bins.triangle_bins`). Linear and continuous as
    the four are, at three quarters of the table reads: the directional D tables' reads
    (performance log L52)."""
    (b00, b10, b01, b11), fx, fy = _bin_cell(w, n)
    bins = (b00, dr.select(fx >= fy, b10, b01), b11)
    weights = (1 - dr.maximum(fx, fy), dr.abs(fx - fy), dr.minimum(fx, fy))
    return bins, weights
