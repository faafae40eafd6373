#include "pipeline/city_run.hpp"
#include "pipeline/view_run.hpp"

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <sys/resource.h>
#include <tbb/global_control.h>
#include <thread>

#include "cloud/cloud_reader.hpp"
#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "core/version.hpp"
#include "crs/crs.hpp"
#include "footprint/building_mask.hpp"
#include "io/cloud_crs.hpp"
#include "io/vector.hpp"
#include "model/building_json.hpp"
#include "pipeline/cloud_cells.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

namespace cityforge {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

double peak_memory_mb() {
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return double(ru.ru_maxrss) / 1024.0;
}

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

}  // namespace

void RunOptions::validate() const {
    if (cloud.empty() && ortho.empty()) throw Error("--ortho", "give an ortho, a cloud, or both");
    if (cloud.empty() && !footprints.empty()) throw Error("--cloud", "heights for given footprints need a dense point cloud");
    if (ortho.empty() && footprints.empty()) throw Error("--ortho", "give the ortho (its grid and CRS) or existing --footprints");
    if (tile_size_px < 64) throw Error("--tile-size", "must be at least 64 pixels");
    if (!(overlap_m >= 0)) throw Error("--overlap-m", "must be >= 0");
    if (threads < 0) throw Error("--threads", "must be >= 0");
    if (!(footprint_grid_m > 0)) throw Error("footprint_grid_m", "must be > 0");
    buildings.validate();
    if (footprints.empty()) extraction.mask.validate();
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
            {"tile_size_px", o.tile_size_px},
            {"overlap_m", o.overlap_m},
            {"threads", o.threads},
            {"keep_rasters", o.keep_rasters},
            {"extraction",
             {{"min_height_m", m.min_height_m},
              {"min_area_m2", m.min_area_m2},
              {"min_hole_m2", m.min_hole_m2},
              {"opening_px", m.opening_radius_px},
              {"mode", to_string(o.extraction.mode)},
              {"cloud_cell_px", o.extraction.cloud_cell_factor},
              {"split_step_m", m.split_step_m},
              {"min_split_part_m2", m.min_split_part_m2},
              {"fit", to_string(o.extraction.fit)},
              {"fit_tolerance_pct", o.extraction.recursive.tolerance_pct},
              {"simplify_m", o.extraction.simplify_m},
              {"footprint_grid_m", o.footprint_grid_m}}},
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
             {{"formats", e.formats}, {"lods", e.lods}, {"geojson_crs", e.geojson_crs}, {"vertical_crs", e.vertical_crs}, {"id_field", e.id_field}}}};
}

RunOptions run_options_from_json(const json& j, const std::string& where, RunOptions o) {
    check_keys(j, {"ortho", "cloud", "cloud_crs", "footprints", "tile_size_px", "overlap_m", "threads", "keep_rasters", "extraction", "cleaning",
                   "heights", "roofs", "export"},
               where);
    take(j, "keep_rasters", o.keep_rasters, where);
    take(j, "ortho", o.ortho, where), take(j, "cloud", o.cloud, where), take(j, "cloud_crs", o.cloud_crs, where);
    take(j, "footprints", o.footprints, where), take(j, "tile_size_px", o.tile_size_px, where);
    take(j, "overlap_m", o.overlap_m, where), take(j, "threads", o.threads, where);
    if (j.contains("extraction")) {
        const json& x = j["extraction"];
        const std::string w = where + ": extraction";
        check_keys(x, {"mode", "cloud_cell_px", "min_height_m", "min_area_m2", "min_hole_m2", "opening_px", "split_step_m", "min_split_part_m2", "fit", "fit_tolerance_pct", "simplify_m", "footprint_grid_m"}, w);
        take(x, "min_height_m", o.extraction.mask.min_height_m, w), take(x, "min_area_m2", o.extraction.mask.min_area_m2, w);
        take(x, "min_hole_m2", o.extraction.mask.min_hole_m2, w), take(x, "opening_px", o.extraction.mask.opening_radius_px, w);
        take(x, "cloud_cell_px", o.extraction.cloud_cell_factor, w);
        take(x, "split_step_m", o.extraction.mask.split_step_m, w), take(x, "min_split_part_m2", o.extraction.mask.min_split_part_m2, w);
        take(x, "fit_tolerance_pct", o.extraction.recursive.tolerance_pct, w), take(x, "simplify_m", o.extraction.simplify_m, w);
        take(x, "footprint_grid_m", o.footprint_grid_m, w);
        if (x.contains("mode")) {
            std::string mode;
            take(x, "mode", mode, w);
            o.extraction.mode = detection_mode_from_string(mode);
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
        check_keys(x, {"formats", "lods", "geojson_crs", "vertical_crs", "id_field"}, w);
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

RunManifest plan_run(const RunOptions& in) {
    RunOptions o = run_options_from_json(to_json(in), "options", in);  // normalised: shared cleaning options
    o.validate();
    RunManifest m;
    m.options = o;
    double gsd_m = 0.0;
    if (!o.ortho.empty()) {
        const RasterInfo info = read_raster_info(o.ortho);
        if (info.crs.geographic) throw Error(o.ortho, "the ortho is in a geographic CRS; city models need a projected CRS");
        m.grid = {info.transform, info.width, info.height};
        m.crs_wkt = info.crs.wkt;
        gsd_m = std::abs(info.transform.pixel_width) * info.crs.linear_unit_m;
    } else {
        const PolygonLayer fp = read_polygon_layer(o.footprints, o.buildings.heights.footprint_layer);
        if (fp.crs.empty() || fp.crs.geographic) throw Error(o.footprints, "footprints need a projected CRS");
        Extent e = empty_extent();
        for (const Feature& f : fp.features) include(e, parts_extent(f.geometry));
        const double cell = o.footprint_grid_m / fp.crs.linear_unit_m;
        const double x0 = std::floor(e.min_x / cell) * cell, y1 = std::ceil(e.max_y / cell) * cell;
        m.grid = {GeoTransform{x0, cell, y1, -cell}, static_cast<int>(std::ceil((e.max_x - x0) / cell)) + 1,
                  static_cast<int>(std::ceil((y1 - e.min_y) / cell)) + 1};
        m.crs_wkt = fp.crs.wkt;
        gsd_m = o.footprint_grid_m;
    }
    m.overlap_px = static_cast<int>(std::ceil(o.overlap_m / gsd_m));
    if (o.cloud.empty()) {
        // Ortho only: segmentation merges regions across the whole raster, so it runs as one tile.
        m.options.tile_size_px = std::max(m.grid.width, m.grid.height);
        m.overlap_px = 0;
        m.tiles.push_back({0, {0, 0, m.grid.width, m.grid.height}, {0, 0, m.grid.width, m.grid.height}});
        return m;
    }
    // The outlier filter's limit, measured once on a sample fixed by the grid
    // (its central 400 m square), so that every tile filters alike.
    if (m.options.buildings.heights.outliers.enabled && !(m.options.buildings.heights.outliers.max_mean_distance > 0)) {
        const CloudSample sample = sample_cloud(o.cloud, o.cloud_crs, crs_from_wkt(m.crs_wkt, "grid"), o.buildings.heights.outliers,
                                                m.grid.transform.pixel_to_map({m.grid.width / 2.0, m.grid.height / 2.0}));
        if (!(sample.outlier_limit_m > 0)) throw Error(o.cloud, "no points in the centre of the grid; is the cloud over the ortho?");
        m.options.buildings.heights.outliers.max_mean_distance = sample.outlier_limit_m;
        m.options.extraction.outliers.max_mean_distance = sample.outlier_limit_m;
        if (m.options.extraction.cloud_cell_factor == 0)
            m.options.extraction.cloud_cell_factor = cloud_cell_factor(sample.points_per_m2, std::abs(m.grid.transform.pixel_width) * crs_from_wkt(m.crs_wkt, "grid").linear_unit_m);
    }
    if (m.options.extraction.cloud_cell_factor == 0 && o.footprints.empty()) {
        // Density from the same central sample (the outlier limit was given).
        const CloudSample sample = sample_cloud(o.cloud, o.cloud_crs, crs_from_wkt(m.crs_wkt, "grid"), o.buildings.heights.outliers,
                                                m.grid.transform.pixel_to_map({m.grid.width / 2.0, m.grid.height / 2.0}));
        m.options.extraction.cloud_cell_factor = cloud_cell_factor(sample.points_per_m2, std::abs(m.grid.transform.pixel_width) * crs_from_wkt(m.crs_wkt, "grid").linear_unit_m);
    }
    const int ts = o.tile_size_px;
    int k = 0;
    for (int r = 0; r < m.grid.height; r += ts)
        for (int c = 0; c < m.grid.width; c += ts) {
            TileSpec t;
            t.index = k++;
            t.core = {c, r, std::min(ts, m.grid.width - c), std::min(ts, m.grid.height - r)};
            const int c0 = std::max(0, c - m.overlap_px), r0 = std::max(0, r - m.overlap_px);
            const int c1 = std::min(m.grid.width, c + t.core.width + m.overlap_px), r1 = std::min(m.grid.height, r + t.core.height + m.overlap_px);
            t.window = {c0, r0, c1 - c0, r1 - r0};
            m.tiles.push_back(t);
        }
    return m;
}

void write_manifest(const std::string& path, const RunManifest& m) {
    json j;
    j["cityforge_manifest"] = 1;
    j["cityforge_version"] = version();
    j["options"] = to_json(m.options);
    j["grid"] = {{"geotransform", m.grid.transform.to_gdal()}, {"width", m.grid.width}, {"height", m.grid.height}, {"crs_wkt", m.crs_wkt}};
    j["overlap_px"] = m.overlap_px;
    json tiles = json::array();
    for (const TileSpec& t : m.tiles)
        tiles.push_back({{"index", t.index},
                         {"core", {t.core.col, t.core.row, t.core.width, t.core.height}},
                         {"window", {t.window.col, t.window.row, t.window.width, t.window.height}}});
    j["tiles"] = tiles;
    write_text_file(path, j.dump(2) + "\n");
}

RunManifest read_manifest(const std::string& path) {
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

fs::path tile_cloud_path(const std::string& out_dir, int k) { return fs::path(out_dir) / "cloud_tiles" / (tile_name(k) + ".las"); }

// One streaming pass over a LAS cloud writes each tile window's points (in
// file order, on the source's integer grid, so coordinates are unchanged) to
// DIR/cloud_tiles/: each tile then reads its window, not the whole file.
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
    LasReader reader(o.cloud);
    const LasHeader header = reader.header();
    struct Window {
        Extent e;
        std::unique_ptr<LasWriter> writer;
        PointCloud pending;
    };
    std::vector<Window> windows;
    for (const TileSpec& t : m.tiles) {
        const MapPoint a = m.grid.transform.pixel_to_map({double(t.window.col), double(t.window.row)});
        const MapPoint b = m.grid.transform.pixel_to_map({double(t.window.col + t.window.width), double(t.window.row + t.window.height)});
        Window w;
        w.e = {std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
        w.writer = std::make_unique<LasWriter>(tile_cloud_path(out_dir, t.index).string(), header.scale, header.offset, cloud_crs.wkt);
        windows.push_back(std::move(w));
    }
    PointCloud chunk;
    auto flush = [](Window& w) {
        w.writer->write(w.pending);
        w.pending.clear();
    };
    while (true) {
        chunk.clear();
        if (reader.read_chunk(chunk, 1u << 20) == 0) break;
        for (Window& w : windows) {
            for (std::size_t i = 0; i < chunk.size(); ++i)
                if (chunk.x[i] >= w.e.min_x && chunk.x[i] < w.e.max_x && chunk.y[i] >= w.e.min_y && chunk.y[i] < w.e.max_y) w.pending.append(chunk, i);
            if (w.pending.size() >= (1u << 16)) flush(w);
        }
    }
    for (Window& w : windows) {
        flush(w);
        w.writer->close();
    }
    write_text_file(dir / "complete", "cloud split into " + std::to_string(windows.size()) + " tile windows\n");
}

// The buildings one tile owns, with their heights and LOD2, as building lines.
std::vector<Building> tile_buildings(const RunManifest& m, const TileSpec& t, const std::string& out_dir, TileReport& rep,
                                     std::vector<std::string>& warnings) {
    const RunOptions& o = m.options;
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    const double unit = grid_crs.linear_unit_m;
    const GeoTransform& gt = m.grid.transform;
    const MapPoint a = gt.pixel_to_map({double(t.window.col), double(t.window.row)});
    const MapPoint b = gt.pixel_to_map({double(t.window.col + t.window.width), double(t.window.row + t.window.height)});
    const Extent window_extent{std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)};
    const MapPoint ca = gt.pixel_to_map({double(t.core.col), double(t.core.row)});
    const MapPoint cb = gt.pixel_to_map({double(t.core.col + t.core.width), double(t.core.row + t.core.height)});

    auto t0 = std::chrono::steady_clock::now();
    if (o.cloud.empty()) {
        // Ortho-only: footprints from the segmentation, no heights (LOD0 only).
        const fs::path tmp = fs::path(out_dir) / "tiles" / "ortho_footprints.gpkg";
        FootprintsRunOptions fo = o.extraction;
        fo.ortho = o.ortho, fo.cloud.clear();
        run_footprints(tmp.string(), fo);
        const PolygonLayer layer = read_polygon_layer(tmp.string());
        fs::remove(tmp);
        ExportOptions eo = o.buildings.model;
        eo.id_field = "id";
        CityModel model = build_city_model(layer, grid_crs, eo, o.ortho);
        rep.seconds["footprints"] = since(t0);
        rep.buildings = model.buildings.size();
        warnings.push_back("no cloud: footprints from the ortho only (no heights, no LOD1/LOD2); ortho-only runs are not tiled");
        return std::move(model.buildings);
    }
    const fs::path part = tile_cloud_path(out_dir, t.index);
    const bool split = fs::exists(part.parent_path() / "complete");
    PreparedCloud pc = prepare_cloud(split ? part.string() : o.cloud, o.cloud_crs, grid_crs, o.buildings.heights.outliers,
                                     o.buildings.heights.ground, &window_extent);
    rep.seconds["cloud"] = since(t0);
    PolygonLayer footprints;
    footprints.crs = pc.crs.empty() ? grid_crs : pc.crs;
    if (!o.footprints.empty()) {
        // Given footprints: those whose bounding-box centre lies in the core.
        t0 = std::chrono::steady_clock::now();
        PolygonLayer all = read_polygon_layer(o.footprints, o.buildings.heights.footprint_layer);
        if (!same_horizontal_crs(all.crs, grid_crs)) throw Error(o.footprints, "footprints are not in the grid's CRS");
        footprints.field_names = all.field_names, footprints.field_types = all.field_types;
        const double cx0 = std::min(ca.x, cb.x), cx1 = std::max(ca.x, cb.x), cy0 = std::min(ca.y, cb.y), cy1 = std::max(ca.y, cb.y);
        const bool last_col = t.core.col + t.core.width == m.grid.width, last_row = t.core.row + t.core.height == m.grid.height;
        for (std::size_t i = 0; i < all.features.size(); ++i) {
            const Extent e = parts_extent(all.features[i].geometry);
            const double x = 0.5 * (e.min_x + e.max_x), y = 0.5 * (e.min_y + e.max_y);
            // Half-open cores (the grid's last row and column closed) own every point exactly once.
            const bool in_x = x >= cx0 && (x < cx1 || (last_col && x <= cx1));
            const bool in_y = y <= cy1 && (y > cy0 || (last_row && y >= cy0));
            if (!in_x || !in_y) continue;
            footprints.features.push_back(all.features[i]);
            footprints.fids.push_back(all.fids[i]);
            if (e.min_x < window_extent.min_x || e.max_x > window_extent.max_x || e.min_y < window_extent.min_y || e.max_y > window_extent.max_y)
                warnings.push_back("building fid " + std::to_string(all.fids[i]) + " is larger than the tile overlap; its points may be cut");
        }
        rep.seconds["footprints"] = since(t0);
    } else {
        // Extraction on the window: rasters, buildings, then only the buildings whose first pixel is in the core.
        t0 = std::chrono::steady_clock::now();
        const GridSpec wg{gt.window(t.window.col, t.window.row), t.window.width, t.window.height};
        if (pc.cloud.size() == 0) throw Error(o.cloud, "no points in tile " + std::to_string(t.index));
        BuildingMaskOptions mo = o.extraction.mask;
        mo.gsd_m = std::abs(gt.pixel_width) * unit;
        mo.min_height_m /= pc.crs.z_unit_m;
        WindowCloudCells wc = cloud_cells_on_window(pc, wg, t.window.col, t.window.row, std::max(1, o.extraction.cloud_cell_factor), unit, mo);
        CloudRasters rasters = std::move(wc.rasters);
        mo.split_step_m /= pc.crs.z_unit_m;
        // With the run's ortho the buildings are redrawn along it, unless the
        // config asks for the cloud alone.
        const DetectionMode detection = o.extraction.mode == DetectionMode::cloud_only ? DetectionMode::cloud_only : DetectionMode::ortho_cloud;
        const BuildingCells cells = std::move(wc.cells);
        BuildingMask mask = buildings_from_cells(cells, t.window.width, t.window.height, mo);
        if (detection == DetectionMode::ortho_cloud) {
            // Each building redrawn along the ortho from a crop around it
            // alone: the same buildings in any tiling.
            RasterReader ortho(o.ortho);
            const RasterInfo& oi = ortho.info();
            const Image<float> colours = ortho.read<float>(PixelWindow{t.window.col, t.window.row, t.window.width, t.window.height});
            const std::vector<uint8_t> valid = data_mask(colours, oi);
            SegmentClassifierOptions co = o.extraction.classifier;
            co.gsd_m = oi.gsd.x_m;
            const std::vector<uint8_t> vegetation = cells.used_classes ? std::vector<uint8_t>{} : vegetation_pixels(colours, co);
            OrthoRefineOptions ro = o.extraction.segmentation;
            ro.cloud_edges = o.extraction.cloud_cell_factor <= 1;
            refine_buildings_with_ortho(mask, cells, colours, valid, rasters.ndsm, 20.0 / pc.crs.z_unit_m, {}, vegetation, ro);
        }
        rep.seconds["detection"] = since(t0);
        if (o.keep_rasters) {
            // The core of each raster: tiles mosaic without overlap.
            const fs::path rdir = fs::path(out_dir) / "rasters";
            ensure_directory(rdir);
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
                write_geotiff((rdir / (tile_name(t.index) + "_" + name + ".tif")).string(), core, gt.window(t.core.col, t.core.row), pc.crs.wkt, wo);
            }
        }
        t0 = std::chrono::steady_clock::now();
        const int w = t.window.width, h = t.window.height;
        std::vector<int64_t> ids(mask.count + 1, 0);
        std::vector<uint8_t> owned(mask.count + 1, 0), cut(mask.count + 1, 0);
        for (int r = 0; r < h; ++r)
            for (int c = 0; c < w; ++c) {
                const uint32_t l = mask.labels.data[static_cast<std::size_t>(r) * w + c];
                if (!l) continue;
                if (r == 0 || c == 0 || r == h - 1 || c == w - 1) cut[l] = 1;
                if (ids[l]) continue;
                const int gc = t.window.col + c, gr = t.window.row + r;
                ids[l] = int64_t(gr) * m.grid.width + gc + 1;
                owned[l] = gc >= t.core.col && gc < t.core.col + t.core.width && gr >= t.core.row && gr < t.core.row + t.core.height;
            }
        FootprintsRunOptions fo = o.extraction;
        const FootprintTable table = footprint_table(mask, rasters.ndsm, gt, t.window.col, t.window.row, ids, to_string(detection), unit,
                                                     pc.crs.z_unit_m, footprints.crs, fo);
        rasters = CloudRasters{};  // free the window's rasters before the heights
        std::set<int64_t> keep;
        for (uint32_t l = 1; l <= mask.count; ++l)
            if (owned[l]) {
                keep.insert(ids[l]);
                // Touching the window's edge (not the grid's): larger than the overlap, cut.
                if (cut[l]) warnings.push_back("building " + std::to_string(ids[l]) + " in tile " + std::to_string(t.index) +
                                               " reaches the edge of the tile's overlap; raise --overlap-m");
            }
        for (const FieldDefinition& f : table.fields) footprints.field_names.push_back(f.name), footprints.field_types.push_back(f.type);
        for (const Feature& f : table.features) {
            const int64_t id = std::get<int64_t>(f.values[0]);
            if (!keep.count(id)) continue;
            footprints.features.push_back(f);
            footprints.fids.push_back(id);
        }
        rep.seconds["footprints"] = since(t0);
    }
    t0 = std::chrono::steady_clock::now();
    HeightsRunOptions ho = o.buildings.heights;
    ho.heights.keep_roof_points = true;
    const std::size_t n = footprints.features.size();
    const HeightsStage st = compute_heights_stage(std::move(footprints), std::move(pc), ho);
    rep.seconds["heights"] = since(t0);
    t0 = std::chrono::steady_clock::now();
    CrsInfo crs = st.table.crs;
    if (!o.buildings.model.vertical_crs.empty() && !crs.vertical_epsg)
        crs = combine_with_vertical(crs, crs_from_user_input(o.buildings.model.vertical_crs, "--vertical-crs"));
    RoofsRunReport rr;
    RoofsRunOptions ro = o.buildings;
    if (o.footprints.empty()) ro.model.id_field = "id";
    std::vector<Building> out;
    if (n) out = build_lod2_model(st, crs, ro, "tile " + std::to_string(t.index), rr).buildings;
    rep.seconds["roofs"] = since(t0);
    rep.buildings = out.size();
    return out;
}

}  // namespace

TileReport run_tile(const RunManifest& m, int k, const std::string& out_dir, const Progress& progress) {
    if (k < 0 || k >= static_cast<int>(m.tiles.size())) throw Error("--tile", "no tile " + std::to_string(k) + " (the manifest has " + std::to_string(m.tiles.size()) + ")");
    std::unique_ptr<tbb::global_control> limit;
    if (m.options.threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, m.options.threads);
    const fs::path dir = fs::path(out_dir) / "tiles";
    ensure_directory(dir);
    const fs::path lines = dir / (tile_name(k) + ".jsonl"), summary = dir / (tile_name(k) + ".json");
    TileReport rep;
    rep.index = k;
    if (fs::exists(summary)) {
        rep.status = "skipped";
        return rep;
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
    json j{{"index", k}, {"status", rep.status}, {"reason", rep.reason}, {"buildings", rep.buildings}, {"seconds", rep.seconds},
           {"peak_memory_mb", rep.peak_memory_mb}, {"warnings", warnings}};
    write_text_file(summary, j.dump(2) + "\n");
    progress(1.0, tile_name(k));
    return rep;
}

RunReport merge_tiles(const RunManifest& m, const std::string& out_dir, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    RunReport rep;
    const fs::path dir = fs::path(out_dir) / "tiles";
    const CrsInfo grid_crs = crs_from_wkt(m.crs_wkt, "manifest");
    std::vector<Building> buildings;
    std::map<std::string, double> stage_seconds;
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
        tr.buildings = s.value("buildings", std::size_t(0)), tr.peak_memory_mb = s.value("peak_memory_mb", 0.0);
        tr.seconds = s.value("seconds", std::map<std::string, double>{});
        for (const auto& [k, v] : tr.seconds) stage_seconds[k] += v;
        for (const auto& w : s.value("warnings", std::vector<std::string>{})) rep.warnings.push_back(w);
        if (tr.status == "failed") rep.warnings.push_back("tile " + std::to_string(t.index) + " failed: " + tr.reason);
        rep.peak_memory_mb = std::max(rep.peak_memory_mb, tr.peak_memory_mb);
        rep.tiles.push_back(tr);
        if (tr.status != "done") continue;
        std::ifstream lines(dir / (tile_name(t.index) + ".jsonl"));
        std::string line;
        int n = 0;
        while (std::getline(lines, line)) {
            ++n;
            const std::string where = (dir / (tile_name(t.index) + ".jsonl")).string() + " line " + std::to_string(n);
            try {
                buildings.push_back(building_from_json(json::parse(line), where));
            } catch (const json::exception& e) {
                throw Error(where, std::string("invalid JSON: ") + e.what());
            }
        }
    }
    progress(0.3, "tiles read");
    // One order whatever the tiling: by numeric id when ids are numbers, else as text.
    auto key = [](const std::string& id) {
        char* end = nullptr;
        const long long v = std::strtoll(id.c_str(), &end, 10);
        return std::pair<long long, std::string>(end && *end == 0 && !id.empty() ? v : LLONG_MAX, id);
    };
    std::sort(buildings.begin(), buildings.end(), [&](const Building& a, const Building& b) { return key(a.id) < key(b.id); });
    CrsInfo crs = grid_crs;
    // The vertical datum: from the cloud (as the tiles saw it) or the option.
    const CrsInfo cloud_crs = m.options.cloud.empty() ? CrsInfo{} : resolve_cloud_crs(m.options.cloud, m.options.cloud_crs).crs;
    crs = combine_with_vertical(crs, cloud_crs);
    if (!m.options.buildings.model.vertical_crs.empty() && !crs.vertical_epsg)
        crs = combine_with_vertical(crs, crs_from_user_input(m.options.buildings.model.vertical_crs, "--vertical-crs"));
    CityModel model;
    model.crs = model_crs_of(crs);
    model.buildings = std::move(buildings);
    for (Building& b : model.buildings) complete_building(b, model.crs, m.options.buildings.model.validity);
    if (m.options.keep_rasters && fs::exists(fs::path(out_dir) / "rasters")) {
        for (const char* name : {"dsm", "dtm", "ndsm"}) {
            std::vector<std::string> parts;
            for (const TileSpec& t : m.tiles) {
                const fs::path f = fs::path(out_dir) / "rasters" / (tile_name(t.index) + "_" + name + ".tif");
                if (fs::exists(f)) parts.push_back(f.string());
            }
            if (!parts.empty()) build_vrt_mosaic((fs::path(out_dir) / (std::string(name) + ".vrt")).string(), parts);
        }
    }
    const auto te = std::chrono::steady_clock::now();
    rep.model = write_city_model(model, crs, out_dir, m.options.buildings.model, progress.sub(0.3, 0.95));
    stage_seconds["export"] = since(te);
    if (fs::exists(fs::path(out_dir) / "buildings.gpkg")) {  // the viewer page, DIR/view/index.html
        const auto tv = std::chrono::steady_clock::now();
        try {
            ViewOptions vo;
            vo.overwrite = true;
            rep.model.files["view"] = write_view(out_dir, vo).path;
        } catch (const Error& e) {
            rep.warnings.push_back(std::string("viewer page: ") + e.what());
            log::warning(rep.warnings.back());
        }
        stage_seconds["view"] = since(tv);
    }
    rep.buildings = rep.model.buildings, rep.valid_lod1 = rep.model.valid_lod1, rep.valid_lod2 = rep.model.valid_lod2;
    rep.peak_memory_mb = std::max(rep.peak_memory_mb, peak_memory_mb());
    rep.seconds = since(t0);

    json j;
    j["cityforge_version"] = version();
    j["options"] = to_json(m.options);
    json inputs = json::object();
    if (!m.options.ortho.empty()) inputs["ortho"] = {{"path", m.options.ortho}, {"crs", grid_crs.label()}};
    if (!m.options.cloud.empty()) inputs["cloud"] = {{"path", m.options.cloud}, {"crs", cloud_crs.label()}};
    if (!m.options.footprints.empty()) inputs["footprints"] = {{"path", m.options.footprints}, {"crs", grid_crs.label()}};
    j["inputs"] = inputs;
    j["crs"] = crs.label();
    j["grid"] = {{"width", m.grid.width}, {"height", m.grid.height}, {"geotransform", m.grid.transform.to_gdal()}};
    json tiles = json::array();
    for (const TileReport& t : rep.tiles)
        tiles.push_back({{"index", t.index}, {"status", t.status}, {"reason", t.reason}, {"buildings", t.buildings}, {"seconds", t.seconds},
                         {"peak_memory_mb", t.peak_memory_mb}});
    j["tiles"] = tiles;
    j["stage_seconds"] = stage_seconds;
    j["peak_memory_mb"] = rep.peak_memory_mb;
    j["counts"] = {{"buildings", rep.model.buildings},   {"with_lod1", rep.model.with_lod1}, {"valid_lod1", rep.model.valid_lod1},
                   {"with_lod2", rep.model.with_lod2},   {"valid_lod2", rep.model.valid_lod2}, {"status", rep.model.status_counts}};
    j["files"] = rep.model.files;
    j["warnings"] = rep.warnings;
    rep.report_path = (fs::path(out_dir) / "run_report.json").string();
    write_text_file(rep.report_path, j.dump(2) + "\n");
    progress(1.0, "merged");
    return rep;
}

RunReport run_city(const RunManifest& m, const std::string& out_dir, const RunShare& share, const Progress& progress) {
    if (share.size < 1 || share.rank < 0 || share.rank >= share.size) throw Error("--mpi", "bad rank/size");
    std::unique_ptr<tbb::global_control> limit;
    if (m.options.threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, m.options.threads);
    ensure_directory(out_dir);
    // Resuming reuses finished tiles: only when they were made with the same plan.
    const fs::path stored = fs::path(out_dir) / "manifest.json";
    const std::string plan_path = stored.string();
    if (fs::exists(stored)) {
        const RunManifest before = read_manifest(plan_path);
        if (to_json(before.options) != to_json(m.options) || before.tiles.size() != m.tiles.size() || before.overlap_px != m.overlap_px)
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
    progress(0.05, "cloud split");
    std::vector<int> mine;
    for (const TileSpec& t : m.tiles)
        if (t.index % share.size == share.rank) mine.push_back(t.index);
    const auto t0 = std::chrono::steady_clock::now();
    const Progress tiles_progress = progress.sub(0.05, share.rank == 0 ? 0.85 : 1.0);
    for (std::size_t i = 0; i < mine.size(); ++i) {
        const TileReport r = run_tile(m, mine[i], out_dir);
        const double done = double(i + 1) / double(mine.size());
        const double eta = since(t0) / done * (1.0 - done);
        std::ostringstream msg;
        msg << "tile " << i + 1 << "/" << mine.size() << " (" << r.status << "), ETA " << static_cast<int>(eta) << " s";
        tiles_progress(done, msg.str());
    }
    if (share.rank != 0) return {};
    // Rank 0 merges once every tile has its report.
    const auto wait0 = std::chrono::steady_clock::now();
    for (;;) {
        bool all = true;
        for (const TileSpec& t : m.tiles) all = all && fs::exists(fs::path(out_dir) / "tiles" / (tile_name(t.index) + ".json"));
        if (all) break;
        if (since(wait0) > share.wait_seconds) throw Error(out_dir, "other ranks' tiles did not finish in time");
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    RunReport rep = merge_tiles(m, out_dir, progress.sub(0.85, 1.0));
    rep.seconds = since(run_start);
    return rep;
}

}  // namespace cityforge
