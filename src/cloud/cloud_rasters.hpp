#pragma once
// DSM / DTM / nDSM / point density rasters from a cleaned, ground-classified
// cloud, on a given north-up grid in the cloud's CRS. No GDAL.
#include <cstdint>
#include <string>
#include <vector>

#include "cloud/point_cloud.hpp"
#include "core/geo_transform.hpp"
#include "core/image.hpp"

namespace cityforge {

/// A north-up grid: `transform` maps pixel edges to CRS coordinates.
struct GridSpec {
    GeoTransform transform;
    int width = 0;
    int height = 0;
};

/// Float rasters, NaN = no data. z in the cloud's vertical units.
struct CloudRasters {
    Image<float> dsm;      ///< highest kept point per cell (NaN where empty)
    Image<float> dtm;      ///< mean ground z per cell, gaps filled within kGapFillReach_m of any kept point (NaN beyond: outside the survey)
    Image<float> ndsm;     ///< dsm - dtm where the dsm has data
    Image<float> density;  ///< kept points per square metre
    /// Share of building (6) among the cell's points that are not vegetation
    /// (3, 4, 5); NaN where the cell has no such point (empty, or crown only).
    /// A majority (>= 0.5) puts building edges where half the cell is roof, so
    /// outlines are not biased outwards; leaving vegetation out keeps roofs
    /// under overhanging crowns, seen by the returns that pierce the crown.
    Image<float> building_share;
    /// Share of the cell's points classified vegetation (3, 4, 5); NaN where empty.
    Image<float> vegetation_share;
};

/// A grid of square `cell` (CRS units) covering the cloud, its origin snapped
/// to multiples of the cell so that grids of neighbouring tiles align.
/// Errors (an empty cloud, a grid too large or beyond memory for the rasters
/// of rasterize_cloud: checked_grid_size) name `subject`, usually the cloud's
/// path.
GridSpec grid_over_cloud(const PointCloud& cloud, double cell, const std::string& subject = "rasterize");
/// Bytes per cell rasterize_cloud allocates at its peak (rasters, counters,
/// the DTM's gap filling): what the memory check of a cloud's grid assumes.
inline constexpr double kCloudRasterBytesPerCell = 88.0;
/// The same grid over the points' bounding box `extent` (e.g. measured while
/// streaming a cloud too large to hold). `bytes_per_cell` = bytes the caller
/// allocates per cell of the grid, all layers counted (0 = those of
/// rasterize_cloud, kCloudRasterBytesPerCell), for the memory check of
/// checked_grid_size (OutOfMemory naming `subject`).
GridSpec grid_over_extent(const Extent& extent, double cell, double bytes_per_cell = 0, const std::string& subject = "rasterize");

/// Rasterises `cloud` (points with keep[i] == 0 skipped; keep may be empty)
/// on `grid`. `unit_m` = metres per horizontal CRS unit (for the density).
CloudRasters rasterize_cloud(const PointCloud& cloud, const std::vector<uint8_t>& keep, const std::vector<uint8_t>& is_ground,
                             const GridSpec& grid, double unit_m);

/// The same on the window of `grid` whose top-left cell is (col0, row0), of
/// width x height cells: points are placed through `grid`'s own transform, so
/// each window cell gets exactly the points the same cell of the whole grid
/// gets (no rounding of a shifted origin). The DTM's gaps are filled within
/// the window.
CloudRasters rasterize_cloud(const PointCloud& cloud, const std::vector<uint8_t>& keep, const std::vector<uint8_t>& is_ground,
                             const GridSpec& grid, int col0, int row0, int width, int height, double unit_m);

}  // namespace cityforge
