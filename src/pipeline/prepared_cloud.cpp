#include "pipeline/prepared_cloud.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <utility>

#include "core/geometry.hpp"

#include "cloud/cloud_reader.hpp"
#include "cloud/surface_support.hpp"
#include "core/error.hpp"
#include "core/grid_size.hpp"
#include "core/log.hpp"
#include "core/memory.hpp"
#include "io/cloud_crs.hpp"

namespace cityforge {

namespace {
// Canonical point order, outliers, ground: the steps after reading.
void clean_prepared(PreparedCloud& p, const OutlierFilterOptions& outliers, const GroundFilterOptions& ground) {
    canonical_order(p.cloud);
    const double unit = p.crs.linear_unit_m;
    OutlierFilterOptions oo = outliers;
    oo.isolated_radius /= unit;
    oo.max_mean_distance /= unit;
    OutlierFilterResult cleaned = filter_outliers(p.cloud, oo);
    if (outliers.enabled) {
        // Sparse surfaces (dark roofs, low densities) back in: see surface_support.hpp.
        SurfaceSupportOptions so;
        so.min_support = std::max(so.min_support, oo.isolated_min_neighbours + 1);  // a restored point is never an isolated one
        if (oo.isolated_radius > 0) so.radius = oo.isolated_radius;
        else so.radius /= unit;
        so.z_tolerance /= p.source_crs.z_unit_m;
        so.max_slope *= unit / p.source_crs.z_unit_m;  // z units per horizontal unit
        const std::size_t restored = restore_surface_points(p.cloud, cleaned.keep, so);
        cleaned.removed_statistical -= restored;
        p.restored_surface = restored;
    }
    p.keep = std::move(cleaned.keep);  // not copied: a byte a point of fresh memory
    p.removed_statistical = cleaned.removed_statistical;
    p.removed_isolated = cleaned.removed_isolated;
    p.outlier_limit_m = cleaned.limit * unit;
    GroundFilterOptions go = ground;
    go.cell /= unit, go.window /= unit, go.elevation_threshold /= p.source_crs.z_unit_m;
    GroundResult g = classify_ground(p.cloud, p.keep, go);
    p.is_ground = std::move(g.is_ground);
    p.ground_points = g.ground_points;
    p.ground_from_classification = g.from_classification;
    // The extent of what is kept must suit a grid of 2 m cells (the heights
    // index; a class-2 ground skips the SMRF grid): far, scattered points are
    // refused here, where the file is known, not deep in a later stage.
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < p.cloud.size(); ++i)
        if (p.keep.empty() || p.keep[i])
            ++kept, minx = std::min(minx, p.cloud.x[i]), maxx = std::max(maxx, p.cloud.x[i]), miny = std::min(miny, p.cloud.y[i]),
                    maxy = std::max(maxy, p.cloud.y[i]);
    if (kept > 0) checked_grid_size(minx, miny, maxx, maxy, 2.0 / unit, 8.0, "cloud extent");  // the heights index: 2 x uint32 a cell
}
// The same, with a failure (a grid too large for scattered points) naming the file.
void clean_prepared(PreparedCloud& p, const OutlierFilterOptions& outliers, const GroundFilterOptions& ground, const std::string& name) {
    if (!(p.crs.linear_unit_m > 0))
        throw Error(name, "the cloud's working CRS (" + p.crs.label() + ") is not projected: the outlier and ground filters need metres");
    try {
        clean_prepared(p, outliers, ground);
    } catch (const OutOfMemory& e) {  // still exit 3
        throw OutOfMemory(name, e);
    } catch (const Error& e) {
        throw Error(name, e.what());
    }
}
}  // namespace

PreparedCloud prepare_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                            const OutlierFilterOptions& outliers, const GroundFilterOptions& ground, const Extent* crop) {
    outliers.validate();
    ground.validate();
    PreparedCloud p;
    // The CRS first (from the header), so that a crop can be applied while reading.
    p.source_crs = require_cloud_crs(cloud_path, cloud_crs_override);
    const bool same = target.empty() || same_horizontal_crs(p.source_crs, target);
    if (crop && same) p.cloud = read_point_cloud_in(cloud_path, crop->min_x, crop->min_y, crop->max_x, crop->max_y);
    else p.cloud = read_point_cloud(cloud_path);
    p.crs = p.source_crs;
    if (!target.empty() && !same_horizontal_crs(p.source_crs, target)) {
        log::info("reprojecting " + cloud_path + " from " + p.source_crs.label() + " to " + target.label());
        p.crs = combine_with_vertical(target, p.source_crs);
        transform_points(p.source_crs, p.crs, p.cloud.x, p.cloud.y, p.cloud.z, cloud_path);
        p.reprojected = true;
    } else if (!target.empty()) {
        p.crs = combine_with_vertical(target, p.source_crs);
    }
    if (crop && !same) {
        PointCloud kept;
        for (std::size_t i = 0; i < p.cloud.size(); ++i)
            if (p.cloud.x[i] >= crop->min_x && p.cloud.x[i] < crop->max_x && p.cloud.y[i] >= crop->min_y && p.cloud.y[i] < crop->max_y)
                kept.append(p.cloud, i);
        p.cloud = std::move(kept);
    }
    if (p.cloud.size() == 0) {
        if (!crop) throw Error(cloud_path, "point cloud is empty");
        return p;  // a tile without points: nothing to clean or classify
    }
    clean_prepared(p, outliers, ground, cloud_path);
    return p;
}

PreparedCloud prepare_cloud(const std::vector<CloudPart>& parts, const std::string& cloud_crs_override, const CrsInfo& target,
                            const OutlierFilterOptions& outliers, const GroundFilterOptions& ground) {
    outliers.validate();
    ground.validate();
    if (parts.empty()) throw Error("cloud", "no parts to read");
    PreparedCloud p;
    const std::string& first = parts.front().path;
    p.source_crs = require_cloud_crs(first, cloud_crs_override);
    if (!target.empty() && !same_horizontal_crs(p.source_crs, target)) throw Error(first, "cloud parts must be in the target CRS");
    p.crs = target.empty() ? p.source_crs : combine_with_vertical(target, p.source_crs);
    // Each part's points in its crop (half-open), read straight into the one cloud.
    for (const CloudPart& part : parts)
        append_point_cloud_in(part.path, part.crop.min_x, part.crop.min_y, part.crop.max_x, part.crop.max_y, p.cloud);
    if (p.cloud.size() == 0) return p;
    clean_prepared(p, outliers, ground, parts.size() == 1 ? first : first + " (and " + std::to_string(parts.size() - 1) + " more parts)");
    return p;
}

CloudSample sample_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                         const OutlierFilterOptions& outliers, const MapPoint& centre, PreparedCloud* points) {
    const double half = 200.0 / (target.empty() ? 1.0 : target.linear_unit_m);
    const Extent box{centre.x - half, centre.y - half, centre.x + half, centre.y + half};
    GroundFilterOptions trust;  // the sample needs no ground: take class 2 as it is, never run SMRF here
    trust.trust_classification = true;
    PreparedCloud sample = prepare_cloud(cloud_path, cloud_crs_override, target, outliers, trust, &box);
    if (!sample.cloud.size()) return {};
    const CloudSample out{sample.outlier_limit_m, point_density_m2(sample)};
    if (points) *points = sample;
    return out;
}

Extent kept_extent(const PreparedCloud& pc) {
    Extent e = empty_extent();
    for (std::size_t i = 0; i < pc.cloud.size(); ++i)
        if (pc.keep.empty() || pc.keep[i]) {
            e.min_x = std::min(e.min_x, pc.cloud.x[i]), e.max_x = std::max(e.max_x, pc.cloud.x[i]);
            e.min_y = std::min(e.min_y, pc.cloud.y[i]), e.max_y = std::max(e.max_y, pc.cloud.y[i]);
        }
    return e;
}

std::string describe_extent(const Extent& e, const CrsInfo& crs) {
    char buf[200];
    const int digits = crs.geographic ? 6 : 1;
    std::snprintf(buf, sizeof buf, "%.*f, %.*f - %.*f, %.*f", digits, e.min_x, digits, e.min_y, digits, e.max_x, digits, e.max_y);
    // The horizontal CRS only: extents say nothing of heights.
    return std::string(buf) + " " + (crs.horizontal_epsg ? "EPSG:" + std::to_string(*crs.horizontal_epsg) : crs.label());
}

void require_cloud_overlap(const PreparedCloud& pc, const std::string& cloud_path, const Extent& extent, const std::string& other_path) {
    for (std::size_t i = 0; i < pc.cloud.size(); ++i)
        if ((pc.keep.empty() || pc.keep[i]) && pc.cloud.x[i] >= extent.min_x && pc.cloud.x[i] <= extent.max_x &&
            pc.cloud.y[i] >= extent.min_y && pc.cloud.y[i] <= extent.max_y)
            return;
    throw Error(cloud_path, "does not overlap " + other_path + ": cloud " + describe_extent(kept_extent(pc), pc.crs) + ", " +
                                std::filesystem::path(other_path).filename().string() + " " + describe_extent(extent, pc.crs));
}

std::size_t check_footprint_overlap(const PreparedCloud& pc, const std::string& cloud_path, const std::vector<Extent>& extents,
                                    const std::string& footprints_path) {
    if (extents.empty()) return 0;
    Extent c = kept_extent(pc);
    const auto overlaps = [&](const Extent& e) { return !(e.max_x < c.min_x || e.min_x > c.max_x || e.max_y < c.min_y || e.min_y > c.max_y); };
    if (c.min_x > c.max_x && pc.cloud.size() > 0) {
        // Nothing kept, but the file has points: if they lie over the footprints, the cleaning removed them all.
        for (std::size_t i = 0; i < pc.cloud.size(); ++i) {
            c.min_x = std::min(c.min_x, pc.cloud.x[i]), c.max_x = std::max(c.max_x, pc.cloud.x[i]);
            c.min_y = std::min(c.min_y, pc.cloud.y[i]), c.max_y = std::max(c.max_y, pc.cloud.y[i]);
        }
        if (std::any_of(extents.begin(), extents.end(), overlaps)) {
            const double unit = pc.crs.empty() ? 1.0 : pc.crs.linear_unit_m;
            const double area_m2 = (c.max_x - c.min_x) * (c.max_y - c.min_y) * unit * unit;
            char density[64] = "";
            if (area_m2 > 0) std::snprintf(density, sizeof density, ", %.3g points per m\u00b2", double(pc.cloud.size()) / area_m2);
            throw Error(cloud_path, "all " + std::to_string(pc.cloud.size()) + " points were removed as outliers (" +
                                        std::to_string(pc.removed_statistical) + " statistical or noise class, " +
                                        std::to_string(pc.removed_isolated) + " isolated" + density +
                                        "): the cloud is too sparse or noisy for the filter; --no-outlier-filter keeps them");
        }
    }
    return check_footprints_within(c, pc.crs, cloud_path, extents, footprints_path);
}

std::size_t check_footprints_within(const Extent& cloud, const CrsInfo& crs, const std::string& cloud_path, const std::vector<Extent>& extents,
                                    const std::string& footprints_path) {
    Extent all = empty_extent();
    std::size_t outside = 0;
    for (const Extent& e : extents) {
        include(all, e);
        outside += e.max_x < cloud.min_x || e.min_x > cloud.max_x || e.max_y < cloud.min_y || e.min_y > cloud.max_y;
    }
    if (!extents.empty() && outside == extents.size())
        throw Error(footprints_path, "no footprint overlaps the cloud " + cloud_path + ": footprints " + describe_extent(all, crs) +
                                         ", cloud " + (cloud.min_x <= cloud.max_x ? describe_extent(cloud, crs) : std::string("without points")));
    if (outside > 0)
        log::warning(footprints_path + ": " + std::to_string(outside) + " of " + std::to_string(extents.size()) +
                     " footprints lie outside the cloud " + cloud_path + " (they get no heights)");
    return outside;
}

double point_density_m2(const PreparedCloud& pc) {
    Extent e = empty_extent();
    std::size_t kept = 0;
    for (std::size_t i = 0; i < pc.cloud.size(); ++i)
        if (pc.keep.empty() || pc.keep[i]) {
            e.min_x = std::min(e.min_x, pc.cloud.x[i]), e.max_x = std::max(e.max_x, pc.cloud.x[i]);
            e.min_y = std::min(e.min_y, pc.cloud.y[i]), e.max_y = std::max(e.max_y, pc.cloud.y[i]);
            ++kept;
        }
    const double unit = pc.crs.empty() ? 1.0 : pc.crs.linear_unit_m;
    const double area_m2 = (e.max_x - e.min_x) * (e.max_y - e.min_y) * unit * unit;
    return kept >= 2 && area_m2 > 0 ? static_cast<double>(kept) / area_m2 : 0.0;
}

}  // namespace cityforge
