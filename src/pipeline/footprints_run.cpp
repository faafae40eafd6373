#include "pipeline/footprints_run.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <new>

#include "cloud/cloud_rasters.hpp"
#include "core/error.hpp"
#include "core/parallel.hpp"
#include "core/memory.hpp"
#include "core/log.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"
#include "heights/building_heights.hpp"
#include "io/vector.hpp"
#include "cloud/cloud_reader.hpp"
#include "io/cloud_crs.hpp"
#include "pipeline/cloud_windows.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"
#include "pipeline/cloud_cells.hpp"
#include "footprint/ortho_refine.hpp"
#include "pipeline/segment_raster.hpp"
#include "pipeline/train_run.hpp"
#include "segment/boundary_refine.hpp"
#include "segment/region_merging.hpp"

namespace cityforge {

DetectionMode detection_mode_from_string(const std::string& s) {
    if (s == "auto") return DetectionMode::automatic;
    if (s == "ortho_cloud") return DetectionMode::ortho_cloud;
    if (s == "ortho_only") return DetectionMode::ortho_only;
    if (s == "cloud_only") return DetectionMode::cloud_only;
    throw Error("--mode", "must be auto, ortho_cloud, ortho_only or cloud_only, not '" + s + "'");
}
std::string to_string(DetectionMode m) {
    switch (m) {
        case DetectionMode::automatic: return "auto";
        case DetectionMode::ortho_cloud: return "ortho_cloud";
        case DetectionMode::ortho_only: return "ortho_only";
        case DetectionMode::cloud_only: return "cloud_only";
    }
    return "auto";
}

OrthoDetector ortho_detector_from_string(const std::string& s) {
    if (s == "auto") return OrthoDetector::automatic;
    if (s == "model") return OrthoDetector::model;
    if (s == "rules") return OrthoDetector::rules;
    throw Error("--detector", "must be auto, model or rules, not '" + s + "'");
}
std::string to_string(OrthoDetector d) { return d == OrthoDetector::automatic ? "auto" : d == OrthoDetector::model ? "model" : "rules"; }

void FootprintsRunOptions::validate() const {
    const bool heights = !cloud.empty() || !ndsm.empty() || ndsm_band > 0;
    if (!heights && ortho.empty()) throw Error("--cloud", "give a point cloud (or an nDSM), an ortho (--ortho) or both");
    if (int(!cloud.empty()) + int(!ndsm.empty()) + int(ndsm_band > 0) > 1)
        throw Error("--ndsm", "give one height source: --cloud, --ndsm or --ndsm-band");
    if (ndsm_band < 0) throw Error("--ndsm-band", "must be >= 1");
    if (nir_band < 0) throw Error("--nir-band", "must be >= 1");
    if (cloud_cell_factor < 0 || cloud_cell_factor > 64) throw Error("--cloud-cell-px", "must be between 0 (automatic) and 64");
    if (!(cloud_tile_m > 0) || !(cloud_overlap_m >= 0)) throw Error("--tile-m", "cloud tiles must be > 0 m and their overlap >= 0 m");
    if (nir_band > 0 && ortho.empty()) throw Error("--nir-band", "needs the ortho that holds the band (--ortho)");
    if (nir_band > 0 && nir_band == ndsm_band) throw Error("--nir-band", "is the nDSM band");
    if (ndsm_band > 0 && ortho.empty()) throw Error("--ndsm-band", "needs the ortho that holds the band (--ortho)");
    if ((mode == DetectionMode::ortho_cloud || mode == DetectionMode::cloud_only) && !heights)
        throw Error("--mode", to_string(mode) + " needs a point cloud (--cloud) or an nDSM (--ndsm, --ndsm-band)");
    if ((mode == DetectionMode::ortho_cloud || mode == DetectionMode::ortho_only) && ortho.empty())
        throw Error("--mode", to_string(mode) + " needs an ortho (--ortho)");
    if (!segments.empty() && mode == DetectionMode::cloud_only) throw Error("--segments", "segments need an ortho mode, not cloud_only");
    if (!segments.empty() && ortho.empty()) throw Error("--segments", "segments need the ortho they were made from (--ortho)");
    if (!model.empty() && detector == OrthoDetector::rules) throw Error("--model", "is used by --detector model, not rules");
    if (!segments.empty() && detector == OrthoDetector::model)
        throw Error("--segments", "the model segments the ortho itself (at its own scales); --segments is for --detector rules");
    if (!segments.empty() && !model.empty()) throw Error("--segments", "the model segments the ortho itself; give --model or --segments");
    segmentation.validate();
    if (!(simplify_m >= 0.0)) throw Error("--simplify-m", "must be >= 0");
    mask.validate();
    seams.validate();
    curved.validate();
}

std::vector<std::vector<Polygon>> vectorize_window(const Image<uint32_t>& labels, const GeoTransform& grid, int col0, int row0) {
    // Traced in pixel units, then placed with integer pixel offsets: every
    // window of a grid gives the very same coordinates for the same pixels.
    std::vector<std::vector<Polygon>> polys = vectorize_all(labels, GeoTransform{0.0, 1.0, 0.0, -1.0});
    auto place = [&](Ring& r) {
        for (MapPoint& q : r) q = grid.pixel_to_map({double(col0) + q.x, double(row0) - q.y});
    };
    for (auto& parts : polys)
        for (Polygon& p : parts) {
            place(p.outer);
            for (Ring& h : p.holes) place(h);
        }
    return polys;
}

FootprintTable footprint_table(const BuildingMask& mask, const Image<float>& ndsm, const GeoTransform& grid, int col0, int row0,
                               const std::vector<int64_t>& ids, const std::string& mode, double unit, double z_unit, const CrsInfo& crs,
                               const FootprintsRunOptions& o, const std::vector<std::string>& sources) {
    FootprintTable table;
    const std::string mode_source = mode == "ortho_only" ? "image_model" : "cloud";
    const auto polygons = vectorize_window(mask.labels, grid, col0, row0);
    // Median nDSM per building, a first height cue for the output.
    std::vector<std::vector<double>> heights(mask.count + 1);
    for (std::size_t k = 0; k < mask.labels.data.size(); ++k)
        if (const uint32_t id = mask.labels.data[k]; id && !ndsm.data.empty() && !std::isnan(ndsm.data[k])) heights[id].push_back(ndsm.data[k]);
    table.fields = {
        {"id", FieldType::integer},           {"mode", FieldType::string},         {"source", FieldType::string},
        {"fit", FieldType::string},
        {"status", FieldType::string},        {"reason", FieldType::string},       {"area_m2", FieldType::real},
        {"raw_area_m2", FieldType::real},     {"geodesic_area_m2", FieldType::real}, {"perimeter_m", FieldType::real},
        {"orientation_deg", FieldType::real}, {"fit_area_error_pct", FieldType::real}, {"fit_iou", FieldType::real},
        {"n_vertices", FieldType::integer},   {"height_p50_m", FieldType::real}};
    // Each building's outline and fit is a task of its own (rows by label);
    // the table is then filled in label order, so its bytes do not depend
    // on the thread count.
    struct Row {
        bool present = false;
        Feature feature;
        double error_pct = 0.0;
    };
    std::vector<Row> rows(std::size_t(mask.count) + 1);
    // An error is that of the lowest failing label, whatever the scheduling.
    OutlineFitOptions fit_options;
    fit_options.fit = o.fit, fit_options.simplify_m = o.simplify_m;
    fit_options.recursive = o.recursive, fit_options.regularize = o.regularize, fit_options.curved = o.curved;
    parallel_tasks_in_order(mask.count, 8, [&](std::size_t task) {
        const uint32_t id = static_cast<uint32_t>(task + 1);
        if (id >= polygons.size() || polygons[id].empty()) return;  // a label left empty (a crown dropped, absorbed)
        // One polygon per building: its largest part (the detection keeps
        // buildings in one part; this guards any other source).
        const Polygon& pixels = *std::max_element(polygons[id].begin(), polygons[id].end(),
                                                  [](const Polygon& a, const Polygon& b) { return polygon_area(a) < polygon_area(b); });
        const FittedOutline fitted = fit_building_outline(pixels, fit_options, grid.pixel_width, unit);
        const Polygon& out = fitted.outline;
        std::vector<Ring> rings{out.outer};
        for (const Ring& h : out.holes) rings.push_back(h);
        std::size_t vertices = out.outer.size();
        for (const Ring& h : out.holes) vertices += h.size();
        const std::optional<double> h50 = percentile(heights[id], 50.0);
        const std::string& source = id < sources.size() && !sources[id].empty() ? sources[id] : mode_source;
        Feature f;
        f.geometry = {out};
        // The id (when not given) is the row's number, set below in label order.
        f.values = {ids.empty() ? int64_t(0) : ids[id], mode, source, fitted.fit, fitted.status, fitted.reason,
                    polygon_area(out) * unit * unit, polygon_area(fitted.raw) * unit * unit,
                    crs.empty() ? AttributeValue() : AttributeValue(geodesic_area_m2(rings, crs)),
                    polygon_perimeter(out) * unit, fitted.orientation_deg, fitted.area_error_pct, fitted.iou, int64_t(vertices),
                    h50 ? AttributeValue(*h50 * z_unit) : AttributeValue()};
        rows[id].present = true, rows[id].feature = std::move(f), rows[id].error_pct = fitted.area_error_pct;
    });
    std::vector<Feature>& features = table.features;
    double error_sum = 0.0;
    for (Row& row : rows) {
        if (!row.present) continue;
        if (ids.empty()) row.feature.values[0] = int64_t(features.size() + 1);
        error_sum += std::abs(row.error_pct);
        features.push_back(std::move(row.feature));
    }
    table.mean_abs_fit_area_error_pct = features.empty() ? 0.0 : error_sum / static_cast<double>(features.size());
    return table;
}

namespace {
// The ortho's bands (nodata pixels marked invalid), as read.
struct OrthoImage {
    Image<float> image;
    std::vector<uint8_t> valid;
};
OrthoImage read_ortho(RasterReader& reader) {
    // The image bands (an alpha band is a mask, not a colour); invalid where
    // a band holds its nodata value or the alpha / mask band says so.
    const RasterInfo& info = reader.info();
    const std::vector<int> bands = image_bands(info);
    const PixelWindow all{0, 0, info.width, info.height};
    OrthoImage o{reader.read<float>(all, bands), {}};
    o.valid = valid_pixels(reader, all, o.image, bands);
    return o;
}

// Heights read from 1-based `band` of the raster `info` describes: its
// nodata value becomes NaN (a gap, not a height).
void gaps_to_nan(Image<float>& heights, const RasterInfo& info, int band) {
    const std::vector<uint8_t> valid = data_mask(heights, info, {band});
    for (std::size_t i = 0; i < valid.size(); ++i)
        if (!valid[i]) heights.data[i] = NAN;
}

// The label raster of --segments: a file, or the level of `scale` (or the
// only level) of a `cityforge segment` folder.
std::string segments_file(const std::string& path, double scale) {
    namespace fs = std::filesystem;
    if (!fs::exists(path)) throw Error(path, "segments not found");
    if (!fs::is_directory(path)) return path;
    const std::string wanted = segment_level_path(path, scale);
    if (fs::exists(wanted)) return wanted;
    std::vector<std::string> levels;
    for (const auto& e : fs::directory_iterator(path)) {
        const std::string name = e.path().filename().string();
        if (name.rfind("segments_scale_", 0) == 0 && e.path().extension() == ".tif") levels.push_back(name);
    }
    std::sort(levels.begin(), levels.end());
    if (levels.size() == 1) return (fs::path(path) / levels[0]).string();
    std::string list;
    for (const std::string& l : levels) list += (list.empty() ? "" : ", ") + l;
    throw Error(path, "no " + fs::path(wanted).filename().string() + " for --segment-scale; levels here: " + (list.empty() ? "none" : list));
}

// Segments read from a label raster on the ortho's grid; returns 1..count.
Image<uint32_t> read_segments(const std::string& path, const GridSpec& grid, uint32_t& count) {
    RasterReader reader(path);
    const RasterInfo& info = reader.info();
    if (info.band_count() != 1) throw Error(path, "segments must be one band of labels, not " + std::to_string(info.band_count()));
    if (info.width != grid.width || info.height != grid.height || std::abs(info.transform.origin_x - grid.transform.origin_x) > 1e-6 * std::abs(grid.transform.pixel_width) ||
        std::abs(info.transform.origin_y - grid.transform.origin_y) > 1e-6 * std::abs(grid.transform.pixel_width))
        throw Error(path, "segments are not on the ortho's grid (" + std::to_string(info.width) + " x " + std::to_string(info.height) + " vs " +
                              std::to_string(grid.width) + " x " + std::to_string(grid.height) + ")");
    Image<uint32_t> labels = reader.read_all<uint32_t>();
    count = 0;
    for (const uint32_t l : labels.data) count = std::max(count, l);
    if (count == 0) throw Error(path, "segments raster holds no segment (all 0)");
    return labels;
}

// A building mask found on the ortho file's own grid carried onto the
// working grid (a lon/lat ortho is read warped onto its UTM zone, but the
// learned detector reads the file's own pixels, which it was trained on:
// bilinear resampling blurs their texture). Each working cell takes the
// label of the file pixel under its centre; labels are renumbered 1..count
// in their order, without the ones no cell took.
BuildingMask mask_on_working_grid(const BuildingMask& m, const GridSpec& from, const CrsInfo& from_crs, const GridSpec& to, const CrsInfo& to_crs,
                                  const std::string& subject) {
    const std::size_t n = std::size_t(to.width) * std::size_t(to.height);
    std::vector<double> x(n), y(n), z(n, 0.0);
    for (int r = 0; r < to.height; ++r)
        for (int c = 0; c < to.width; ++c) {
            const MapPoint p = to.transform.pixel_centre(c, r);
            const std::size_t i = std::size_t(r) * std::size_t(to.width) + std::size_t(c);
            x[i] = p.x, y[i] = p.y;
        }
    transform_points(to_crs, from_crs, x, y, z, subject);
    BuildingMask out;
    out.used_classes = m.used_classes;
    out.labels = Image<uint32_t>(to.width, to.height, 1, 0u);
    std::vector<uint32_t> renumber(std::size_t(m.count) + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
        const PixelPoint q = from.transform.map_to_pixel({x[i], y[i]});
        const double c = std::floor(q.col), r = std::floor(q.row);
        if (!(c >= 0.0 && r >= 0.0 && c < from.width && r < from.height)) continue;
        const uint32_t l = m.labels.data[std::size_t(r) * std::size_t(from.width) + std::size_t(c)];
        if (l > 0 && l <= m.count) renumber[l] = 1, out.labels.data[i] = l;
    }
    for (std::size_t l = 1; l < renumber.size(); ++l)
        if (renumber[l]) renumber[l] = ++out.count;
    for (uint32_t& l : out.labels.data) l = renumber[l];
    return out;
}

// ortho_cloud: the buildings outside the heights' coverage, found by an
// image model trained on the buildings under them, appended to `mask`
// (labels count+1..) with source "image_model".
void add_self_trained_buildings(BuildingMask& mask, std::vector<std::string>& sources, const OrthoImage& img, const RasterInfo& info,
                                const Image<float>& ndsm, const FootprintsRunOptions& o, const BuildingMaskOptions& mo, FootprintsReport& rep,
                                const Progress& progress) {
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = std::size_t(w) * std::size_t(h);
    std::vector<int> source_bands;  // the bands read (image_bands: no alpha, also not the warper's), but the nDSM band
    for (int b : image_bands(info))
        if (b != o.ndsm_band) source_bands.push_back(b);
    const DetectionImage di = detection_image_from(img.image, source_bands, img.valid, info, o.nir_band, o.ortho);
    std::vector<uint8_t> has(n), cloud_building(n);
    for (std::size_t i = 0; i < n; ++i) has[i] = std::isnan(ndsm.data[i]) ? 0 : 1, cloud_building[i] = mask.labels.data[i] ? 1 : 0;
    const int radius = static_cast<int>(std::lround(o.self_training.coverage_closing_m / di.gsd_m));
    const std::vector<uint8_t> covered = detect::coverage_mask(has, w, h, radius);
    const detect::SelfTrainingResult r =
        detect::self_train_and_detect(di.normalised, di.valid, di.layout, di.gsd_m, covered, cloud_building, o.self_training, progress);
    rep.uncovered_share = r.uncovered_share;
    if (!r.trained) {
        rep.self_training = "not trained: " + r.reason;
        if (o.self_training.enabled && r.uncovered_share >= o.self_training.min_uncovered_share)
            log::warning(o.ortho + ": " + std::to_string(int(std::lround(r.uncovered_share * 100.0))) +
                         " % of the ortho lies outside the heights, but no image model was trained for it: " + r.reason);
        return;
    }
    const BuildingMask extra = label_buildings(r.building, w, h, mo);
    for (std::size_t i = 0; i < n; ++i)
        if (const uint32_t e = extra.labels.data[i]; e && !mask.labels.data[i]) mask.labels.data[i] = mask.count + e;
    mask.count += extra.count;
    sources.resize(mask.count + 1, "image_model");
    rep.self_training = "image model trained on " + std::to_string(r.training_segments) + " segments under the heights (" +
                        std::to_string(r.building_examples) + " building), " + std::to_string(extra.count) + " buildings found outside them";
}

FootprintsReport run_footprints_unguarded(const std::string& output_path, const FootprintsRunOptions& o, const Progress& progress);

}  // namespace

// (declared in footprints_run.hpp) An nDSM raster on `grid` (when `grid` has cells: same horizontal CRS,
// pixel edges aligned with it) or on its own grid (grid and crs are set);
// nodata becomes NaN.
Image<float> read_ndsm_raster(const std::string& path, GridSpec& grid, CrsInfo& crs) {
    RasterReader reader(path);
    const RasterInfo& info = reader.info();
    Image<float> h;
    if (grid.width == 0) {
        grid = {info.transform, info.width, info.height};
        crs = info.crs;
        h = reader.read_all<float>({1});
    } else {
        if (!same_horizontal_crs(info.crs, crs)) throw Error(path, "the nDSM is in " + info.crs.label() + ", the ortho in " + crs.label());
        const GeoTransform& g = grid.transform;
        const GeoTransform& t = info.transform;
        const double c0 = (g.origin_x - t.origin_x) / t.pixel_width, r0 = (g.origin_y - t.origin_y) / t.pixel_height;
        const double cw = grid.width * g.pixel_width / t.pixel_width, rh = grid.height * g.pixel_height / t.pixel_height;
        auto whole = [](double v) { return std::abs(v - std::round(v)) < 1e-3; };
        if (!whole(c0) || !whole(r0) || !whole(cw) || !whole(rh))
            throw Error(path, "the nDSM's pixels are not aligned with the ortho's; warp it onto the ortho's grid first (gdalwarp -te/-tr/-tap)");
        const PixelWindow win{static_cast<int>(std::lround(c0)), static_cast<int>(std::lround(r0)), static_cast<int>(std::lround(cw)),
                              static_cast<int>(std::lround(rh))};
        if (win.col < 0 || win.row < 0 || win.col + win.width > info.width || win.row + win.height > info.height)
            throw Error(path, "the nDSM does not cover the whole ortho");
        h = reader.read_resampled<float>(win, grid.width, grid.height, {1}, win.width > grid.width ? "average" : "bilinear");
    }
    gaps_to_nan(h, info, 1);
    return h;
}

FootprintsReport run_footprints(const std::string& output_path, const FootprintsRunOptions& o, const Progress& progress) {
    try {
        return run_footprints_unguarded(output_path, o, progress);
    } catch (const std::bad_alloc&) {  // named: a bare "out of memory" does not say which input was too large
        const std::string input = !o.ortho.empty() ? o.ortho : !o.cloud.empty() ? o.cloud : o.ndsm;
        throw OutOfMemory(input, "footprint extraction over it does not fit in memory: tile it (cityforge run --tile-size 2048) or crop it");
    }
}

namespace {
// The detection mode `automatic` stands for, from the inputs given.
DetectionMode resolve_detection_mode(const FootprintsRunOptions& o) {
    if (o.mode != DetectionMode::automatic) return o.mode;
    const bool heights = !o.cloud.empty() || !o.ndsm.empty() || o.ndsm_band > 0;
    // A model given with heights is applied (with them as its nDSM band when trained so).
    return !o.model.empty() && !o.ortho.empty() ? DetectionMode::ortho_only
           : heights && !o.ortho.empty()        ? DetectionMode::ortho_cloud
           : heights                            ? DetectionMode::cloud_only
                                                : DetectionMode::ortho_only;
}

// What a footprint run works on: the working grid and CRS, their units, the
// ortho (its pixels where the mode uses them), the nDSM and the cloud's cells.
struct FootprintScene {
    GridSpec grid;
    CrsInfo crs;        ///< the working CRS
    CrsInfo input_crs;  ///< the CRS the footprints are written in by default
    double unit = 1.0, z_unit = 1.0;  ///< metres per horizontal / vertical unit of `crs`
    std::unique_ptr<RasterReader> ortho;
    OrthoImage img;            ///< the ortho's colour bands (not the nDSM band) and valid pixels
    Image<float> ndsm_band;    ///< the ortho's nDSM band, when --ndsm-band
    Image<float> ndsm;         ///< heights above ground on `grid` (empty in ortho-only mode)
    BuildingCells cells;       ///< building evidence from the heights (not in ortho-only mode)
};

// The ortho opened on the working CRS (a lon/lat ortho on its UTM zone), its
// bands checked against the options, and its pixels read when the mode uses
// them; with --ndsm-band the nDSM band leaves the colours.
void open_ortho(const FootprintsRunOptions& o, DetectionMode mode, FootprintScene& s) {
    RasterOpenOptions ro;
    ro.project_geographic = true;  // metres: a lon/lat ortho is read on its UTM zone
    ro.working_crs = o.working_crs;
    s.ortho = std::make_unique<RasterReader>(o.ortho, ro);
    const RasterInfo& info = s.ortho->info();
    if (info.warped) log::info(o.ortho + ": " + info.source_crs.label() + " read on " + info.crs.label() + " (working CRS)");
    s.grid = {info.transform, info.width, info.height};
    s.crs = info.crs;
    s.input_crs = info.source_crs;
    s.unit = info.metres_per_unit, s.z_unit = s.crs.z_unit_m;
    if (o.ndsm_band > info.band_count())
        throw Error(o.ortho, "has " + std::to_string(info.band_count()) + " bands; --ndsm-band " + std::to_string(o.ndsm_band) + " does not exist");
    if (o.nir_band > info.band_count())
        throw Error(o.ortho, "has " + std::to_string(info.band_count()) + " bands; --nir-band " + std::to_string(o.nir_band) + " does not exist");
    for (const int b : {o.ndsm_band, o.nir_band})
        if (b > 0 && b == info.alpha_band) throw Error(o.ortho, "band " + std::to_string(b) + " is the alpha band (a mask), not an image band");
    const bool learned = mode == DetectionMode::ortho_only && o.detector != OrthoDetector::rules && o.segments.empty();  // reads its own bands
    if ((mode != DetectionMode::cloud_only && !learned) || o.ndsm_band > 0) s.img = read_ortho(*s.ortho);
    if (o.ndsm_band <= 0) return;
    // The nDSM band leaves the colours.
    OrthoImage& img = s.img;
    const int b = o.ndsm_band - 1;
    s.ndsm_band = Image<float>(img.image.width, img.image.height, 1, 0.0f);
    std::copy(img.image.band_data(b), img.image.band_data(b) + img.image.pixel_count(), s.ndsm_band.data.begin());
    gaps_to_nan(s.ndsm_band, info, o.ndsm_band);
    Image<float> colours(img.image.width, img.image.height, img.image.bands - 1, 0.0f);
    for (int k = 0, out = 0; k < img.image.bands; ++k)
        if (k != b) std::copy(img.image.band_data(k), img.image.band_data(k) + img.image.pixel_count(), colours.band_data(out++));
    img.image = std::move(colours);
    // A nodata value in the height band alone does not make the colours invalid.
    std::vector<int> sources;
    for (int k : image_bands(info))
        if (k != o.ndsm_band) sources.push_back(k);
    img.valid = valid_pixels(*s.ortho, {0, 0, info.width, info.height}, img.image, sources);
    if (img.image.bands == 0 && mode != DetectionMode::cloud_only) throw Error(o.ortho, "has no colour band besides the nDSM band");
}

// Building cells and the nDSM from the point cloud, held whole or read window
// by window (cloud_windows.hpp): the same decisions either way. Without an
// ortho the grid is laid over the cloud's points.
void cells_from_cloud(const FootprintsRunOptions& o, FootprintScene& s, FootprintsReport& rep, const Progress& progress) {
    BuildingMaskOptions mo = o.mask;
    rep.height_source = "point cloud";
    // Whole-cloud decisions made before the cloud is read, alike whether it
    // is held whole or read window by window (cloud_windows.hpp).
    const CrsInfo target = s.ortho ? s.ortho->info().crs : CrsInfo{};
    const bool windows = read_cloud_by_windows(CloudReader(o.cloud), o.max_points_in_memory, 0.0);  // the grid covers the whole box anyway
    if (!s.ortho) {
        s.unit = require_cloud_crs(o.cloud, o.cloud_crs).linear_unit_m;
        s.grid = grid_over_extent(cloud_point_bounds(o.cloud), o.mask.gsd_m / s.unit, 0, o.cloud);
    }
    const GridSpec& grid = s.grid;
    const CloudPlan plan = plan_cloud(o.cloud, o.cloud_crs, target, o.outliers, grid.transform.pixel_to_map({grid.width / 2.0, grid.height / 2.0}));
    mo.gsd_m = std::abs(grid.transform.pixel_width) * s.unit;
    rep.cloud_cell_factor = o.cloud_cell_factor > 0 ? o.cloud_cell_factor : cloud_cell_factor(plan.density_m2, mo.gsd_m);
    const int f = rep.cloud_cell_factor;
    WindowCloudCells wc;
    if (windows) {
        const GridSpec coarse = cloud_cell_grid(grid, 0, 0, f);
        const double cell_m = mo.gsd_m * f;
        const double tile_m = window_tile_edge_m(o.cloud_tile_m, o.cloud_overlap_m, plan.density_m2, o.max_points_in_memory);
        WindowedRasters w = rasterize_cloud_by_windows(o.cloud, o.cloud_crs, target, coarse, s.unit, plan.outliers, o.ground,
                                                       std::max(16, static_cast<int>(std::lround(tile_m / cell_m))),
                                                       static_cast<int>(std::ceil(o.cloud_overlap_m / cell_m)), progress.sub(0.0, 0.3));
        if (w.core_points == 0)
            throw Error(o.cloud, s.ortho ? "does not overlap " + o.ortho + ": no kept point of the cloud lies on its grid" : "no kept point");
        s.crs = w.crs;
        if (s.input_crs.empty()) s.input_crs = w.source_crs;
        s.z_unit = w.crs.z_unit_m;
        rep.cloud_windows = w.windows;
        mo.min_height_m /= s.z_unit;
        wc = cloud_cells_from_rasters(std::move(w.rasters), grid.width, grid.height, 0, 0, f, mo);
    } else {
        const PreparedCloud pc = prepare_cloud(o.cloud, o.cloud_crs, target, plan.outliers, o.ground);
        s.crs = pc.crs;
        if (s.input_crs.empty()) s.input_crs = pc.source_crs;
        s.z_unit = pc.crs.z_unit_m;
        if (s.ortho) require_cloud_overlap(pc, o.cloud, s.ortho->info().extent, o.ortho);
        progress(0.3, "cloud");
        mo.min_height_m /= s.z_unit;
        wc = cloud_cells_on_window(pc, grid, 0, 0, f, s.unit, mo);
    }
    s.cells = std::move(wc.cells);
    s.ndsm = std::move(wc.rasters.ndsm);
}

// Building cells from an nDSM raster or band: no classes, so vegetation is told by roughness.
void cells_from_ndsm(const FootprintsRunOptions& o, FootprintScene& s, FootprintsReport& rep) {
    if (o.ndsm_band > 0) {
        rep.height_source = "ortho band " + std::to_string(o.ndsm_band);
        s.ndsm = std::move(s.ndsm_band);
    } else {
        rep.height_source = "nDSM raster";
        s.ndsm = read_ndsm_raster(o.ndsm, s.grid, s.crs);
        if (s.input_crs.empty()) s.input_crs = s.crs;
        s.unit = ground_metres_per_unit(s.crs, s.grid.transform, s.grid.width, s.grid.height), s.z_unit = s.crs.z_unit_m;
        if (!(s.unit > 0.0)) throw Error(o.ndsm, "an nDSM in a geographic CRS needs metres: warp it (gdalwarp -t_srs) or give it as a band of the ortho");
    }
    BuildingMaskOptions mo = o.mask;
    mo.gsd_m = std::abs(s.grid.transform.pixel_width) * s.unit;
    mo.min_height_m /= s.z_unit;
    const Image<float> none(s.ndsm.width, s.ndsm.height, 1, NAN);
    s.cells = building_cells(s.ndsm, s.ndsm, none, none, mo);
}

// Ortho-only, learned detection (src/detect): segments and outlines from the model's own segmentation.
BuildingMask detect_with_model(const FootprintsRunOptions& o, const FootprintScene& s, FootprintsReport& rep, const Progress& progress) {
    DetectionImage di = read_detection_image(o.ortho, o.nir_band);
    const std::string path = o.model.empty() ? default_model_path(di.layout, di.gsd_m) : o.model;
    const detect::DetectorModel model = detect::read_model_file(path);
    if (model.layout.ndsm_band >= 0 && (!o.ndsm.empty() || !o.cloud.empty())) {
        // A model trained with heights gets them as its last band.
        rep.height_source = !o.cloud.empty() ? "point cloud" : "nDSM raster";
        add_ndsm_band(di, heights_on_image_grid(di, o.ndsm, o.cloud, o.cloud_crs));
    }
    rep.detector = "model " + path;
    BuildingMask mask = detect_building_mask(model, di, 0, progress.sub(0.1, 0.55));
    if (s.ortho->info().warped) mask = mask_on_working_grid(mask, di.grid, di.crs, s.grid, s.crs, o.ortho);
    return mask;
}

// The segments of --segments (the level of segment_scale), or none.
Image<uint32_t> given_segments(const FootprintsRunOptions& o, const GridSpec& grid, FootprintsReport& rep) {
    if (o.segments.empty()) return {};
    const std::string path = segments_file(o.segments, o.segmentation.segment_scale);
    rep.segments_path = path;
    return read_segments(path, grid, rep.segments);
}

// Ortho-only with the hand-set segment rules (footprint/segment_classifier).
BuildingMask detect_with_rules(const FootprintsRunOptions& o, const FootprintScene& s, const BuildingMaskOptions& mo, const SegmentClassifierOptions& co,
                               FootprintsReport& rep, const Progress& progress) {
    rep.detector = "rules";
    Image<float> normalised = s.img.image;
    normalize_bands(normalised, s.img.valid);
    Image<uint32_t> segments = given_segments(o, s.grid, rep);
    if (o.segments.empty())
        segments = segment_at_scale(normalised, s.img.valid, o.segmentation.watershed, o.segmentation.segment_scale, rep.segments, progress.sub(0.35, 0.55));
    refine_segment_boundaries(normalised, normalised.bands, segments, rep.segments, o.segmentation.refine_passes);
    std::vector<uint8_t> building;
    classify_segments(s.img.image, segments, rep.segments, co, building);
    return label_buildings(std::move(building), s.grid.width, s.grid.height, mo);
}

// Buildings from the heights' cells; in ortho_cloud mode each redrawn along
// the ortho's edges and split at roof seams; hidden roofs completed.
BuildingMask detect_from_heights(const FootprintsRunOptions& o, DetectionMode mode, FootprintScene& s, const BuildingMaskOptions& mo,
                                 const SegmentClassifierOptions& co, FootprintsReport& rep, const Progress& progress) {
    BuildingMask mask = buildings_from_cells(s.cells, s.grid.width, s.grid.height, mo);
    if (mode == DetectionMode::ortho_cloud) {
        // Each building redrawn along the ortho's edges (see footprint/ortho_refine.hpp).
        const Image<uint32_t> segments = given_segments(o, s.grid, rep);
        const std::vector<uint8_t> vegetation = s.cells.used_classes ? std::vector<uint8_t>{} : vegetation_pixels(s.img.image, co);
        progress(0.45, "buildings");
        OrthoRefineOptions ro = o.segmentation;
        ro.cloud_edges = rep.cloud_cell_factor == 1;
        ro.max_crown_plane_sigma_m /= s.z_unit, ro.min_crown_local_roughness_m /= s.z_unit, ro.gsd_m = mo.gsd_m;
        rep.crowns_dropped =
            static_cast<int>(refine_buildings_with_ortho(mask, s.cells, s.img.image, s.img.valid, s.ndsm, 20.0 / s.z_unit, segments, vegetation, ro));
        RoofSeamOptions so = o.seams;
        so.gsd_m = mo.gsd_m, so.ridge_rise_m /= s.z_unit, so.valley_depth_m /= s.z_unit;
        rep.seam_splits = split_at_roof_seams(mask, s.img.image, s.img.valid, s.ndsm, so);
    }
    if (mo.hidden_completion_max_share > 0) rep.hidden_completed_cells = complete_hidden_roofs(mask, s.cells, mo.hidden_completion_max_share);
    return mask;
}

FootprintsReport run_footprints_unguarded(const std::string& output_path, const FootprintsRunOptions& o, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    const std::string driver = vector_driver_for(output_path);
    FootprintsReport rep;
    const DetectionMode mode = resolve_detection_mode(o);
    rep.mode = to_string(mode);
    FootprintScene s;
    if (!o.ortho.empty()) open_ortho(o, mode, s);
    if (mode != DetectionMode::ortho_only) {
        if (!o.cloud.empty()) cells_from_cloud(o, s, rep, progress);
        else cells_from_ndsm(o, s, rep);
        rep.used_classes = s.cells.used_classes;
    }
    BuildingMaskOptions mo = o.mask;
    mo.gsd_m = std::abs(s.grid.transform.pixel_width) * s.unit;
    mo.split_step_m /= s.z_unit, mo.split_gap_step_m /= s.z_unit;
    SegmentClassifierOptions co = o.classifier;
    if (s.ortho) co.gsd_m = s.ortho->info().gsd.x_m;
    // The NIR band's index among the colours (the nDSM band left them).
    co.nir_band = o.nir_band > 0 ? o.nir_band - 1 - (o.ndsm_band > 0 && o.ndsm_band < o.nir_band ? 1 : 0) : -1;
    BuildingMask mask = mode == DetectionMode::ortho_only && o.detector != OrthoDetector::rules && o.segments.empty()
                            ? detect_with_model(o, s, rep, progress)
                        : mode == DetectionMode::ortho_only ? detect_with_rules(o, s, mo, co, rep, progress)
                                                            : detect_from_heights(o, mode, s, mo, co, rep, progress);
    // What found each building (the `source` field).
    const std::string first_source = mode == DetectionMode::ortho_only ? (rep.detector == "rules" ? "image_rules" : "image_model")
                                     : rep.height_source == "point cloud"  ? "cloud"
                                                                           : "ndsm";
    std::vector<std::string> sources(mask.count + 1, first_source);
    if (mode == DetectionMode::ortho_cloud) add_self_trained_buildings(mask, sources, s.img, s.ortho->info(), s.ndsm, o, mo, rep, progress.sub(0.5, 0.6));
    rep.width = s.grid.width, rep.height = s.grid.height;
    progress(0.6, "detection");
    FootprintTable table = footprint_table(mask, s.ndsm, s.grid.transform, 0, 0, {}, rep.mode, s.unit, s.z_unit, s.crs, o, sources);
    rep.buildings = table.features.size();
    for (const Feature& f : table.features) {
        const std::string& src = std::get<std::string>(f.values[2]);
        (src == "cloud" || src == "ndsm" ? rep.from_heights : rep.from_image) += 1;
    }
    if (table.features.empty()) {
        // Nothing found is not a result: no empty file, a non-zero exit.
        const std::string input = !o.ortho.empty() ? o.ortho : !o.cloud.empty() ? o.cloud : o.ndsm;
        throw Error(input, "no building found (" + rep.mode + " mode" + (rep.height_source.empty() ? "" : ", heights from the " + rep.height_source) +
                               "); nothing written to " + output_path);
    }
    rep.mean_abs_fit_area_error_pct = table.mean_abs_fit_area_error_pct;
    VectorWriteOptions wopt;
    wopt.driver = driver;
    // Written in the input's CRS (or --out-crs), whatever CRS the work was done in.
    CrsInfo out_crs = !o.out_crs.empty() ? crs_from_user_input(o.out_crs, "--out-crs") : s.input_crs.empty() ? s.crs : s.input_crs;
    out_crs = combine_with_vertical(out_crs, s.crs);
    if (!same_horizontal_crs(out_crs, s.crs)) reproject_features(table.features, s.crs, out_crs, output_path);
    write_polygon_features(output_path, out_crs, table.fields, table.features, wopt);
    rep.crs = out_crs.label();
    rep.working_crs = s.crs.label();
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "written");
    return rep;
}
}  // namespace

}  // namespace cityforge
