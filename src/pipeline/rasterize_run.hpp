#pragma once
// `cityforge cloud rasterize`: DSM, DTM, nDSM and point density GeoTIFFs from
// a cloud, on the exact grid of a reference raster (same origin, size, GSD,
// CRS) or on a grid of a given GSD over the cloud's extent.
#include <string>

#include "cloud/cloud_filters.hpp"
#include "core/progress.hpp"

namespace cityforge {

struct RasterizeOptions {
    std::string cloud_crs;         ///< overrides/supplies the cloud's CRS
    std::string grid_raster;       ///< reference raster whose grid is used (empty = gsd_m over the cloud)
    double gsd_m = 0.5;            ///< cell size when no grid raster is given
    OutlierFilterOptions outliers;
    GroundFilterOptions ground;
    /// With a grid raster, a cloud announcing more points is never held
    /// whole: the grid is cut into tiles of `tile_m` read as windows grown by
    /// `overlap_m` (streamed); each tile's core is kept. The DTM fill is local,
    /// so cores join seamlessly; the outlier limit is measured once on the
    /// grid's central 400 m.
    uint64_t max_points_in_memory = 20'000'000;
    double tile_m = 1000.0;
    double overlap_m = 100.0;
    void validate() const;
};

struct RasterizeReport {
    std::string dsm_path, dtm_path, ndsm_path, density_path;
    int width = 0, height = 0;
    std::string crs;
    uint64_t points = 0;
    std::size_t ground_points = 0;
    std::size_t tiles = 1;          ///< cloud windows read (1 = the whole cloud at once)
    bool ground_from_classification = false;
    double seconds = 0.0;
};

/// Writes dsm.tif, dtm.tif, ndsm.tif and density.tif (Float32, nodata
/// -9999, tiled DEFLATE) into `out_dir`.
RasterizeReport rasterize_run(const std::string& cloud_path, const std::string& out_dir, const RasterizeOptions& options,
                              const Progress& progress = {});

}  // namespace cityforge
