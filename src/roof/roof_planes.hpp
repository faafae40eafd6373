#pragma once
// Planar roof segments in a building's roof points: normals from k nearest
// neighbours (PCA), region growing from the flattest seeds, merging of
// near-coplanar segments, and plane fits by least squares. Coordinates are
// local metres (x, y east/north, z up) so that tolerances are in metres.
// Deterministic: seeds in (curvature, index) order. No GDAL.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace cityforge {

/// Which segmentation finds the planar segments (normals, the least-squares
/// fits and the merging are shared): ours (region growing with a refitted
/// plane, seeds by curvature), CGAL 5.5 Shape_detection region growing on the
/// point set, or CGAL efficient RANSAC. Compared in bench/bench_planes.
enum class PlaneDetector { region_growing, cgal_region_growing, cgal_ransac };
std::string to_string(PlaneDetector d);
PlaneDetector plane_detector_from_string(const std::string& s, const std::string& option);  ///< throws Error naming the option

struct RoofPlaneOptions {
    double distance_tolerance_m = 0.2;  ///< max point-to-plane distance when growing and merging
    double normal_tolerance_deg = 12.0; ///< max angle between a point's normal and the segment's
    int min_points = 12;                ///< planes with less support are discarded
    int k_neighbours = 10;              ///< neighbourhood of the normal estimation and the growing
    double merge_angle_deg = 6.0;       ///< adjacent segments closer in orientation ...
    double merge_distance_m = 0.15;     ///< ... and offset (mean distance) are merged
    double max_slope_deg = 70.0;        ///< steeper segments are walls or noise, not roofs
    PlaneDetector detector = PlaneDetector::region_growing;  ///< see PlaneDetector (ours: better on Delft and synthetic roofs)
    void validate() const;              ///< throws Error naming the option
};

/// z = a x + b y + c over the building's local frame.
struct RoofPlane {
    double a = 0.0, b = 0.0, c = 0.0;
    std::vector<uint32_t> points;  ///< indices into the input, ascending
    double rmse_m = 0.0;           ///< vertical RMS distance of its points
    double slope_deg = 0.0;        ///< 0 = flat
    double azimuth_deg = 0.0;      ///< direction the plane faces (downhill), clockwise from north; 0 when flat
    double z(double x, double y) const { return a * x + b * y + c; }
};

/// Planes ordered by decreasing support (ties by lowest point index).
std::vector<RoofPlane> detect_roof_planes(const std::vector<std::array<double, 3>>& points, const RoofPlaneOptions& options = {});

/// Least-squares plane z = a x + b y + c through the given points (with
/// slope, azimuth and rmse); at least 3 non-collinear points.
RoofPlane fit_roof_plane(const std::vector<std::array<double, 3>>& points, std::vector<uint32_t> indices);

}  // namespace cityforge
