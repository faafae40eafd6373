#pragma once
// Surface support for points an outlier filter removed. The statistical
// outlier test (filter_outliers) compares each point's mean distance to its k
// nearest neighbours with one limit for the whole cloud (mean + m sigma), set
// by the cloud's dominant density. A surface sampled more sparsely than the
// rest -- a dark roof returning a fifth of the pulses, a cloud of 2-4 pts/m2,
// the far edge of a flight strip -- exceeds that limit point by point and
// would vanish whole, although each of its points lies on a surface with its
// neighbours. Such points are put back here; a point floating above or below
// everything around it (birds, multipath, the 5-45 m spikes of our synthetic
// clouds) has no support and stays removed. Pure algorithm, CRS units.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cloud/point_cloud.hpp"

namespace cityforge {

struct SurfaceSupportOptions {
    double radius = 2.0;       ///< neighbourhood radius (3-D), CRS units: the isolated-point filter's radius
    int min_support = 3;       ///< supporting neighbours needed (more than the isolated filter's 2, so a restored point is never isolated)
    double z_tolerance = 0.3;  ///< vertical offset always accepted, CRS units (noise of the surface)
    double max_slope = 1.0;    ///< plus this many units of height per unit of horizontal distance (1 = 45 degrees)
    /// Throws Error naming the option on bad values.
    void validate() const;
};

/// Puts back (keep[i] = 1) every removed point (keep[i] == 0, not classified
/// noise 7/18) that has at least `min_support` other non-noise points, kept
/// or removed, within `radius` in 3-D and within `z_tolerance + max_slope *
/// horizontal distance` vertically: points continuing a surface, however
/// sparse. Depends only on the points within `radius` of each point (so a
/// window with that much overlap decides its core alike) and not on the
/// order or the thread count. Returns the number of points restored.
std::size_t restore_surface_points(const PointCloud& cloud, std::vector<uint8_t>& keep, const SurfaceSupportOptions& options);

}  // namespace cityforge
