"""The multi-scale tables of one tile in Dr.Jit memory, and the per-lane queries the
``cloth`` BSDF makes of them: footprint integrals (SATs), height-field visibility and
visibility-cluster means."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import Extent, flat_array, flat_word_array, gather, gather_block, gather_word, gather_words
from ..precompute.direction_bins import bin_centres
from ..scattering import sggx
from .sat_queries import RectUnion, ResidualSATs, hemisphere_bins


class FootprintData:
    """Uploads a :class:`mscloth.precompute.tables.MultiscaleTables`."""

    #: Lay the full directional SAT out one direction bin's plane at a time (channel-major)
    #: rather than all bins of a texel corner together: a region of pixels under one sun
    #: reads the same four bins at every corner, so its reads stay in four planes (66 KiB
    #: each for a 128^2 tile) instead of a cache line at every corner of a 68 MiB table
    #: (satin-plane: -9% time per sample; performance log L50). The rank-K table keeps its
    #: coefficients together: a corner reads them all, in packets.
    CHANNEL_MAJOR = True

    def __init__(self, tables, with_sats: bool, with_parallax: bool):
        self.H, self.W = tables.visibility.shape[:2]
        # The tile's width as traced code reads it: opaque, so that tiles of different
        # sizes trace the same code (:class:`.jit_arrays.Extent`).
        self.width = Extent(self.W)
        self.dr = int(tables.dr)
        self.dv = int(tables.dv)
        self.clusters = int(tables.cluster_vis.shape[0])
        self.n_dirs = self.dv * self.dv
        # Each visibility entry says whether the ray along a bin's centre escapes (0 or 255),
        # so a texel's directions pack into bits: 32x less memory than floats (1 MiB for a
        # 256^2 tile at 8x8 bins), which keeps the per-texel lookups in cache. A texel's
        # block holds its front words, then its back (mirrored side) words: at up to 8x8
        # bins one packet of four words, read once per texel and shared by every direction
        # that texel is evaluated for (wi, each wo) instead of one read per bin and direction.
        vis = np.stack([tables.visibility, tables.visibility_back], axis=2).reshape(-1, 2, self.n_dirs)
        if not np.all((vis == 0) | (vis == 255)):
            raise ValueError("FootprintData: visibility tables must hold 0 or 255 (escape or hit)")
        self.words_per_side = (self.n_dirs + 31) // 32
        self.packed_visibility = 2 * self.words_per_side <= 4
        self.words_per_texel = 4 if self.packed_visibility else 2 * self.words_per_side
        words = np.zeros((vis.shape[0], self.words_per_texel * 4), dtype=np.uint8)
        for side in range(2):
            bits = np.packbits(vis[:, side] == 255, axis=-1, bitorder="little")
            start = 4 * side * self.words_per_side
            words[:, start:start + bits.shape[1]] = bits
        self.visibility = flat_word_array(words.view("<u4"))
        # (side, direction, cluster): the clusters of one direction bin are contiguous.
        cvis = np.stack([tables.cluster_vis, tables.cluster_vis_back]).astype(np.float32)
        self.cluster_vis = flat_array(np.moveaxis(cvis, 1, 2))
        # Cluster ids as floats (exact for small integers): one gatherable array type.
        self.cluster_id = flat_array(np.maximum(tables.cluster_id, 0))
        if with_parallax:  # (H, W, dv*dv, 2) texel offsets; 18 MiB for a 192^2 tile
            self.parallax = flat_array(tables.parallax)
        self.per_cluster = with_sats and getattr(tables, "d_sat_cluster", None) is not None
        # (bin, cluster): each cluster's mean D * gap over the tile, a bin's clusters contiguous.
        tile = getattr(tables, "d_cluster_tile", None)
        self.d_cluster_tile = flat_array(tile) if with_sats and tile is not None else None
        if with_sats:
            # Rank-K compression: K coefficient channels and a (bins x K) basis.
            basis = getattr(tables, "d_basis", None)
            self.d_rank = 0 if basis is None else int(basis.shape[1])
            if self.d_rank:
                self.d_basis = flat_array(basis)
            self.d_sat = ResidualSATs(tables.d_sat, tables.d_mean, channel_major=not self.d_rank and self.CHANNEL_MAJOR)
            # The bins' centre directions (x, y, z, 0): one packet read each, for the binned
            # D of a single texel (the control variate of the residual texels).
            centres = bin_centres(self.dr)
            self.bin_centres = flat_array(np.concatenate([centres, np.zeros((len(centres), 1))], axis=1))
            # gap, moments (6), cluster histogram (k), albedo (3): one buffer, channel offsets.
            # Albedo last: uniformly coloured yarns read the channels before it alone.
            sats = [tables.gap_sat, tables.moment_sat, tables.cluster_sat, tables.albedo_sat]
            means = [tables.gap_mean, tables.moment_mean, tables.cluster_mean, tables.albedo_mean]
            sats = np.concatenate([np.asarray(s).reshape(-1, self.H + 1, self.W + 1) for s in sats])
            means = np.concatenate([np.ravel(m) for m in means])
            # Zero channels up to a multiple of four: a footprint reads them all in packets.
            pad = -len(sats) % 4
            self.scalar_sats = ResidualSATs(np.concatenate([sats, np.zeros((pad,) + sats.shape[1:], sats.dtype)]),
                                            np.concatenate([means, np.zeros(pad)]))
            if self.per_cluster:
                k, b = self.clusters, self.d_sat.channels
                self.d_sat_cluster = ResidualSATs(np.asarray(tables.d_sat_cluster).reshape(k * b, self.H + 1, self.W + 1),
                                                  np.ravel(tables.d_cluster_mean))

    def d_integral(self, q, bins, weights, cluster=None):
        """The integral of D(h, t) I over query ``q``'s rectangle, interpolated between the
        direction ``bins`` around h with their ``weights``
        (:func:`.sat_queries.hemisphere_triangle_bins`): three channels of the full
        directional SAT, or for the rank-K table its K coefficient channels weighted by the
        bins' mixed basis row (three basis reads, one SAT read). ``cluster``: over that
        visibility cluster's texels only (the per-cluster tables)."""
        if isinstance(q, RectUnion):  # one branch around all of a part's reads
            return q.sum_over(lambda part: [self.d_integral(part, bins, weights, cluster)])[0]
        sats = self.d_sat if cluster is None else self.d_sat_cluster
        offset = 0 if cluster is None else cluster * self.d_sat.channels
        if not self.d_rank:
            total = mi.Float(0.0)
            for b, w in zip(bins, weights):
                total += w * sats.integral(q, offset + b)
            return total
        coef = self.d_basis_row(bins, weights)
        total = mi.Float(0.0)
        for c, v in zip(coef, sats.integrals(q, offset, self.d_rank)):
            total += c * v
        return total

    def d_basis_row(self, bins, weights):
        """The rank-K basis row of direction h: the rows of its ``bins`` mixed with their
        ``weights`` (K values per lane)."""
        K = self.d_rank
        row = [mi.Float(0.0) for _ in range(K)]
        for b, w in zip(bins, weights):
            for k, c in enumerate(gather_block(self.d_basis, b * K, K)):
                row[k] += w * c
        return row

    def bin_centres_of(self, bins):
        """The centre directions of the direction ``bins`` (for :meth:`binned_ndf`)."""
        centres = []
        for b in bins:
            c = gather_block(self.bin_centres, b * 4, 4)
            centres.append(mi.Vector3f(c[0], c[1], c[2]))
        return centres

    @staticmethod
    def binned_ndf(centres, weights, tangent, alpha, norms=None):
        """D(h, t) I of one texel as the tables hold it: the fibre NDF of ``tangent`` at the
        ``centres`` of the direction bins around h (:meth:`bin_centres_of`, read once for
        every texel), mixed with their ``weights``. Its footprint mean is what
        :meth:`d_integral` reads (up to rank compression), so the residual texels take it
        as their control variate: the footprint estimate is then free of the bins' bias
        whatever their size, at the price of more variance where the bins are coarse for
        the lobe. ``norms``: the centres' squared lengths if known (once for every texel)."""
        return sggx.ndf_mixture(centres, tangent, alpha, weights, norms)

    def cluster_d_means(self, bins, weights):
        """Each visibility cluster's mean of D(h, t) I over the tile, interpolated between
        the direction ``bins`` around h."""
        out = [mi.Float(0.0) for _ in range(self.clusters)]
        for b, w in zip(bins, weights):
            for c, v in enumerate(gather_block(self.d_cluster_tile, b * self.clusters, self.clusters)):
                out[c] += w * v
        return out

    # Channel offsets inside scalar_sats (ALBEDO, after the k cluster channels: per instance).
    GAP, MOMENTS, CLUSTERS = 0, 1, 7

    @property
    def ALBEDO(self):
        return self.CLUSTERS + self.clusters

    # ------------------------------------------------------------------ visibility
    def texel_visibility(self, ix, iy):
        """The visibility bits of texel (ix, iy), for :meth:`visibility_of`: its four words
        (up to 8x8 bins), or where its block starts."""
        base = (iy * self.width.u + ix) * self.words_per_texel
        if self.packed_visibility:
            return gather_words(self.visibility, base, 4)
        return base

    def visibility_of(self, texel, w, back):
        """V(p, w) of the texel whose :meth:`texel_visibility` is ``texel``, for an
        upper-hemisphere direction ``w`` of the front (back=False) or mirrored back
        (back=True) height field, bilinear over direction bins."""
        return self.visibility_in_bins(texel, self.visibility_bins(w), back)

    def visibility_bins(self, w):
        """The four visibility direction bins around ``w`` and their weights: computed once
        per direction where several texels are looked up (:meth:`visibility_in_bins`)."""
        return hemisphere_bins(w, self.dv)

    def visibility_in_bins(self, texel, bins_weights, back):
        """:meth:`visibility_of` for the direction whose :meth:`visibility_bins` are given."""
        bins, weights = bins_weights
        v = mi.Float(0.0)
        if self.packed_visibility:
            # The side's bits as one word (64 bits at 8x8 bins), chosen once per direction:
            # each bin is then a shift, not a choice among the texel's four words.
            if self.words_per_side == 2:
                word = mi.UInt64
                front = word(texel[0]) | (word(texel[1]) << 32)
                back_bits = word(texel[2]) | (word(texel[3]) << 32)
            else:
                word = mi.UInt32
                front, back_bits = texel[0], texel[1]
            bits = dr.select(back, back_bits, front)
            for b, wt in zip(bins, weights):
                v += dr.select(((bits >> word(b)) & 1) != 0, wt, 0.0)
            return v
        side = dr.select(back, mi.UInt32(32 * self.words_per_side), mi.UInt32(0))
        for b, wt in zip(bins, weights):
            bit = side + b  # in the texel's block
            word = gather_word(self.visibility, texel + (bit >> 5))
            v += dr.select(((word >> (bit & 31)) & 1) != 0, wt, 0.0)
        return v

    def visibility_at(self, ix, iy, w, back):
        """V(p, w) of texel (ix, iy) (see :meth:`visibility_of`)."""
        return self.visibility_of(self.texel_visibility(ix, iy), w, back)

    def cluster_visibilities(self, w, back):
        """Mean V of every visibility cluster for direction ``w`` (same conventions as
        :meth:`visibility_at`): a list of ``clusters`` values."""
        bins, weights = hemisphere_bins(w, self.dv)
        side = dr.select(back, mi.UInt32(self.n_dirs), mi.UInt32(0))
        values = [mi.Float(0.0) for _ in range(self.clusters)]
        for b, wt in zip(bins, weights):
            # A bin's clusters are contiguous: packets of four when there are 4k of them.
            row = gather_block(self.cluster_vis, (side + b) * self.clusters, self.clusters)
            for c in range(self.clusters):
                values[c] += wt * row[c]
        return values

    def parallax_offset(self, ix, iy, w):
        """Texel offset (dx, dy) from texel (ix, iy) to where a view ray from direction ``w``
        (upper hemisphere, front side) first meets the height field (Alg. 3)."""
        bins, weights = hemisphere_bins(w, self.dv)
        base = ((iy * self.width.u + ix) * self.n_dirs)
        dx = mi.Float(0.0)
        dy = mi.Float(0.0)
        for b, wt in zip(bins, weights):
            dx += wt * gather(self.parallax, 2 * (base + b))
            dy += wt * gather(self.parallax, 2 * (base + b) + 1)
        return dx, dy

    def cluster_of(self, ix, iy):
        return mi.UInt32(gather(self.cluster_id, iy * self.width.u + ix))
