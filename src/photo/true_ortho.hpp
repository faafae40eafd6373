#pragma once
// A true ortho from a coloured dense cloud: each cell of a north-up grid takes
// the colour of the cloud's top surface there (the mean colour of the points
// within `top_band_m` of the cell's highest point), so roofs sit on their
// footprints without the lean of a perspective photo. Empty cells are filled
// from filled neighbours for a few passes (small gaps between patches); what
// is still empty is 0 in every band (the nodata value; colours are at least 1). No GDAL.
#include <cstdint>

#include "cloud/cloud_rasters.hpp"
#include "cloud/point_cloud.hpp"
#include "core/image.hpp"

namespace cityforge::photo {

struct TrueOrthoOptions {
    double top_band_m = 0.3;  ///< points this far below a cell's highest point share its colour, metres (cloud z units)
    int fill_passes = 3;      ///< passes of filling empty cells from their 8 neighbours (each pass grows by one cell)
    /// Throws Error on out-of-range values.
    void validate() const;
};

/// RGB (3 bands, 8-bit, 0 = no data) on `grid`
/// (the cloud's CRS). The cloud needs RGB (16-bit LAS colours; 8-bit values
/// scaled by 257 are read as such). Throws Error naming `subject` when the
/// cloud has no colours or no point falls on the grid.
Image<uint8_t> true_ortho_from_cloud(const PointCloud& cloud, const GridSpec& grid, const TrueOrthoOptions& options,
                                     const std::string& subject);

}  // namespace cityforge::photo
