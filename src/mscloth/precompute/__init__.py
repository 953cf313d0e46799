"""NumPy precomputation for multi-scale shading (docs/design.md §4): direction bins, residual
summed-area tables, height-field visibility and its clusters, parallax offsets, and the
cached per-tile :class:`MultiscaleTables`.
"""
from .direction_bins import (bilinear_bins, bin_centres, direction_to_bin, fold_upper,
                             hemisphere_to_square, square_to_hemisphere, triangle_bins)
from .parallax import parallax_table
from .summed_area import ResidualSAT, build_sat, rect_mean, rect_sum
from .tables import (FORMAT_VERSION, MultiscaleTables, TableKey, build_tables, default_cache_dir,
                     load_or_build, sggx_fibre_ndf, table_key)
from .visibility import cluster_visibility, visibility_table

__all__ = [
    "FORMAT_VERSION", "MultiscaleTables", "ResidualSAT", "TableKey", "bilinear_bins", "bin_centres", "triangle_bins", "build_sat",
    "build_tables", "cluster_visibility", "default_cache_dir", "direction_to_bin", "fold_upper",
    "hemisphere_to_square", "load_or_build", "parallax_table", "rect_mean", "rect_sum",
    "sggx_fibre_ndf", "square_to_hemisphere", "table_key", "visibility_table",
]
