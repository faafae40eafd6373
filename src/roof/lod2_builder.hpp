#pragma once
// LOD2 building reconstruction from roof points: roof planes (roof_planes),
// a partition of the footprint by the planes' intersection lines (ridges,
// hips, valleys) and step lines, each cell labelled with the plane most of
// its points lie on, then a closed 2.5-D solid: roof faces on their planes,
// vertical walls down to the ground along the footprint and at height steps
// between roof parts, a ground face. Where the points are too few for planes
// it falls back to a flat roof (LOD1.2) and says why. Exact arrangement
// (CGAL) for the partition; map coordinates in, map coordinates out. No GDAL.
#include <array>
#include <string>
#include <vector>

#include "core/geometry.hpp"
#include "model/solid.hpp"
#include "roof/roof_planes.hpp"

namespace cityforge {

struct Lod2Options {
    RoofPlaneOptions planes;
    double line_extension_m = 2.0;     ///< partition lines reach this far beyond their planes' common boundary
    double ridge_snap_m = 1.0;         ///< a plane intersection farther than this from the planes' common boundary is a step, not a ridge
    double flat_slope_deg = 5.0;       ///< planes flatter than this count as flat for the roof type
    double min_roof_height_m = 0.3;    ///< roof vertices must be at least this far above the ground, else fallback
    int min_points = 30;               ///< fewer roof points -> flat-roof fallback
    double max_median_residual_m = 0.5;///< a model whose points' median residual is larger -> flat-roof fallback
    /// A roof whose planes need more partition lines (one per adjacent plane
    /// pair) falls back flat: the partition's size and time grow with their
    /// square (noisy photogrammetric roofs gave thousands of planes).
    int max_partition_lines = 200;
    /// A model that falls back (planes or partition failed) or whose RMSE is
    /// above `retry_rmse_m` is rebuilt with alternative plane settings (wider
    /// normal tolerance, smaller minimum support, longer partition lines);
    /// the valid model with the lowest RMSE is kept. Deterministic.
    bool retry_alternatives = true;
    double retry_rmse_m = 0.3;         ///< metres; see retry_alternatives
    double unit_m = 1.0;               ///< metres per horizontal CRS unit
    double z_unit_m = 1.0;             ///< metres per z unit
    void validate() const;             ///< throws Error naming the option
};

struct Lod2Result {
    std::vector<Solid> solids;         ///< one per footprint part, map CRS, z in the vertical datum
    bool fallback = false;             ///< true: flat roof at `fallback_roof_z` (LOD1.2)
    std::string fallback_reason;       ///< why the planes were not used
    std::string roof_type;             ///< flat, shed, gable, hip, complex
    int roof_planes = 0;               ///< planes used in the roof
    double roof_slope_deg = 0.0;       ///< of the main (largest) roof plane
    double roof_azimuth_deg = 0.0;     ///< downhill direction of the main plane, clockwise from north
    /// RMS of the 3-D distances of the building's points to the model (roof,
    /// wall and ground faces), metres; like 3DBAG's b3_rmse_lod22.
    double rmse_m = 0.0;
    double median_residual_m = 0.0;    ///< median vertical distance (robust to chimneys, trees and wall points), metres
    /// Which plane settings made the model: "default", or the alternative that
    /// replaced it ("normal_tolerance_20deg", "min_support_6", "long_partition_lines").
    std::string attempt = "default";
};

/// `roof_points` are the building's roof points (x, y in the footprint's CRS,
/// z in the vertical datum), `ground_z` its ground height and
/// `fallback_roof_z` the flat roof used when planes cannot be (e.g. the 70th
/// percentile of the roof points). Never throws for bad data: it falls back.
Lod2Result reconstruct_lod2(const std::vector<Polygon>& footprint, const std::vector<std::array<double, 3>>& roof_points, double ground_z,
                            double fallback_roof_z, const Lod2Options& options = {});

}  // namespace cityforge
