#include "pipeline/cloud_windows.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "cloud/cloud_reader.hpp"
#include "core/error.hpp"
#include "core/geometry.hpp"
#include "core/log.hpp"
#include "io/cloud_crs.hpp"

namespace cityforge {

CloudPlan plan_cloud(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                     const OutlierFilterOptions& outliers, const MapPoint& centre) {
    CloudPlan plan;
    plan.outliers = outliers;
    const CloudSample s = sample_cloud(cloud_path, cloud_crs_override, target, outliers, centre);
    if (outliers.enabled && !(outliers.max_mean_distance > 0)) {
        plan.outliers.max_mean_distance = s.outlier_limit_m;
        if (!(s.outlier_limit_m > 0))
            log::warning(cloud_path + ": no point in the 400 m around the work area's centre; each cloud window measures its own outlier limit");
    }
    plan.density_m2 = s.points_per_m2;
    return plan;
}

double window_tile_edge_m(double tile_m, double overlap_m, double density_m2, uint64_t max_points) {
    double edge = tile_m;
    if (density_m2 > 0 && max_points > 0) edge = std::min(edge, std::sqrt(double(max_points) / density_m2) - 2 * overlap_m);
    return std::max(edge, 50.0);
}

WindowedRasters rasterize_cloud_by_windows(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                                           const GridSpec& grid, double unit_m, const OutlierFilterOptions& outliers,
                                           const GroundFilterOptions& ground, int tile_px, int overlap_px, const Progress& progress) {
    if (tile_px < 1 || overlap_px < 0) throw Error("cloud windows", "tiles must have at least one cell and the overlap >= 0");
    WindowedRasters out;
    CloudRasters& r = out.rasters;
    const int W = grid.width, H = grid.height;
    for (Image<float>* img : {&r.dsm, &r.dtm, &r.ndsm, &r.building_share, &r.vegetation_share}) *img = Image<float>(W, H, 1, NAN);
    r.density = Image<float>(W, H, 1, 0.0f);
    const GeoTransform& gt = grid.transform;
    const int tiles_x = (W + tile_px - 1) / tile_px, tiles_y = (H + tile_px - 1) / tile_px;
    const std::size_t total = static_cast<std::size_t>(tiles_x) * tiles_y;
    bool first = true;
    for (int r0 = 0; r0 < H; r0 += tile_px)
        for (int c0 = 0; c0 < W; c0 += tile_px) {
            const int cw = std::min(tile_px, W - c0), ch = std::min(tile_px, H - r0);
            const int wc = std::max(0, c0 - overlap_px), wr = std::max(0, r0 - overlap_px);
            const int ww = std::min(W, c0 + cw + overlap_px) - wc, wh = std::min(H, r0 + ch + overlap_px) - wr;
            // The points read reach the overlap beyond the grid's edge too (the
            // whole cloud's neighbours there count), and one cell more: a
            // point on a cell's closed edge is read whichever way the axis runs.
            const MapPoint a = gt.pixel_to_map({double(c0 - overlap_px - 1), double(r0 - overlap_px - 1)}),
                           b = gt.pixel_to_map({double(c0 + cw + overlap_px + 1), double(r0 + ch + overlap_px + 1)});
            const Extent window{std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
            const PreparedCloud pc = prepare_cloud(cloud_path, cloud_crs_override, target, outliers, ground, &window);
            ++out.windows;
            if (first) out.crs = pc.crs, out.source_crs = pc.source_crs, first = false;
            out.points += pc.cloud.size(), out.ground_points += pc.ground_points;
            out.ground_from_classification = out.ground_from_classification || pc.ground_from_classification;
            out.reprojected = out.reprojected || pc.reprojected;
            if (pc.cloud.size() > 0) {
                const CloudRasters t = rasterize_cloud(pc.cloud, pc.keep, pc.is_ground, grid, wc, wr, ww, wh, unit_m);
                for (const auto& [dst, src] : {std::pair<Image<float>*, const Image<float>*>{&r.dsm, &t.dsm}, {&r.dtm, &t.dtm}, {&r.ndsm, &t.ndsm},
                                              {&r.density, &t.density}, {&r.building_share, &t.building_share},
                                              {&r.vegetation_share, &t.vegetation_share}})
                    for (int y = 0; y < ch; ++y)
                        std::copy_n(&src->at(0, c0 - wc, r0 - wr + y), cw, &dst->at(0, c0, r0 + y));
                // Kept points on the core's cells (each point of the grid counted once).
                for (std::size_t i = 0; i < pc.cloud.size(); ++i) {
                    if (!pc.keep.empty() && !pc.keep[i]) continue;
                    const PixelPoint p = gt.map_to_pixel({pc.cloud.x[i], pc.cloud.y[i]});
                    const double col = std::floor(p.col), row = std::floor(p.row);
                    out.core_points += col >= c0 && col < c0 + cw && row >= r0 && row < r0 + ch;
                }
            }
            progress(double(out.windows) / double(total), "cloud windows");
        }
    return out;
}

bool read_cloud_by_windows(const CloudReader& reader, uint64_t max_points, double cell) {
    if (max_points == 0) return false;
    if (reader.announced_points() > max_points) return true;
    const auto& b = reader.announced_bounds();
    if (!b || !(cell > 0)) return false;
    for (double v : *b)
        if (!std::isfinite(v)) return false;
    if (!((*b)[0] <= (*b)[2] && (*b)[1] <= (*b)[3])) return false;  // an empty or inverted header box says nothing
    const double cells = std::floor(((*b)[2] - (*b)[0]) / cell + 1.0) * std::floor(((*b)[3] - (*b)[1]) / cell + 1.0);
    // Large and sparse: more cells than the budget and than 4 per point (a
    // fully covered LAS of under 1 point per cell stays whole).
    if (!(cells > static_cast<double>(max_points)) || !(cells > 4.0 * static_cast<double>(reader.announced_points()))) return false;
    char text[200];
    std::snprintf(text, sizeof text, "its bounding box (%.0f x %.0f CRS units) would need a grid of %.3g cells of %g: read window by window",
                  (*b)[2] - (*b)[0], (*b)[3] - (*b)[1], cells, cell);
    log::info(reader.path() + ": " + text);
    return true;
}

namespace {
// One streamed pass over the cloud's points moved to `target` (as they are
// in the file when `target` is empty or has the file's horizontal CRS; an
// empty `target` reads no CRS record). Reports the share of the header's
// point count read (nothing when the file announces none, e.g. XYZ) with
// "<what>: N of M points".
template <class Visit>
void for_each_point_on(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target, Visit&& visit,
                       const Progress& progress, const char* what) {
    const CrsInfo from = target.empty() ? CrsInfo{} : resolve_cloud_crs(cloud_path, cloud_crs_override).crs;
    const bool move = !target.empty() && !from.empty() && !same_horizontal_crs(from, target);
    CloudReader reader(cloud_path);
    const uint64_t announced = reader.announced_points();
    uint64_t read = 0;
    PointCloud chunk;
    std::vector<double> z;
    while (true) {
        chunk.clear();
        if (reader.read_chunk(chunk, 1u << 20) == 0) break;
        if (move) {
            z.assign(chunk.size(), 0.0);
            transform_points(from, target, chunk.x, chunk.y, z, cloud_path);
        }
        for (std::size_t i = 0; i < chunk.size(); ++i) visit(chunk.x[i], chunk.y[i]);
        read += chunk.size();
        if (progress.active() && announced > 0)
            progress(std::min(1.0, static_cast<double>(read) / static_cast<double>(announced)),
                     std::string(what) + ": " + std::to_string(read) + " of " + std::to_string(announced) + " points");
    }
}
}  // namespace

DensestSquare densest_square(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                             const Extent& within, double cell, const Progress& progress) {
    DensestSquare best{{0.5 * (within.min_x + within.max_x), 0.5 * (within.min_y + within.max_y)}, 0};
    if (!(cell > 0) || !(within.min_x <= within.max_x && within.min_y <= within.max_y)) return best;
    // At most 4 M squares: larger areas get larger squares.
    auto count = [&](double c) { return (std::floor(within.width() / c) + 1) * (std::floor(within.height() / c) + 1); };
    while (count(cell) > 4e6) cell *= 2;
    const auto nx = static_cast<std::size_t>(std::floor(within.width() / cell)) + 1, ny = static_cast<std::size_t>(std::floor(within.height() / cell)) + 1;
    std::vector<uint64_t> counts(nx * ny, 0);
    for_each_point_on(cloud_path, cloud_crs_override, target, [&](double x, double y) {
        if (!(x >= within.min_x && x <= within.max_x && y >= within.min_y && y <= within.max_y)) return;
        const auto c = std::min(nx - 1, static_cast<std::size_t>((x - within.min_x) / cell));
        const auto r = std::min(ny - 1, static_cast<std::size_t>((y - within.min_y) / cell));
        ++counts[r * nx + c];
    }, progress, "densest 400 m square");
    std::size_t at = 0;
    for (std::size_t k = 1; k < counts.size(); ++k)
        if (counts[k] > counts[at]) at = k;
    if (counts[at] == 0) return best;
    best.points = counts[at];
    // The square's centre, kept inside `within` (a last square may be cut).
    const double x0 = within.min_x + static_cast<double>(at % nx) * cell, y0 = within.min_y + static_cast<double>(at / nx) * cell;
    best.centre = {0.5 * (x0 + std::min(within.max_x, x0 + cell)), 0.5 * (y0 + std::min(within.max_y, y0 + cell))};
    return best;
}

std::vector<uint64_t> count_points_in_blocks(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target,
                                             const GridSpec& grid, int block_px, const Progress& progress) {
    if (block_px < 1 || grid.width < 1 || grid.height < 1) throw Error("count_points_in_blocks", "needs a grid and blocks of at least one pixel");
    const auto bx = static_cast<std::size_t>((grid.width + block_px - 1) / block_px), by = static_cast<std::size_t>((grid.height + block_px - 1) / block_px);
    std::vector<uint64_t> counts(bx * by, 0);
    for_each_point_on(cloud_path, cloud_crs_override, target, [&](double x, double y) {
        const PixelPoint p = grid.transform.map_to_pixel({x, y});
        const double c = std::floor(p.col), r = std::floor(p.row);
        if (!(c >= 0 && r >= 0 && c < grid.width && r < grid.height)) return;  // also NaN
        ++counts[static_cast<std::size_t>(r) / static_cast<std::size_t>(block_px) * bx + static_cast<std::size_t>(c) / static_cast<std::size_t>(block_px)];
    }, progress, "points per tile");
    return counts;
}


Extent cloud_point_bounds(const std::string& cloud_path, const Progress& progress) {
    Extent e = empty_extent();
    uint64_t n = 0;
    for_each_point_on(cloud_path, {}, {}, [&](double x, double y) {
        e.min_x = std::min(e.min_x, x), e.max_x = std::max(e.max_x, x);
        e.min_y = std::min(e.min_y, y), e.max_y = std::max(e.max_y, y);
        ++n;
    }, progress.sub(0.0, 0.6), "cloud bounds");
    if (!(e.min_x <= e.max_x)) throw Error(cloud_path, "point cloud is empty");
    // A box this empty (over 100 square units a point: 0.01 points per m2)
    // may be stretched by a few far points (a z of -1700 m is harmless here, a
    // point 10 km away makes a grid of 10 km). A second pass counts the points
    // on 512 squares along the longer side: points in squares that hold under a
    // tenth of a typical square's points and whose 8 neighbours are as empty
    // (so at least a square's width from any populated part) are left out of
    // the box, when they are at most 1 % of the points. Otherwise the box is
    // every point's, as before.
    if (n < 1000 || !(e.width() * e.height() > 100.0 * static_cast<double>(n))) return e;
    const double cell = std::max(e.width(), e.height()) / 512.0;
    const auto nx = static_cast<std::size_t>(std::floor(e.width() / cell)) + 1, ny = static_cast<std::size_t>(std::floor(e.height() / cell)) + 1;
    struct Square {
        uint32_t points = 0;
        Extent box = empty_extent();
    };
    std::vector<Square> sq(nx * ny);
    for_each_point_on(cloud_path, {}, {}, [&](double x, double y) {
        const auto c = std::min(nx - 1, static_cast<std::size_t>((x - e.min_x) / cell)), r = std::min(ny - 1, static_cast<std::size_t>((y - e.min_y) / cell));
        Square& s = sq[r * nx + c];
        if (s.points < UINT32_MAX) ++s.points;
        include(s.box, Extent{x, y, x, y});
    }, progress.sub(0.6, 0.8), "cloud bounds, far points");
    std::vector<uint32_t> counts;
    for (const Square& s : sq)
        if (s.points) counts.push_back(s.points);
    const auto mid = counts.begin() + static_cast<std::ptrdiff_t>(counts.size() / 2);
    std::nth_element(counts.begin(), mid, counts.end());
    const uint32_t populated = std::max<uint32_t>(1, *mid / 10);
    Extent kept = empty_extent();
    uint64_t dropped = 0;
    for (std::size_t r = 0; r < ny; ++r)
        for (std::size_t c = 0; c < nx; ++c) {
            const Square& s = sq[r * nx + c];
            if (!s.points) continue;
            bool isolated = s.points < populated;
            for (std::size_t rr = r ? r - 1 : 0; isolated && rr <= std::min(ny - 1, r + 1); ++rr)
                for (std::size_t cc = c ? c - 1 : 0; isolated && cc <= std::min(nx - 1, c + 1); ++cc)
                    isolated = sq[rr * nx + cc].points < populated;
            if (isolated) dropped += s.points;
            else include(kept, s.box);
        }
    if (dropped == 0 || dropped * 100 > n) return e;
    // What the smaller box leaves out (isolated squares inside it stay in).
    uint64_t outside = 0;
    for_each_point_on(
        cloud_path, {}, {}, [&](double x, double y) { outside += x < kept.min_x || x > kept.max_x || y < kept.min_y || y > kept.max_y; }, progress.sub(0.8, 1.0),
        "cloud bounds, points left out");
    if (outside == 0) return e;  // cannot be: every point is then in `kept`, which is `e`
    char text[400];
    std::snprintf(text, sizeof text,
                  "%llu of %llu points lie over %.0f CRS units from every populated part of the cloud: the grid covers the rest, "
                  "%.1f, %.1f - %.1f, %.1f instead of %.1f, %.1f - %.1f, %.1f",
                  static_cast<unsigned long long>(outside), static_cast<unsigned long long>(n), cell, kept.min_x, kept.min_y, kept.max_x,
                  kept.max_y, e.min_x, e.min_y, e.max_x, e.max_y);
    log::warning(cloud_path + ": " + text);
    return kept;
}

Extent cloud_bounds_in(const std::string& cloud_path, const std::string& cloud_crs_override, const CrsInfo& target, const Progress& progress) {
    const Extent e = cloud_point_bounds(cloud_path, progress);
    const CrsInfo from = resolve_cloud_crs(cloud_path, cloud_crs_override).crs;
    if (target.empty() || from.empty() || same_horizontal_crs(from, target)) return e;
    std::vector<double> x, y;
    for (int k = 0; k <= 8; ++k) {
        const double f = k / 8.0;
        x.insert(x.end(), {e.min_x + f * e.width(), e.min_x + f * e.width(), e.min_x, e.max_x});
        y.insert(y.end(), {e.min_y, e.max_y, e.min_y + f * e.height(), e.min_y + f * e.height()});
    }
    std::vector<double> z(x.size(), 0.0);
    transform_points(from, target, x, y, z, cloud_path);
    Extent out = empty_extent();
    for (std::size_t i = 0; i < x.size(); ++i) include(out, Extent{x[i], y[i], x[i], y[i]});
    return out;
}

}  // namespace cityforge
