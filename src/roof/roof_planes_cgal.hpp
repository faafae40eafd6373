#pragma once
// Roof plane segments by CGAL 5.5's Shape_detection, for comparison with our
// own region growing (bench/bench_planes): region growing on the point set
// (K_neighbor_query + Least_squares_plane_fit_region, seeds sorted by
// Least_squares_plane_fit_sorting) or efficient RANSAC (Schnabel et al.,
// planes only, seeded for determinism). Local metres, as detect_roof_planes.
#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "roof/roof_planes.hpp"

namespace cityforge {

/// Point index sets of planar segments found by CGAL in `points` with their
/// unit `normals` (z up), under the tolerances of `options`
/// (distance_tolerance_m, normal_tolerance_deg, min_points, k_neighbours).
/// `ransac` selects Efficient_RANSAC instead of region growing.
std::vector<std::vector<uint32_t>> cgal_plane_segments(const std::vector<std::array<double, 3>>& points,
                                                       const std::vector<Eigen::Vector3d>& normals, const RoofPlaneOptions& options,
                                                       bool ransac);

}  // namespace cityforge
