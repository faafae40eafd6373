#pragma once
// 3-D k-d trees over point clouds (nanoflann). Points are stored as float
// xyz relative to a local origin: half the memory of doubles and faster
// queries, while float keeps about 0.1 mm over 10 km. Shared by the outlier
// filter and the cloud audit.
#include <nanoflann.hpp>
#include <vector>

#include "cloud/point_cloud.hpp"

namespace cityforge {

struct LocalPoints {
    std::vector<float> xyz;  ///< x0 y0 z0 x1 y1 z1 ..., relative to the origin
    std::size_t kdtree_get_point_count() const { return xyz.size() / 3; }
    float kdtree_get_pt(std::size_t i, std::size_t d) const { return xyz[3 * i + d]; }
    template <class BBox>
    bool kdtree_get_bbox(BBox&) const { return false; }
};

using PointTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, LocalPoints>, LocalPoints, 3>;

/// The cloud's points relative to (ox, oy, oz).
inline LocalPoints local_points(const PointCloud& c, double ox, double oy, double oz) {
    LocalPoints l;
    l.xyz.resize(3 * c.size());
    for (std::size_t i = 0; i < c.size(); ++i) {
        l.xyz[3 * i] = static_cast<float>(c.x[i] - ox);
        l.xyz[3 * i + 1] = static_cast<float>(c.y[i] - oy);
        l.xyz[3 * i + 2] = static_cast<float>(c.z[i] - oz);
    }
    return l;
}

}  // namespace cityforge
