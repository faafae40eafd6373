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
    /// Points the statistical test removed that continue a sparse surface and
    /// were put back (restore_surface_points); not counted in removed_statistical.
    std::size_t restored_surface = 0;
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

/// One file of a cloud split in parts (e.g. the tile windows of a run) and
/// the extent (target CRS units, half-open: min <= x < max) taken from it.
struct CloudPart {
    std::string path;
    Extent crop;
};
/// The same on the union of parts of one cloud (in the target CRS): the
/// points of each part inside its crop. Crops that do not overlap give each
/// point once. The points come in canonical order (cloud::canonical_order),
/// as they do from every prepare_cloud: the result depends on the set of
/// points, not on the files they came from.
PreparedCloud prepare_cloud(const std::vector<CloudPart>& parts, const std::string& cloud_crs_override, const CrsInfo& target,
                            const OutlierFilterOptions& outliers, const GroundFilterOptions& ground);

/// What the 400 m square of the cloud centred on `centre` (target CRS)
/// tells about the whole cloud, so that windows of one cloud all work alike:
/// the outlier filter's mean-kNN-distance limit (metres) and the density of
/// the kept points (per m², over their bounding box). Both 0 when the square
/// holds no point.
struct CloudSample {
    double outlier_limit_m = 0.0;
    double points_per_m2 = 0.0;
};
/// `points`, when given, receives the sample's prepared cloud (ground from class 2).
CloudSample sample_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                         const OutlierFilterOptions& outliers, const MapPoint& centre, PreparedCloud* points = nullptr);

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

/// The extent part of check_footprint_overlap: footprint bounding boxes
/// `extents` against the cloud's bounding box `cloud` (both in `crs`). Throws
/// when none overlaps (both files and extents named), warns with the count
/// when some do not; returns the count outside.
std::size_t check_footprints_within(const Extent& cloud, const CrsInfo& crs, const std::string& cloud_path, const std::vector<Extent>& extents,
                                    const std::string& footprints_path);

/// Kept points per m² over their bounding box (0 for fewer than 2 points).
double point_density_m2(const PreparedCloud& pc);

}  // namespace cityforge
