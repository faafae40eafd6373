#pragma once
// Shared first steps of every cloud-based command: read the cloud, resolve
// its CRS (override > file), bring it into the target CRS, remove outliers
// and find the ground. Lengths in the options are metres.
#include <string>
#include <vector>

#include "cloud/cloud_filters.hpp"
#include "cloud/point_cloud.hpp"
#include "core/geo_transform.hpp"
#include "crs/crs.hpp"

namespace cityforge {

struct PreparedCloud {
    PointCloud cloud;             ///< in `crs` (the target's horizontal CRS + the cloud's vertical)
    CrsInfo crs;
    CrsInfo source_crs;           ///< the cloud's own CRS
    std::vector<uint8_t> keep;    ///< 0 = outlier
    std::vector<uint8_t> is_ground;
    bool reprojected = false;
    std::size_t removed_statistical = 0, removed_isolated = 0, ground_points = 0;
    bool ground_from_classification = false;
    double outlier_limit_m = 0.0;  ///< mean kNN distance limit the outlier filter used, metres
};

/// `target` may be empty (keep the cloud's CRS). Throws Error naming the file
/// for a missing/empty cloud, a cloud without CRS and no override, or CRSs
/// PROJ cannot relate.
/// With `crop` (target CRS units), only points inside it are kept: read
/// streaming when the cloud is already in the target CRS, else cropped after
/// reprojection. An empty crop result is not an error (a tile without points).
PreparedCloud prepare_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                            const OutlierFilterOptions& outliers, const GroundFilterOptions& ground, const Extent* crop = nullptr);

/// What the 400 m square of the cloud centred on `centre` (target CRS)
/// tells about the whole cloud, so that windows of one cloud all work alike:
/// the outlier filter's mean-kNN-distance limit (metres) and the density of
/// the kept points (per m², over their bounding box). Both 0 when the square
/// holds no point.
struct CloudSample {
    double outlier_limit_m = 0.0;
    double points_per_m2 = 0.0;
};
CloudSample sample_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                         const OutlierFilterOptions& outliers, const MapPoint& centre);

/// Bounding box of the kept points (in pc.crs); empty_extent() when none.
Extent kept_extent(const PreparedCloud& pc);

/// "min_x, min_y - max_x, max_y CRS" with a precision fit for the unit.
std::string describe_extent(const Extent& e, const CrsInfo& crs);

/// Throws Error naming both files and their extents in the cloud's
/// (prepared, common) CRS when no kept point of `pc` falls inside `extent`:
/// an input that cannot produce a result is an error, not an empty output.
void require_cloud_overlap(const PreparedCloud& pc, const std::string& cloud_path, const Extent& extent,
                           const std::string& other_path);

/// How many of `extents` (footprint bounding boxes, in pc.crs) hold no kept
/// point's bounding box at all. When none overlaps, throws Error naming both
/// files and their extents in pc.crs; when only some do, logs a warning with
/// the count. Returns the count outside.
std::size_t check_footprint_overlap(const PreparedCloud& pc, const std::string& cloud_path, const std::vector<Extent>& extents,
                                    const std::string& footprints_path);

/// Kept points per m² over their bounding box (0 for fewer than 2 points).
double point_density_m2(const PreparedCloud& pc);

}  // namespace cityforge
