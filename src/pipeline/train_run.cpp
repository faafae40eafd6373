#include "pipeline/train_run.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <filesystem>

#include "audit/footprint_match.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "detect/label_raster.hpp"
#include "detect/segment_merge.hpp"
#include "footprint/vectorize.hpp"
#include "io/vector.hpp"
#include "pipeline/cloud_cells.hpp"
#include "pipeline/footprints_run.hpp"
#include "pipeline/prepared_cloud.hpp"
#include "raster/raster.hpp"

#ifndef CITYFORGE_MODELS_DIR
#define CITYFORGE_MODELS_DIR "models"
#endif

namespace cityforge {

namespace fs = std::filesystem;

DetectionImage detection_image_from(const Image<float>& image, const std::vector<int>& source_bands, const std::vector<uint8_t>& valid,
                                    const RasterInfo& info, int nir_band, const std::string& path) {
    if (int(source_bands.size()) != image.bands) throw Error(path, "band list does not match the image read");
    DetectionImage d;
    d.path = path;
    d.grid = {info.transform, info.width, info.height};
    d.crs = info.crs;
    std::vector<int> colours;  // positions in `image`
    for (std::size_t k = 0; k < source_bands.size(); ++k) {
        const int b = source_bands[k];
        if (source_bands.size() > 1 && info.bands[b - 1].color_interpretation == "Alpha" && d.alpha_band == 0) {
            d.alpha_band = b;
            continue;
        }
        colours.push_back(int(k));
    }
    if (nir_band > info.band_count()) throw Error(path, "has " + std::to_string(info.band_count()) + " bands; --nir-band " + std::to_string(nir_band) + " does not exist");
    if (nir_band > 0 && nir_band == d.alpha_band) throw Error(path, "band " + std::to_string(nir_band) + " is an alpha band, not near infrared");
    d.layout.bands = static_cast<int>(colours.size());
    for (std::size_t k = 0; k < colours.size(); ++k)
        if (source_bands[colours[k]] == nir_band) d.layout.nir_band = static_cast<int>(k);
    d.normalised = Image<float>(image.width, image.height, d.layout.bands, 0.0f);
    for (std::size_t k = 0; k < colours.size(); ++k)
        std::copy(image.band_data(colours[k]), image.band_data(colours[k]) + image.pixel_count(), d.normalised.band_data(int(k)));
    d.valid = valid;
    if (d.alpha_band) {
        const int a = int(std::find(source_bands.begin(), source_bands.end(), d.alpha_band) - source_bands.begin());
        const float* alpha = image.band_data(a);
        for (std::size_t i = 0; i < d.valid.size(); ++i)
            if (!(alpha[i] > 0.0f)) d.valid[i] = 0;
    }
    std::size_t n_valid = 0;
    for (const uint8_t v : d.valid) n_valid += v;
    if (n_valid == 0) throw Error(path, "has no valid pixel (all nodata or transparent)");
    // Integer sources deeper than 8 bits (UInt16 pan ...) hold linear counts: brought to a display tone first.
    for (std::size_t k = 0; k < colours.size(); ++k) {
        const SampleType t = info.bands[source_bands[colours[k]] - 1].type;
        if (t == SampleType::uint16 || t == SampleType::int16 || t == SampleType::uint32 || t == SampleType::int32)
            detect::encode_linear_counts(d.normalised, int(k));
    }
    normalize_bands(d.normalised, d.valid);
    // True ground size of the centre pixel for any CRS (Web Mercator's grid
    // metres are not ground metres away from the equator).
    if (info.crs.empty()) {
        d.gsd_m = std::sqrt(info.gsd.x_m * info.gsd.y_m);
    } else {
        const GeoTransform& t = info.transform;
        const double c = info.width / 2.0, r = info.height / 2.0;
        const std::vector<MapPoint> px{t.pixel_to_map({c, r}), t.pixel_to_map({c + 1, r}), t.pixel_to_map({c + 1, r + 1}), t.pixel_to_map({c, r + 1})};
        d.gsd_m = std::sqrt(geodesic_area_m2({px}, info.crs));
    }
    if (!(d.gsd_m > 0.0)) throw Error(path, "cannot determine the ground sample distance");
    return d;
}

DetectionImage read_detection_image(const std::string& path, int nir_band) {
    RasterReader reader(path);
    const RasterInfo& info = reader.info();
    std::vector<int> all;
    for (int b = 1; b <= info.band_count(); ++b) all.push_back(b);
    // The colour bands (an alpha band is a mask, not data).
    std::vector<int> colours;
    for (int b = 1; b <= info.band_count(); ++b)
        if (!(info.band_count() > 1 && info.bands[b - 1].color_interpretation == "Alpha")) colours.push_back(b);
    if (colours.empty()) colours = all;
    Image<float> image = reader.read_all<float>(all);
    Image<float> colour_image(image.width, image.height, int(colours.size()), 0.0f);
    for (std::size_t k = 0; k < colours.size(); ++k)
        std::copy(image.band_data(colours[k] - 1), image.band_data(colours[k] - 1) + image.pixel_count(), colour_image.band_data(int(k)));
    // Nodata values, the alpha band and an internal or external mask band (valid_pixels, as every reader of the ortho).
    const std::vector<uint8_t> valid = valid_pixels(reader, {0, 0, info.width, info.height}, colour_image, colours);
    return detection_image_from(image, all, valid, info, nir_band, path);
}

Image<float> heights_on_image_grid(const DetectionImage& image, const std::string& ndsm_path, const std::string& cloud_path,
                                   const std::string& cloud_crs) {
    if (!ndsm_path.empty()) {
        GridSpec grid = image.grid;
        CrsInfo crs = image.crs;
        Image<float> h = read_ndsm_raster(ndsm_path, grid, crs);
        RasterReader probe(ndsm_path);
        const double z = probe.info().crs.z_unit_m > 0.0 ? probe.info().crs.z_unit_m : 1.0;
        for (float& v : h.data) v = static_cast<float>(v * z);
        return h;
    }
    const PreparedCloud pc = prepare_cloud(cloud_path, cloud_crs, image.crs, OutlierFilterOptions{}, GroundFilterOptions{});
    const double unit = image.crs.linear_unit_m;
    if (!(unit > 0.0)) throw Error(image.path, "a cloud on an image in a geographic CRS: warp the image to a projected CRS first (gdalwarp -t_srs)");
    const GeoTransform& t = image.grid.transform;
    const MapPoint a = t.pixel_to_map({0.0, 0.0}), b = t.pixel_to_map({double(image.grid.width), double(image.grid.height)});
    require_cloud_overlap(pc, cloud_path, Extent{std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y)}, image.path);
    BuildingMaskOptions mo;
    mo.gsd_m = std::abs(t.pixel_width) * unit;
    mo.min_height_m /= pc.crs.z_unit_m;
    const int factor = cloud_cell_factor(point_density_m2(pc), mo.gsd_m);
    Image<float> h = cloud_cells_on_window(pc, image.grid, 0, 0, factor, unit, mo).rasters.ndsm;
    for (float& v : h.data) v = static_cast<float>(v * pc.crs.z_unit_m);
    return h;
}

void add_ndsm_band(DetectionImage& image, const Image<float>& heights_m) {
    if (heights_m.width != image.normalised.width || heights_m.height != image.normalised.height)
        throw Error(image.path, "the heights are not on the image's grid");
    if (image.layout.ndsm_band >= 0) throw Error(image.path, "already has an nDSM band");
    const int b = image.normalised.bands;
    Image<float> out(image.normalised.width, image.normalised.height, b + 1, 0.0f);
    std::copy(image.normalised.data.begin(), image.normalised.data.end(), out.data.begin());
    float* h = out.band_data(b);
    for (std::size_t i = 0; i < heights_m.data.size(); ++i) {
        const float v = heights_m.data[i];
        h[i] = std::isnan(v) ? 0.0f : static_cast<float>(std::clamp(double(v), 0.0, detect::kNdsmFullScaleM) / detect::kNdsmFullScaleM * 255.0);
    }
    image.normalised = std::move(out);
    image.layout.ndsm_band = b;
    image.layout.bands = b + 1;
}

namespace {

BuildingMask mask_from_probabilities(const detect::SceneSegments& segments, const std::vector<float>& probability, double threshold,
                                     double gsd_m, const detect::DetectorOptions& o, const std::vector<float>* pixel_map,
                                     const std::vector<uint32_t>* groups = nullptr, const std::vector<float>* core_map = nullptr) {
    BuildingMaskOptions mo;
    mo.gsd_m = gsd_m;
    mo.min_area_m2 = o.min_area_m2;
    mo.min_hole_m2 = o.min_hole_m2;
    const int w = segments.labels.width, h = segments.labels.height;
    detect::DetectorOptions t = o;
    t.threshold = threshold;
    const std::vector<uint8_t> whole = detect::building_pixels(segments, probability, threshold, 0, pixel_map, o.pixel_object_threshold);
    return label_cut_buildings(whole, detect::object_pixels(segments, probability, t, pixel_map, groups, core_map, gsd_m), w, h, mo);
}

// Labelled data of one training image, in its pixel space.
struct LabelledImage {
    DetectionImage image;
    std::vector<uint8_t> truth;                     // 1 = building pixel
    std::vector<std::vector<Polygon>> reference;    // x = column, y = -row (footprint_table's pixel space)
    detect::SceneSegments segments;
    detect::FeatureMatrix features;
    std::vector<float> share;                       // per segment (index = label)
    std::vector<int> fold;                          // per segment (index = label - 1)
    std::vector<uint32_t> reference_ids;            // per pixel: 1-based label feature burnt there (0 = none)
    detect::SegmentPairs pairs;                     // adjacent segments and their features
    std::vector<int8_t> pair_y;                     // per pair: 1 same building, 0 different, -1 not an example
};

bool is_raster_path(const std::string& p) {
    std::string ext = fs::path(p).extension().string();
    for (char& ch : ext) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    return ext == ".tif" || ext == ".tiff" || ext == ".vrt" || ext == ".img";
}

void load_labels(LabelledImage& li, const std::string& path, const std::string& layer) {
    const int w = li.image.grid.width, h = li.image.grid.height;
    const GeoTransform& t = li.image.grid.transform;
    if (is_raster_path(path)) {
        RasterReader reader(path);
        const RasterInfo& info = reader.info();
        if (info.width != w || info.height != h || std::abs(info.transform.origin_x - t.origin_x) > 1e-6 * std::abs(t.pixel_width) ||
            std::abs(info.transform.origin_y - t.origin_y) > 1e-6 * std::abs(t.pixel_height))
            throw Error(path, "the label mask is not on the grid of " + li.image.path + " (" + std::to_string(info.width) + " x " +
                                  std::to_string(info.height) + " vs " + std::to_string(w) + " x " + std::to_string(h) + ")");
        const Image<float> m = reader.read_all<float>({1});
        li.truth.assign(m.data.size(), 0);
        for (std::size_t i = 0; i < m.data.size(); ++i) li.truth[i] = m.data[i] > 0.0f;
        std::vector<uint32_t> labels, sizes;
        const uint32_t n = label_components(li.truth, 1, w, h, labels, sizes);
        li.reference_ids = labels;
        Image<uint32_t> img(w, h, 1, 0);
        std::copy(labels.begin(), labels.end(), img.data.begin());
        auto polys = vectorize_all(img, GeoTransform{0.0, 1.0, 0.0, -1.0});
        for (uint32_t k = 1; k <= n; ++k)
            if (!polys[k].empty()) li.reference.push_back(std::move(polys[k]));
        return;
    }
    const PolygonLayer labels = read_polygon_layer(path, layer);
    if (labels.crs.empty()) throw Error(path, "the labels have no CRS");
    const bool reproject = !same_horizontal_crs(labels.crs, li.image.crs);
    std::vector<Polygon> burn;
    uint32_t feature_id = 0;
    for (const Feature& f : labels.features) {
        std::vector<Polygon> parts = f.geometry;
        for (Polygon& p : parts) {
            std::vector<Ring*> rings{&p.outer};
            for (Ring& r : p.holes) rings.push_back(&r);
            for (Ring* r : rings) {
                if (reproject) {
                    std::vector<double> x, y, z;
                    for (const MapPoint& q : *r) x.push_back(q.x), y.push_back(q.y), z.push_back(0.0);
                    transform_points(labels.crs, li.image.crs, x, y, z, path);
                    for (std::size_t i = 0; i < r->size(); ++i) (*r)[i] = {x[i], y[i]};
                }
                for (MapPoint& q : *r) {
                    const PixelPoint pp = t.map_to_pixel(q);
                    q = {pp.col, pp.row};
                }
            }
        }
        const Extent e = parts_extent(parts);
        if (e.max_x <= 0 || e.max_y <= 0 || e.min_x >= w || e.min_y >= h) continue;  // outside this image
        for (const Polygon& p : parts) burn.push_back(p);
        // Each label feature's own pixels (which label a segment belongs to).
        const std::vector<uint8_t> own = detect::rasterize_polygons(parts, w, h);
        if (li.reference_ids.empty()) li.reference_ids.assign(std::size_t(w) * h, 0);
        ++feature_id;
        for (std::size_t k = 0; k < own.size(); ++k)
            if (own[k]) li.reference_ids[k] = feature_id;
        const double cx = 0.5 * (e.min_x + e.max_x), cy = 0.5 * (e.min_y + e.max_y);
        if (cx < 0 || cy < 0 || cx >= w || cy >= h) continue;  // mostly outside: not counted as a reference
        for (Polygon& p : parts) {
            for (MapPoint& q : p.outer) q.y = -q.y;
            for (Ring& r : p.holes)
                for (MapPoint& q : r) q.y = -q.y;
            orient_polygon(p);
        }
        li.reference.push_back(std::move(parts));
    }
    if (burn.empty()) throw Error(path, "no label polygon overlaps " + li.image.path + " (in " + li.image.crs.label() + ")");
    li.truth = detect::rasterize_polygons(burn, w, h);
}

// Predicted footprints (recursive rectangle fits, exactly as `footprints`
// writes them) in the pixel space of the references.
std::vector<std::vector<Polygon>> predicted_footprints(const BuildingMask& mask, double gsd_m) {
    FootprintsRunOptions fo;
    fo.ortho = "x";  // only the outline options are used
    const FootprintTable table = footprint_table(mask, Image<float>{}, GeoTransform{0.0, 1.0, 0.0, -1.0}, 0, 0, {}, "ortho_only", gsd_m, 1.0, CrsInfo{}, fo);
    std::vector<std::vector<Polygon>> out;
    for (const Feature& f : table.features) out.push_back(f.geometry);
    return out;
}

// The pixel stage on every training image: the model, and per image the
// map its segment features are computed from (out-of-fold with folds, else
// the model's own map). Nothing when the pixel stage is off.
detect::PixelStage train_pixel_map_stage(const std::vector<LabelledImage>& data, const detect::BandLayout& layout, const TrainOptions& o,
                                         const detect::FoldBlocks* folds) {
    if (!o.detector.pixel.enabled) return {};
    std::vector<detect::PixelTrainingImage> px;
    for (const LabelledImage& li : data) px.push_back({&li.image.normalised, &li.image.valid, &li.truth, li.image.gsd_m});
    detect::PixelStage s = detect::train_pixel_stage(px, layout, o.detector.pixel, folds, o.folds);
    if (!folds)
        for (const LabelledImage& li : data)
            s.out_of_fold.push_back(detect::pixel_probability(s.model, li.image.normalised, li.image.valid, layout, li.image.gsd_m,
                                                              o.detector.pixel, 0, detect::kCnnTrainingTiling));
    return s;
}

// The core CNN's target (InstanceOptions): labelled pixels whose every
// pixel within `core_depth_m` (a square) is labelled by the same label feature.
std::vector<uint8_t> core_truth(const LabelledImage& li, double core_depth_m) {
    const int w = li.image.grid.width, h = li.image.grid.height;
    const int r = std::max(1, static_cast<int>(std::lround(core_depth_m / li.image.gsd_m)));
    std::vector<uint8_t> core(li.truth.size(), 0);
    const bool ids = li.reference_ids.size() == li.truth.size();
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            if (!li.truth[i]) continue;
            bool ok = x >= r && y >= r && x + r < w && y + r < h;
            for (int dy = -r; ok && dy <= r; ++dy)
                for (int dx = -r; ok && dx <= r; ++dx) {
                    const std::size_t j = std::size_t(y + dy) * w + (x + dx);
                    ok = li.truth[j] && (!ids || li.reference_ids[j] == li.reference_ids[i]);
                }
            core[i] = ok;
        }
    return core;
}

// The core CNN (InstanceOptions) on every training image: its model and
// out-of-fold core maps (with folds). Nothing unless `wanted`.
detect::PixelStage train_core_stage(const std::vector<LabelledImage>& data, const std::vector<std::vector<uint8_t>>& cores, const detect::BandLayout& layout,
                                    const TrainOptions& o, const detect::FoldBlocks* folds) {
    std::vector<detect::PixelTrainingImage> px;
    for (std::size_t i = 0; i < data.size(); ++i) px.push_back({&data[i].image.normalised, &data[i].image.valid, &cores[i], data[i].image.gsd_m});
    return detect::train_pixel_stage(px, layout, o.detector.instance.pixel_options(), folds, o.folds);
}

int fold_of(const detect::FoldBlocks& folds, std::size_t image, const std::vector<Polygon>& parts) {
    const Extent e = parts_extent(parts);
    return folds.fold_at(image, 0.5 * (e.min_x + e.max_x), -0.5 * (e.min_y + e.max_y));
}

// The out-of-fold building mask of one training image under `opts`: its
// cross-validation probabilities (`cv` per segment, `cv_pairs` per pair),
// grouped by the pair classifier when the options have it, then every object
// rule (mask_from_probabilities). `pixel_map`, `core_map` may be null.
BuildingMask out_of_fold_mask(const LabelledImage& li, const std::vector<float>& cv, const std::vector<float>& cv_pairs,
                              const detect::DetectorOptions& opts, const std::vector<float>* pixel_map, const std::vector<float>* core_map) {
    std::vector<uint32_t> groups;
    if (opts.merge_threshold > 0.0) {
        std::vector<uint8_t> building(li.segments.count + 1, 0);
        for (uint32_t k = 1; k <= li.segments.count; ++k) building[k] = cv[k] >= opts.threshold;
        groups = detect::merge_groups(li.pairs, cv_pairs, building, opts.merge_threshold);
    }
    return mask_from_probabilities(li.segments, cv, opts.threshold, li.image.gsd_m, opts, pixel_map, groups.empty() ? nullptr : &groups, core_map);
}

nlohmann::json polygons_json(const std::vector<std::vector<Polygon>>& objects) {
    nlohmann::json a = nlohmann::json::array();
    for (const auto& parts : objects) {
        nlohmann::json obj = nlohmann::json::array();
        for (const Polygon& p : parts) {
            nlohmann::json rings = nlohmann::json::array();
            std::vector<const Ring*> rs{&p.outer};
            for (const Ring& r : p.holes) rs.push_back(&r);
            for (const Ring* r : rs) {
                nlohmann::json ring = nlohmann::json::array();
                for (const MapPoint& q : *r) ring.push_back({q.x, q.y});
                rings.push_back(std::move(ring));
            }
            obj.push_back(std::move(rings));
        }
        a.push_back(std::move(obj));
    }
    return a;
}

// Raw little-endian values, written atomically (never half-written).
template <class T, class A>
void write_raw(const fs::path& path, const std::vector<T, A>& v) {
    write_text_file(path, std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T)));
}

// TrainOptions::cv_out_dir: the chosen options' out-of-fold result per image.
void write_cv_out(const std::string& dir, const std::vector<std::string>& orthos, const std::vector<LabelledImage>& data,
                  const detect::FoldBlocks& folds, const std::vector<std::vector<float>>& cv, const std::vector<std::vector<float>>& cv_pairs,
                  const detect::PixelStage& pixel, const detect::PixelStage& core, const detect::DetectorOptions& opts) {
    ensure_directory(dir);
    for (std::size_t i = 0; i < data.size(); ++i) {
        const LabelledImage& li = data[i];
        const int w = li.segments.labels.width, h = li.segments.labels.height;
        const bool has_map = opts.pixel.enabled && i < pixel.out_of_fold.size();
        const bool has_core = i < core.out_of_fold.size();
        const BuildingMask mask = out_of_fold_mask(li, cv[i], cv_pairs[i], opts, has_map ? &pixel.out_of_fold[i] : nullptr,
                                                   has_core ? &core.out_of_fold[i] : nullptr);
        const std::string stem = fs::path(orthos[i]).stem().string();
        const nlohmann::json j{{"ortho", orthos[i]}, {"width", w}, {"height", h}, {"gsd_m", li.image.gsd_m},
                               {"predicted", polygons_json(predicted_footprints(mask, li.image.gsd_m))}, {"reference", polygons_json(li.reference)}};
        write_text_file(fs::path(dir) / (stem + "_cv.json"), j.dump());
        if (has_map) write_raw(fs::path(dir) / (stem + "_cv_map.f32"), pixel.out_of_fold[i]);
        if (has_core) write_raw(fs::path(dir) / (stem + "_cv_core.f32"), core.out_of_fold[i]);
        std::vector<uint8_t> fold(std::size_t(w) * h);
        for (int r = 0; r < h; ++r)
            for (int c = 0; c < w; ++c) fold[std::size_t(r) * w + c] = uint8_t(folds.fold_at(i, c + 0.5, r + 0.5));
        write_raw(fs::path(dir) / (stem + "_cv_fold.u8"), fold);
        write_raw(fs::path(dir) / (stem + "_cv_truth.u8"), li.truth);
        write_raw(fs::path(dir) / (stem + "_cv_segments.u32"), li.segments.labels.data);
    }
}

}  // namespace

BuildingMask detect_building_mask(const detect::DetectorModel& model, const DetectionImage& image, int threads, const Progress& progress) {
    detect::check_bands(model, image.layout, image.path);
    const detect::Detection d = detect::detect_buildings(model, image.normalised, image.valid, image.gsd_m, threads, progress);
    return mask_from_probabilities(d.segments, d.probability, model.options.threshold, image.gsd_m, model.options,
                                   d.pixel_probability.empty() ? nullptr : &d.pixel_probability, d.groups.empty() ? nullptr : &d.groups,
                                   d.core_probability.empty() ? nullptr : &d.core_probability);
}

std::pair<double, double> training_gsd_range_m(const detect::DetectorModel& model) {
    double lo = 0.0, hi = 0.0;
    const auto it = model.training.find("sources");
    if (it == model.training.end() || !it->is_array()) return {lo, hi};
    for (const nlohmann::json& s : *it) {
        if (!s.is_object() || !s.contains("gsd_m") || !s["gsd_m"].is_number()) continue;
        const double g = s["gsd_m"].get<double>();
        if (!(g > 0.0)) continue;
        lo = lo > 0.0 ? std::min(lo, g) : g;
        hi = std::max(hi, g);
    }
    return {lo, hi};
}

namespace {

std::string fixed_text(double v, int decimals) {
    char b[64];
    std::snprintf(b, sizeof b, "%.*f", decimals, v);
    return b;
}

// log of how far `gsd_m` lies outside the range (0 inside).
double gsd_distance(std::pair<double, double> range_m, double gsd_m) {
    if (!(range_m.first > 0.0) || !(gsd_m > 0.0)) return 0.0;  // no GSD recorded or known: fits any
    if (gsd_m < range_m.first) return std::log(range_m.first / gsd_m);
    if (gsd_m > range_m.second) return std::log(gsd_m / range_m.second);
    return 0.0;
}

}  // namespace

std::string default_model_path(const detect::BandLayout& layout, double gsd_m) {
    const char* env = std::getenv("CITYFORGE_MODELS_DIR");
    const fs::path dir = env && *env ? env : CITYFORGE_MODELS_DIR;
    const std::string prefix = layout.bands == 1 ? "default_pan" : layout.bands == 3 && layout.nir_band < 0 ? "default_rgb" : "";
    if (prefix.empty())
        throw Error("--model", "no default model for " + detect::describe_bands(layout) + " images; train one with `cityforge train` and pass --model");
    std::vector<std::string> names;  // default_<bands>*.cfdet, by name
    std::error_code ec;
    for (fs::directory_iterator d(dir, ec), end; !ec && d != end; d.increment(ec)) {
        const std::string n = d->path().filename().string();
        if (n.size() >= prefix.size() + 6 && n.compare(0, prefix.size(), prefix) == 0 && n.compare(n.size() - 6, 6, ".cfdet") == 0) names.push_back(n);
    }
    std::sort(names.begin(), names.end());
    if (names.empty())
        throw Error("--model", "no default model for " + detect::describe_bands(layout) + " images in " + dir.string() + " (" + prefix +
                                   "*.cfdet); train one with `cityforge train` and pass --model");
    std::string best, trained;
    double best_distance = 0.0;
    for (const std::string& n : names) {
        const std::string path = (dir / n).string();
        const std::pair<double, double> r = training_gsd_range_m(detect::read_model_file(path));
        const double d = gsd_distance(r, gsd_m);
        if (best.empty() || d < best_distance) best = path, best_distance = d;
        trained += (trained.empty() ? "" : ", ") + n + " " + fixed_text(r.first, 2) + "-" + fixed_text(r.second, 2) + " m";
    }
    if (best_distance > std::log(kDefaultModelGsdReach) + 1e-9)
        throw Error("--model", "no default model fits a " + fixed_text(gsd_m, 3) + " m image (trained at " + trained + "; each serves up to " +
                                   fixed_text(kDefaultModelGsdReach, 0) + "x beyond its range): resample the image or train a model for it and pass --model");
    return best;
}

void TrainOptions::validate() const {
    if (orthos.empty()) throw Error("--ortho", "give at least one training image");
    if (labels.empty()) throw Error("--labels", "give the building labels (a polygon layer or a mask raster)");
    if (labels.size() != 1 && labels.size() != orthos.size())
        throw Error("--labels", "give one label file for all images or one per image (" + std::to_string(orthos.size()) + "), not " +
                                    std::to_string(labels.size()));
    if (nir_band < 0) throw Error("--nir-band", "must be >= 1");
    if (!ndsms.empty() && !clouds.empty()) throw Error("--ndsm", "give the heights as nDSM rasters (--ndsm) or clouds (--cloud), not both");
    if (!ndsms.empty() && ndsms.size() != orthos.size())
        throw Error("--ndsm", "give one nDSM per ortho (" + std::to_string(orthos.size()) + "), not " + std::to_string(ndsms.size()));
    if (!clouds.empty() && clouds.size() != orthos.size())
        throw Error("--cloud", "give one cloud per ortho (" + std::to_string(orthos.size()) + "), not " + std::to_string(clouds.size()));
    if (folds == 1 || folds < 0 || folds > 20) throw Error("--folds", "must be 0 (no cross-validation) or 2..20");
    if (!(fold_block_m > 0.0)) throw Error("--fold-block-m", "must be > 0");
    for (const int l : split_levels)
        if (l < 0 || l > 16) throw Error("--split-levels", "each split level must be between 0 and 16");
    for (const double t : thresholds)
        if (!(t > 0.0 && t < 1.0)) throw Error("--thresholds", "each threshold must be in (0, 1)");
    for (const double t : merge_thresholds)
        if (!(t > 0.0 && t < 1.0)) throw Error("--merge-thresholds", "each merge threshold must be in (0, 1)");
    for (const double m : neck_split_candidates_m)
        if (!(m > 0.0 && m <= 20.0)) throw Error("--neck-splits-m", "each neck split must be in (0, 20] metres");
    for (const double t : core_threshold_candidates)
        if (!(t > 0.0 && t < 1.0)) throw Error("--core-thresholds", "each core threshold must be in (0, 1)");
    if (!cv_out_dir.empty() && folds < 2) throw Error("--cv-out", "writes the cross-validation's result: give --folds 2 or more");
}

void DetectionScores::add(const DetectionScores& o) { tp += o.tp, predicted += o.predicted, reference += o.reference; }
void DetectionScores::finish() {
    precision = predicted ? double(tp) / double(predicted) : 0.0;
    recall = reference ? double(tp) / double(reference) : 0.0;
    f1 = precision + recall > 0 ? 2.0 * precision * recall / (precision + recall) : 0.0;
}

namespace {
// The model file and the --cv-out folder are refused before any work when
// they exist (the folder when not empty), unless `overwrite`.
void refuse_existing_train_outputs(const std::string& out_path, const TrainOptions& o, bool overwrite) {
    if (out_path.empty()) throw Error("--out", "give the model file to write");
    if (fs::exists(out_path) && !overwrite) throw Error(out_path, "exists; pass --overwrite to replace it");
    if (!o.cv_out_dir.empty() && fs::exists(o.cv_out_dir) && !(fs::is_directory(o.cv_out_dir) && fs::is_empty(o.cv_out_dir)) && !overwrite)
        throw Error(o.cv_out_dir, "exists and is not an empty folder; pass --overwrite to write the cross-validation's result into it");
}

// The image's training segments and those labelled building, added to the report.
void count_training_segments(const LabelledImage& li, double min_label_share, TrainReport& rep) {
    rep.segments += li.segments.count;
    for (uint32_t k = 1; k <= li.segments.count; ++k) rep.building_segments += li.share[k] >= min_label_share;
}

// Every training image read (heights as a last band when given), its labels
// burnt, segmented, and each segment's labelled share. `fp` takes each
// image's heights, normalised bands and label mask, in image order.
std::vector<LabelledImage> load_training_images(const TrainOptions& o, TrainReport& rep, uint64_t& fp, const Progress& progress) {
    std::vector<LabelledImage> data(o.orthos.size());
    for (std::size_t i = 0; i < o.orthos.size(); ++i) {
        LabelledImage& li = data[i];
        li.image = read_detection_image(o.orthos[i], o.nir_band);
        if (!o.ndsms.empty() || !o.clouds.empty()) {
            const Image<float> h = heights_on_image_grid(li.image, o.ndsms.empty() ? "" : o.ndsms[i], o.clouds.empty() ? "" : o.clouds[i], o.cloud_crs);
            add_ndsm_band(li.image, h);
            fp = detect::fnv1a64(h.data.data(), h.data.size() * sizeof(float), fp);
        }
        if (i > 0 && (li.image.layout.bands != data[0].image.layout.bands || li.image.layout.nir_band != data[0].image.layout.nir_band))
            throw Error(o.orthos[i], "has " + detect::describe_bands(li.image.layout) + ", " + o.orthos[0] + " has " +
                                         detect::describe_bands(data[0].image.layout) + ": one model is trained on one band set");
        if (i == 0) o.detector.validate(li.image.layout.bands);
        load_labels(li, o.labels.size() == 1 ? o.labels[0] : o.labels[i], o.label_layer);
        li.segments = detect::segment_scene(li.image.normalised, li.image.valid, o.detector.segmentation, {}, li.image.gsd_m);
        li.share = detect::building_share(li.segments, li.truth);
        fp = detect::fnv1a64(li.image.normalised.data.data(), li.image.normalised.data.size() * sizeof(float), fp);
        fp = detect::fnv1a64(li.truth.data(), li.truth.size(), fp);
        count_training_segments(li, o.detector.min_label_share, rep);
        rep.reference_buildings += li.reference.size();
        progress(0.5 * double(i + 1) / double(o.orthos.size()), "features");
    }
    if (rep.building_segments == 0) throw Error(o.labels[0], "no training segment is a building (labels and images do not overlap?)");
    return data;
}

// The cross-validation's folds: each image cut into blocks of fold_block_m.
detect::FoldBlocks make_training_folds(const std::vector<LabelledImage>& data, const TrainOptions& o) {
    std::vector<int> ws, hs, bs;
    for (const LabelledImage& li : data)
        ws.push_back(li.image.grid.width), hs.push_back(li.image.grid.height),
            bs.push_back(std::max(1, static_cast<int>(std::lround(o.fold_block_m / li.image.gsd_m))));
    return detect::make_folds(ws, hs, bs, o.folds, o.detector.booster.seed);
}

// Segment rows where keep(image, label): images in order, segments in label
// order; target 1 where at least `min_label_share` of the segment is labelled.
template <class Keep>
void segment_rows(const std::vector<LabelledImage>& data, double min_label_share, Keep&& keep, std::vector<float>& X, std::vector<float>& y,
                  std::vector<float>& wt) {
    for (std::size_t i = 0; i < data.size(); ++i) {
        const LabelledImage& li = data[i];
        for (uint32_t k = 1; k <= li.segments.count; ++k) {
            if (!keep(i, k) || li.features.pixel_count[k - 1] == 0) continue;
            const float* r = li.features.values.data() + std::size_t(k - 1) * li.features.cols;
            X.insert(X.end(), r, r + li.features.cols);
            y.push_back(li.share[k] >= min_label_share ? 1.0f : 0.0f);
            // Every segment counts once: object F1 counts small buildings
            // like large ones (measured on OAM dev CV: F1 0.511 vs 0.487
            // with sqrt(size) weights).
            wt.push_back(1.0f);
        }
    }
}

// Pair rows where keep(image, pair), examples only (pair_y >= 0).
template <class Keep>
void pair_rows(const std::vector<LabelledImage>& data, Keep&& keep, std::vector<float>& X, std::vector<float>& y, std::vector<float>& wt) {
    for (std::size_t i = 0; i < data.size(); ++i) {
        const LabelledImage& li = data[i];
        for (std::size_t k = 0; k < li.pairs.size(); ++k) {
            if (li.pair_y[k] < 0 || !keep(i, k)) continue;
            const float* r = li.pairs.values.data() + k * li.pairs.cols;
            X.insert(X.end(), r, r + li.pairs.cols);
            y.push_back(float(li.pair_y[k]));
            wt.push_back(1.0f);
        }
    }
}

// Out-of-fold probabilities: fold f predicted by the models trained on the others.
struct OutOfFold {
    std::vector<std::vector<float>> segments;  ///< per image, per label (index 0 unused): building probability
    std::vector<std::vector<float>> pairs;     ///< per image, per adjacent pair: "same building" probability
};

// Trains one segment model (and pair model when `merging`) per fold, the
// folds in parallel (each model on one thread: the bytes do not depend on the
// thread count), and predicts the held-out fold. Fills each fold's segment counts.
OutOfFold out_of_fold_probabilities(const std::vector<LabelledImage>& data, const TrainOptions& o, std::size_t feature_cols, std::size_t pair_cols,
                                    bool merging, std::vector<FoldReport>& fold_reports) {
    OutOfFold oof;
    for (const LabelledImage& li : data) oof.segments.emplace_back(li.segments.count + 1, 0.0f), oof.pairs.emplace_back(li.pairs.size(), 0.0f);
    fold_reports.resize(o.folds);
    tbb::parallel_for(0, o.folds, [&](int f) {
        std::vector<float> X, y, wt;
        segment_rows(data, o.detector.min_label_share, [&](std::size_t i, uint32_t k) { return data[i].fold[k - 1] != f; }, X, y, wt);
        fold_reports[f].fold = f + 1;
        fold_reports[f].train_segments = y.size();
        std::size_t pos = 0;
        for (const float v : y) pos += v > 0.5f;
        if (pos == 0) return;  // no building to learn from: fold predicts nothing
        const std::vector<uint8_t> model = detect::train_booster(X, y.size(), feature_cols, y, wt, o.detector.booster);
        for (std::size_t i = 0; i < data.size(); ++i) {
            const LabelledImage& li = data[i];
            std::vector<float> Xt;
            std::vector<uint32_t> ks;
            for (uint32_t k = 1; k <= li.segments.count; ++k)
                if (li.fold[k - 1] == f) {
                    const float* r = li.features.values.data() + std::size_t(k - 1) * li.features.cols;
                    Xt.insert(Xt.end(), r, r + li.features.cols);
                    ks.push_back(k);
                }
            const std::vector<float> p = detect::predict_booster(model, Xt, ks.size(), feature_cols, 1);
            for (std::size_t j = 0; j < ks.size(); ++j) oof.segments[i][ks[j]] = p[j];
            fold_reports[f].test_segments += ks.size();
        }
        if (!merging) return;
        // The pair classifier of the other folds (a pair belongs to its first segment's fold).
        std::vector<float> Xp, yp, wp;
        pair_rows(data, [&](std::size_t i, std::size_t k) { return data[i].fold[data[i].pairs.a[k] - 1] != f; }, Xp, yp, wp);
        std::size_t same = 0;
        for (const float v : yp) same += v > 0.5f;
        if (same == 0 || same == yp.size()) return;
        const std::vector<uint8_t> pair_model = detect::train_booster(Xp, yp.size(), pair_cols, yp, wp, o.detector.booster);
        for (std::size_t i = 0; i < data.size(); ++i) {
            const LabelledImage& li = data[i];
            std::vector<float> Xt;
            std::vector<std::size_t> ks;
            for (std::size_t k = 0; k < li.pairs.size(); ++k)
                if (li.fold[li.pairs.a[k] - 1] == f) {
                    const float* r = li.pairs.values.data() + k * li.pairs.cols;
                    Xt.insert(Xt.end(), r, r + li.pairs.cols);
                    ks.push_back(k);
                }
            const std::vector<float> p = detect::predict_booster(pair_model, Xt, ks.size(), pair_cols, 1);
            for (std::size_t j = 0; j < ks.size(); ++j) oof.pairs[i][ks[j]] = p[j];
        }
    });
    return oof;
}

// Object scores of detector options on the out-of-fold probabilities: the
// fitted footprints of each fold against its references at IoU >= 0.5.
class CrossValidation {
public:
    CrossValidation(const std::vector<LabelledImage>& data, const detect::FoldBlocks& folds, int fold_count, const OutOfFold& oof,
                    const detect::PixelStage& pixel, const detect::PixelStage& core)
        : data_(data), folds_(folds), fold_count_(fold_count), oof_(oof), pixel_(pixel), core_(core) {}

    /// Pooled object scores of `opts`; per fold (objects and segment pixels)
    /// and per image when asked (added to, not reset).
    DetectionScores score(const detect::DetectorOptions& opts, std::vector<FoldReport>* per_fold = nullptr,
                          std::vector<DetectionScores>* per_image = nullptr) const {
        DetectionScores pooled;
        for (std::size_t i = 0; i < data_.size(); ++i) {
            const LabelledImage& li = data_[i];
            const BuildingMask mask = out_of_fold_mask(li, oof_.segments[i], oof_.pairs[i], opts, opts.pixel.enabled ? &pixel_.out_of_fold[i] : nullptr,
                                                       opts.instance.enabled() ? &core_.out_of_fold[i] : nullptr);
            const auto pred = predicted_footprints(mask, li.image.gsd_m);
            DetectionScores img;
            for (int f = 0; f < fold_count_; ++f) {
                std::vector<std::vector<Polygon>> pf, rf;
                for (const auto& p : pred)
                    if (fold_of(folds_, i, p) == f) pf.push_back(p);
                for (const auto& r : li.reference)
                    if (fold_of(folds_, i, r) == f) rf.push_back(r);
                const FootprintScores s = match_footprints(pf, rf, 0.5);
                DetectionScores d;
                d.tp = s.true_positives, d.predicted = pf.size(), d.reference = rf.size();
                pooled.add(d);
                img.add(d);
                if (per_fold) {
                    (*per_fold)[f].objects.add(d);
                    (*per_fold)[f].segments.add(segment_pixel_scores(li, i, f, opts.threshold));
                }
            }
            img.finish();
            if (per_image) per_image->push_back(img);
        }
        pooled.finish();
        return pooled;
    }

private:
    // Labelled pixels of fold f's segments at or above the threshold (segment pixel scores).
    DetectionScores segment_pixel_scores(const LabelledImage& li, std::size_t image, int f, double threshold) const {
        double tp = 0, pr = 0, rf_px = 0;
        for (uint32_t k = 1; k <= li.segments.count; ++k) {
            if (li.fold[k - 1] != f) continue;
            const double n = li.features.pixel_count[k - 1];
            rf_px += li.share[k] * n;
            if (oof_.segments[image][k] >= threshold) pr += n, tp += li.share[k] * n;
        }
        DetectionScores px;
        px.tp = std::size_t(std::llround(tp)), px.predicted = std::size_t(std::llround(pr)), px.reference = std::size_t(std::llround(rf_px));
        return px;
    }

    const std::vector<LabelledImage>& data_;
    const detect::FoldBlocks& folds_;
    int fold_count_;
    const OutOfFold& oof_;
    const detect::PixelStage& pixel_;
    const detect::PixelStage& core_;
};

// The options with the best pooled object F1, step by step (each step keeps
// the earlier candidate on ties): every (split level, threshold) pair, the
// pair classifier's merge thresholds, pixels of the map joining buildings,
// neck splits, core cuts; the threshold tried again after a step that changed
// the buildings.
detect::DetectorOptions choose_detector_options(const CrossValidation& cv, const TrainOptions& o) {
    detect::DetectorOptions chosen = o.detector;
    double best_f1 = -1.0;
    std::vector<int> levels = o.split_levels;
    if (levels.empty()) levels = {o.detector.object_split_level};
    for (const int level : levels) {
        if (level >= int(o.detector.segmentation.scales.size())) continue;
        for (const double t : o.thresholds) {
            detect::DetectorOptions cand = o.detector;
            cand.threshold = t, cand.object_split_level = level;
            const DetectionScores s = cv.score(cand);
            if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.threshold = t, chosen.object_split_level = level;
        }
    }
    // Buildings grouped by the pair classifier instead of a split level.
    for (const double mt : o.merge_thresholds)
        for (const double t : o.thresholds) {
            detect::DetectorOptions cand = o.detector;
            cand.threshold = t, cand.object_split_level = 0, cand.merge_threshold = mt;
            const DetectionScores s = cv.score(cand);
            if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.threshold = t, chosen.object_split_level = 0, chosen.merge_threshold = mt;
        }
    auto retune_threshold = [&] {
        for (const double t : o.thresholds) {
            detect::DetectorOptions cand = chosen;
            cand.threshold = t;
            const DetectionScores s = cv.score(cand);
            if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.threshold = t;
        }
    };
    // Then pixels of the pixel map joining the buildings (0 = off), and the threshold again.
    if (o.detector.pixel.enabled) {
        for (const double pt : {0.6, 0.7, 0.8, 0.9}) {
            detect::DetectorOptions cand = chosen;
            cand.pixel_object_threshold = pt;
            const DetectionScores s = cv.score(cand);
            if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.pixel_object_threshold = pt;
        }
        if (chosen.pixel_object_threshold > 0.0) retune_threshold();
    }
    // Then touching buildings cut apart at narrow necks (0 = off), and the threshold again.
    for (const double nm : o.neck_split_candidates_m) {
        detect::DetectorOptions cand = chosen;
        cand.neck_split_m = nm;
        const DetectionScores s = cv.score(cand);
        if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.neck_split_m = nm;
    }
    if (chosen.neck_split_m > 0.0) retune_threshold();
    // Then buildings cut between the core CNN's cores (0 = off; pixel cuts, then
    // segments voting into cores), and the threshold again.
    for (const bool by_segments : {false, true})
        for (const double ct : o.core_threshold_candidates) {
            detect::DetectorOptions cand = chosen;
            cand.instance.core_threshold = ct;
            cand.instance.by_segments = by_segments;
            const DetectionScores s = cv.score(cand);
            if (s.f1 > best_f1 + 1e-12) best_f1 = s.f1, chosen.instance.core_threshold = ct, chosen.instance.by_segments = by_segments;
        }
    if (chosen.instance.enabled()) retune_threshold();
    return chosen;
}

nlohmann::json scores_json(const DetectionScores& s) {
    auto r3 = [](double v) { return std::round(v * 1000.0) / 1000.0; };
    return nlohmann::json{{"tp", s.tp}, {"predicted", s.predicted}, {"reference", s.reference},
                          {"precision", r3(s.precision)}, {"recall", r3(s.recall)}, {"f1", r3(s.f1)}};
}

// The model header's "training" block: sources, segment counts, the
// cross-validation's figures (null without one) and the version.
nlohmann::json training_header(const std::vector<LabelledImage>& data, const TrainOptions& o, const TrainReport& rep,
                               const detect::DetectorOptions& chosen) {
    nlohmann::json sources = nlohmann::json::array();
    for (std::size_t i = 0; i < data.size(); ++i) {
        sources.push_back({{"ortho", fs::path(o.orthos[i]).filename().string()},
                           {"labels", fs::path(o.labels.size() == 1 ? o.labels[0] : o.labels[i]).filename().string()},
                           {"gsd_m", std::round(data[i].image.gsd_m * 1e4) / 1e4},
                           {"segments", data[i].segments.count},
                           {"reference_buildings", data[i].reference.size()}});
        if (!o.ndsms.empty() || !o.clouds.empty())
            sources.back()["heights"] = fs::path(o.ndsms.empty() ? o.clouds[i] : o.ndsms[i]).filename().string();
    }
    nlohmann::json cvj = nullptr;
    if (o.folds >= 2) {
        nlohmann::json fold_json = nlohmann::json::array();
        for (const FoldReport& f : rep.folds)
            fold_json.push_back({{"fold", f.fold}, {"objects_iou_0.5", scores_json(f.objects)}, {"segment_pixels", scores_json(f.segments)}});
        nlohmann::json images = nlohmann::json::array();
        for (const auto& [name, s] : rep.per_image) images.push_back({{"ortho", fs::path(name).filename().string()}, {"objects_iou_0.5", scores_json(s)}});
        cvj = {{"folds", o.folds}, {"fold_block_m", o.fold_block_m}, {"threshold", chosen.threshold}, {"object_split_level", chosen.object_split_level}, {"per_fold", fold_json}, {"per_image", images},
               {"pooled_objects_iou_0.5", scores_json(rep.pooled_objects)}, {"pooled_segment_pixels", scores_json(rep.pooled_segments)}};
        if (chosen.merge_threshold > 0.0) cvj["merge_threshold"] = chosen.merge_threshold;  // absent when off: such models keep their bytes
    }
    return {{"sources", sources}, {"segments", rep.segments}, {"building_segments", rep.building_segments},
            {"cross_validation", cvj}, {"cityforge_version", CITYFORGE_VERSION}};
}
}  // namespace

TrainReport run_train(const std::string& out_path, const TrainOptions& o, bool overwrite, const Progress& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    o.validate();
    refuse_existing_train_outputs(out_path, o, overwrite);
    TrainReport rep;
    uint64_t fp = detect::fnv1a64("cityforge-train", 15);
    std::vector<LabelledImage> data = load_training_images(o, rep, fp, progress);
    const detect::BandLayout layout = data[0].image.layout;
    const detect::FoldBlocks folds = o.folds >= 2 ? make_training_folds(data, o) : detect::FoldBlocks{};
    // The pixel stage (src/detect/pixel_classifier): its out-of-fold maps give the segment features.
    const detect::PixelStage pixel = train_pixel_map_stage(data, layout, o, o.folds >= 2 ? &folds : nullptr);
    // Map-guided first segments: split along the map each segment will be classified with (out-of-fold in the CV).
    if (o.detector.map_split_threshold > 0.0) {  // validate(): only with the pixel stage
        rep.segments = rep.building_segments = 0;
        for (std::size_t i = 0; i < data.size(); ++i) {
            LabelledImage& li = data[i];
            detect::apply_map_split(li.segments, o.detector, &pixel.out_of_fold[i], li.image.gsd_m);
            li.share = detect::building_share(li.segments, li.truth);
            count_training_segments(li, o.detector.min_label_share, rep);
        }
    }
    // The core CNN (instance separation): trained when the CV has candidates, or when fixed on without CV.
    const bool want_core = o.folds >= 2 ? !o.core_threshold_candidates.empty() : o.detector.instance.enabled();
    detect::PixelStage core;
    if (want_core) {
        std::vector<std::vector<uint8_t>> cores;
        for (const LabelledImage& li : data) {
            cores.push_back(core_truth(li, o.detector.instance.core_depth_m));
            fp = detect::fnv1a64(cores.back().data(), cores.back().size(), fp);
        }
        core = train_core_stage(data, cores, layout, o, o.folds >= 2 ? &folds : nullptr);
    }
    for (std::size_t i = 0; i < data.size(); ++i)
        data[i].features = detect::segment_features(data[i].image.normalised, data[i].image.valid, data[i].segments, layout, data[i].image.gsd_m,
                                                    o.detector.pixel.enabled ? &pixel.out_of_fold[i] : nullptr);
    const std::vector<std::string> names = detect::feature_names(layout, int(o.detector.segmentation.scales.size()) - 1, o.detector.pixel.enabled);
    // Adjacent segment pairs and their "same building" labels (the pair classifier).
    const bool merging = !o.merge_thresholds.empty() || o.detector.merge_threshold > 0.0;
    const std::size_t pair_cols = detect::pair_feature_names(int(o.detector.segmentation.scales.size()) - 1, o.detector.pixel.enabled).size();
    if (merging)
        for (std::size_t i = 0; i < data.size(); ++i) {
            LabelledImage& li = data[i];
            li.pairs = detect::segment_pairs(li.image.normalised, li.segments, li.image.gsd_m, o.detector.pixel.enabled ? &pixel.out_of_fold[i] : nullptr);
            li.pair_y = detect::pair_labels(li.pairs, li.segments, li.share, li.reference_ids, o.detector.min_label_share);
        }
    rep.images = data.size();
    rep.features = names.size();
    rep.bands = detect::describe_bands(layout);

    detect::DetectorOptions chosen = o.detector;
    if (o.folds >= 2) {
        for (std::size_t i = 0; i < data.size(); ++i) {
            LabelledImage& li = data[i];
            li.fold.resize(li.segments.count);
            for (uint32_t k = 1; k <= li.segments.count; ++k)
                li.fold[k - 1] = folds.fold_at(i, li.features.centroid_col[k - 1] + 0.5, li.features.centroid_row[k - 1] + 0.5);
        }
        const OutOfFold oof = out_of_fold_probabilities(data, o, names.size(), pair_cols, merging, rep.folds);
        progress(0.8, "cross-validation");
        const CrossValidation cv(data, folds, o.folds, oof, pixel, core);
        chosen = choose_detector_options(cv, o);
        std::vector<DetectionScores> per_image;
        rep.pooled_objects = cv.score(chosen, &rep.folds, &per_image);
        if (!o.cv_out_dir.empty()) write_cv_out(o.cv_out_dir, o.orthos, data, folds, oof.segments, oof.pairs, pixel, core, chosen);
        for (FoldReport& f : rep.folds) {
            f.objects.finish();
            f.segments.finish();
            rep.pooled_segments.add(f.segments);
        }
        rep.pooled_segments.finish();
        for (std::size_t i = 0; i < data.size(); ++i) rep.per_image.emplace_back(o.orthos[i], per_image[i]);
    }
    rep.threshold = chosen.threshold;
    rep.object_split_level = chosen.object_split_level;
    rep.merge_threshold = chosen.merge_threshold;

    // The model: every segment.
    std::vector<float> X, y, wt;
    segment_rows(data, o.detector.min_label_share, [](std::size_t, uint32_t) { return true; }, X, y, wt);
    detect::DetectorModel model;
    model.layout = layout;
    model.features = names;
    model.options = chosen;
    model.booster = detect::train_booster(X, y.size(), names.size(), y, wt, o.detector.booster);
    model.pixel_model = pixel.model;
    if (chosen.instance.enabled()) model.core_model = core.model;
    if (chosen.merge_threshold > 0.0) {
        std::vector<float> Xp, yp, wp;
        pair_rows(data, [](std::size_t, std::size_t) { return true; }, Xp, yp, wp);
        model.merge_model = detect::train_booster(Xp, yp.size(), pair_cols, yp, wp, o.detector.booster);
    }
    const std::string opts = detect::to_json(o.detector).dump();
    fp = detect::fnv1a64(opts.data(), opts.size(), fp);
    model.fingerprint = detect::hex64(fp);
    rep.fingerprint = model.fingerprint;
    model.training = training_header(data, o, rep, chosen);
    const std::vector<uint8_t> bytes = detect::serialize_model(model);
    rep.model_bytes = bytes.size();
    detect::write_model_file(out_path, model);
    progress(1.0, "written");
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
}

}  // namespace cityforge
