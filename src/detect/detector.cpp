#include "detect/detector.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <queue>

#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "detect/segment_merge.hpp"

namespace cityforge::detect {

namespace {
constexpr char kMagic[] = "CFDET1\n";
constexpr std::size_t kMagicLen = 7;

void put_u64(std::vector<uint8_t>& out, uint64_t v) {
    for (int i = 0; i < 8; ++i) out.push_back(static_cast<uint8_t>(v >> (8 * i)));
}
uint64_t get_u64(const std::vector<uint8_t>& in, std::size_t at) {
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= uint64_t(in[at + i]) << (8 * i);
    return v;
}
}  // namespace

uint64_t fnv1a64(const void* data, std::size_t n, uint64_t h) {
    const auto* p = static_cast<const uint8_t*>(data);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 0x100000001b3ULL;
    return h;
}

std::string hex64(uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

void InstanceOptions::validate() const {
    if (!(core_threshold >= 0.0 && core_threshold < 1.0)) throw Error("instance.core_threshold", "must be in [0, 1) (0 = off)");
    if (!(core_depth_m > 0.0 && core_depth_m <= 10.0)) throw Error("instance.core_depth_m", "must be in (0, 10] metres");
    if (!(min_core_m2 >= 0.0)) throw Error("instance.min_core_m2", "must be >= 0");
    pixel_options().validate();
}

PixelClassifierOptions InstanceOptions::pixel_options() const {
    PixelClassifierOptions p;
    p.kind = PixelStageKind::cnn;
    p.cell_m = cell_m;
    p.cnn = cnn;
    return p;
}

void DetectorOptions::validate(int bands) const {
    segmentation.validate(bands);
    instance.validate();
    booster.validate();
    if (pixel.enabled) pixel.validate();
    if (!(min_label_share > 0.0 && min_label_share < 1.0)) throw Error("min_label_share", "must be in (0, 1)");
    if (!(threshold > 0.0 && threshold < 1.0)) throw Error("threshold", "must be in (0, 1)");
    if (object_split_level < 0 || object_split_level >= int(segmentation.scales.size()))
        throw Error("object_split_level", "must be 0 or a context scale (1.." + std::to_string(segmentation.scales.size() - 1) + ")");
    if (!(min_area_m2 >= 0.0)) throw Error("min_area_m2", "must be >= 0");
    if (!(pixel_object_threshold >= 0.0 && pixel_object_threshold < 1.0)) throw Error("pixel_object_threshold", "must be in [0, 1) (0 = off)");
    if (pixel_object_threshold > 0.0 && !pixel.enabled) throw Error("pixel_object_threshold", "needs the pixel stage");
    if (!(min_hole_m2 >= 0.0)) throw Error("min_hole_m2", "must be >= 0");
    if (!(merge_threshold >= 0.0 && merge_threshold < 1.0)) throw Error("merge_threshold", "must be in [0, 1) (0 = off)");
    if (!(neck_split_m >= 0.0 && neck_split_m <= 20.0)) throw Error("neck_split_m", "must be in [0, 20] metres (0 = off)");
    if (!(map_split_threshold >= 0.0 && map_split_threshold < 1.0)) throw Error("map_split_threshold", "must be in [0, 1) (0 = off)");
    if (map_split_threshold > 0.0 && !pixel.enabled) throw Error("map_split_threshold", "needs the pixel stage");
    if (!(map_split_min_m2 >= 0.0 && map_split_min_m2 <= 1000.0)) throw Error("map_split_min_m2", "must be in [0, 1000] square metres");
}

std::size_t apply_map_split(SceneSegments& segments, const DetectorOptions& options, const std::vector<float>* pixel_map, double gsd_m) {
    if (!(options.map_split_threshold > 0.0) || pixel_map == nullptr) return 0;
    if (!(gsd_m > 0.0)) throw Error("map_split", "internal: needs the image's GSD");
    const auto min_pixels = static_cast<std::size_t>(std::ceil(options.map_split_min_m2 / (gsd_m * gsd_m) - 1e-9));
    return split_segments_by_map(segments, *pixel_map, options.map_split_threshold, min_pixels);
}

void encode_linear_counts(Image<float>& image, int band) {
    if (band < 0 || band >= image.bands) throw Error("encode_linear_counts", "band " + std::to_string(band) + " does not exist");
    float* v = image.band_data(band);
    for (std::size_t i = 0; i < image.pixel_count(); ++i) v[i] = std::sqrt(std::max(v[i], 0.0f));
}

std::string describe_bands(const BandLayout& l) {
    if (l.ndsm_band >= 0) {
        BandLayout image = l;
        image.bands -= 1, image.ndsm_band = -1;
        return (image.bands > 0 ? describe_bands(image) : std::string("no image band")) + "+nDSM";
    }
    if (l.bands == 1) return "pan";
    if (l.bands == 3 && l.nir_band < 0) return "RGB";
    if (l.bands == 4 && l.nir_band == 3) return "RGB+NIR";
    return std::to_string(l.bands) + " bands" + (l.nir_band >= 0 ? " (NIR band " + std::to_string(l.nir_band + 1) + ")" : "");
}

namespace {
// The options of a booster (the segment classifier's or the pixel stage's) in a model header.
nlohmann::json booster_json(const BoosterOptions& b) {
    return {{"rounds", b.rounds},         {"max_depth", b.max_depth},
            {"learning_rate", b.learning_rate}, {"subsample", b.subsample},
            {"colsample", b.colsample},   {"min_child_weight", b.min_child_weight},
            {"lambda", b.lambda},         {"seed", b.seed}};
}
BoosterOptions booster_from_json(const nlohmann::json& b) {
    BoosterOptions o;
    o.rounds = b.at("rounds").get<int>();
    o.max_depth = b.at("max_depth").get<int>();
    o.learning_rate = b.at("learning_rate").get<double>();
    o.subsample = b.at("subsample").get<double>();
    o.colsample = b.at("colsample").get<double>();
    o.min_child_weight = b.at("min_child_weight").get<double>();
    o.lambda = b.at("lambda").get<double>();
    o.seed = b.at("seed").get<uint64_t>();
    return o;
}
nlohmann::json cnn_json(const CnnOptions& c) {
    nlohmann::json j = {{"base_channels", c.base_channels}, {"levels", c.levels}, {"crop_cells", c.crop_cells},
                        {"batch", c.batch}, {"steps", c.steps}, {"learning_rate", c.learning_rate}, {"seed", c.seed}};
    if (c.tta != 1) j["tta"] = c.tta;  // written only when on: models without it keep their header bytes
    return j;
}
CnnOptions cnn_from_json(const nlohmann::json& c) {
    CnnOptions o;
    o.base_channels = c.at("base_channels").get<int>();
    o.levels = c.at("levels").get<int>();
    o.crop_cells = c.at("crop_cells").get<int>();
    o.batch = c.at("batch").get<int>();
    o.steps = c.at("steps").get<int>();
    o.learning_rate = c.at("learning_rate").get<double>();
    o.seed = c.at("seed").get<uint64_t>();
    o.tta = c.value("tta", 1);  // absent: no test-time augmentation
    return o;
}
}  // namespace

nlohmann::json to_json(const DetectorOptions& o) {
    const auto& s = o.segmentation;
    nlohmann::json j = {{"segmentation",
             {{"h_minima", s.watershed.h_minima}, {"smoothing_sigma_px", s.watershed.smoothing_sigma_px},
              {"band_weights", s.watershed.band_weights}, {"scales", s.scales}, {"color_weight", s.color_weight}, {"reference_gsd_m", s.reference_gsd_m}}},
            {"booster", booster_json(o.booster)},
            {"pixel",
             {{"enabled", o.pixel.enabled},
              {"kind", to_string(o.pixel.kind)},
              {"cnn", cnn_json(o.pixel.cnn)},
              {"cell_m", o.pixel.cell_m},
              {"sigmas_m", o.pixel.sigmas_m},
              {"samples_per_image", o.pixel.samples_per_image},
              {"booster", booster_json(o.pixel.booster)}}},
            {"min_label_share", o.min_label_share},
            {"threshold", o.threshold},
            {"object_split_level", o.object_split_level},
            {"pixel_object_threshold", o.pixel_object_threshold},
            {"min_area_m2", o.min_area_m2},
            {"min_hole_m2", o.min_hole_m2}};
    // Written only when on: models without the pair classifier keep their header bytes.
    if (o.merge_threshold > 0.0) j["merge_threshold"] = o.merge_threshold;
    if (o.neck_split_m > 0.0) j["neck_split_m"] = o.neck_split_m;  // likewise
    if (o.map_split_threshold > 0.0) j["map_split"] = {{"threshold", o.map_split_threshold}, {"min_m2", o.map_split_min_m2}};  // likewise
    if (o.instance.enabled())  // likewise
        j["instance"] = {{"core_threshold", o.instance.core_threshold}, {"core_depth_m", o.instance.core_depth_m},
                         {"min_core_m2", o.instance.min_core_m2}, {"cell_m", o.instance.cell_m}, {"cnn", cnn_json(o.instance.cnn)}};
    if (o.instance.enabled() && o.instance.by_segments) j["instance"]["by_segments"] = true;
    return j;
}

DetectorOptions detector_options_from_json(const nlohmann::json& j) {
    DetectorOptions o;
    const auto& s = j.at("segmentation");
    o.segmentation.watershed.h_minima = s.at("h_minima").get<double>();
    o.segmentation.watershed.smoothing_sigma_px = s.at("smoothing_sigma_px").get<double>();
    o.segmentation.watershed.band_weights = s.at("band_weights").get<std::vector<double>>();
    o.segmentation.scales = s.at("scales").get<std::vector<double>>();
    o.segmentation.color_weight = s.at("color_weight").get<double>();
    o.segmentation.reference_gsd_m = s.value("reference_gsd_m", 0.0);
    o.booster = booster_from_json(j.at("booster"));
    if (j.contains("pixel")) {
        const auto& p = j.at("pixel");
        o.pixel.enabled = p.at("enabled").get<bool>();
        o.pixel.cell_m = p.at("cell_m").get<double>();
        o.pixel.sigmas_m = p.at("sigmas_m").get<std::vector<double>>();
        o.pixel.samples_per_image = p.at("samples_per_image").get<std::size_t>();
        o.pixel.booster = booster_from_json(p.at("booster"));
        o.pixel.kind = parse_pixel_stage_kind(p.value("kind", std::string("boosted")));  // absent before the CNN kind
        if (p.contains("cnn")) o.pixel.cnn = cnn_from_json(p.at("cnn"));
    } else {
        o.pixel.enabled = false;  // models from before the pixel stage
    }
    o.min_label_share = j.at("min_label_share").get<double>();
    o.object_split_level = j.value("object_split_level", 0);
    o.pixel_object_threshold = j.value("pixel_object_threshold", 0.0);
    o.merge_threshold = j.value("merge_threshold", 0.0);
    o.neck_split_m = j.value("neck_split_m", 0.0);
    if (j.contains("map_split")) {  // absent before map-guided segments, or off
        o.map_split_threshold = j.at("map_split").at("threshold").get<double>();
        o.map_split_min_m2 = j.at("map_split").at("min_m2").get<double>();
    }
    if (j.contains("instance")) {  // absent before the instance stage, or off
        const auto& in = j.at("instance");
        o.instance.core_threshold = in.at("core_threshold").get<double>();
        o.instance.core_depth_m = in.at("core_depth_m").get<double>();
        o.instance.min_core_m2 = in.at("min_core_m2").get<double>();
        o.instance.cell_m = in.at("cell_m").get<double>();
        o.instance.cnn = cnn_from_json(in.at("cnn"));
        o.instance.by_segments = in.value("by_segments", false);
    }
    o.threshold = j.at("threshold").get<double>();
    o.min_area_m2 = j.at("min_area_m2").get<double>();
    o.min_hole_m2 = j.at("min_hole_m2").get<double>();
    return o;
}

std::vector<uint8_t> serialize_model(const DetectorModel& m) {
    const bool pixel = m.options.pixel.enabled;
    const bool cnn = pixel && m.options.pixel.kind != PixelStageKind::boosted;
    if (pixel && m.pixel_model.empty()) throw Error("detector model", "internal: pixel stage without its model");
    const bool merge = m.options.merge_threshold > 0.0;
    if (merge && m.merge_model.empty()) throw Error("detector model", "internal: merge threshold without the pair classifier");
    const bool instance = m.options.instance.enabled();
    if (instance && m.core_model.empty()) throw Error("detector model", "internal: instance stage without its core CNN");
    nlohmann::json header = {{"format", "cityforge-detector"},
                                   {"format_version", cnn ? 3 : pixel ? 2 : 1},
                                   {"classifier", "xgboost gbtree (binary:logistic, hist)"},
                                   {"bands", describe_bands(m.layout)},
                                   {"band_count", m.layout.bands},
                                   {"nir_band", m.layout.nir_band},
                                   {"features", m.features},
                                   {"options", to_json(m.options)},
                                   {"fingerprint", m.fingerprint},
                                   {"training", m.training}};
    if (m.layout.ndsm_band >= 0) header["ndsm_band"] = m.layout.ndsm_band;
    if (merge) header["merge_features"] = pair_feature_names(int(m.options.segmentation.scales.size()) - 1, pixel);  // absent: no nDSM band (older models parse alike)
    const std::string text = header.dump(1);
    std::vector<uint8_t> out(kMagic, kMagic + kMagicLen);
    put_u64(out, text.size());
    out.insert(out.end(), text.begin(), text.end());
    put_u64(out, m.booster.size());
    out.insert(out.end(), m.booster.begin(), m.booster.end());
    if (pixel) {
        put_u64(out, m.pixel_model.size());
        out.insert(out.end(), m.pixel_model.begin(), m.pixel_model.end());
    }
    if (merge) {
        put_u64(out, m.merge_model.size());
        out.insert(out.end(), m.merge_model.begin(), m.merge_model.end());
    }
    if (instance) {
        put_u64(out, m.core_model.size());
        out.insert(out.end(), m.core_model.begin(), m.core_model.end());
    }
    put_u64(out, fnv1a64(out.data(), out.size()));
    return out;
}

DetectorModel parse_model(const std::vector<uint8_t>& in, const std::string& subject) {
    if (in.size() < kMagicLen + 24 || std::memcmp(in.data(), kMagic, kMagicLen) != 0)
        throw Error(subject, "not a cityforge detector model (train one with `cityforge train`)");
    const std::size_t n = in.size();
    const uint64_t hlen = get_u64(in, kMagicLen);
    if (hlen > n - kMagicLen - 24) throw Error(subject, "truncated detector model (header)");
    const std::size_t bat = kMagicLen + 8 + hlen;
    // Length-prefixed blobs (booster, then the pixel booster of format 2) up to the checksum.
    std::vector<std::pair<std::size_t, std::size_t>> blobs;  // offset, length
    for (std::size_t at = bat; at < n - 8;) {
        if (at + 8 > n - 8) throw Error(subject, "truncated detector model (blob length)");
        const uint64_t len = get_u64(in, at);
        if (len > n - 8 - (at + 8)) throw Error(subject, "truncated or padded detector model (a block runs past the end: " + std::to_string(n) + " bytes)");
        blobs.emplace_back(at + 8, std::size_t(len));
        at += 8 + len;
        if (blobs.size() > 4) throw Error(subject, "corrupt detector model (too many blocks)");
    }
    if (blobs.empty()) throw Error(subject, "truncated detector model (no booster)");
    if (get_u64(in, n - 8) != fnv1a64(in.data(), n - 8)) throw Error(subject, "corrupt detector model (checksum mismatch)");
    DetectorModel m;
    int version = 1;
    std::vector<std::string> merge_features;
    try {
        const auto header = nlohmann::json::parse(in.begin() + kMagicLen + 8, in.begin() + static_cast<std::ptrdiff_t>(bat));
        version = header.at("format_version").get<int>();
        if (header.at("format").get<std::string>() != "cityforge-detector" || version < 1 || version > 3)
            throw Error(subject, "unsupported detector model format");
        m.layout.bands = header.at("band_count").get<int>();
        m.layout.nir_band = header.at("nir_band").get<int>();
        m.layout.ndsm_band = header.value("ndsm_band", -1);
        m.features = header.at("features").get<std::vector<std::string>>();
        m.options = detector_options_from_json(header.at("options"));
        m.fingerprint = header.at("fingerprint").get<std::string>();
        m.training = header.at("training");
        if (header.contains("merge_features")) merge_features = header.at("merge_features").get<std::vector<std::string>>();
    } catch (const nlohmann::json::exception& e) {
        throw Error(subject, std::string("invalid detector model header: ") + e.what());
    }
    try {
        m.options.validate(m.layout.bands);
    } catch (const Error& e) {  // "option: problem", said of the file that holds it
        throw Error(subject, std::string("invalid option in the detector model header: ") + e.what());
    }
    const bool cnn = m.options.pixel.enabled && m.options.pixel.kind != PixelStageKind::boosted;
    const bool merge = m.options.merge_threshold > 0.0;
    const bool instance = m.options.instance.enabled();
    if (blobs.size() != 1u + (m.options.pixel.enabled ? 1u : 0u) + (merge ? 1u : 0u) + (instance ? 1u : 0u) || (version >= 2) != m.options.pixel.enabled || (version == 3) != cnn)
        throw Error(subject, "corrupt detector model (block count does not match the header)");
    if (merge && merge_features != pair_feature_names(int(m.options.segmentation.scales.size()) - 1, m.options.pixel.enabled))
        throw Error(subject, "the model's pair feature list is not the one this version of cityforge computes");
    if (m.features != feature_names(m.layout, int(m.options.segmentation.scales.size()) - 1, m.options.pixel.enabled))
        throw Error(subject, "the model's feature list is not the one this version of cityforge computes");
    auto blob = [&](std::size_t k) {
        return std::vector<uint8_t>(in.begin() + std::ptrdiff_t(blobs[k].first), in.begin() + std::ptrdiff_t(blobs[k].first + blobs[k].second));
    };
    m.booster = blob(0);
    if (m.options.pixel.enabled) m.pixel_model = blob(1);
    if (merge) m.merge_model = blob(m.options.pixel.enabled ? 2 : 1);
    if (instance) {
        m.core_model = blob(blobs.size() - 1);
        check_cnn_weights(m.core_model, m.layout.bands, m.options.instance.cnn, subject);
    }
    if (m.options.pixel.enabled && m.options.pixel.kind == PixelStageKind::cnn) check_cnn_weights(m.pixel_model, m.layout.bands, m.options.pixel.cnn, subject);
    if (m.options.pixel.enabled && m.options.pixel.kind == PixelStageKind::both)
        check_cnn_weights(unpack_pixel_models(m.pixel_model, subject).second, m.layout.bands, m.options.pixel.cnn, subject);
    return m;
}

DetectorModel read_model_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path, std::filesystem::exists(path) ? "cannot read the model" : "model not found");
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    return parse_model(bytes, path);
}

void write_model_file(const std::string& path, const DetectorModel& model) {
    const std::vector<uint8_t> bytes = serialize_model(model);
    write_text_file(path, std::string(bytes.begin(), bytes.end()));
}

void check_bands(const DetectorModel& model, const BandLayout& l, const std::string& image) {
    if (model.layout.ndsm_band >= 0 && l.ndsm_band < 0)
        throw Error(image, "has no nDSM band; the detector model was trained on " + describe_bands(model.layout) +
                               ": give the heights (--ndsm N.tif or --cloud C with --mode ortho_only)");
    if (model.layout.ndsm_band < 0 && l.ndsm_band >= 0)
        throw Error(image, "was given heights, but the detector model was trained on " + describe_bands(model.layout) + " without an nDSM band");
    if (l.bands != model.layout.bands || l.nir_band != model.layout.nir_band || l.ndsm_band != model.layout.ndsm_band)
        throw Error(image, "has " + describe_bands(l) + " (" + std::to_string(l.bands) + " band" + (l.bands == 1 ? "" : "s") +
                               " besides any alpha); the detector model was trained on " + describe_bands(model.layout) + " (" +
                               std::to_string(model.layout.bands) + " band" + (model.layout.bands == 1 ? "" : "s") + ")");
}

std::vector<float> segment_probabilities(const DetectorModel& model, const FeatureMatrix& f, int threads) {
    const std::vector<float> p = predict_booster(model.booster, f.values, f.rows, f.cols, threads);
    std::vector<float> out(f.rows + 1, 0.0f);
    std::copy(p.begin(), p.end(), out.begin() + 1);
    return out;
}

std::vector<uint8_t> building_pixels(const SceneSegments& s, const std::vector<float>& probability, double threshold, int split_level,
                                     const std::vector<float>* pixel_probability, double pixel_threshold, const std::vector<uint32_t>* groups) {
    std::vector<uint8_t> b(s.labels.data.size(), 0);
    const bool px = pixel_probability && pixel_threshold > 0.0;
    if (px && pixel_probability->size() != b.size()) throw Error("building pixels", "internal: pixel probability map size");
    for (std::size_t i = 0; i < b.size(); ++i)
        if (const uint32_t a = s.labels.data[i])
            b[i] = probability[a] >= threshold || (px && (*pixel_probability)[i] >= pixel_threshold) ? 1 : 0;
    if (groups && groups->size() != std::size_t(s.count) + 1) throw Error("building pixels", "internal: one group per segment");
    if (!groups && split_level <= 0) return b;
    if (!groups && split_level > int(s.context.size())) throw Error("object_split_level", "exceeds the number of context scales");
    // A pixel whose right or lower neighbour is building in another context
    // region (or group) leaves the building mask: a cut between the two objects.
    const std::vector<uint32_t>& parent = groups ? *groups : s.context[std::size_t(split_level - 1)];
    const int w = s.labels.width, h = s.labels.height;
    const uint32_t* L = s.labels.data.data();
    std::vector<uint8_t> out = b;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            if (!b[i]) continue;
            const uint32_t p = parent[L[i]];
            if ((x + 1 < w && b[i + 1] && parent[L[i + 1]] != p) || (y + 1 < h && b[i + w] && parent[L[i + w]] != p)) out[i] = 0;
        }
    return out;
}

namespace {
// A building pixel whose right or lower neighbour is a building pixel of
// another instance (both non-zero) leaves the mask: a one-pixel cut.
// Calls visit(j) for each 4-neighbour j of pixel i of a w x h grid.
template <class Visit>
void for_each_4_neighbour(std::size_t i, int w, int h, Visit&& visit) {
    const int x = int(i % std::size_t(w)), y = int(i / std::size_t(w));
    if (x > 0) visit(i - 1);
    if (x + 1 < w) visit(i + 1);
    if (y > 0) visit(i - w);
    if (y + 1 < h) visit(i + w);
}

// Markers of the instance splits: the 4-connected components of the pixels
// where is_core(i), numbered 1.. in raster order of their first pixel.
// Components of fewer than min_core_px pixels are left out (0; their numbers
// are not reused). `kept` gets the kept markers' pixels in labelling order.
template <class IsCore>
std::vector<uint32_t> label_cores(int w, int h, IsCore&& is_core, int min_core_px, std::vector<std::size_t>& kept) {
    const std::size_t n = std::size_t(w) * std::size_t(h);
    std::vector<uint32_t> inst(n, 0);
    std::vector<std::size_t> queue;
    std::vector<uint32_t> size{0};
    uint32_t next = 0;
    for (std::size_t s = 0; s < n; ++s) {
        if (!is_core(s) || inst[s]) continue;
        ++next;
        const std::size_t first = queue.size();
        inst[s] = next, queue.push_back(s);
        for (std::size_t q = first; q < queue.size(); ++q)
            for_each_4_neighbour(queue[q], w, h, [&](std::size_t j) {
                if (is_core(j) && !inst[j]) inst[j] = next, queue.push_back(j);
            });
        size.push_back(uint32_t(queue.size() - first));
    }
    kept.clear();
    for (const std::size_t i : queue) {
        if (size[inst[i]] < uint32_t(std::max(1, min_core_px))) inst[i] = 0;
        else kept.push_back(i);
    }
    return inst;
}

// The smallest core, pixels, of InstanceOptions::min_core_m2 at `gsd_m`.
int min_core_pixels(const InstanceOptions& o, double gsd_m) {
    return std::max(1, static_cast<int>(std::lround(o.min_core_m2 / (gsd_m * gsd_m))));
}

std::vector<uint8_t> cut_between_instances(const std::vector<uint8_t>& building, const std::vector<uint32_t>& inst, int w, int h) {
    std::vector<uint8_t> out = building;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            const uint32_t a = inst[i];
            if (!building[i] || !a) continue;
            if ((x + 1 < w && building[i + 1] && inst[i + 1] && inst[i + 1] != a) || (y + 1 < h && building[i + w] && inst[i + w] && inst[i + w] != a))
                out[i] = 0;
        }
    return out;
}
}  // namespace

std::vector<uint8_t> split_at_necks(const std::vector<uint8_t>& building, int w, int h, int radius_px, int min_core_px) {
    const std::size_t n = std::size_t(w) * std::size_t(h);
    if (building.size() != n) throw Error("split_at_necks", "internal: mask size");
    if (radius_px <= 0 || n == 0) return building;
    // Chessboard distance to the nearest non-building pixel (or the border), two passes.
    const int big = w + h + 2;
    std::vector<int> d(n);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            if (!building[i]) { d[i] = 0; continue; }
            int v = big;
            if (x == 0 || y == 0) v = 1;
            else {
                v = std::min(v, d[i - 1] + 1);
                v = std::min(v, d[i - w] + 1);
                v = std::min(v, d[i - w - 1] + 1);
                if (x + 1 < w) v = std::min(v, d[i - w + 1] + 1);
            }
            d[i] = v;
        }
    for (int y = h - 1; y >= 0; --y)
        for (int x = w - 1; x >= 0; --x) {
            const std::size_t i = std::size_t(y) * w + x;
            if (!d[i]) continue;
            int v = d[i];
            if (x + 1 == w || y + 1 == h) v = 1;
            else {
                v = std::min(v, d[i + 1] + 1);
                v = std::min(v, d[i + w] + 1);
                v = std::min(v, d[i + w + 1] + 1);
                if (x > 0) v = std::min(v, d[i + w - 1] + 1);
            }
            d[i] = v;
        }
    // Cores: 4-connected components of the pixels deeper than the radius;
    // small cores are no building of their own.
    std::vector<std::size_t> front;
    std::vector<uint32_t> inst = label_cores(w, h, [&](std::size_t i) { return d[i] > radius_px; }, min_core_px, front);
    // Grow the cores back over the building pixels, breadth first.
    for (std::size_t q = 0; q < front.size(); ++q) {
        const std::size_t i = front[q];
        for_each_4_neighbour(i, w, h, [&](std::size_t j) {
            if (building[j] && !inst[j]) inst[j] = inst[i], front.push_back(j);
        });
    }
    return cut_between_instances(building, inst, w, h);
}

std::vector<uint8_t> split_at_necks(std::vector<uint8_t> building, int w, int h, const DetectorOptions& options, double gsd_m) {
    if (!(options.neck_split_m > 0.0) || !(gsd_m > 0.0)) return building;
    const int radius = std::max(1, static_cast<int>(std::lround(options.neck_split_m / gsd_m)));
    const int min_core = std::max(1, static_cast<int>(std::lround(3.0 / (gsd_m * gsd_m))));
    return split_at_necks(building, w, h, radius, min_core);
}

std::vector<uint32_t> core_instances(const std::vector<uint8_t>& building, int w, int h, const std::vector<float>& core, double threshold,
                                     int min_core_px) {
    const std::size_t n = std::size_t(w) * std::size_t(h);
    if (building.size() != n || core.size() != n) throw Error("split_at_cores", "internal: mask size");
    if (!(threshold > 0.0) || n == 0) return std::vector<uint32_t>(n, 0);
    // Markers: 4-connected building pixels at or above the threshold.
    std::vector<std::size_t> markers;
    std::vector<uint32_t> inst = label_cores(w, h, [&](std::size_t i) { return building[i] && core[i] >= threshold; }, min_core_px, markers);
    // Grown over the building pixels, the most core-like first (a priority
    // flood: the cut falls on the valleys of the core map between markers);
    // ties go to the earlier arrival.
    struct Entry {
        float core;
        uint64_t order;
        std::size_t pixel;
    };
    struct Lower {
        bool operator()(const Entry& a, const Entry& b) const { return a.core != b.core ? a.core < b.core : a.order > b.order; }
    };
    std::priority_queue<Entry, std::vector<Entry>, Lower> heap;
    uint64_t order = 0;
    for (const std::size_t i : markers) heap.push({core[i], order++, i});
    while (!heap.empty()) {
        const std::size_t i = heap.top().pixel;
        heap.pop();
        for_each_4_neighbour(i, w, h, [&](std::size_t j) {
            if (building[j] && !inst[j]) inst[j] = inst[i], heap.push({core[j], order++, j});
        });
    }
    return inst;
}

std::vector<uint8_t> split_at_cores(const std::vector<uint8_t>& building, int w, int h, const std::vector<float>& core, double threshold,
                                    int min_core_px) {
    if (!(threshold > 0.0)) return building;
    const std::vector<uint32_t> inst = core_instances(building, w, h, core, threshold, min_core_px);
    return cut_between_instances(building, inst, w, h);
}

std::vector<uint8_t> split_at_cores(std::vector<uint8_t> building, int w, int h, const std::vector<float>* core, const DetectorOptions& options,
                                    double gsd_m) {
    if (!options.instance.enabled() || options.instance.by_segments || !core || !(gsd_m > 0.0)) return building;
    return split_at_cores(building, w, h, *core, options.instance.core_threshold, min_core_pixels(options.instance, gsd_m));
}

std::vector<uint8_t> object_pixels(const SceneSegments& s, const std::vector<float>& probability, const DetectorOptions& o,
                                   const std::vector<float>* pixel_map, const std::vector<uint32_t>* groups, const std::vector<float>* core_map,
                                   double gsd_m) {
    const int w = s.labels.width, h = s.labels.height;
    std::vector<uint8_t> b = building_pixels(s, probability, o.threshold, o.object_split_level, pixel_map, o.pixel_object_threshold, groups);
    if (o.instance.enabled() && o.instance.by_segments && core_map && gsd_m > 0.0) {
        // Each building segment votes for the core holding most of its
        // pixels; segments of different (group, core) are cut apart.
        const std::vector<uint32_t> inst = core_instances(b, w, h, *core_map, o.instance.core_threshold, min_core_pixels(o.instance, gsd_m));
        std::vector<std::vector<std::pair<uint32_t, uint32_t>>> votes(std::size_t(s.count) + 1);  // (core, pixels) per segment
        for (std::size_t i = 0; i < b.size(); ++i) {
            if (!inst[i]) continue;
            auto& v = votes[s.labels.data[i]];
            auto it = std::find_if(v.begin(), v.end(), [&](const auto& e) { return e.first == inst[i]; });
            if (it == v.end()) v.push_back({inst[i], 1});
            else ++it->second;
        }
        std::vector<std::pair<uint64_t, uint32_t>> keys(std::size_t(s.count) + 1);  // ((group, core), segment)
        for (uint32_t k = 0; k <= s.count; ++k) {
            uint32_t best = 0, most = 0;
            for (const auto& [c, n] : votes[k])
                if (n > most || (n == most && c < best)) best = c, most = n;
            const uint64_t g = groups ? (*groups)[k] : (o.object_split_level > 0 ? s.context[std::size_t(o.object_split_level - 1)][k] : 0u);
            keys[k] = {(g << 32) | best, k};
        }
        std::vector<std::pair<uint64_t, uint32_t>> sorted = keys;
        std::sort(sorted.begin(), sorted.end());
        std::vector<uint32_t> regroup(std::size_t(s.count) + 1, 0);
        uint32_t id = 0;
        for (std::size_t i = 0; i < sorted.size(); ++i) {
            if (i == 0 || sorted[i].first != sorted[i - 1].first) ++id;
            regroup[sorted[i].second] = id;
        }
        b = building_pixels(s, probability, o.threshold, 0, pixel_map, o.pixel_object_threshold, &regroup);
    }
    b = split_at_necks(std::move(b), w, h, o, gsd_m);
    return split_at_cores(std::move(b), w, h, core_map, o, gsd_m);
}

Detection detect_buildings(const DetectorModel& model, const Image<float>& normalised, const std::vector<uint8_t>& valid, double gsd_m,
                           int threads, const Progress& progress) {
    Detection d;
    const bool pixel = model.options.pixel.enabled;
    if (pixel) {
        d.pixel_probability = pixel_probability(model.pixel_model, normalised, valid, model.layout, gsd_m, model.options.pixel, threads, kCnnDetectionTiling);
        progress(0.3, "pixel probability");
    }
    d.segments = segment_scene(normalised, valid, model.options.segmentation, progress.sub(pixel ? 0.3 : 0.0, 0.8), gsd_m);
    apply_map_split(d.segments, model.options, pixel ? &d.pixel_probability : nullptr, gsd_m);
    const FeatureMatrix f = segment_features(normalised, valid, d.segments, model.layout, gsd_m, pixel ? &d.pixel_probability : nullptr);
    progress(0.9, "features");
    d.probability = segment_probabilities(model, f, threads);
    if (model.options.merge_threshold > 0.0) {
        const SegmentPairs pairs = segment_pairs(normalised, d.segments, gsd_m, pixel ? &d.pixel_probability : nullptr);
        const std::vector<float> pp = predict_booster(model.merge_model, pairs.values, pairs.size(), pairs.cols, threads);
        std::vector<uint8_t> building(d.segments.count + 1, 0);
        for (uint32_t k = 1; k <= d.segments.count; ++k) building[k] = d.probability[k] >= model.options.threshold;
        d.groups = merge_groups(pairs, pp, building, model.options.merge_threshold);
    }
    if (model.options.instance.enabled())
        d.core_probability = pixel_probability(model.core_model, normalised, valid, model.layout, gsd_m, model.options.instance.pixel_options(), threads,
                                                kCnnDetectionTiling);
    d.building = object_pixels(d.segments, d.probability, model.options, pixel ? &d.pixel_probability : nullptr, d.groups.empty() ? nullptr : &d.groups,
                               d.core_probability.empty() ? nullptr : &d.core_probability, gsd_m);
    progress(1.0, "classified");
    return d;
}

}  // namespace cityforge::detect
