#pragma once
// Building heights from dense point clouds, per footprint: ground height from
// ground points in a ring around the footprint, roof percentiles of the
// non-ground points inside it, LOD1 height, point density and coverage, and a
// quality flag. Pure algorithm (no GDAL): cloud and footprints share one CRS,
// horizontal units convert to metres with `unit_m`, z is in the cloud's
// vertical datum.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/statistics.hpp"  // percentile
#include "cloud/point_cloud.hpp"
#include "core/geometry.hpp"
#include "core/progress.hpp"

namespace cityforge {

/// How the ground height under a footprint is estimated from the ground ring.
/// plane: robust (iteratively trimmed) least-squares plane through the ring's
/// ground points, evaluated at the footprint's area centroid = the mean
/// terrain height under a planar footprint; unbiased on sloping terrain.
/// Falls back to the ring's median ("ring_median") when the ring cannot hold
/// a plane (too few points, all on a line, extrapolation beyond the ring).
/// percentile: the ground_percentile of the ring's z (biased low on slopes).
enum class GroundMethod { plane, percentile };
std::string to_string(GroundMethod m);
/// "plane" or "percentile"; throws Error naming `option` otherwise.
GroundMethod ground_method_from_string(const std::string& s, const std::string& option = "--ground-method");

/// The largest footprint side (metres) heights are computed for: the largest
/// buildings are under 2 km long; 20 km leaves room for site outlines.
inline constexpr double kMaxFootprintSide_m = 20000.0;

struct HeightOptions {
    double ground_buffer_m = 3.0;          ///< ring around the footprint searched for ground points
    GroundMethod ground_method = GroundMethod::plane;  ///< see GroundMethod
    double ground_percentile = 10.0;       ///< percentile of ground z taken as the building's ground (method percentile)
    double ground_outlier_m = 0.3;         ///< plane method: ring points farther than max(this, 3 robust sigma) from the plane are left out
    int min_ground_points = 5;             ///< fewer -> ring widened (x2, x4), then flagged
    double roof_percentile = 70.0;         ///< percentile of roof z used for height_m (LOD1)
    double min_height_above_ground_m = 0.5;///< roof points must be this far above ground_z
    int min_roof_points = 5;               ///< fewer -> percentiles null, flagged
    /// When a footprint holds at least min_roof_points building-class (6)
    /// points, only those are roof points: unclassified points there are
    /// mostly vegetation overhanging the roof. Otherwise every non-ground,
    /// non-noise, non-water point counts (unclassified or photogrammetric clouds).
    bool prefer_building_class = true;
    double coverage_cell_m = 1.0;          ///< cell size of the nodata_fraction grid
    double unit_m = 1.0;                   ///< metres per horizontal CRS unit
    double z_unit_m = 1.0;                 ///< metres per z unit
    bool keep_roof_points = false;         ///< fill BuildingHeight::roof_points (for LOD2 roofs)
    /// Throws Error naming the option on bad values.
    void validate() const;
};

/// One footprint's heights. Absolute z values are in the cloud's vertical
/// datum and units; heights above ground in metres. Nulls mean "could not be
/// measured" (see height_quality), never a made-up number.
struct BuildingHeight {
    std::optional<double> ground_z;
    /// "ring_plane", "ring_median" (plane not possible), "ring_percentile"; empty without ground.
    std::string ground_method;
    std::optional<double> ground_rmse_m;    ///< RMS residual of the ring's kept ground points about the ground model, metres
    std::optional<double> ground_slope_deg; ///< slope of the ground plane (ring_plane only)
    int64_t n_points_ground_outliers = 0;   ///< ring points left out of the plane fit
    std::optional<double> roof_z_min, roof_z_50p, roof_z_70p, roof_z_90p, roof_z_max;
    std::optional<double> height_m;  ///< roof_percentile z - ground_z, metres
    int64_t n_points_roof = 0;
    int64_t n_points_ground = 0;
    double ground_buffer_used_m = 0.0;
    double point_density_m2 = 0.0;   ///< roof points per square metre of footprint
    double nodata_fraction = 1.0;    ///< share of coverage cells inside the footprint without roof points
    /// "good", "ground_buffer_widened", "few_ground_points", "no_ground",
    /// "few_roof_points", "no_roof_points", "sparse" (< 1 roof point per m2),
    /// "footprint_too_large" (a side beyond kMaxFootprintSide_m: no building,
    /// corrupt coordinates or a wrong CRS; nothing is computed for it).
    std::string height_quality;
    std::vector<uint32_t> roof_points;  ///< indices of the roof points in the cloud (only with keep_roof_points)
};

/// Heights of every footprint (a footprint may have several parts). Points
/// with keep[i] == 0 are ignored; is_ground marks ground points. Cost grows
/// with points + footprints (grid index), parallel over footprints; output
/// order = input order, independent of the thread count.
std::vector<BuildingHeight> compute_building_heights(const PointCloud& cloud, const std::vector<uint8_t>& keep,
                                                     const std::vector<uint8_t>& is_ground,
                                                     const std::vector<std::vector<Polygon>>& footprints,
                                                     const HeightOptions& options, const Progress& progress = {});

}  // namespace cityforge
