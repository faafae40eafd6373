#pragma once
// Affine pixel <-> map transform of a north-up raster, GDAL's convention:
// map_x = origin_x + col * pixel_width, map_y = origin_y + row * pixel_height,
// where (col, row) = (0, 0) is the outer corner of the top-left pixel and
// pixel_height is negative for north-up images. Units are the CRS's axis units.
#include <array>

namespace cityforge {

struct MapPoint {
    double x = 0.0;  ///< easting (or longitude), CRS units
    double y = 0.0;  ///< northing (or latitude), CRS units
};

struct PixelPoint {
    double col = 0.0;  ///< fractional column, 0 = left edge of the raster
    double row = 0.0;  ///< fractional row, 0 = top edge of the raster
};

/// Non-rotated geotransform (rotation terms are refused when reading).
struct GeoTransform {
    double origin_x = 0.0;       ///< map x of the raster's left edge
    double pixel_width = 1.0;    ///< > 0, CRS units per column
    double origin_y = 0.0;       ///< map y of the raster's top edge
    double pixel_height = -1.0;  ///< != 0, CRS units per row (negative = north-up)

    static GeoTransform from_gdal(const std::array<double, 6>& gt) {
        return GeoTransform{gt[0], gt[1], gt[3], gt[5]};
    }
    std::array<double, 6> to_gdal() const { return {origin_x, pixel_width, 0.0, origin_y, 0.0, pixel_height}; }

    MapPoint pixel_to_map(PixelPoint p) const {
        return {origin_x + p.col * pixel_width, origin_y + p.row * pixel_height};
    }
    /// Centre of pixel (col, row).
    MapPoint pixel_centre(int col, int row) const { return pixel_to_map({col + 0.5, row + 0.5}); }
    PixelPoint map_to_pixel(MapPoint m) const {
        return {(m.x - origin_x) / pixel_width, (m.y - origin_y) / pixel_height};
    }
    /// The transform of a window whose top-left pixel is (col0, row0) of this raster.
    GeoTransform window(int col0, int row0) const {
        return {origin_x + col0 * pixel_width, pixel_width, origin_y + row0 * pixel_height, pixel_height};
    }
};

/// Axis-aligned extent in CRS units.
struct Extent {
    double min_x = 0.0, min_y = 0.0, max_x = 0.0, max_y = 0.0;
    double width() const { return max_x - min_x; }
    double height() const { return max_y - min_y; }
};

}  // namespace cityforge
