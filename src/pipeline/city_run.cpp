#include "pipeline/city_run.hpp"
#include "pipeline/view_run.hpp"

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>
#include <tbb/global_control.h>
#include <system_error>
#include <thread>
#include <atomic>
#include <exception>
#include <mutex>

#include "cloud/cloud_reader.hpp"
#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "core/resource_usage.hpp"
#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "core/log.hpp"
#include "core/memory.hpp"
#include "core/parallel.hpp"
#include "core/version.hpp"
#include "crs/crs.hpp"
#include "footprint/building_mask.hpp"
#include "io/cloud_crs.hpp"
#include "io/vector.hpp"
#include "model/building_json.hpp"
#include "pipeline/cloud_cells.hpp"
#include "pipeline/cloud_windows.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

namespace cityforge {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

double since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// Refuses keys of `j` not in `allowed`, naming their path.
void check_keys(const json& j, const std::set<std::string>& allowed, const std::string& where) {
    if (!j.is_object()) throw Error(where, "must be a JSON object");
    for (const auto& [k, v] : j.items())
        if (!allowed.count(k)) throw Error(where, "unknown key '" + k + "'");
}

template <typename T>
void take(const json& j, const char* key, T& out, const std::string& where) {
    if (!j.contains(key)) return;
    try {
        out = j.at(key).get<T>();
    } catch (const json::exception&) {
        throw Error(where + "." + key, "has the wrong type");
    }
}

std::string tile_name(int k) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "tile_%05d", k);
    return buf;
}

// The context every decision about a building looks at around it (pixels):
// the ortho crop's margin, the heights' ground ring, the ground filter's
// window when it runs, and slack for the cell decisions. A building whose
// box grown by this stays inside a window (or reaches only the grid's edge)
// comes out of that window as out of any larger one.
int context_px(const RunOptions& o, double gsd_m) {
    // The DTM under and around a building is filled from ground up to kGapFillReach_m away;
    // without classes, that ground comes from SMRF's opening window over a minimum surface
    // filled the same way.
    double m = o.extraction.segmentation.margin_px * gsd_m + o.buildings.heights.heights.ground_buffer_m + 5.0 + kGapFillReach_m;
    if (!o.buildings.heights.ground.trust_classification) m += o.buildings.heights.ground.window + kGapFillReach_m;
    m = std::max(m, 20.0);
    return static_cast<int>(std::ceil(m / gsd_m)) + 2 * std::max(1, o.extraction.cloud_cell_factor);
}

}  // namespace

void RunOptions::validate() const {
    if (cloud.empty() && ortho.empty()) throw Error("--ortho", "give an ortho, a cloud, or both");
    if (cloud.empty() && !footprints.empty()) throw Error("--cloud", "heights for given footprints need a dense point cloud");
    if (ortho.empty() && footprints.empty() && extraction.mode == DetectionMode::ortho_cloud)
        throw Error("extraction.mode", "ortho_cloud needs an ortho: give --ortho, or choose auto or cloud_only");
    if (tile_size_px < 64) throw Error("--tile-size", "must be at least 64 pixels");
    if (!(overlap_m >= 0)) throw Error("--overlap-m", "must be >= 0");
    if (threads < 0) throw Error("--threads", "must be >= 0");
    if (concurrent_tiles < 0) throw Error("--concurrent-tiles", "must be >= 0");
    if (!(footprint_grid_m > 0)) throw Error("footprint_grid_m", "must be > 0");
    if (!(extraction.mask.gsd_m > 0)) throw Error("cloud_grid_m", "must be > 0");
    buildings.validate();
    if (footprints.empty()) extraction.mask.validate(), extraction.segmentation.validate();
    if (!cloud.empty() && extraction.mode == DetectionMode::ortho_only)
        throw Error("extraction.mode", "ortho_only would ignore the cloud: choose auto, ortho_cloud or cloud_only, or drop the cloud");
    if (cloud.empty() && (extraction.mode == DetectionMode::ortho_cloud || extraction.mode == DetectionMode::cloud_only))
        throw Error("extraction.mode", to_string(extraction.mode) + " needs a cloud");
}

json to_json(const RunOptions& o) {
    const auto& m = o.extraction.mask;
    const auto& h = o.buildings.heights.heights;
    const auto& l = o.buildings.lod2;
    const auto& e = o.buildings.model;
    return {{"ortho", o.ortho},
            {"cloud", o.cloud},
            {"cloud_crs", o.cloud_crs},
            {"footprints", o.footprints},
            {"working_crs", o.working_crs},
            {"out_crs", o.out_crs},
            {"tile_size_px", o.tile_size_px},
            {"overlap_m", o.overlap_m},
            {"threads", o.threads},
            {"concurrent_tiles", o.concurrent_tiles},
            {"keep_rasters", o.keep_rasters},
            {"extraction",
             {{"min_height_m", m.min_height_m},
              {"min_area_m2", m.min_area_m2},
              {"min_hole_m2", m.min_hole_m2},
              {"opening_px", m.opening_radius_px},
              {"hidden_completion_max_share", m.hidden_completion_max_share},
              {"mode", to_string(o.extraction.mode)},
              {"cloud_cell_px", o.extraction.cloud_cell_factor},
              {"use_point_classes", o.extraction.mask.use_classes < 0 ? "auto" : o.extraction.mask.use_classes ? "yes" : "no"},
              {"split_step_m", m.split_step_m},
              {"roof_seams", o.extraction.seams.enabled},
              {"crown_plane_sigma_m", o.extraction.segmentation.max_crown_plane_sigma_m},
              {"min_split_part_m2", m.min_split_part_m2},
              {"fit", to_string(o.extraction.fit)},
              {"fit_tolerance_pct", o.extraction.recursive.tolerance_pct},
              {"simplify_m", o.extraction.simplify_m},
              {"detector", to_string(o.extraction.detector)},
              {"model", o.extraction.model},
              {"footprint_grid_m", o.footprint_grid_m},
              {"cloud_grid_m", o.extraction.mask.gsd_m}}},
            {"cleaning",
             {{"outlier_filter", o.buildings.heights.outliers.enabled},
              {"recompute_ground", !o.buildings.heights.ground.trust_classification},
              {"outlier_limit_m", o.buildings.heights.outliers.max_mean_distance}}},
            {"heights",
             {{"roof_percentile", h.roof_percentile},
              {"ground_method", to_string(h.ground_method)},
              {"ground_percentile", h.ground_percentile},
              {"ground_buffer_m", h.ground_buffer_m},
              {"min_height_m", h.min_height_above_ground_m},
              {"min_roof_points", h.min_roof_points}}},
            {"roofs",
             {{"plane_distance_m", l.planes.distance_tolerance_m},
              {"plane_normal_deg", l.planes.normal_tolerance_deg},
              {"plane_min_points", l.planes.min_points},
              {"lod2_min_points", l.min_points},
              {"max_median_residual_m", l.max_median_residual_m}}},
            {"export",
             {{"formats", e.formats}, {"lods", e.lods}, {"geojson_crs", e.geojson_crs}, {"vertical_crs", e.vertical_crs}, {"id_field", e.id_field},
              {"texture_ortho", e.texture_ortho}}}};
}

RunOptions run_options_from_json(const json& j, const std::string& where, RunOptions o) {
    check_keys(j, {"ortho", "cloud", "cloud_crs", "footprints", "working_crs", "out_crs", "tile_size_px", "overlap_m", "threads", "concurrent_tiles", "keep_rasters", "extraction", "cleaning",
                   "heights", "roofs", "export"},
               where);
    take(j, "keep_rasters", o.keep_rasters, where);
    take(j, "ortho", o.ortho, where), take(j, "cloud", o.cloud, where), take(j, "cloud_crs", o.cloud_crs, where);
    take(j, "footprints", o.footprints, where), take(j, "tile_size_px", o.tile_size_px, where);
    take(j, "working_crs", o.working_crs, where), take(j, "out_crs", o.out_crs, where);
    take(j, "overlap_m", o.overlap_m, where), take(j, "threads", o.threads, where), take(j, "concurrent_tiles", o.concurrent_tiles, where);
    if (j.contains("extraction")) {
        const json& x = j["extraction"];
        const std::string w = where + ": extraction";
        check_keys(x, {"mode", "cloud_cell_px", "use_point_classes", "min_height_m", "min_area_m2", "min_hole_m2", "opening_px", "hidden_completion_max_share", "split_step_m", "roof_seams", "crown_plane_sigma_m", "min_split_part_m2", "fit", "fit_tolerance_pct", "simplify_m", "footprint_grid_m", "cloud_grid_m", "detector", "model"}, w);
        take(x, "min_height_m", o.extraction.mask.min_height_m, w), take(x, "min_area_m2", o.extraction.mask.min_area_m2, w);
        take(x, "min_hole_m2", o.extraction.mask.min_hole_m2, w), take(x, "opening_px", o.extraction.mask.opening_radius_px, w);
        take(x, "hidden_completion_max_share", o.extraction.mask.hidden_completion_max_share, w);
        take(x, "cloud_cell_px", o.extraction.cloud_cell_factor, w);
        take(x, "split_step_m", o.extraction.mask.split_step_m, w), take(x, "min_split_part_m2", o.extraction.mask.min_split_part_m2, w);
        take(x, "roof_seams", o.extraction.seams.enabled, w);
        take(x, "crown_plane_sigma_m", o.extraction.segmentation.max_crown_plane_sigma_m, w);
        take(x, "fit_tolerance_pct", o.extraction.recursive.tolerance_pct, w), take(x, "simplify_m", o.extraction.simplify_m, w);
        take(x, "footprint_grid_m", o.footprint_grid_m, w), take(x, "cloud_grid_m", o.extraction.mask.gsd_m, w);
        take(x, "model", o.extraction.model, w);
        if (x.contains("detector")) {
            std::string d;
            take(x, "detector", d, w);
            if (d != "auto" && d != "model" && d != "rules") throw Error(w + ".detector", "must be auto, model or rules, not '" + d + "'");
            o.extraction.detector = ortho_detector_from_string(d);
        }
        if (x.contains("mode")) {
            std::string mode;
            take(x, "mode", mode, w);
            o.extraction.mode = detection_mode_from_string(mode);
        }
        if (x.contains("use_point_classes")) {
            std::string v;
            take(x, "use_point_classes", v, w);
            if (v != "auto" && v != "yes" && v != "no") throw Error(w + ".use_point_classes", "must be auto, yes or no");
            o.extraction.mask.use_classes = v == "auto" ? -1 : v == "yes" ? 1 : 0;
        }
        if (x.contains("fit")) {
            std::string fit;
            take(x, "fit", fit, w);
            o.extraction.fit = footprint_fit_from_string(fit);
        }
    }
    if (j.contains("cleaning")) {
        const json& x = j["cleaning"];
        const std::string w = where + ": cleaning";
        check_keys(x, {"outlier_filter", "recompute_ground", "outlier_limit_m"}, w);
        take(x, "outlier_filter", o.buildings.heights.outliers.enabled, w);
        take(x, "outlier_limit_m", o.buildings.heights.outliers.max_mean_distance, w);
        bool recompute = !o.buildings.heights.ground.trust_classification;
        take(x, "recompute_ground", recompute, w);
        o.buildings.heights.ground.trust_classification = !recompute;
    }
    if (j.contains("heights")) {
        const json& x = j["heights"];
        const std::string w = where + ": heights";
        auto& h = o.buildings.heights.heights;
        check_keys(x, {"roof_percentile", "ground_method", "ground_percentile", "ground_buffer_m", "min_height_m", "min_roof_points"}, w);
        if (x.contains("ground_method")) {
            std::string m;
            take(x, "ground_method", m, w);
            h.ground_method = ground_method_from_string(m, w + ".ground_method");
        }
        take(x, "roof_percentile", h.roof_percentile, w), take(x, "ground_percentile", h.ground_percentile, w);
        take(x, "ground_buffer_m", h.ground_buffer_m, w), take(x, "min_height_m", h.min_height_above_ground_m, w);
        take(x, "min_roof_points", h.min_roof_points, w);
    }
    if (j.contains("roofs")) {
        const json& x = j["roofs"];
        const std::string w = where + ": roofs";
        auto& l = o.buildings.lod2;
        check_keys(x, {"plane_distance_m", "plane_normal_deg", "plane_min_points", "lod2_min_points", "max_median_residual_m"}, w);
        take(x, "max_median_residual_m", l.max_median_residual_m, w);
        take(x, "plane_distance_m", l.planes.distance_tolerance_m, w), take(x, "plane_normal_deg", l.planes.normal_tolerance_deg, w);
        take(x, "plane_min_points", l.planes.min_points, w), take(x, "lod2_min_points", l.min_points, w);
    }
    if (j.contains("export")) {
        const json& x = j["export"];
        const std::string w = where + ": export";
        auto& e = o.buildings.model;
        check_keys(x, {"formats", "lods", "geojson_crs", "vertical_crs", "id_field", "texture_ortho"}, w);
        take(x, "texture_ortho", e.texture_ortho, w);
        take(x, "formats", e.formats, w), take(x, "lods", e.lods, w), take(x, "geojson_crs", e.geojson_crs, w);
        take(x, "vertical_crs", e.vertical_crs, w), take(x, "id_field", e.id_field, w);
    }
    // The cleaning options serve the extraction as well: one cloud, one cleaning.
    o.extraction.outliers = o.buildings.heights.outliers;
    o.extraction.ground = o.buildings.heights.ground;
    o.extraction.cloud = o.cloud, o.extraction.cloud_crs = o.cloud_crs;
    o.buildings.heights.cloud_crs = o.cloud_crs;
    return o;
}

namespace {
// The fields a run computes for given footprints (heights, then roofs): input fields of these names are replaced.
std::vector<std::string> run_computed_fields() {
    std::vector<std::string> ours = heights_output_fields();
    for (const FieldDefinition& f : roof_output_fields()) ours.push_back(f.name);
    ours.insert(ours.end(), model_output_fields().begin(), model_output_fields().end());
    return ours;
}

// The CRS a run writes its city models in: --out-crs, else the input's own
// CRS (ortho or footprints), else, when that is geographic, the working CRS
// (a city model in degrees is refused, as by `export`).
CrsInfo run_output_crs(const RunManifest& m, const CrsInfo& grid_crs) {
    const RunOptions& o = m.options;
    if (!o.out_crs.empty()) {
        const CrsInfo out = crs_from_user_input(o.out_crs, "--out-crs");
        if (out.geographic) throw Error("--out-crs", out.label() + " is geographic; city models need a projected CRS");
        return out;
    }
    if (o.ortho.empty()) return grid_crs;
    const CrsInfo own = read_raster_info(o.ortho).crs;
    return own.geographic ? grid_crs : own;
}

}  // namespace

namespace {
// The grid's extent (CRS units).
Extent grid_extent(const RunManifest& m) {
    const GeoTransform& t = m.grid.transform;
    const MapPoint a = t.pixel_to_map({0.0, 0.0}), b = t.pixel_to_map({double(m.grid.width), double(m.grid.height)});
    return {std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
}

// The bounding box of the cloud's points on the grid's CRS (one streamed pass).
Extent cloud_bounds_on_grid(const RunManifest& m, const Progress& progress) {
    return cloud_bounds_in(m.options.cloud, m.options.cloud_crs, crs_from_wkt(m.crs_wkt, "grid"), progress);
}

// The square of half-side `half` centred on `c`.
Extent square_around(const MapPoint& c, double half) { return {c.x - half, c.y - half, c.x + half, c.y + half}; }

// The part of the grid the cloud covers; Error naming both inputs and their extents when none.
Extent covered_part(const RunManifest& m, const Extent& cloud) {
    const RunOptions& o = m.options;
    const Extent g = grid_extent(m);
    const Extent c{std::max(g.min_x, cloud.min_x), std::max(g.min_y, cloud.min_y), std::min(g.max_x, cloud.max_x), std::min(g.max_y, cloud.max_y)};
    if (c.min_x <= c.max_x && c.min_y <= c.max_y) return c;
    const std::string& other = o.ortho.empty() ? o.footprints : o.ortho;
    const CrsInfo crs = crs_from_wkt(m.crs_wkt, "grid");
    throw Error(o.cloud, "does not overlap " + other + ": cloud " + describe_extent(cloud, crs) + ", " +
                             std::filesystem::path(other).filename().string() + " " + describe_extent(g, crs));
}
}  // namespace

namespace {
// What plan_run says (a log line) and the run report keeps (a warning) about
// the tiles left out for want of points.
std::string tiles_left_out_note(const RunManifest& m) {
    return std::to_string(m.tiles_left_out) + " of " + std::to_string(m.tiles_left_out + static_cast<int>(m.tiles.size())) + " tiles have no point of " +
           m.options.cloud + " in their window and are not planned" +
           (m.options.ortho.empty() ? "" : " (no building is detected there: the cloud covers part of " + m.options.ortho + ")");
}
}  // namespace

RasterOpenOptions run_ortho_open_options(const RunOptions& o) {
    RasterOpenOptions ro;
    ro.project_geographic = true;  // metres: a lon/lat ortho is read on its UTM zone
    ro.working_crs = o.working_crs;
    return ro;
}

double grid_metres_per_unit(const RunManifest& m) {
    return ground_metres_per_unit(crs_from_wkt(m.crs_wkt, "manifest"), m.grid.transform, m.grid.width, m.grid.height);
}

namespace {
// The run's grid before any tile: where its pixels are, in which CRS, at
// which ground sample distance, and what was read on the way.
struct PlannedGrid {
    double gsd_m = 0.0;
    /// Given footprints, on the grid's CRS (empty without footprints).
    std::vector<Extent> footprint_extents;
    /// The cloud's points' box on the grid's CRS when it was read to place
    /// the grid (cloud only); empty_extent() otherwise.
    Extent cloud_bounds = empty_extent();
};

// The working grid: the ortho's, or a lon/lat ortho warped onto its UTM zone
// (as `footprints` reads it). Given footprints are read now, so that a
// missing or unreadable file is refused at plan time (not by every tile), and
// the ones outside the cloud are counted as in a run without ortho.
PlannedGrid grid_from_ortho(RunManifest& m) {
    const RunOptions& o = m.options;
    PlannedGrid g;
    const RasterInfo info = read_raster_info(o.ortho, run_ortho_open_options(o));
    if (info.crs.geographic) throw Error(o.working_crs.empty() ? o.ortho : "--working-crs", "the working CRS must be projected (metres)");
    if (info.warped) log::info(o.ortho + ": " + info.source_crs.label() + " read on " + info.crs.label() + " (working CRS)");
    m.grid = {info.transform, info.width, info.height};
    m.crs_wkt = info.crs.wkt;
    g.gsd_m = std::abs(info.transform.pixel_width) * info.metres_per_unit;
    if (!o.footprints.empty()) {
        PolygonLayer fp = read_polygon_layer(o.footprints, o.buildings.heights.footprint_layer);
        put_layer_on(fp, info.crs, o.footprints);
        for (const Feature& f : fp.features) g.footprint_extents.push_back(parts_extent(f.geometry));
    }
    return g;
}

// Cloud only: a grid of extraction.mask.gsd_m cells (the config's
// extraction.cloud_grid_m, as `footprints --gsd`) over the cloud's points
// (cloud_point_bounds: a few points kilometres away do not make it), in the
// cloud's projected CRS or --working-crs.
PlannedGrid grid_from_cloud(RunManifest& m, const Progress& bounds_progress) {
    const RunOptions& o = m.options;
    PlannedGrid g;
    const CrsInfo cloud = o.working_crs.empty() ? require_cloud_crs(o.cloud, o.cloud_crs) : crs_from_user_input(o.working_crs, "--working-crs");
    if (cloud.geographic) throw Error("--working-crs", "the working CRS must be projected (metres)");
    const Extent e = cloud_bounds_in(o.cloud, o.cloud_crs, cloud, bounds_progress);
    g.cloud_bounds = e;  // the grid's CRS is `cloud`: no second pass for it
    const double unit = ground_metres_per_unit_at(cloud, e);
    const double cell = o.extraction.mask.gsd_m / unit;
    // The top edge strictly above the highest point: windows keep y < top.
    const double x0 = std::floor(e.min_x / cell) * cell, y1 = (std::floor(e.max_y / cell) + 1) * cell;
    m.grid = {GeoTransform{x0, cell, y1, -cell}, static_cast<int>(std::ceil((e.max_x - x0) / cell)) + 1,
              static_cast<int>(std::ceil((y1 - e.min_y) / cell)) + 1};
    m.crs_wkt = cloud.wkt;
    g.gsd_m = o.extraction.mask.gsd_m;
    return g;
}

// Footprints given, no ortho: a grid of footprint_grid_m cells over them, in
// their own projected CRS, or --working-crs, or (lon/lat footprints) the
// cloud's projected CRS, else their UTM zone.
PlannedGrid grid_from_footprints(RunManifest& m) {
    const RunOptions& o = m.options;
    PlannedGrid g;
    PolygonLayer fp = read_polygon_layer(o.footprints, o.buildings.heights.footprint_layer);
    std::string working = o.working_crs;
    if (working.empty() && fp.crs.geographic) {
        const CrsInfo cloud = resolve_cloud_crs(o.cloud, o.cloud_crs).crs;
        if (!cloud.empty() && !cloud.geographic && cloud.horizontal_epsg) working = "EPSG:" + std::to_string(*cloud.horizontal_epsg);
    }
    const CrsInfo on = working_crs_for_layer(fp, working, o.footprints);
    if (fp.crs.geographic) log::warning(o.footprints + ": lon/lat footprints (" + fp.crs.label() + ") worked on in " + on.label());
    put_layer_on(fp, on, o.footprints);
    drop_colliding_fields(fp, run_computed_fields(), o.footprints);  // the warning, once per run
    for (const Feature& f : fp.features) g.footprint_extents.push_back(parts_extent(f.geometry));
    Extent e = empty_extent();
    for (const Feature& f : fp.features) include(e, parts_extent(f.geometry));
    const double cell = o.footprint_grid_m / fp.crs.linear_unit_m;
    const double x0 = std::floor(e.min_x / cell) * cell, y1 = std::ceil(e.max_y / cell) * cell;
    m.grid = {GeoTransform{x0, cell, y1, -cell}, static_cast<int>(std::ceil((e.max_x - x0) / cell)) + 1,
              static_cast<int>(std::ceil((y1 - e.min_y) / cell)) + 1};
    m.crs_wkt = fp.crs.wkt;
    g.gsd_m = o.footprint_grid_m;
    return g;
}

// Whether the run leaves to a cloud sample the outlier filter's limit, or
// (extracting buildings) the cloud cells' size or whether point classes
// decide building cells.
bool cloud_sample_needed(const RunOptions& o) {
    const auto& outliers = o.buildings.heights.outliers;
    const auto& ex = o.extraction;
    const bool extract = o.footprints.empty();
    return (outliers.enabled && !(outliers.max_mean_distance > 0)) || (extract && (ex.cloud_cell_factor == 0 || ex.mask.use_classes < 0));
}

// What must be alike in every tile, measured once on a sample fixed by where
// the cloud is on the grid (the central 400 m square of the part it covers,
// `covered`, so an ortho cropped around the cloud decides as the whole ortho
// does): the outlier filter's limit, the cloud cells' size, and whether
// point classes decide building cells. Sets them in m.options where the
// options leave them to the run.
void measure_cloud_sample(RunManifest& m, const Extent& covered, double gsd_m, const Progress& progress) {
    const RunOptions& o = m.options;
    auto& outliers = m.options.buildings.heights.outliers;
    auto& ex = m.options.extraction;
    const bool need_limit = outliers.enabled && !(outliers.max_mean_distance > 0);
    const bool extract = o.footprints.empty();
    if (!cloud_sample_needed(o)) return;
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "grid");
    PreparedCloud points;
    MapPoint centre{0.5 * (covered.min_x + covered.max_x), 0.5 * (covered.min_y + covered.max_y)};
    progress(0.4, "cloud sample: the 400 m square at the centre of the covered part");  // a streamed pass, not counted
    CloudSample sample = sample_cloud(o.cloud, o.cloud_crs, grid_crs, outliers, centre, &points);
    // Too few points there to measure anything (the box says little of
    // where the points are: an L-shaped survey): the grid's most
    // populated 400 m square.
    constexpr std::size_t kMinSample = 100;
    if (points.cloud.size() < kMinSample) {
        const DensestSquare d = densest_square(o.cloud, o.cloud_crs, grid_crs, grid_extent(m), 400.0 / grid_metres_per_unit(m), progress.sub(0.4, 0.5));
        if (d.points > points.cloud.size()) {
            PreparedCloud p;
            CloudSample s = sample_cloud(o.cloud, o.cloud_crs, grid_crs, outliers, d.centre, &p);
            if (p.cloud.size() > points.cloud.size()) centre = d.centre, sample = s, points = std::move(p);
        }
    }
    if (need_limit) {
        if (!(sample.outlier_limit_m > 0))
            throw Error(o.cloud, "too few points to measure the outlier filter's limit: " + std::to_string(points.cloud.size()) +
                                     " in the grid's most populated 400 m square, " + describe_extent(square_around(centre, 200.0 / grid_metres_per_unit(m)), grid_crs) +
                                     "; set cleaning.outlier_limit_m or cleaning.outlier_filter false in the --config");
        outliers.max_mean_distance = sample.outlier_limit_m;
        ex.outliers.max_mean_distance = sample.outlier_limit_m;
    }
    if (extract && ex.cloud_cell_factor == 0) ex.cloud_cell_factor = cloud_cell_factor(sample.points_per_m2, gsd_m);
    if (extract && ex.mask.use_classes < 0) {
        // The sample on the run's cloud cells, decided as a window would.
        const double cell = std::abs(m.grid.transform.pixel_width) * std::max(1, ex.cloud_cell_factor);
        const double unit = grid_metres_per_unit(m);
        const double half = 200.0 / unit;
        const int n = std::max(1, static_cast<int>(std::ceil(2 * half / cell)));
        const GridSpec g{GeoTransform{centre.x - half, cell, centre.y + half, -cell}, n, n};
        const CloudRasters r = points.cloud.size() ? rasterize_cloud(points.cloud, points.keep, points.is_ground, g, unit) : CloudRasters{};
        ex.mask.use_classes = points.cloud.size() && point_classes_present(r.building_share, r.vegetation_share) ? 1 : 0;
    }
}

// Points of the cloud per block of the grid, as a summed-area table: whether
// a pixel window may hold a point. Blocks are 16 px or more (doubled until
// the table has at most 2^22 entries); a block the window only partly covers
// counts whole, so a window said to have points may still find none, but no
// window with points is said to have none.
class PointBlockTable {
public:
    PointBlockTable(const RunManifest& m, const Progress& progress) {
        while ((int64_t(m.grid.width) / block_ + 1) * (int64_t(m.grid.height) / block_ + 1) > (int64_t(1) << 22)) block_ *= 2;
        blocks_x_ = (m.grid.width + block_ - 1) / block_;
        const int blocks_y = (m.grid.height + block_ - 1) / block_;
        const std::vector<uint64_t> counts = count_points_in_blocks(m.options.cloud, m.options.cloud_crs, crs_from_wkt(m.crs_wkt, "grid"), m.grid, block_, progress);
        const std::size_t stride = static_cast<std::size_t>(blocks_x_) + 1;
        sums_.assign(static_cast<std::size_t>(blocks_y + 1) * stride, 0);
        for (int by = 0; by < blocks_y; ++by)
            for (int bx = 0; bx < blocks_x_; ++bx)
                sums_[(by + 1) * stride + bx + 1] = counts[static_cast<std::size_t>(by) * blocks_x_ + bx] + sums_[by * stride + bx + 1] +
                                                    sums_[(by + 1) * stride + bx] - sums_[by * stride + bx];
    }
    bool may_hold_points(const PixelWindow& w) const {
        const std::size_t x0 = static_cast<std::size_t>(w.col / block_), x1 = static_cast<std::size_t>((w.col + w.width - 1) / block_) + 1;
        const std::size_t y0 = static_cast<std::size_t>(w.row / block_), y1 = static_cast<std::size_t>((w.row + w.height - 1) / block_) + 1;
        const std::size_t stride = static_cast<std::size_t>(blocks_x_) + 1;
        return sums_[y1 * stride + x1] + sums_[y0 * stride + x0] - sums_[y0 * stride + x1] - sums_[y1 * stride + x0] > 0;
    }

private:
    int block_ = 16;
    int blocks_x_ = 0;
    std::vector<uint64_t> sums_;  ///< (blocks_y + 1) x (blocks_x + 1), inclusive prefix sums
};

// Cuts the grid into tiles of tile_size_px with overlap_px around each core.
// Extraction (`points` given): a tile whose window holds no point of the
// cloud would only fail for want of points ("no points in tile K"), so it is
// not planned: a corridor or an L-shaped survey costs its own area, not its
// box's, and a cloud over part of the ortho runs where it has points. Sets
// m.tiles (indices 0.. in row order) and m.tiles_left_out.
void cut_tiles(RunManifest& m, const PointBlockTable* points) {
    const int ts = m.options.tile_size_px;
    int k = 0, left_out = 0;
    for (int r = 0; r < m.grid.height; r += ts)
        for (int c = 0; c < m.grid.width; c += ts) {
            TileSpec t;
            t.core = {c, r, std::min(ts, m.grid.width - c), std::min(ts, m.grid.height - r)};
            const int c0 = std::max(0, c - m.overlap_px), r0 = std::max(0, r - m.overlap_px);
            const int c1 = std::min(m.grid.width, c + t.core.width + m.overlap_px), r1 = std::min(m.grid.height, r + t.core.height + m.overlap_px);
            t.window = {c0, r0, c1 - c0, r1 - r0};
            if (points && !points->may_hold_points(t.window)) {
                ++left_out;
                continue;
            }
            t.index = k++;
            m.tiles.push_back(t);
        }
    m.tiles_left_out = left_out;
}
}  // namespace

RunManifest plan_run(const RunOptions& in, const Progress& progress) {
    RunOptions o = run_options_from_json(to_json(in), "options", in);  // normalised: shared cleaning options
    o.validate();
    RunManifest m;
    m.options = o;
    // The plan's passes over the cloud: its box, the sample, points per tile.
    const Progress bounds_progress = progress.sub(0.0, 0.4), tiles_progress = progress.sub(0.5, 1.0);
    PlannedGrid g = !o.ortho.empty() ? grid_from_ortho(m) : o.footprints.empty() ? grid_from_cloud(m, bounds_progress) : grid_from_footprints(m);
    run_output_crs(m, crs_from_wkt(m.crs_wkt, "grid"));  // a geographic --out-crs is refused before any tile runs
    m.overlap_px = static_cast<int>(std::ceil(o.overlap_m / g.gsd_m));
    if (o.cloud.empty()) {
        // Ortho only: segmentation merges regions across the whole raster, so it runs as one tile.
        m.options.tile_size_px = std::max(m.grid.width, m.grid.height);
        m.overlap_px = 0;
        m.tiles.push_back({0, {0, 0, m.grid.width, m.grid.height}, {0, 0, m.grid.width, m.grid.height}});
        return m;
    }
    // An input that cannot produce a result is an error naming both files and their
    // extents; given footprints outside the cloud are counted in a warning.
    auto bounds = [&]() -> const Extent& {
        if (!(g.cloud_bounds.min_x <= g.cloud_bounds.max_x)) g.cloud_bounds = cloud_bounds_on_grid(m, bounds_progress);
        return g.cloud_bounds;
    };
    if (!g.footprint_extents.empty()) {
        covered_part(m, bounds());
        check_footprints_within(bounds(), crs_from_wkt(m.crs_wkt, "grid"), o.cloud, g.footprint_extents, o.footprints);
    }
    if (cloud_sample_needed(m.options)) measure_cloud_sample(m, covered_part(m, bounds()), g.gsd_m, progress);
    const bool extract = o.footprints.empty();
    // At least the context of one building (smaller overlaps would only make
    // every building near a core's edge be done again on a grown window).
    m.overlap_px = std::max(m.overlap_px, context_px(m.options, g.gsd_m));
    if (extract) {
        const PointBlockTable points(m, tiles_progress);
        cut_tiles(m, &points);
    } else {
        cut_tiles(m, nullptr);
    }
    if (m.tiles.empty()) {  // the box met the grid, no point did: nothing to run
        const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "grid");
        throw Error(o.cloud, "no point of the cloud lies on the grid of " + (o.ortho.empty() ? o.cloud : o.ortho) + ": cloud " +
                                 describe_extent(bounds(), grid_crs) + ", grid " + describe_extent(grid_extent(m), grid_crs));
    }
    if (m.tiles_left_out > 0) {
        if (o.ortho.empty()) log::info(tiles_left_out_note(m));
        else log::warning(tiles_left_out_note(m));
    }
    progress(1.0, "planned");  // ends the progress line, whichever passes ran
    return m;
}

void write_manifest(const std::string& path, const RunManifest& m) {
    json j;
    j["cityforge_manifest"] = 1;
    j["cityforge_version"] = version();
    j["options"] = to_json(m.options);
    j["grid"] = {{"geotransform", m.grid.transform.to_gdal()}, {"width", m.grid.width}, {"height", m.grid.height}, {"crs_wkt", m.crs_wkt}};
    j["overlap_px"] = m.overlap_px;
    j["tiles_left_out"] = m.tiles_left_out;
    json tiles = json::array();
    for (const TileSpec& t : m.tiles)
        tiles.push_back({{"index", t.index},
                         {"core", {t.core.col, t.core.row, t.core.width, t.core.height}},
                         {"window", {t.window.col, t.window.row, t.window.width, t.window.height}}});
    j["tiles"] = tiles;
    write_text_file(path, j.dump(2) + "\n");
}

RunManifest read_manifest(const std::string& path) {
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw Error(path, "is a directory, not a manifest (make one with `cityforge plan`)");
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open the manifest");
    json j;
    try {
        j = json::parse(in);
    } catch (const json::exception& e) {
        throw Error(path, std::string("invalid JSON: ") + e.what());
    }
    if (!j.contains("cityforge_manifest")) throw Error(path, "not a cityforge manifest (make one with `cityforge plan`)");
    try {
        RunManifest m;
        m.options = run_options_from_json(j.at("options"), path + ": options");
        const auto gt = j.at("grid").at("geotransform").get<std::array<double, 6>>();
        m.grid = {GeoTransform::from_gdal(gt), j["grid"].at("width").get<int>(), j["grid"].at("height").get<int>()};
        m.crs_wkt = j["grid"].at("crs_wkt").get<std::string>();
        m.overlap_px = j.at("overlap_px").get<int>();
        m.tiles_left_out = j.value("tiles_left_out", 0);
        for (const auto& t : j.at("tiles")) {
            const auto c = t.at("core").get<std::array<int, 4>>(), w = t.at("window").get<std::array<int, 4>>();
            m.tiles.push_back({t.at("index").get<int>(), {c[0], c[1], c[2], c[3]}, {w[0], w[1], w[2], w[3]}});
        }
        return m;
    } catch (const json::exception& e) {
        throw Error(path, std::string("malformed manifest: ") + e.what());
    }
}

namespace {

// Buildings (footprints and solids) from `from` to `to`, horizontally.
void reproject_buildings(std::vector<Building>& buildings, const CrsInfo& from, const CrsInfo& to, const std::string& subject) {
    std::vector<double> x, y, z;
    auto each = [&](auto&& visit) {
        for (Building& b : buildings) {
            for (Polygon& p : b.footprint) {
                for (MapPoint& q : p.outer) visit(q.x, q.y, nullptr);
                for (Ring& h : p.holes)
                    for (MapPoint& q : h) visit(q.x, q.y, nullptr);
            }
            for (std::vector<Solid>* solids : {&b.lod1, &b.lod2})
                for (Solid& sd : *solids)
                    for (Face& f : sd.faces) {
                        for (Point3& q : f.outer) visit(q.x, q.y, &q.z);
                        for (Ring3& h : f.holes)
                            for (Point3& q : h) visit(q.x, q.y, &q.z);
                    }
        }
    };
    each([&](double& px, double& py, double* pz) { x.push_back(px), y.push_back(py), z.push_back(pz ? *pz : 0.0); });
    transform_points(from, to, x, y, z, subject);
    std::size_t i = 0;
    each([&](double& px, double& py, double*) { px = x[i], py = y[i], ++i; });  // heights stay in their vertical datum
}

// Declared attribute types in a tile report: [[name, "integer" | "real" | "string"], ...].
json attribute_types_json(const std::vector<std::pair<std::string, FieldType>>& types) {
    json out = json::array();
    for (const auto& [name, t] : types)
        out.push_back({name, t == FieldType::integer ? "integer" : t == FieldType::real ? "real" : "string"});
    return out;
}
std::vector<std::pair<std::string, FieldType>> attribute_types_from(const json& j, const std::string& where) {
    std::vector<std::pair<std::string, FieldType>> out;
    if (!j.is_array()) throw Error(where, "attribute_types must be an array");
    for (const json& a : j) {
        const std::string t = a.at(1).get<std::string>();
        if (t != "integer" && t != "real" && t != "string") throw Error(where, "unknown attribute type '" + t + "'");
        out.emplace_back(a.at(0).get<std::string>(), t == "integer" ? FieldType::integer : t == "real" ? FieldType::real : FieldType::string);
    }
    return out;
}

fs::path tile_cloud_path(const std::string& out_dir, int k) { return fs::path(out_dir) / "cloud_tiles" / (tile_name(k) + ".las"); }

Extent window_extent_of(const GeoTransform& gt, const PixelWindow& w) {
    const MapPoint a = gt.pixel_to_map({double(w.col), double(w.row)});
    const MapPoint b = gt.pixel_to_map({double(w.col + w.width), double(w.row + w.height)});
    return {std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
}

// One streaming pass over a LAS cloud writes each tile window's points (in
// file order, on the source's integer grid, so coordinates are unchanged) to
// DIR/cloud_tiles/ (split_las_into_windows): each tile then reads its
// window, not the whole file.
// Only for LAS clouds already in the grid's CRS; other tiles read the source.
void split_cloud(const RunManifest& m, const std::string& out_dir) {
    const RunOptions& o = m.options;
    const fs::path dir = fs::path(out_dir) / "cloud_tiles";
    if (fs::exists(dir / "complete") || fs::exists(dir / "not_split")) return;
    ensure_directory(dir);
    if (o.cloud.empty()) {
        write_text_file(dir / "not_split", "no cloud\n");
        return;
    }
    CloudReader probe(o.cloud);
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    const CrsInfo cloud_crs = resolve_cloud_crs(probe, o.cloud_crs).crs;
    if (probe.format() != CloudFormat::las || cloud_crs.empty() || !same_horizontal_crs(cloud_crs, grid_crs)) {
        write_text_file(dir / "not_split", "tiles read the source cloud (not LAS, or not in the grid's CRS)\n");
        return;
    }
    if (probe.copc()) {  // each tile decodes only the octree nodes it needs
        write_text_file(dir / "not_split", "tiles read the COPC source's nodes in their window\n");
        return;
    }
    std::vector<std::array<double, 4>> windows;
    std::vector<std::string> paths;
    for (const TileSpec& t : m.tiles) {
        const Extent e = window_extent_of(m.grid.transform, t.window);
        windows.push_back({e.min_x, e.min_y, e.max_x, e.max_y});
        paths.push_back(tile_cloud_path(out_dir, t.index).string());
    }
    split_las_into_windows(o.cloud, windows, paths, cloud_crs.wkt);
    write_text_file(dir / "complete", "cloud split into " + std::to_string(windows.size()) + " tile windows\n");
}

bool intersects(const PixelWindow& a, const PixelWindow& b) {
    return a.col < b.col + b.width && b.col < a.col + a.width && a.row < b.row + b.height && b.row < a.row + a.height;
}

PixelWindow intersection(const PixelWindow& a, const PixelWindow& b) {
    const int c0 = std::max(a.col, b.col), r0 = std::max(a.row, b.row);
    const int c1 = std::min(a.col + a.width, b.col + b.width), r1 = std::min(a.row + a.height, b.row + b.height);
    return {c0, r0, std::max(0, c1 - c0), std::max(0, r1 - r0)};
}

// Global pixel box (inclusive) of a building.
struct PixelBox {
    int c0 = INT_MAX, r0 = INT_MAX, c1 = INT_MIN, r1 = INT_MIN;
    void add(int c, int r) { c0 = std::min(c0, c), r0 = std::min(r0, r), c1 = std::max(c1, c), r1 = std::max(r1, r); }
    void add(const PixelBox& b) { c0 = std::min(c0, b.c0), r0 = std::min(r0, b.r0), c1 = std::max(c1, b.c1), r1 = std::max(r1, b.r1); }
    bool empty() const { return c1 < c0; }
};

// The window of the grid holding `b` grown by `margin`, with edges at global
// multiples of 32 pixels (clipped to the grid).
PixelWindow window_around(const PixelBox& b, int margin, const GridSpec& grid) {
    constexpr int align = 32;
    auto down = [](int v) { return v >= 0 ? v / align * align : -((-v + align - 1) / align) * align; };
    const int c0 = std::max(0, down(b.c0 - margin)), r0 = std::max(0, down(b.r0 - margin));
    const int c1 = std::min(grid.width, down(b.c1 + 1 + margin + align - 1)), r1 = std::min(grid.height, down(b.r1 + 1 + margin + align - 1));
    return {c0, r0, c1 - c0, r1 - r0};
}

// Is `b` grown by `margin` inside `w`, edges of the grid aside?
bool fits(const PixelBox& b, int margin, const PixelWindow& w, const GridSpec& grid) {
    return (w.col == 0 || b.c0 - margin >= w.col) && (w.row == 0 || b.r0 - margin >= w.row) &&
           (w.col + w.width == grid.width || b.c1 + margin < w.col + w.width) && (w.row + w.height == grid.height || b.r1 + margin < w.row + w.height);
}

// The cloud of a window of the grid, cleaned and classified: from the tile
// split files whose cores cover it (each point once), or from the source.
PreparedCloud window_cloud(const RunManifest& m, const std::string& out_dir, const PixelWindow& w) {
    const RunOptions& o = m.options;
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    const GeoTransform& gt = m.grid.transform;
    const bool split = fs::exists(fs::path(out_dir) / "cloud_tiles" / "complete");
    if (!split) {
        const Extent e = window_extent_of(gt, w);
        return prepare_cloud(o.cloud, o.cloud_crs, grid_crs, o.buildings.heights.outliers, o.buildings.heights.ground, &e);
    }
    std::vector<CloudPart> parts;
    for (const TileSpec& t : m.tiles) {
        if (t.window.col == w.col && t.window.row == w.row && t.window.width == w.width && t.window.height == w.height) {
            parts = {{tile_cloud_path(out_dir, t.index).string(), window_extent_of(gt, w)}};
            break;
        }
        if (!intersects(t.core, w)) continue;
        parts.push_back({tile_cloud_path(out_dir, t.index).string(), window_extent_of(gt, intersection(t.core, w))});
    }
    return prepare_cloud(parts, o.cloud_crs, grid_crs, o.buildings.heights.outliers, o.buildings.heights.ground);
}

// Buildings detected on one window of the grid (labels on the window's pixels).
struct WindowBuildings {
    PixelWindow window;
    PreparedCloud pc;
    BuildingMask mask;          ///< final buildings (after the ortho redraw)
    Image<float> ndsm;
    std::string mode;
    std::vector<PixelBox> box;  ///< per label: its cells before and after the redraw (global pixels)
    std::vector<int64_t> id;    ///< per label: 1 + global index of its first pixel (raster order)
};

WindowBuildings detect_on_window(const RunManifest& m, const PixelWindow& win, PreparedCloud pc, const std::string& where) {
    const RunOptions& o = m.options;
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    const double unit = grid_metres_per_unit(m);
    const GeoTransform& gt = m.grid.transform;
    WindowBuildings d;
    d.window = win;
    const GridSpec wg{gt.window(win.col, win.row), win.width, win.height};
    if (pc.cloud.size() == 0) throw Error(o.cloud, "no points in " + where);
    BuildingMaskOptions mo = o.extraction.mask;
    mo.gsd_m = std::abs(gt.pixel_width) * unit;
    mo.min_height_m /= pc.crs.z_unit_m;
    WindowCloudCells wc = cloud_cells_on_window(pc, wg, win.col, win.row, std::max(1, o.extraction.cloud_cell_factor), unit, mo);
    mo.split_step_m /= pc.crs.z_unit_m, mo.split_gap_step_m /= pc.crs.z_unit_m;
    // Pieces of larger buildings at the window's edges (not the grid's) stay, whatever their area.
    mo.keep_border_sides = (win.col > 0 ? 1 : 0) | (win.row > 0 ? 2 : 0) | (win.col + win.width < m.grid.width ? 4 : 0) |
                           (win.row + win.height < m.grid.height ? 8 : 0);
    // With the run's ortho the buildings are redrawn along it, unless the
    // config asks for the cloud alone.
    const DetectionMode detection = o.extraction.mode == DetectionMode::cloud_only || o.ortho.empty() ? DetectionMode::cloud_only : DetectionMode::ortho_cloud;
    d.mode = to_string(detection);
    const BuildingCells cells = std::move(wc.cells);
    d.mask = buildings_from_cells(cells, win.width, win.height, mo);
    d.box.assign(d.mask.count + 1, PixelBox{});
    for (int r = 0; r < win.height; ++r)
        for (int c = 0; c < win.width; ++c)
            if (const uint32_t l = d.mask.labels.data[static_cast<std::size_t>(r) * win.width + c]) d.box[l].add(win.col + c, win.row + r);

    if (detection == DetectionMode::ortho_cloud) {
        // Each building redrawn along the ortho from a crop around it alone.
        RasterReader ortho(o.ortho, run_ortho_open_options(o));  // the manifest's grid
        const RasterInfo& oi = ortho.info();
        const std::vector<int> bands = image_bands(oi);  // an alpha band is a mask, not a colour
        const Image<float> colours = ortho.read<float>(win, bands);
        const std::vector<uint8_t> valid = valid_pixels(ortho, win, colours, bands);
        SegmentClassifierOptions co = o.extraction.classifier;
        co.gsd_m = oi.gsd.x_m;
        const std::vector<uint8_t> vegetation = cells.used_classes ? std::vector<uint8_t>{} : vegetation_pixels(colours, co);
        OrthoRefineOptions ro = o.extraction.segmentation;
        ro.cloud_edges = o.extraction.cloud_cell_factor <= 1;
        ro.max_crown_plane_sigma_m /= pc.crs.z_unit_m, ro.min_crown_local_roughness_m /= pc.crs.z_unit_m, ro.gsd_m = mo.gsd_m;
        refine_buildings_with_ortho(d.mask, cells, colours, valid, wc.rasters.ndsm, 20.0 / pc.crs.z_unit_m, {}, vegetation, ro);
        RoofSeamOptions so = o.extraction.seams;
        so.gsd_m = mo.gsd_m, so.ridge_rise_m /= pc.crs.z_unit_m, so.valley_depth_m /= pc.crs.z_unit_m;
        const Image<uint32_t> before = so.enabled ? d.mask.labels : Image<uint32_t>{};
        if (split_at_roof_seams(d.mask, colours, valid, wc.rasters.ndsm, so) > 0) {
            // Terraces cut at their seams: each part keeps its building's
            // cells before the redraw in its box (the box decides which tile
            // owns it and whether the window holds it whole).
            std::vector<PixelBox> box(d.mask.count + 1, PixelBox{});
            for (std::size_t k = 0; k < before.data.size(); ++k)
                if (const uint32_t l = d.mask.labels.data[k]; l && before.data[k]) box[l] = d.box[before.data[k]];
            d.box = std::move(box);
        }
    }
    if (mo.hidden_completion_max_share > 0) complete_hidden_roofs(d.mask, cells, mo.hidden_completion_max_share);
    d.id.assign(d.mask.count + 1, 0);
    for (int r = 0; r < win.height; ++r)
        for (int c = 0; c < win.width; ++c) {
            const uint32_t l = d.mask.labels.data[static_cast<std::size_t>(r) * win.width + c];
            if (!l) continue;
            const int gc = win.col + c, gr = win.row + r;
            d.box[l].add(gc, gr);
            if (!d.id[l]) d.id[l] = int64_t(gr) * m.grid.width + gc + 1;
        }
    d.ndsm = std::move(wc.rasters.ndsm);
    d.pc = std::move(pc);
    return d;
}

// Footprints (fits, global ids) of the chosen labels of a window.
void add_footprints(const RunManifest& m, const WindowBuildings& d, const std::vector<uint32_t>& labels, PolygonLayer& footprints) {
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    std::set<int64_t> keep;
    for (uint32_t l : labels) keep.insert(d.id[l]);
    const FootprintTable table = footprint_table(d.mask, d.ndsm, m.grid.transform, d.window.col, d.window.row, d.id, d.mode,
                                                 grid_metres_per_unit(m), d.pc.crs.z_unit_m, footprints.crs, m.options.extraction);
    if (footprints.field_names.empty())
        for (const FieldDefinition& f : table.fields) footprints.field_names.push_back(f.name), footprints.field_types.push_back(f.type);
    for (const Feature& f : table.features) {
        const int64_t id = std::get<int64_t>(f.values[0]);
        if (!keep.count(id)) continue;
        footprints.features.push_back(f);
        footprints.fids.push_back(id);
    }
}

// Heights and LOD2 of footprints on a prepared cloud, as buildings.
std::vector<Building> buildings_of(const RunManifest& m, PolygonLayer footprints, PreparedCloud pc, const std::string& source, TileReport& rep) {
    const RunOptions& o = m.options;
    auto t0 = std::chrono::steady_clock::now();
    HeightsRunOptions ho = o.buildings.heights;
    ho.heights.keep_roof_points = true;
    const std::size_t n = footprints.features.size();
    if (!n) return {};
    const HeightsStage st = compute_heights_stage(std::move(footprints), std::move(pc), ho);
    rep.seconds["heights"] += since(t0);
    t0 = std::chrono::steady_clock::now();
    CrsInfo crs = st.table.crs;
    if (!o.buildings.model.vertical_crs.empty() && !crs.vertical_epsg)
        crs = combine_with_vertical(crs, crs_from_user_input(o.buildings.model.vertical_crs, "--vertical-crs"));
    RoofsRunReport rr;
    RoofsRunOptions ro = o.buildings;
    if (o.footprints.empty()) ro.model.id_field = "id";
    CityModel model = build_lod2_model(st, crs, ro, source, rr);
    if (rep.attribute_types.empty()) rep.attribute_types = model.attribute_types;
    rep.seconds["roofs"] += since(t0);
    return std::move(model.buildings);
}

// The buildings one tile owns, with their heights and LOD2, as building lines.
std::vector<Building> tile_buildings(const RunManifest& m, const TileSpec& t, const std::string& out_dir, TileReport& rep,
                                     std::vector<std::string>& warnings) {
    const RunOptions& o = m.options;
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    const double unit = grid_metres_per_unit(m);
    const GeoTransform& gt = m.grid.transform;
    const MapPoint ca = gt.pixel_to_map({double(t.core.col), double(t.core.row)});
    const MapPoint cb = gt.pixel_to_map({double(t.core.col + t.core.width), double(t.core.row + t.core.height)});
    const double gsd_m = std::abs(gt.pixel_width) * unit;
    const int margin = context_px(o, gsd_m);
    const std::string tile_label = "tile " + std::to_string(t.index);

    auto t0 = std::chrono::steady_clock::now();
    if (o.cloud.empty()) {
        // Ortho-only: footprints from the segmentation, no heights (LOD0 only).
        const fs::path tmp = fs::path(out_dir) / "tiles" / "ortho_footprints.gpkg";
        FootprintsRunOptions fo = o.extraction;
        fo.ortho = o.ortho, fo.cloud.clear();
        fo.working_crs = o.working_crs, fo.out_crs = grid_crs.wkt;  // the grid's CRS; merge_tiles writes the output CRS
        run_footprints(tmp.string(), fo);
        const PolygonLayer layer = read_polygon_layer(tmp.string());
        fs::remove(tmp);
        ExportOptions eo = o.buildings.model;
        eo.id_field = "id";
        eo.warn_missing_heights = false;  // "no cloud" is said below: the ortho is no table lacking heights
        CityModel model = build_city_model(layer, grid_crs, eo, o.ortho);
        rep.seconds["footprints"] = since(t0);
        rep.buildings = model.buildings.size();
        rep.attribute_types = model.attribute_types;
        warnings.push_back("no cloud: footprints from the ortho only (no heights, no LOD1/LOD2); ortho-only runs are not tiled");
        return std::move(model.buildings);
    }
    PreparedCloud pc = window_cloud(m, out_dir, t.window);
    rep.seconds["cloud"] = since(t0);
    const auto in_core = [&](int64_t id) {
        const int64_t gr = (id - 1) / m.grid.width, gc = (id - 1) % m.grid.width;
        return gc >= t.core.col && gc < t.core.col + t.core.width && gr >= t.core.row && gr < t.core.row + t.core.height;
    };
    std::vector<Building> out;
    if (!o.footprints.empty()) {
        // Given footprints: those whose bounding-box centre lies in the core.
        t0 = std::chrono::steady_clock::now();
        PolygonLayer footprints;
        footprints.crs = pc.crs.empty() ? grid_crs : pc.crs;
        const CrsInfo layer_crs = footprints.crs;
        PolygonLayer all = read_polygon_layer(o.footprints, o.buildings.heights.footprint_layer);
        put_layer_on(all, grid_crs, o.footprints);  // footprints in another CRS than the ortho's (or lon/lat ones): on the grid
        // Input fields we compute (a run on its own output, truth files) are replaced; plan_run said which.
        drop_colliding_fields(all, run_computed_fields(), o.footprints, false);
        footprints.field_names = all.field_names, footprints.field_types = all.field_types;
        const double cx0 = std::min(ca.x, cb.x), cx1 = std::max(ca.x, cb.x), cy0 = std::min(ca.y, cb.y), cy1 = std::max(ca.y, cb.y);
        const bool last_col = t.core.col + t.core.width == m.grid.width, last_row = t.core.row + t.core.height == m.grid.height;
        std::vector<std::pair<PixelWindow, std::size_t>> larger;  // footprints whose context leaves the window
        for (std::size_t i = 0; i < all.features.size(); ++i) {
            const Extent e = parts_extent(all.features[i].geometry);
            const double x = 0.5 * (e.min_x + e.max_x), y = 0.5 * (e.min_y + e.max_y);
            // Half-open cores (the grid's last row and column closed) own every point exactly once.
            const bool in_x = x >= cx0 && (x < cx1 || (last_col && x <= cx1));
            const bool in_y = y <= cy1 && (y > cy0 || (last_row && y >= cy0));
            if (!in_x || !in_y) continue;
            const PixelPoint p0 = gt.map_to_pixel({e.min_x, e.max_y}), p1 = gt.map_to_pixel({e.max_x, e.min_y});
            PixelBox b;
            b.add(static_cast<int>(std::floor(std::min(p0.col, p1.col))), static_cast<int>(std::floor(std::min(p0.row, p1.row))));
            b.add(static_cast<int>(std::floor(std::max(p0.col, p1.col))), static_cast<int>(std::floor(std::max(p0.row, p1.row))));
            if (!fits(b, margin, t.window, m.grid)) {
                // Its own window, grown to hold it and its context.
                larger.push_back({window_around(b, margin, m.grid), i});
                continue;
            }
            footprints.features.push_back(all.features[i]);
            footprints.fids.push_back(all.fids[i]);
        }
        rep.seconds["footprints"] = since(t0);
        out = buildings_of(m, std::move(footprints), std::move(pc), tile_label, rep);
        for (const auto& [w, i] : larger) {
            PolygonLayer one;
            one.crs = layer_crs, one.field_names = all.field_names, one.field_types = all.field_types;
            one.features.push_back(all.features[i]);
            one.fids.push_back(all.fids[i]);
            std::vector<Building> b = buildings_of(m, std::move(one), window_cloud(m, out_dir, w), tile_label, rep);
            ++rep.grown;
            for (Building& x : b) out.push_back(std::move(x));
        }
        std::sort(out.begin(), out.end(), [](const Building& a, const Building& b) { return a.id < b.id; });
        rep.buildings = out.size();
        return out;
    }
    // Extraction on the window: rasters, buildings, then only the buildings
    // whose first pixel is in the core. A building whose context leaves the
    // window is done again on a window grown around it, until it fits.
    t0 = std::chrono::steady_clock::now();
    WindowBuildings d = detect_on_window(m, t.window, std::move(pc), tile_label);
    if (o.keep_rasters) {
        // The core of each raster: tiles mosaic without overlap.
        const fs::path rdir = fs::path(out_dir) / "rasters";
        ensure_directory(rdir);
        const GridSpec wg{gt.window(t.window.col, t.window.row), t.window.width, t.window.height};
        BuildingMaskOptions mo = o.extraction.mask;
        mo.gsd_m = gsd_m, mo.min_height_m /= d.pc.crs.z_unit_m;
        const CloudRasters rasters = cloud_cells_on_window(d.pc, wg, t.window.col, t.window.row, std::max(1, o.extraction.cloud_cell_factor), unit, mo).rasters;
        const int dc = t.core.col - t.window.col, dr = t.core.row - t.window.row;
        GeoTiffWriteOptions wo;
        wo.nodata = -9999.0;
        for (const auto& [name, img] : {std::pair<const char*, const Image<float>*>{"dsm", &rasters.dsm}, {"dtm", &rasters.dtm}, {"ndsm", &rasters.ndsm}}) {
            Image<float> core(t.core.width, t.core.height, 1);
            for (int r = 0; r < t.core.height; ++r)
                for (int c = 0; c < t.core.width; ++c) {
                    const float v = img->at(0, c + dc, r + dr);
                    core.at(0, c, r) = std::isnan(v) ? -9999.0f : v;
                }
            wo.band_descriptions = {std::string(name) + " (z, vertical CRS units)"};
            write_geotiff((rdir / (tile_name(t.index) + "_" + name + ".tif")).string(), core, gt.window(t.core.col, t.core.row), d.pc.crs.wkt, wo);
        }
    }
    rep.seconds["detection"] = since(t0);
    t0 = std::chrono::steady_clock::now();
    // Labels with a pixel in the core: owned when their context fits (first
    // pixel in the core), or redone when it does not.
    std::vector<uint8_t> touches_core(d.mask.count + 1, 0);
    for (int r = t.core.row; r < t.core.row + t.core.height; ++r)
        for (int c = t.core.col; c < t.core.col + t.core.width; ++c)
            if (const uint32_t l = d.mask.labels.data[static_cast<std::size_t>(r - t.window.row) * t.window.width + (c - t.window.col)]) touches_core[l] = 1;
    std::vector<uint32_t> owned;
    std::vector<std::vector<int64_t>> redo;  // global pixels of each building to do again
    for (uint32_t l = 1; l <= d.mask.count; ++l) {
        if (!touches_core[l]) continue;
        if (fits(d.box[l], margin, t.window, m.grid)) {
            if (in_core(d.id[l])) owned.push_back(l);
            continue;
        }
        redo.emplace_back();
    }
    if (!redo.empty()) {
        std::vector<std::vector<int64_t>*> slot(d.mask.count + 1, nullptr);
        std::size_t j = 0;
        for (uint32_t l = 1; l <= d.mask.count; ++l)
            if (touches_core[l] && !fits(d.box[l], margin, t.window, m.grid)) slot[l] = &redo[j++];
        for (int r = 0; r < t.window.height; ++r)
            for (int c = 0; c < t.window.width; ++c)
                if (const uint32_t l = d.mask.labels.data[static_cast<std::size_t>(r) * t.window.width + c]; l && slot[l])
                    slot[l]->push_back(int64_t(t.window.row + r) * m.grid.width + t.window.col + c);
    }
    std::vector<PixelBox> redo_box;
    for (uint32_t l = 1; l <= d.mask.count; ++l)
        if (touches_core[l] && !fits(d.box[l], margin, t.window, m.grid)) redo_box.push_back(d.box[l]);
    PolygonLayer footprints;
    footprints.crs = d.pc.crs.empty() ? grid_crs : d.pc.crs;
    add_footprints(m, d, owned, footprints);
    std::set<int64_t> done;
    for (uint32_t l : owned) done.insert(d.id[l]);
    rep.seconds["footprints"] = since(t0);
    out = buildings_of(m, std::move(footprints), std::move(d.pc), tile_label, rep);
    d = WindowBuildings{};

    for (std::size_t i = 0; i < redo.size(); ++i) {
        t0 = std::chrono::steady_clock::now();
        std::vector<int64_t> pixels = std::move(redo[i]);
        PixelWindow w = window_around(redo_box[i], margin, m.grid);
        WindowBuildings g;
        uint32_t label = 0;
        for (int iter = 0;; ++iter) {
            g = detect_on_window(m, w, window_cloud(m, out_dir, w), tile_label + " (a building grown beyond it)");
            // The building: the label holding most of the pixels it had.
            std::map<uint32_t, std::size_t> overlap;
            for (int64_t p : pixels) {
                const int gr = static_cast<int>(p / m.grid.width), gc = static_cast<int>(p % m.grid.width);
                if (gc < w.col || gr < w.row || gc >= w.col + w.width || gr >= w.row + w.height) continue;
                if (const uint32_t l = g.mask.labels.data[static_cast<std::size_t>(gr - w.row) * w.width + (gc - w.col)]) ++overlap[l];
            }
            label = 0;
            std::size_t best = 0;
            for (const auto& [l, n] : overlap)
                if (n > best) best = n, label = l;
            if (!label || fits(g.box[label], margin, w, m.grid)) break;
            PixelWindow grown = window_around(g.box[label], margin, m.grid);
            const int c0 = std::min(w.col, grown.col), r0 = std::min(w.row, grown.row);
            const int c1 = std::max(w.col + w.width, grown.col + grown.width), r1 = std::max(w.row + w.height, grown.row + grown.height);
            grown = {c0, r0, c1 - c0, r1 - r0};
            if (iter >= 8 || (grown.col == w.col && grown.row == w.row && grown.width == w.width && grown.height == w.height)) {
                warnings.push_back("building " + std::to_string(g.id[label]) + " in " + tile_label + " did not fit a window grown " +
                                   std::to_string(iter + 1) + " times; its result may depend on the tiling");
                break;
            }
            pixels.clear();
            for (int r = 0; r < w.height; ++r)
                for (int c = 0; c < w.width; ++c)
                    if (g.mask.labels.data[static_cast<std::size_t>(r) * w.width + c] == label) pixels.push_back(int64_t(w.row + r) * m.grid.width + w.col + c);
            w = grown;
        }
        rep.seconds["detection"] += since(t0);
        // Owned by the tile whose core holds its first pixel; once.
        if (!label || !in_core(g.id[label]) || done.count(g.id[label])) continue;
        done.insert(g.id[label]);
        ++rep.grown;
        PolygonLayer one;
        one.crs = g.pc.crs.empty() ? grid_crs : g.pc.crs;
        add_footprints(m, g, {label}, one);
        for (Building& b : buildings_of(m, std::move(one), std::move(g.pc), tile_label, rep)) out.push_back(std::move(b));
    }
    // One order whatever the path a building took.
    auto key = [](const std::string& id) { return std::pair<std::size_t, std::string>(id.size(), id); };
    std::sort(out.begin(), out.end(), [&](const Building& a, const Building& b) { return key(a.id) < key(b.id); });
    rep.buildings = out.size();
    return out;
}

// A tile report's status and the job that wrote it ("" when absent);
// nothing when the file is missing or is not a JSON object.
struct TileReportState {
    std::string status, job;
};
std::optional<TileReportState> read_tile_report_state(const fs::path& summary) {
    try {
        std::ifstream in(summary);
        if (!in) return std::nullopt;
        const json r = json::parse(in);
        return TileReportState{r.value("status", ""), r.value("job", "")};
    } catch (const std::exception&) {
        return std::nullopt;
    }
}

}  // namespace

TileReport run_tile(const RunManifest& m, int k, const std::string& out_dir, const Progress& progress, const TileResume& resume) {
    if (k < 0 || k >= static_cast<int>(m.tiles.size())) throw Error("--tile", "no tile " + std::to_string(k) + " (the manifest has " + std::to_string(m.tiles.size()) + ")");
    std::unique_ptr<tbb::global_control> limit;
    if (m.options.threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, m.options.threads);
    const fs::path dir = fs::path(out_dir) / "tiles";
    ensure_directory(dir);
    const fs::path lines = dir / (tile_name(k) + ".jsonl"), summary = dir / (tile_name(k) + ".json");
    TileReport rep;
    rep.index = k;
    if (fs::exists(summary)) {
        const auto before = read_tile_report_state(summary);  // unreadable: the tile runs again and rewrites it
        const std::string status = before ? before->status : "";
        if (status == "done" || (status == "failed" && !resume.rerun_failed)) {
            rep.status = "skipped";
            return rep;
        }
        log::info("tile " + std::to_string(k) + ": " + (status == "failed" ? "failed before, running it again" : "its report is unreadable, running it again"));
    }
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<std::string> warnings;
    try {
        const std::vector<Building> buildings = tile_buildings(m, m.tiles[k], out_dir, rep, warnings);
        AtomicTextFile file(lines);
        for (const Building& b : buildings) file.stream() << building_to_json(b).dump() << '\n';
        file.commit();
        rep.status = "done";
    } catch (const Error& e) {
        rep.status = "failed", rep.reason = e.what();
        log::warning("tile " + std::to_string(k) + " failed: " + rep.reason);
    }
    rep.seconds["total"] = since(t0);
    rep.peak_memory_mb = peak_memory_mb();
    json j{{"index", k}, {"status", rep.status}, {"reason", rep.reason}, {"buildings", rep.buildings}, {"grown", rep.grown}, {"seconds", rep.seconds},
           {"peak_memory_mb", rep.peak_memory_mb}, {"warnings", warnings}, {"attribute_types", attribute_types_json(rep.attribute_types)}};
    if (!resume.job.empty()) j["job"] = resume.job;
    write_text_file(summary, j.dump(2) + "\n");
    progress(1.0, tile_name(k));
    return rep;
}

namespace {
// Every planned tile's report (DIR/tiles/tile_K.json) into rep.tiles, with
// its warnings (a failed tile's reason among them) and peak memory; the
// tiles' stage seconds summed into `stage_seconds`. Error naming the file
// when a tile has not run or its report is not valid.
void read_tile_reports(const RunManifest& m, const fs::path& dir, RunReport& rep, std::map<std::string, double>& stage_seconds) {
    for (const TileSpec& t : m.tiles) {
        const fs::path summary = dir / (tile_name(t.index) + ".json");
        if (!fs::exists(summary)) throw Error(summary.string(), "tile " + std::to_string(t.index) + " has not run yet");
        std::ifstream in(summary);
        json s;
        try {
            s = json::parse(in);
        } catch (const json::exception& e) {
            throw Error(summary.string(), std::string("invalid tile report: ") + e.what());
        }
        TileReport tr;
        tr.index = t.index, tr.status = s.value("status", ""), tr.reason = s.value("reason", "");
        tr.buildings = s.value("buildings", std::size_t(0)), tr.grown = s.value("grown", std::size_t(0)), tr.peak_memory_mb = s.value("peak_memory_mb", 0.0);
        tr.seconds = s.value("seconds", std::map<std::string, double>{});
        try {
            if (s.contains("attribute_types")) tr.attribute_types = attribute_types_from(s["attribute_types"], summary.string());
        } catch (const json::exception& e) {
            throw Error(summary.string(), std::string("invalid attribute_types: ") + e.what());
        }
        for (const auto& [k, v] : tr.seconds) stage_seconds[k] += v;
        for (const auto& w : s.value("warnings", std::vector<std::string>{})) rep.warnings.push_back(w);
        if (tr.status == "failed") rep.warnings.push_back("tile " + std::to_string(t.index) + " failed: " + tr.reason);
        rep.peak_memory_mb = std::max(rep.peak_memory_mb, tr.peak_memory_mb);
        rep.tiles.push_back(tr);
    }
}

// The finished tiles' building lines (DIR/tiles/tile_K.jsonl), parsed in
// parallel (one task per tile), joined in tile order; the first bad line in
// tile order is the error, naming the file and line.
std::vector<Building> read_tile_buildings(const std::vector<TileReport>& tiles, const fs::path& dir) {
    std::vector<std::vector<Building>> per_tile(tiles.size());
    parallel_tasks_in_order(tiles.size(), 1, [&](std::size_t k) {
        if (tiles[k].status != "done") return;
        const fs::path path = dir / (tile_name(tiles[k].index) + ".jsonl");
        std::ifstream lines(path);
        std::string line;
        int n = 0;
        while (std::getline(lines, line)) {
            ++n;
            const std::string where = path.string() + " line " + std::to_string(n);
            try {
                per_tile[k].push_back(building_from_json(json::parse(line), where));
            } catch (const json::exception& e) {
                throw Error(where, std::string("invalid JSON: ") + e.what());
            }
        }
    });
    std::vector<Building> buildings;
    for (std::vector<Building>& tile : per_tile)
        for (Building& b : tile) buildings.push_back(std::move(b));
    return buildings;
}

// Errors for a run that cannot give a city model: every tile failed (empty
// models would read as "no buildings here"; the tiles' reports keep every
// reason), or no building was found (as in `footprints`).
void check_city_has_buildings(const RunManifest& m, const RunReport& rep, const std::vector<Building>& buildings, const std::string& out_dir,
                              const fs::path& dir) {
    if (!rep.tiles.empty() && std::all_of(rep.tiles.begin(), rep.tiles.end(), [](const TileReport& t) { return t.status == "failed"; }))
        throw Error(out_dir, "every tile failed (" + std::to_string(rep.tiles.size()) + " of " + std::to_string(rep.tiles.size()) +
                                 "; tile " + std::to_string(rep.tiles.front().index) + ": " + rep.tiles.front().reason + "); no city model written");
    if (buildings.empty()) {
        const RunOptions& o = m.options;
        const std::string& input = !o.footprints.empty() ? o.footprints : !o.cloud.empty() ? o.cloud : o.ortho;
        throw Error(input, "no building found in " + std::to_string(rep.tiles.size()) + " tile(s) (" +
                               (o.cloud.empty() ? "ortho only" : o.ortho.empty() ? "cloud only" : "ortho and cloud") +
                               "; the tiles' reports are in " + dir.string() + "); no city model written");
    }
}

// The city model's CRS: the input's or --out-crs horizontally (the buildings,
// worked on the grid's projected CRS, are reprojected to it), with the
// vertical datum of the cloud (as the tiles saw it) or --vertical-crs; a
// cloud without one is a warning in `rep`. `cloud_crs` receives the cloud's CRS.
CrsInfo city_model_crs(const RunManifest& m, const CrsInfo& grid_crs, std::vector<Building>& buildings, const std::string& out_dir, RunReport& rep,
                       CrsInfo& cloud_crs) {
    CrsInfo crs = run_output_crs(m, grid_crs);
    if (!same_horizontal_crs(crs, grid_crs)) {
        log::info("city model reprojected from the working CRS " + grid_crs.label() + " to " + crs.label());
        reproject_buildings(buildings, grid_crs, crs, out_dir);
    }
    cloud_crs = m.options.cloud.empty() ? CrsInfo{} : resolve_cloud_crs(m.options.cloud, m.options.cloud_crs).crs;
    crs = combine_with_vertical(crs, cloud_crs);
    if (!m.options.buildings.model.vertical_crs.empty() && !crs.vertical_epsg)
        crs = combine_with_vertical(crs, crs_from_user_input(m.options.buildings.model.vertical_crs, "--vertical-crs"));
    if (!m.options.cloud.empty() && !crs.vertical_epsg && crs.vertical_name.empty()) {
        rep.warnings.push_back(m.options.cloud + ": no vertical CRS: the city models' heights are written without a named height datum (give --vertical-crs, e.g. EPSG:5703 NAVD88, 5709 NAP, 5720 NGF-IGN69 height)");
        log::warning(rep.warnings.back());
    }
    return crs;
}

// keep_rasters: the tiles' DSM, DTM and nDSM as one VRT mosaic each (DIR/dsm.vrt, ...).
void mosaic_kept_rasters(const RunManifest& m, const std::string& out_dir) {
    if (!m.options.keep_rasters || !fs::exists(fs::path(out_dir) / "rasters")) return;
    for (const char* name : {"dsm", "dtm", "ndsm"}) {
        std::vector<std::string> parts;
        for (const TileSpec& t : m.tiles) {
            const fs::path f = fs::path(out_dir) / "rasters" / (tile_name(t.index) + "_" + name + ".tif");
            if (fs::exists(f)) parts.push_back(f.string());
        }
        if (!parts.empty()) build_vrt_mosaic((fs::path(out_dir) / (std::string(name) + ".vrt")).string(), parts);
    }
}

// The run's export options; without a cloud there is no solid, so the
// 3D-only formats (glTF, 3D Tiles) are dropped with a warning in `rep`.
ExportOptions run_export_options(const RunManifest& m, RunReport& rep) {
    ExportOptions eo = m.options.buildings.model;
    if (!m.options.cloud.empty()) return eo;
    const std::size_t before = eo.formats.size();
    eo.formats.erase(std::remove_if(eo.formats.begin(), eo.formats.end(), [](const std::string& f) { return f == "gltf" || f == "3dtiles"; }),
                     eo.formats.end());
    if (eo.formats.size() != before) {
        rep.warnings.push_back("no cloud, no solids: glTF and 3D Tiles not written");
        log::warning(rep.warnings.back());
    }
    return eo;
}

// The viewer page (DIR/view/index.html) when a GeoPackage was written; a
// failure is a warning in `rep`, not the run's error.
void write_run_view(const std::string& out_dir, RunReport& rep, std::map<std::string, double>& stage_seconds) {
    if (!fs::exists(fs::path(out_dir) / "buildings.gpkg")) return;
    const auto tv = std::chrono::steady_clock::now();
    try {
        ViewOptions vo;
        vo.overwrite = true;
        rep.model.files["view"] = write_view(out_dir, vo).path;
    } catch (const Error& e) {
        rep.warnings.push_back(std::string("viewer page: ") + e.what());
        log::warning(rep.warnings.back());
    }
    stage_seconds["view"] = rep.wall_seconds["view"] = since(tv);
}

// DIR/run_report.json: options, inputs with their CRSs, the model's CRS and
// the working CRS, the grid, every tile, times, memory, counts, files, warnings.
json run_report_json(const RunManifest& m, const RunReport& rep, const CrsInfo& crs, const CrsInfo& grid_crs, const CrsInfo& cloud_crs,
                     const std::map<std::string, double>& stage_seconds) {
    json j;
    j["cityforge_version"] = version();
    j["options"] = to_json(m.options);
    json inputs = json::object();
    if (!m.options.ortho.empty()) inputs["ortho"] = {{"path", m.options.ortho}, {"crs", read_raster_info(m.options.ortho).crs.label()}};
    if (!m.options.cloud.empty()) inputs["cloud"] = {{"path", m.options.cloud}, {"crs", cloud_crs.label()}};
    if (!m.options.footprints.empty())  // the file's own CRS (the working CRS is `working_crs`)
        inputs["footprints"] = {{"path", m.options.footprints},
                                {"crs", read_polygon_layer(m.options.footprints, m.options.buildings.heights.footprint_layer).crs.label()}};
    j["inputs"] = inputs;
    j["crs"] = crs.label();
    j["working_crs"] = grid_crs.label();
    j["grid"] = {{"width", m.grid.width}, {"height", m.grid.height}, {"geotransform", m.grid.transform.to_gdal()}};
    json tiles = json::array();
    for (const TileReport& t : rep.tiles)
        tiles.push_back({{"index", t.index}, {"status", t.status}, {"reason", t.reason}, {"buildings", t.buildings}, {"grown", t.grown}, {"seconds", t.seconds},
                         {"peak_memory_mb", t.peak_memory_mb}});
    j["tiles"] = tiles;
    j["stage_seconds"] = stage_seconds;
    j["wall_seconds"] = rep.wall_seconds;
    j["peak_memory_mb"] = rep.peak_memory_mb;
    j["counts"] = {{"buildings", rep.model.buildings},   {"with_lod1", rep.model.with_lod1}, {"valid_lod1", rep.model.valid_lod1},
                   {"with_lod2", rep.model.with_lod2},   {"valid_lod2", rep.model.valid_lod2}, {"status", rep.model.status_counts}};
    j["files"] = rep.model.files;
    j["warnings"] = rep.warnings;
    return j;
}
}  // namespace

RunReport merge_tiles(const RunManifest& m, const std::string& out_dir, const Progress& progress, const std::map<std::string, double>& phases) {
    const auto t0 = std::chrono::steady_clock::now();
    RunReport rep;
    rep.wall_seconds = phases;
    const fs::path dir = fs::path(out_dir) / "tiles";
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    std::map<std::string, double> stage_seconds;
    read_tile_reports(m, dir, rep, stage_seconds);
    std::vector<Building> buildings = read_tile_buildings(rep.tiles, dir);
    if (m.tiles_left_out > 0) rep.warnings.push_back(tiles_left_out_note(m));
    check_city_has_buildings(m, rep, buildings, out_dir, dir);
    progress(0.3, "tiles read");
    // One order whatever the tiling: by numeric id when ids are numbers, else as text.
    auto key = [](const std::string& id) {
        char* end = nullptr;
        const long long v = std::strtoll(id.c_str(), &end, 10);
        return std::pair<long long, std::string>(end && *end == 0 && !id.empty() ? v : LLONG_MAX, id);
    };
    std::sort(buildings.begin(), buildings.end(), [&](const Building& a, const Building& b) { return key(a.id) < key(b.id); });
    CrsInfo cloud_crs;
    const CrsInfo crs = city_model_crs(m, grid_crs, buildings, out_dir, rep, cloud_crs);
    CityModel model;
    Extent extent = empty_extent();
    for (const Building& b : buildings) include(extent, parts_extent(b.footprint));
    model.crs = model_crs_of(crs, extent);
    model.buildings = std::move(buildings);
    // The tile lines hold values only: the declared types come from the tile reports.
    for (const TileReport& t : rep.tiles)
        if (model.attribute_types.empty()) model.attribute_types = t.attribute_types;
    for (Building& b : model.buildings) complete_building(b, model.crs, m.options.buildings.model.validity);
    mosaic_kept_rasters(m, out_dir);
    const auto te = std::chrono::steady_clock::now();
    rep.wall_seconds["merge"] = std::chrono::duration<double>(te - t0).count();
    const ExportOptions eo = run_export_options(m, rep);
    rep.model = write_city_model(model, crs, out_dir, eo, progress.sub(0.3, 0.95));
    stage_seconds["export"] = rep.wall_seconds["export"] = since(te);
    write_run_view(out_dir, rep, stage_seconds);
    rep.buildings = rep.model.buildings, rep.valid_lod1 = rep.model.valid_lod1, rep.valid_lod2 = rep.model.valid_lod2;
    rep.peak_memory_mb = std::max(rep.peak_memory_mb, peak_memory_mb());
    rep.seconds = since(t0);
    double before_merge = 0.0;
    for (const auto& [phase, sec] : phases) before_merge += sec;
    rep.wall_seconds["total"] = before_merge + rep.seconds;
    rep.report_path = (fs::path(out_dir) / "run_report.json").string();
    write_text_file(rep.report_path, run_report_json(m, rep, crs, grid_crs, cloud_crs, stage_seconds).dump(2) + "\n");
    progress(1.0, "merged");
    return rep;
}

bool same_plan(const RunManifest& stored, const RunManifest& m) {
    auto work = [](const RunOptions& o) {
        json j = to_json(o);
        j.erase("threads"), j.erase("concurrent_tiles");
        return j;
    };
    return work(stored.options) == work(m.options) && stored.tiles.size() == m.tiles.size() && stored.overlap_px == m.overlap_px;
}

namespace {
// Whether a tile's report is final for rank 0's merge: it exists and, for a
// multi-rank job with an id, says "done" or was written by this job (a
// "failed" report of an earlier run is being redone by its rank).
bool tile_report_ready(const fs::path& summary, const std::string& job) {
    if (!fs::exists(summary)) return false;
    if (job.empty()) return true;
    const auto r = read_tile_report_state(summary);  // unreadable: being replaced, or damaged; its rank rewrites it
    return r && (r->status == "done" || r->job == job);
}
}  // namespace

double estimated_tile_bytes(double window_points, double window_pixels) { return 100.0 * window_points + 50.0 * window_pixels; }

int choose_concurrent_tiles(int requested, int threads, std::size_t tiles, double tile_bytes, double usable_bytes) {
    threads = std::max(1, threads);
    if (requested > 0) return std::min(requested, threads);
    if (threads < 2 || tiles < 2) return 1;
    return usable_bytes <= 0.0 || 2.0 * tile_bytes <= 0.5 * usable_bytes ? 2 : 1;
}

namespace {
// Points of the run's largest tile window: exact from the split's tile files
// when the cloud was split; else twice the cloud's mean density over the
// largest window (the header's count, or for a text cloud without one, a
// point per 20 bytes of the file: more points than any XYZ line holds).
double largest_tile_points(const RunManifest& m, const std::string& out_dir, double largest_px) {
    const RunOptions& o = m.options;
    if (o.cloud.empty()) return 0.0;
    if (fs::exists(fs::path(out_dir) / "cloud_tiles" / "complete")) {
        double most = 0.0;
        for (const TileSpec& t : m.tiles)
            if (const fs::path p = tile_cloud_path(out_dir, t.index); fs::exists(p)) {
                try {
                    most = std::max(most, double(CloudReader(p.string()).announced_points()));
                } catch (const Error&) {  // a damaged tile file: that tile fails and says why, the others run
                }
            }
        return most;
    }
    const CloudReader reader(o.cloud);
    double points = double(reader.announced_points());
    if (points == 0.0) {
        std::error_code ec;
        const auto bytes = fs::file_size(o.cloud, ec);
        points = ec ? 0.0 : double(bytes) / 20.0;
    }
    const double grid_px = std::max(1.0, double(m.grid.width) * double(m.grid.height));
    return 2.0 * points * std::min(1.0, largest_px / grid_px);
}

// The run's tiles at once (choose_concurrent_tiles), the automatic choice logged.
int concurrent_tiles_of(const RunManifest& m, const std::string& out_dir) {
    const RunOptions& o = m.options;
    const int threads = o.threads > 0 ? o.threads : static_cast<int>(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
    if (o.concurrent_tiles > 0 || threads < 2 || m.tiles.size() < 2) return choose_concurrent_tiles(o.concurrent_tiles, threads, m.tiles.size(), 0.0, 0.0);
    double largest_px = 0.0;
    for (const TileSpec& t : m.tiles) largest_px = std::max(largest_px, double(t.window.width) * double(t.window.height));
    const double tile_bytes = estimated_tile_bytes(largest_tile_points(m, out_dir, largest_px), largest_px);
    const double usable = usable_memory_bytes();
    const int at_once = choose_concurrent_tiles(0, threads, m.tiles.size(), tile_bytes, usable);
    log::info(std::string(at_once == 2 ? "2 tiles at once" : "1 tile at a time") + " (about " + format_bytes(tile_bytes) + " per tile, " +
              format_bytes(usable) + " usable; --concurrent-tiles sets it)");
    return at_once;
}
}  // namespace

RunReport run_city(const RunManifest& m, const std::string& out_dir, const RunShare& share, const Progress& progress) {
    if (share.size < 1 || share.rank < 0 || share.rank >= share.size) throw Error("--mpi", "bad rank/size");
    std::unique_ptr<tbb::global_control> limit;
    if (m.options.threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, m.options.threads);
    ensure_directory(out_dir);
    if (share.size == 1) {
        // Temporaries of an interrupted run (killed while writing) are ours to
        // remove; with several ranks another host may still be writing them.
        std::size_t removed = 0;
        for (const char* sub : {"", "tiles", "cloud_tiles", "rasters"}) removed += remove_stale_temporaries(fs::path(out_dir) / sub);
        if (removed) log::info("removed " + std::to_string(removed) + " temporaries of an interrupted run in " + out_dir);
    }
    // Resuming reuses finished tiles: only when they were made with the same plan.
    const fs::path stored = fs::path(out_dir) / "manifest.json";
    const std::string plan_path = stored.string();
    if (fs::exists(stored)) {
        const RunManifest before = read_manifest(plan_path);
        if (!same_plan(before, m))
            throw Error(out_dir, "holds a run with other options or tiles; resume with the same options or use a new folder");
    } else if (share.rank == 0) {
        write_manifest(plan_path, m);
    }
    const auto run_start = std::chrono::steady_clock::now();
    // One pass over the cloud for all tiles (rank 0); the other ranks wait for it.
    if (share.rank == 0) {
        split_cloud(m, out_dir);
    } else {
        const fs::path dir = fs::path(out_dir) / "cloud_tiles";
        while (!fs::exists(dir / "complete") && !fs::exists(dir / "not_split") && since(run_start) < share.wait_seconds)
            std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    std::map<std::string, double> phases{{"split", since(run_start)}};
    progress(0.05, "cloud split");
    std::vector<int> mine;
    for (const TileSpec& t : m.tiles)
        if (t.index % share.size == share.rank) mine.push_back(t.index);
    const Progress tiles_progress = progress.sub(0.05, share.rank == 0 ? 0.85 : 1.0);
    // Tiles at once: each a thread taking the next tile; their inner
    // parallel steps share the run's TBB workers. Every tile writes only its
    // own files, so the outputs are the same for any count.
    ensure_directory(fs::path(out_dir) / "tiles");
    if (m.options.keep_rasters) ensure_directory(fs::path(out_dir) / "rasters");
    const std::size_t at_once = std::min<std::size_t>(mine.size(), std::size_t(concurrent_tiles_of(m, out_dir)));
    // --threads N is the whole run's: each tile's thread is one of them.
    std::unique_ptr<tbb::global_control> tile_threads;
    if (m.options.threads > 0 && at_once > 1)
        tile_threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                      std::max<std::size_t>(1, std::size_t(m.options.threads) - at_once + 1));
    // With several ranks, rank 0 tells this job's reports from older ones by
    // the job id; without one, a failed tile of an earlier run is kept as it is.
    const TileResume resume{share.size == 1 || !share.job.empty(), share.job};
    if (!resume.rerun_failed && share.rank == 0)
        log::warning("no MPI job id in the environment: tiles that failed in an earlier run of " + out_dir + " are not run again");
    std::atomic<std::size_t> next{0};
    std::size_t finished = 0;
    std::mutex finished_mutex;
    std::exception_ptr failure;
    auto work = [&]() {
        try {
            for (std::size_t i = next++; i < mine.size(); i = next++) {
                const TileReport r = run_tile(m, mine[i], out_dir, {}, resume);
                std::lock_guard lock(finished_mutex);
                ++finished;
                std::ostringstream msg;  // the progress line adds the ETA
                msg << "tile " << finished << "/" << mine.size() << " (" << r.status << ")";
                tiles_progress(double(finished) / double(mine.size()), msg.str());
            }
        } catch (...) {
            next = mine.size();  // the other threads stop after their tile
            std::lock_guard lock(finished_mutex);
            if (!failure) failure = std::current_exception();
        }
    };
    std::vector<std::thread> workers;
    for (std::size_t k = 1; k < at_once; ++k) {
        try {
            workers.emplace_back(work);
        } catch (const std::system_error&) {
            break;  // no thread to be had: the threads started (and this one) do the tiles
        }
    }
    work();
    for (std::thread& w : workers) w.join();
    if (failure) std::rethrow_exception(failure);
    phases["tiles"] = since(run_start) - phases["split"];
    if (share.rank != 0) return {};
    // Rank 0 merges once every tile has its report.
    const auto wait0 = std::chrono::steady_clock::now();
    for (;;) {
        bool all = true;
        for (const TileSpec& t : m.tiles) all = all && tile_report_ready(fs::path(out_dir) / "tiles" / (tile_name(t.index) + ".json"), share.size > 1 ? share.job : "");
        if (all) break;
        if (since(wait0) > share.wait_seconds) throw Error(out_dir, "other ranks' tiles did not finish in time");
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    if (share.size > 1) phases["wait"] = since(wait0);
    RunReport rep = merge_tiles(m, out_dir, progress.sub(0.85, 1.0), phases);
    rep.seconds = since(run_start);
    return rep;
}

}  // namespace cityforge
