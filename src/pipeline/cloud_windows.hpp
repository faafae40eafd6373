#pragma once
// Clouds larger than memory, window by window. A command that rasterises a
// cloud on a grid (cloud rasterize, footprints) or measures it under
// footprints (heights) either holds the cloud whole or reads it as windows
// (streamed crops, each grown by an overlap); both give the same bytes:
//  - the decisions that depend on the whole cloud are made once, before any
//    window is read, from the central 400 m of the work area (the outlier
//    filter's limit, the point density), in both paths (plan_cloud);
//  - points are placed on cells through the full grid's transform, and each
//    window keeps only its core, whose cells depend on points within the
//    overlap only (canonical point order, exact neighbours).
#include <cstdint>
#include <string>
#include <vector>

#include "cloud/cloud_rasters.hpp"
#include "cloud/cloud_reader.hpp"
#include "core/progress.hpp"
#include "pipeline/prepared_cloud.hpp"

namespace cityforge {

/// Plan-time measures of a cloud for a work area centred on `centre` (target CRS).
struct CloudPlan {
    /// `outliers` with max_mean_distance fixed (metres): the given value, or
    /// the limit measured on the sample (0 = the filter is off or the sample
    /// holds no point: each cloud read then measures its own).
    OutlierFilterOptions outliers;
    double density_m2 = 0.0;  ///< kept points per m² of the sample (0 = unknown)
};

/// Measures the plan on the 400 m square around `centre` (sample_cloud; the
/// whole cloud when it is smaller). One streamed pass over the file.
CloudPlan plan_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                     const OutlierFilterOptions& outliers, const MapPoint& centre);

/// Whether a command reads the cloud window by window: it announces more
/// than `max_points` points, or its header's bounding box (LAS; finite,
/// min <= max) would need a grid of more than `max_points` cells of `cell`
/// file-CRS units and of more than 4 cells per announced point, e.g. the
/// ground filter's grid over a corridor at 45 degrees or over points
/// kilometres apart (said in an info line). `max_points` = 0: never;
/// `cell` <= 0: by the point count only (commands whose output grid covers
/// the whole box anyway: `cloud rasterize`, `footprints`).
bool read_cloud_by_windows(const CloudReader& reader, uint64_t max_points, double cell);

/// Edge (metres) of square tiles whose windows (tile + 2 x overlap_m a side)
/// hold about `max_points` at `density_m2`: at most `tile_m`, at least 50 m.
double window_tile_edge_m(double tile_m, double overlap_m, double density_m2, uint64_t max_points);

/// The cloud's rasters on a whole grid, computed window by window.
struct WindowedRasters {
    CloudRasters rasters;                ///< on the whole grid
    CrsInfo crs, source_crs;             ///< as PreparedCloud's
    uint64_t points = 0;                 ///< points read, summed over the windows (overlaps counted in each)
    std::size_t ground_points = 0;       ///< summed over the windows
    bool ground_from_classification = false;
    bool reprojected = false;
    std::size_t windows = 0;             ///< windows read
    uint64_t core_points = 0;            ///< kept points on the grid (each counted once)
};

/// Rasterises the cloud on `grid` (target CRS) in tiles of `tile_px` cells,
/// each read as a window grown by `overlap_px` cells (prepare_cloud with a
/// crop: streamed, canonical order, `outliers` with a fixed limit, `ground`),
/// rasterised on its window of the grid (rasterize_cloud's window form) and
/// its core copied. Memory: one window's points plus the grid's rasters.
/// Equal to rasterize_cloud on the whole prepared cloud wherever a core
/// cell's points, their neighbours and the DTM gaps it fills from lie within
/// the overlap.
WindowedRasters rasterize_cloud_by_windows(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                                           const GridSpec& grid, double unit_m, const OutlierFilterOptions& outliers,
                                           const GroundFilterOptions& ground, int tile_px, int overlap_px, const Progress& progress = {});

/// The most populated square of `cell` (target CRS units) a side, on squares
/// anchored at `within`'s lower-left corner, among the cloud's points inside
/// `within` (target CRS): its centre and its point count (0 and `within`'s
/// centre when no point falls inside). One streamed pass; ties go to the
/// lowest row (from min_y), then column, so the answer is the same whatever
/// the order of the points. Used to sample a cloud whose bounding box says
/// little of where its points are (a few far outliers, an L-shaped survey).
struct DensestSquare {
    MapPoint centre;
    uint64_t points = 0;
};
DensestSquare densest_square(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                             const Extent& within, double cell, const Progress& progress = {});

/// Points of the cloud (moved to `target`) on each block of `block_px` x
/// `block_px` pixels of `grid`, row-major from the grid's first row and
/// column (the last blocks may be cut); points off the grid are not counted.
/// One streamed pass. Used to leave out the tiles of a run where the cloud
/// has no point (a corridor across its bounding box).
std::vector<uint64_t> count_points_in_blocks(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                                             const GridSpec& grid, int block_px, const Progress& progress = {});

/// The bounding box of the cloud's points (file CRS), one streamed pass:
/// what the grid of a cloud held whole or read by windows covers. A box
/// emptier than 0.01 points per square unit gets a second pass, which leaves
/// out (with a warning naming the file) up to 1 % of the points when they lie
/// in squares of 1/512 of the box's longer side that are nearly empty, as are
/// their 8 neighbours: a few points kilometres away do not make the grid.
/// Each pass reports its share of the header's point count to `progress`.
Extent cloud_point_bounds(const std::string& cloud_path, const Progress& progress = {});

/// cloud_point_bounds moved to `target` (its outline, 9 points a side,
/// transformed; the file's box when `target` is empty or the same CRS).
/// `cloud_crs_override` as for prepare_cloud.
Extent cloud_bounds_in(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target, const Progress& progress = {});

}  // namespace cityforge
