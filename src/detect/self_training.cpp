#include "detect/self_training.hpp"

#include <algorithm>

#include "core/error.hpp"

namespace cityforge::detect {

void SelfTrainingOptions::validate(int bands) const {
    segmentation.validate(bands);
    booster.validate();
    if (!(min_train_coverage > 0.0 && min_train_coverage <= 1.0)) throw Error("self_training.min_train_coverage", "must be in (0, 1]");
    if (!(max_detect_coverage > 0.0 && max_detect_coverage <= min_train_coverage))
        throw Error("self_training.max_detect_coverage", "must be in (0, min_train_coverage]");
    if (!(min_label_share > 0.0 && min_label_share < 1.0)) throw Error("self_training.min_label_share", "must be in (0, 1)");
    if (!(threshold > 0.0 && threshold < 1.0)) throw Error("self_training.threshold", "must be in (0, 1)");
    if (!(coverage_closing_m >= 0.0 && coverage_closing_m <= 100.0)) throw Error("self_training.coverage_closing_m", "must be in [0, 100]");
    if (!(min_uncovered_share >= 0.0 && min_uncovered_share < 1.0)) throw Error("self_training.min_uncovered_share", "must be in [0, 1)");
    if (min_examples < 1) throw Error("self_training.min_examples", "must be >= 1");
}

namespace {
// Sum of `m` over the square of radius r around every pixel (clipped to the image).
std::vector<uint32_t> box_sums(const std::vector<uint8_t>& m, int w, int h, int r) {
    std::vector<uint32_t> integral(std::size_t(w + 1) * std::size_t(h + 1), 0);
    for (int y = 0; y < h; ++y) {
        uint32_t row = 0;
        for (int x = 0; x < w; ++x) {
            row += m[std::size_t(y) * w + x] ? 1u : 0u;
            integral[std::size_t(y + 1) * (w + 1) + x + 1] = integral[std::size_t(y) * (w + 1) + x + 1] + row;
        }
    }
    std::vector<uint32_t> out(std::size_t(w) * h);
    for (int y = 0; y < h; ++y) {
        const int y0 = std::max(0, y - r), y1 = std::min(h, y + r + 1);
        for (int x = 0; x < w; ++x) {
            const int x0 = std::max(0, x - r), x1 = std::min(w, x + r + 1);
            out[std::size_t(y) * w + x] = integral[std::size_t(y1) * (w + 1) + x1] - integral[std::size_t(y0) * (w + 1) + x1] -
                                          integral[std::size_t(y1) * (w + 1) + x0] + integral[std::size_t(y0) * (w + 1) + x0];
        }
    }
    return out;
}
}  // namespace

std::vector<uint8_t> coverage_mask(const std::vector<uint8_t>& has_data, int w, int h, int radius_px) {
    if (has_data.size() != std::size_t(w) * std::size_t(h)) throw Error("coverage_mask", "mask size does not match the grid");
    if (radius_px <= 0) return has_data;
    const std::vector<uint32_t> near = box_sums(has_data, w, h, radius_px);
    // Erosion of the dilation: a pixel stays when no uncovered pixel is within
    // the radius (outside the image counts as covered: the borders stay).
    std::vector<uint8_t> gap(near.size());
    for (std::size_t i = 0; i < near.size(); ++i) gap[i] = near[i] == 0 ? 1 : 0;
    const std::vector<uint32_t> gaps = box_sums(gap, w, h, radius_px);
    std::vector<uint8_t> out(near.size());
    for (std::size_t i = 0; i < near.size(); ++i) out[i] = gaps[i] == 0 ? 1 : 0;
    return out;
}

SelfTrainingResult self_train_and_detect(const Image<float>& normalised, const std::vector<uint8_t>& valid, const BandLayout& layout,
                                         double gsd_m, const std::vector<uint8_t>& covered, const std::vector<uint8_t>& cloud_building,
                                         const SelfTrainingOptions& o, const Progress& progress) {
    o.validate(normalised.bands);
    const std::size_t n = normalised.pixel_count();
    if (covered.size() != n || cloud_building.size() != n || valid.size() != n)
        throw Error("self_train_and_detect", "masks do not match the ortho's grid");
    SelfTrainingResult r;
    r.building.assign(n, 0);
    std::size_t valid_n = 0, uncovered = 0;
    for (std::size_t i = 0; i < n; ++i)
        if (valid[i]) ++valid_n, uncovered += covered[i] ? 0 : 1;
    r.uncovered_share = valid_n ? double(uncovered) / double(valid_n) : 0.0;
    if (!o.enabled) {
        r.reason = "self-training is off";
        return r;
    }
    if (valid_n == 0 || r.uncovered_share < o.min_uncovered_share) {
        r.reason = "the heights cover the ortho";
        return r;
    }
    const SceneSegments s = segment_scene(normalised, valid, o.segmentation, progress.sub(0.0, 0.6), gsd_m);
    const FeatureMatrix f = segment_features(normalised, valid, s, layout, gsd_m);
    progress(0.7, "features");
    const std::vector<float> cover = building_share(s, covered);
    const std::vector<float> label = building_share(s, cloud_building);
    std::vector<float> X, y, wt;
    std::size_t negatives = 0;
    for (uint32_t k = 1; k <= s.count; ++k) {
        if (f.pixel_count[k - 1] == 0 || cover[k] < o.min_train_coverage) continue;
        const float* row = f.values.data() + std::size_t(k - 1) * f.cols;
        X.insert(X.end(), row, row + f.cols);
        const bool b = label[k] >= o.min_label_share;
        y.push_back(b ? 1.0f : 0.0f);
        wt.push_back(1.0f);
        r.building_examples += b ? 1 : 0;
        negatives += b ? 0 : 1;
    }
    r.training_segments = y.size();
    if (r.building_examples < o.min_examples || negatives < o.min_examples) {
        r.reason = "too few examples under the heights (" + std::to_string(r.building_examples) + " building and " + std::to_string(negatives) +
                   " other segments; " + std::to_string(o.min_examples) + " of each needed)";
        return r;
    }
    r.model = train_booster(X, y.size(), f.cols, y, wt, o.booster);
    progress(0.9, "trained");
    // Classify the segments the heights do not decide.
    std::vector<float> Xt;
    std::vector<uint32_t> ks;
    for (uint32_t k = 1; k <= s.count; ++k)
        if (f.pixel_count[k - 1] > 0 && cover[k] < o.max_detect_coverage) {
            const float* row = f.values.data() + std::size_t(k - 1) * f.cols;
            Xt.insert(Xt.end(), row, row + f.cols);
            ks.push_back(k);
        }
    r.classified_segments = ks.size();
    std::vector<uint8_t> is_building(s.count + 1, 0);
    if (!ks.empty()) {
        const std::vector<float> p = predict_booster(r.model, Xt, ks.size(), f.cols);
        for (std::size_t j = 0; j < ks.size(); ++j)
            if (p[j] >= o.threshold) is_building[ks[j]] = 1, ++r.building_segments;
    }
    for (std::size_t i = 0; i < n; ++i)
        if (const uint32_t a = s.labels.data[i]; a && is_building[a] && !cloud_building[i]) r.building[i] = 1;
    r.trained = true;
    progress(1.0, "classified");
    return r;
}

}  // namespace cityforge::detect
