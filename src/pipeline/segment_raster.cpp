#include "pipeline/segment_raster.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <set>
#include <sstream>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "raster/raster.hpp"

namespace cityforge {

void SegmentOptions::validate() const {
    if (!(working_gsd_m >= 0.0 && working_gsd_m <= 100.0)) throw Error("--gsd", "working GSD must be between 0 and 100 m");
    for (int b : bands)
        if (b < 1) throw Error("--bands", "band numbers start at 1");
}

SegmentOptions segment_options_from_json(const nlohmann::json& j, const std::string& source) {
    if (!j.is_object()) throw Error(source, "segment config must be a JSON object");
    SegmentOptions o;
    static const std::set<std::string> known{"scales", "strategy", "color_weight", "compactness", "band_weights",
                                             "h_minima", "smoothing_sigma_px", "working_gsd_m", "bands"};
    for (const auto& [k, v] : j.items())
        if (!known.count(k)) throw Error(source, "unknown key '" + k + "' in segment config");
    try {
        if (j.contains("scales")) o.merging.scales = j.at("scales").get<std::vector<double>>();
        if (j.contains("strategy")) o.merging.strategy = queue_strategy_from_string(j.at("strategy").get<std::string>());
        if (j.contains("color_weight")) o.merging.color_weight = j.at("color_weight").get<double>();
        if (j.contains("compactness")) o.merging.compactness = j.at("compactness").get<double>();
        if (j.contains("band_weights")) {
            o.merging.band_weights = j.at("band_weights").get<std::vector<double>>();
            o.watershed.band_weights = o.merging.band_weights;
        }
        if (j.contains("h_minima")) o.watershed.h_minima = j.at("h_minima").get<double>();
        if (j.contains("smoothing_sigma_px")) o.watershed.smoothing_sigma_px = j.at("smoothing_sigma_px").get<double>();
        if (j.contains("working_gsd_m")) o.working_gsd_m = j.at("working_gsd_m").get<double>();
        if (j.contains("bands")) o.bands = j.at("bands").get<std::vector<int>>();
    } catch (const nlohmann::json::exception& e) {
        throw Error(source, std::string("bad value in segment config: ") + e.what());
    }
    return o;
}

namespace {

std::string scale_name(double s) {
    std::ostringstream o;
    if (s == std::floor(s)) o << static_cast<long long>(s);
    else o << s;
    return o.str();
}

}  // namespace

std::string segment_level_path(const std::string& out_dir, double scale) {
    return (std::filesystem::path(out_dir) / ("segments_scale_" + scale_name(scale) + ".tif")).string();
}

namespace {
// Nearest-neighbour transfer of working-grid labels back to the input grid.
Image<uint32_t> to_input_grid(const Image<uint32_t>& work, int width, int height) {
    if (work.width == width && work.height == height) return work;
    Image<uint32_t> out(width, height, 1, 0u);
    for (int r = 0; r < height; ++r) {
        const int wr = std::min(work.height - 1, static_cast<int>((r + 0.5) * work.height / height));
        for (int c = 0; c < width; ++c) {
            const int wc = std::min(work.width - 1, static_cast<int>((c + 0.5) * work.width / width));
            out.at(0, c, r) = work.at(0, wc, wr);
        }
    }
    return out;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

SegmentReport segment_raster(const std::string& path, const std::string& out_dir, const SegmentOptions& o,
                             const Progress& progress) {
    o.validate();
    auto t0 = std::chrono::steady_clock::now();
    RasterOpenOptions ro;
    ro.allow_pixel_coordinates = o.allow_pixel_coordinates;
    RasterReader reader(path, ro);
    const RasterInfo& info = reader.info();
    std::vector<int> bands = o.bands;
    if (bands.empty())
        for (int b = 1; b <= info.band_count(); ++b) bands.push_back(b);
    for (int b : bands)
        if (b > info.band_count())
            throw Error(path, "band " + std::to_string(b) + " requested but the raster has " + std::to_string(info.band_count()));
    o.watershed.validate(static_cast<int>(bands.size()));
    o.merging.validate(static_cast<int>(bands.size()));

    SegmentReport rep;
    rep.input_path = path;
    rep.crs = info.georeferenced ? info.crs.label() : "pixel coordinates";
    rep.input_width = info.width, rep.input_height = info.height;
    rep.input_gsd_m = info.gsd.x_m;
    rep.strategy = to_string(o.merging.strategy);
    // Working grid: resample when the GSD differs by more than 1 %.
    int ww = info.width, wh = info.height;
    if (o.working_gsd_m > 0.0 && std::abs(info.gsd.x_m / o.working_gsd_m - 1.0) > 0.01) {
        ww = std::max(1, static_cast<int>(std::lround(info.width * info.gsd.x_m / o.working_gsd_m)));
        wh = std::max(1, static_cast<int>(std::lround(info.height * info.gsd.y_m / o.working_gsd_m)));
    }
    rep.working_width = ww, rep.working_height = wh;
    rep.working_gsd_m = info.gsd.x_m * info.width / ww;
    const PixelWindow all{0, 0, info.width, info.height};
    const std::string method = ww == info.width ? "nearest" : (ww < info.width ? "average" : "bilinear");
    Image<float> image = reader.read_resampled<float>(all, ww, wh, bands, method);
    // Valid mask: a pixel is nodata when any used band holds its nodata value.
    std::vector<uint8_t> valid(image.pixel_count(), 1);
    bool any_nodata = false;
    for (std::size_t k = 0; k < bands.size(); ++k) {
        const auto& nd = info.bands[bands[k] - 1].nodata;
        if (!nd) continue;
        any_nodata = true;
        const Image<float> nearest = method == "nearest" ? Image<float>() : reader.read_resampled<float>(all, ww, wh, {bands[k]}, "nearest");
        const float* v = method == "nearest" ? image.band_data(static_cast<int>(k)) : nearest.band_data(0);
        for (std::size_t i = 0; i < valid.size(); ++i)
            if (v[i] == static_cast<float>(*nd)) valid[i] = 0;
    }
    if (any_nodata && std::none_of(valid.begin(), valid.end(), [](uint8_t v) { return v != 0; }))
        throw Error(path, "raster holds only nodata pixels");
    normalize_bands(image, valid);
    {
        // A raster of one colour has nothing to segment.
        bool varies = false;
        for (int b = 0; b < image.bands && !varies; ++b) {
            const float* v = image.band_data(b);
            float first = 0.0f;
            bool have = false;
            for (std::size_t i = 0; i < valid.size(); ++i) {
                if (!valid[i]) continue;
                if (!have) first = v[i], have = true;
                else if (v[i] != first) {
                    varies = true;
                    break;
                }
            }
        }
        if (!varies) throw Error(path, "raster has a single value everywhere: nothing to segment");
    }
    rep.read_seconds = seconds_since(t0);
    progress(0.1, "read");

    t0 = std::chrono::steady_clock::now();
    const Oversegmentation over = watershed_oversegment(image, valid, o.watershed, progress.sub(0.1, 0.4));
    rep.oversegmentation_regions = over.region_count;
    rep.watershed_seconds = seconds_since(t0);
    log::info("watershed: " + std::to_string(over.region_count) + " regions");

    const RegionMergingResult merged = merge_regions(image, over.labels, over.region_count, o.merging, progress.sub(0.4, 0.7));

    namespace fs = std::filesystem;
    ensure_directory(out_dir);
    const GeoTransform& gt = info.transform;
    const std::string wkt = info.georeferenced ? info.crs.wkt : "";
    GeoTiffWriteOptions wo;
    wo.nodata = 0.0;
    rep.oversegmentation_path = (fs::path(out_dir) / "oversegmentation.tif").string();
    write_geotiff(rep.oversegmentation_path, to_input_grid(over.labels, info.width, info.height), gt, wkt, wo);
    nlohmann::json hierarchy;
    hierarchy["levels"] = nlohmann::json::array();
    for (std::size_t s = 0; s < merged.levels.size(); ++s) {
        const ScaleLevel& l = merged.levels[s];
        SegmentLevelReport lr;
        lr.scale = l.scale;
        lr.regions_before = l.regions_before, lr.regions_after = l.regions_after;
        lr.initial_queue_length = l.initial_queue_length, lr.merges = l.merges, lr.queue_pushes = l.queue_pushes;
        lr.seconds = l.seconds;
        lr.labels_path = segment_level_path(out_dir, l.scale);
        write_geotiff(lr.labels_path, to_input_grid(relabel(over.labels, l.label_of_input), info.width, info.height), gt, wkt, wo);
        hierarchy["levels"].push_back({{"scale", l.scale},
                                       {"from", s == 0 ? std::string("oversegmentation.tif") : fs::path(rep.levels.back().labels_path).filename().string()},
                                       {"to", fs::path(lr.labels_path).filename().string()},
                                       {"parent", l.parent}});
        rep.levels.push_back(lr);
        progress(0.7 + 0.3 * double(s + 1) / double(merged.levels.size()), "writing");
    }
    rep.hierarchy_path = (fs::path(out_dir) / "hierarchy.json").string();
    write_text_file(rep.hierarchy_path, hierarchy.dump() + "\n");
    write_text_file((fs::path(out_dir) / "segment_report.json").string(), to_json(rep).dump(2) + "\n");
    return rep;
}

nlohmann::json to_json(const SegmentReport& r) {
    nlohmann::json j;
    j["input"] = {{"path", r.input_path}, {"crs", r.crs}, {"width", r.input_width}, {"height", r.input_height}, {"gsd_m", r.input_gsd_m}};
    j["working_grid"] = {{"width", r.working_width}, {"height", r.working_height}, {"gsd_m", r.working_gsd_m}};
    j["read_seconds"] = r.read_seconds;
    j["oversegmentation"] = {{"regions", r.oversegmentation_regions}, {"seconds", r.watershed_seconds},
                             {"labels", std::filesystem::path(r.oversegmentation_path).filename().string()}};
    j["strategy"] = r.strategy;
    j["hierarchy"] = std::filesystem::path(r.hierarchy_path).filename().string();
    nlohmann::json levels = nlohmann::json::array();
    for (const auto& l : r.levels)
        levels.push_back({{"scale", l.scale},
                          {"regions_before", l.regions_before},
                          {"regions_after", l.regions_after},
                          {"initial_queue_length", l.initial_queue_length},
                          {"merges", l.merges},
                          {"queue_pushes", l.queue_pushes},
                          {"seconds", l.seconds},
                          {"labels", std::filesystem::path(l.labels_path).filename().string()}});
    j["scales"] = levels;
    return j;
}

}  // namespace cityforge
