#include "roof/roof_planes_cgal.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Random.h>
#include <CGAL/Shape_detection/Efficient_RANSAC.h>
#include <CGAL/Shape_detection/Region_growing/Region_growing.h>
#include <CGAL/Shape_detection/Region_growing/Region_growing_on_point_set.h>
#include <CGAL/property_map.h>
#include <algorithm>
#include <cmath>
#include <iterator>
#include <utility>

namespace cityforge {

namespace {
using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using PointWithNormal = std::pair<Kernel::Point_3, Kernel::Vector_3>;
using Range = std::vector<PointWithNormal>;
using PointMap = CGAL::First_of_pair_property_map<PointWithNormal>;
using NormalMap = CGAL::Second_of_pair_property_map<PointWithNormal>;
namespace SD = CGAL::Shape_detection;
}  // namespace

std::vector<std::vector<uint32_t>> cgal_plane_segments(const std::vector<std::array<double, 3>>& p, const std::vector<Eigen::Vector3d>& normals,
                                                       const RoofPlaneOptions& o, bool ransac) {
    Range range;
    range.reserve(p.size());
    for (std::size_t i = 0; i < p.size(); ++i)
        range.emplace_back(Kernel::Point_3(p[i][0], p[i][1], p[i][2]), Kernel::Vector_3(normals[i].x(), normals[i].y(), normals[i].z()));
    std::vector<std::vector<uint32_t>> out;
    if (range.empty()) return out;
    if (!ransac) {
        using NeighborQuery = SD::Point_set::K_neighbor_query<Kernel, Range, PointMap>;
        using RegionType = SD::Point_set::Least_squares_plane_fit_region<Kernel, Range, PointMap, NormalMap>;
        using Sorting = SD::Point_set::Least_squares_plane_fit_sorting<Kernel, Range, NeighborQuery, PointMap>;
        using RegionGrowing = SD::Region_growing<Range, NeighborQuery, RegionType, typename Sorting::Seed_map>;
        NeighborQuery query(range, static_cast<std::size_t>(o.k_neighbours), PointMap());
        RegionType region(range, o.distance_tolerance_m, o.normal_tolerance_deg, static_cast<std::size_t>(o.min_points), PointMap(), NormalMap());
        Sorting sorting(range, query, PointMap());
        sorting.sort();
        RegionGrowing growing(range, query, region, sorting.seed_map());
        std::vector<std::vector<std::size_t>> regions;
        growing.detect(std::back_inserter(regions));
        for (const auto& r : regions) out.emplace_back(r.begin(), r.end());
    } else {
        using Traits = SD::Efficient_RANSAC_traits<Kernel, Range, PointMap, NormalMap>;
        using Ransac = SD::Efficient_RANSAC<Traits>;
        // CGAL draws its samples from the default random generator (per
        // thread): seeded here, the same points give the same planes.
        CGAL::get_default_random() = CGAL::Random(17);
        Ransac r;
        r.set_input(range);
        r.add_shape_factory<SD::Plane<Traits>>();
        Ransac::Parameters par;
        par.probability = 0.01;
        par.min_points = static_cast<std::size_t>(o.min_points);
        par.epsilon = o.distance_tolerance_m;
        par.cluster_epsilon = 1.0;  // metres: points of one plane closer than this are connected (AHN3 spacing ~0.3 m)
        par.normal_threshold = std::cos(o.normal_tolerance_deg * 3.14159265358979323846 / 180.0);
        r.detect(par);
        for (const auto& shape : r.shapes()) {
            const auto& idx = shape->indices_of_assigned_points();
            out.emplace_back(idx.begin(), idx.end());
        }
    }
    for (auto& s : out) std::sort(s.begin(), s.end());
    return out;
}

}  // namespace cityforge
