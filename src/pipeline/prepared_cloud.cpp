#include "pipeline/prepared_cloud.hpp"

#include "cloud/cloud_reader.hpp"
#include "core/error.hpp"
#include "core/log.hpp"

namespace cityforge {

PreparedCloud prepare_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                            const OutlierFilterOptions& outliers, const GroundFilterOptions& ground) {
    outliers.validate();
    ground.validate();
    PreparedCloud p;
    std::string file_wkt;
    p.cloud = read_point_cloud(cloud_path, &file_wkt);
    if (!cloud_crs_override.empty()) p.source_crs = crs_from_user_input(cloud_crs_override, "--cloud-crs");
    else if (!file_wkt.empty()) p.source_crs = crs_from_wkt(file_wkt, cloud_path);
    else throw Error(cloud_path, "point cloud has no CRS; give it with --cloud-crs (e.g. EPSG:7415)");
    if (p.source_crs.geographic) throw Error(cloud_path, "point cloud is in a geographic CRS; a projected CRS is needed");
    p.crs = p.source_crs;
    if (!target.empty() && !same_horizontal_crs(p.source_crs, target)) {
        log::info("reprojecting " + cloud_path + " from " + p.source_crs.label() + " to " + target.label());
        p.crs = combine_with_vertical(target, p.source_crs);
        transform_points(p.source_crs, p.crs, p.cloud.x, p.cloud.y, p.cloud.z, cloud_path);
        p.reprojected = true;
    } else if (!target.empty()) {
        p.crs = combine_with_vertical(target, p.source_crs);
    }
    const double unit = p.crs.linear_unit_m;
    OutlierFilterOptions oo = outliers;
    oo.isolated_radius /= unit;
    const OutlierFilterResult cleaned = filter_outliers(p.cloud, oo);
    p.keep = cleaned.keep;
    p.removed_statistical = cleaned.removed_statistical;
    p.removed_isolated = cleaned.removed_isolated;
    GroundFilterOptions go = ground;
    go.cell /= unit, go.window /= unit, go.elevation_threshold /= p.source_crs.z_unit_m;
    GroundResult g = classify_ground(p.cloud, p.keep, go);
    p.is_ground = std::move(g.is_ground);
    p.ground_points = g.ground_points;
    p.ground_from_classification = g.from_classification;
    return p;
}

}  // namespace cityforge
