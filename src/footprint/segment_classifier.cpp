#include "footprint/segment_classifier.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"
#include "footprint/building_mask.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

namespace cityforge {

void SegmentClassifierOptions::validate() const {
    if (!(gsd_m > 0)) throw Error("--gsd", "must be > 0");
    if (!(min_area_m2 >= 0 && max_area_m2 > min_area_m2)) throw Error("--min-area-m2", "must be below the maximum area");
    if (!(min_rectangularity >= 0 && min_rectangularity <= 1)) throw Error("--min-rectangularity", "must be between 0 and 1");
}

std::vector<SegmentFeatures> classify_segments(const Image<float>& image, const Image<uint32_t>& labels, uint32_t count,
                                               const SegmentClassifierOptions& o, std::vector<uint8_t>& mask) {
    o.validate();
    const std::size_t n = labels.pixel_count();
    const bool rgb = image.bands >= 3;
    std::vector<double> sum_r(count + 1, 0), sum_g(count + 1, 0), sum_b(count + 1, 0), area(count + 1, 0);
    // Brightness reference: 99th percentile of the mean band value (sampled).
    std::vector<float> sample;
    for (std::size_t i = 0; i < n; i += std::max<std::size_t>(1, n / 200000)) {
        double s = 0;
        for (int b = 0; b < std::min(image.bands, 3); ++b) s += image.band_data(b)[i];
        sample.push_back(static_cast<float>(s / std::min(image.bands, 3)));
    }
    std::sort(sample.begin(), sample.end());
    const double ref = sample.empty() ? 1.0 : std::max(1e-6, static_cast<double>(sample[sample.size() * 99 / 100]));
    for (std::size_t i = 0; i < n; ++i) {
        const uint32_t l = labels.data[i];
        if (!l) continue;
        area[l] += 1;
        sum_r[l] += image.band_data(0)[i];
        if (rgb) sum_g[l] += image.band_data(1)[i], sum_b[l] += image.band_data(2)[i];
    }
    std::vector<SegmentFeatures> f(count + 1);
    std::vector<uint8_t> candidate(count + 1, 0);
    for (uint32_t l = 1; l <= count; ++l) {
        if (area[l] == 0) continue;
        SegmentFeatures& s = f[l];
        s.area_m2 = area[l] * o.gsd_m * o.gsd_m;
        const double r = sum_r[l] / area[l], g = rgb ? sum_g[l] / area[l] : r, b = rgb ? sum_b[l] / area[l] : r;
        s.brightness = (r + g + b) / 3.0 / ref;
        s.vegetation_index = rgb && r + g + b > 0 ? (2 * g - r - b) / (r + g + b) : 0.0;
        candidate[l] = s.vegetation_index <= o.max_vegetation_index && s.brightness >= o.min_brightness && s.area_m2 <= o.max_area_m2;
    }
    // Components of candidate pixels, and their shapes.
    const int w = labels.width, h = labels.height;
    std::vector<uint8_t> cand_mask(n, 0);
    for (std::size_t i = 0; i < n; ++i) cand_mask[i] = labels.data[i] && candidate[labels.data[i]];
    std::vector<uint32_t> comp, sizes;
    const uint32_t nc = label_components(cand_mask, 1, w, h, comp, sizes);
    Image<uint32_t> comp_img(w, h, 1, 0u);
    comp_img.data.assign(comp.begin(), comp.end());
    const GeoTransform pixel_grid{0.0, o.gsd_m, 0.0, -o.gsd_m};
    const auto polygons = vectorize_all(comp_img, pixel_grid);
    std::vector<uint8_t> comp_ok(nc + 1, 0);
    for (uint32_t c = 1; c <= nc; ++c) {
        const double a_m2 = sizes[c] * o.gsd_m * o.gsd_m;
        if (a_m2 < o.min_area_m2 || a_m2 > o.max_area_m2 || c >= polygons.size() || polygons[c].empty()) continue;
        try {
            const OrientedRectangle rect = minimum_area_rectangle(polygons[c][0]);
            const double rectangularity = a_m2 / std::max(1e-9, rect.length * rect.width);
            const double elongation = rect.length / std::max(1e-9, rect.width);
            comp_ok[c] = rectangularity >= o.min_rectangularity && elongation <= o.max_elongation;
        } catch (const Error&) {
        }
    }
    mask.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
        mask[i] = comp[i] && comp_ok[comp[i]];
        if (mask[i]) f[labels.data[i]].building = true;
    }
    return f;
}

}  // namespace cityforge
