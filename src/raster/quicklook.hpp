#pragma once
// A small 8-bit PNG picture of part of a raster, for reports: the window that
// covers a map extent, resampled so its longer side is at most `max_px`,
// contrast-stretched (2-98 % per band). RGB from bands 1-3, grey otherwise.
#include <cstdint>
#include <string>
#include <vector>

#include "core/geo_transform.hpp"

namespace cityforge {

struct Quicklook {
    std::string png;  ///< PNG file bytes
    Extent extent;    ///< map extent the picture covers (the request clipped to the raster), in the CRS of the request
    int width = 0, height = 0;  ///< pixels
};

/// Throws Error naming the file when it cannot be read or does not overlap
/// `extent`. `extent` is in `crs_wkt` (the picture is then warped onto that
/// CRS when the raster's horizontal CRS differs, e.g. a lon/lat ortho under a
/// UTM model) or, when `crs_wkt` is empty, in the raster's own CRS.
Quicklook render_quicklook_png(const std::string& raster_path, const Extent& extent, int max_px = 1024,
                               const std::string& crs_wkt = {});

/// PNG file bytes of an 8-bit picture: `bytes` pixel-interleaved, rows from the
/// top, `bands` 1 (grey), 3 (RGB) or 4 (RGBA). Throws Error naming `where`.
std::string encode_png(const std::vector<uint8_t>& bytes, int width, int height, int bands, const std::string& where);

}  // namespace cityforge
