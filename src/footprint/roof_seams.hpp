#pragma once
// Terraces: touching buildings of one height come out of the cloud as one
// component. Their party walls still show as straight seams across the row:
// the roofs' colours step there (each house re-roofed on its own) while the
// roof surface runs on unchanged; pitched roofs whose ridges run across the
// row meet in a valley; and a ridge along the row stops abruptly where the
// next house's ridge runs across it. This splits a building along such
// seams, perpendicular to either of its principal axes. Each cue is checked
// against the scatter of the heights it rests on, so sparse or noisy roofs
// (dark roofs, low densities) are not cut by noise.
// Pure raster algorithm on the building grid (no GDAL).
#include <cstdint>
#include <vector>

#include "core/image.hpp"
#include "footprint/building_mask.hpp"

namespace cityforge {

struct RoofSeamOptions {
    /// On by default (`footprints --no-roof-seams`, run config
    /// `extraction.roof_seams: false` turn it off). Terraces 50 % of the blocks,
    /// 300 m towns, seeds 210-233: F1 0.34-0.78 without, 0.91-1.00 with; no cut
    /// on 84 towns of twelve other variants and 12 at 600 m (bench/sweep_outlines.sh).
    bool enabled = true;
    double gsd_m = 0.5;              ///< cell size of the rasters, metres
    double window_m = 2.0;           ///< colour / height profiles compared over this length on each side of a seam
    double min_part_length_m = 4.5;  ///< parts shorter than this along the axis are not split off (house widths >= 5 m)
    double min_part_area_m2 = 30.0;  ///< parts smaller than this are not split off
    /// Colour step across the seam, in units of the profile's own noise
    /// (standard deviation of the per-slice colour means on both sides).
    double min_colour_contrast = 5.0;
    /// and as a share of the roof's colour scale (mean over bands of the
    /// building's own pixel standard deviation): steps smaller than this
    /// fraction of the roof's texture are noise. (The scale holds the steps
    /// between the houses themselves, so a high share misses a terrace of
    /// similar roofs; shading between facets is told apart by the heights.)
    double min_colour_step_share = 0.15;
    /// A colour seam counts only where the roof surface runs on unchanged:
    /// the height trends on both sides differ by less than this over the
    /// window and no ridge within the window stands higher than this above
    /// its ends (two facets shade differently; that is not a party wall); metres.
    double ridge_rise_m = 0.3;
    /// A valley across the axis deeper than this on both sides, both sides
    /// sloping into it alike (pitched terraces with ridges across the row),
    /// is a seam whatever the colours; metres. Also the least rise of a ridge
    /// along the row (middle third of the width above the outer thirds) that
    /// counts as a ridge where it turns.
    double valley_depth_m = 0.3;
    /// The seam's slice and both sides must be about equally wide (each at
    /// least this share of the widest): a straight row, not the corner of an
    /// L or the wing of a U. The colour step must also show in each third of
    /// the width (a straight seam, not a shadow edge or a crown).
    double min_width_share = 0.85;
    void validate() const;  ///< throws Error naming the option
};

/// Splits the buildings of `mask` at roof seams (see RoofSeamOptions).
/// `colours` = the ortho's colour bands on the mask's grid (any value range),
/// `valid` its data mask (may be empty), `ndsm` heights above ground in metres
/// (NaN = none). Parts are relabelled 1..count in raster order of first
/// appearance. Returns the number of seams cut. Deterministic.
int split_at_roof_seams(BuildingMask& mask, const Image<float>& colours, const std::vector<uint8_t>& valid, const Image<float>& ndsm,
                        const RoofSeamOptions& options);

}  // namespace cityforge
