#pragma once
// Cleaning and ground classification of dense clouds. Pure algorithms on a
// PointCloud in a projected CRS; distances are in CRS units (callers convert
// metre options with the CRS's linear unit).
#include <cstdint>
#include <span>
#include <vector>

#include "cloud/point_cloud.hpp"

namespace cityforge {

/// Sorts the points by (x, y, z, then their other attributes): every later
/// step then depends on the set of points, not on the order a file (or the
/// tiles a run split it into) listed them. Points equal in every attribute
/// are interchangeable. O(n log n).
void canonical_order(PointCloud& cloud);

struct OutlierFilterOptions {
    bool enabled = true;
    int k_neighbours = 8;            ///< statistical outlier removal: neighbours per point
    double std_multiplier = 3.0;     ///< remove when mean kNN distance > mean + m * sigma
    double isolated_radius = 2.0;    ///< isolated-point filter radius, CRS units (0 = off)
    int isolated_min_neighbours = 2; ///< fewer neighbours than this within the radius = isolated
    /// Absolute limit of the mean kNN distance (CRS units; metres in the
    /// commands' options). 0 = mean + std_multiplier * sigma of this cloud.
    /// Tiled runs fix it once so that every tile filters alike.
    double max_mean_distance = 0.0;
    /// Throws Error naming the option on bad values.
    void validate() const;
};

struct OutlierFilterResult {
    std::vector<uint8_t> keep;          ///< 1 = kept, one per point
    std::size_t removed_statistical = 0;
    std::size_t removed_isolated = 0;
    double limit = 0.0;                 ///< mean kNN distance limit used (CRS units)
};

/// Mean kNN distances over kGrossOutlierFactor x their median are gross
/// outliers: left out of the statistics of the outlier limit.
inline constexpr double kGrossOutlierFactor = 50.0;

/// The value at position size / 2 of the values rounded to float and sorted
/// ascending (what std::nth_element gives on a float copy; the sign of a zero
/// may differ). Values must not be NaN. Any thread count, the same value.
/// Empty input: not allowed (throws Error).
float median_as_float(std::span<const double> values);

/// The statistical filter's limit for these mean kNN distances (one a point):
/// mean + std_multiplier * sigma over the points that are not gross outliers
/// (all of them when none is). 0 for no point.
double outlier_limit(std::span<const double> mean_dist, double std_multiplier);

/// Statistical outlier removal (3D k nearest neighbours) followed by an
/// isolated-point filter. Points classified as noise (7, 18) are removed too
/// and counted as statistical. Deterministic (k-d tree, fixed tie order).
OutlierFilterResult filter_outliers(const PointCloud& cloud, const OutlierFilterOptions& options);

/// Simple Morphological Filter (SMRF, Pingel et al. 2013) parameters.
struct GroundFilterOptions {
    /// Use class 2 when the cloud has ground points; false = always recompute.
    bool trust_classification = true;
    double cell = 1.0;                 ///< minimum-surface grid cell, CRS units
    double slope = 0.15;               ///< rise over run
    double window = 18.0;              ///< largest opening window, CRS units
    double elevation_threshold = 0.5;  ///< max height above the provisional DTM, CRS units
    double elevation_scalar = 1.25;    ///< extra threshold per unit of local slope
    void validate() const;
};

struct GroundResult {
    std::vector<uint8_t> is_ground;  ///< 1 = ground, one per point
    bool from_classification = false;
    std::size_t ground_points = 0;
};

/// Ground points: class 2 when present and trusted, SMRF otherwise. Points
/// with keep[i] == 0 are never ground (keep may be empty = all kept).
GroundResult classify_ground(const PointCloud& cloud, const std::vector<uint8_t>& keep, const GroundFilterOptions& options);

}  // namespace cityforge
