#include "footprint/segment_classifier.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>

#include "core/error.hpp"
#include "footprint/building_mask.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

namespace cityforge {

void SegmentClassifierOptions::validate() const {
    if (!(gsd_m > 0)) throw Error("--gsd", "must be > 0");
    if (!(min_area_m2 >= 0 && max_area_m2 > min_area_m2)) throw Error("--min-area-m2", "must be below the maximum area");
    if (!(max_ndvi > -1 && max_ndvi < 1)) throw Error("--max-ndvi", "must be between -1 and 1");
    if (!(weak_vegetation_index <= max_vegetation_index)) throw Error("weak_vegetation_index", "must not exceed --max-vegetation-index");
    if (!(weak_ndvi > -1 && weak_ndvi <= max_ndvi)) throw Error("weak_ndvi", "must be between -1 and --max-ndvi");
    if (!(min_rectangularity >= 0 && min_rectangularity <= 1)) throw Error("--min-rectangularity", "must be between 0 and 1");
}

namespace {
// The vegetation indices, for pixels and for segment means alike.
double excess_green(double r, double g, double b) { return r + g + b > 0 ? (2 * g - r - b) / (r + g + b) : 0.0; }
double ndvi_of(double nir, double r) { return nir + r > 0 ? (nir - r) / (nir + r) : 0.0; }
}  // namespace

std::vector<uint8_t> vegetation_pixels(const Image<float>& image, const SegmentClassifierOptions& o) {
    o.validate();
    const bool rgb = image.bands >= 3, nir = o.nir_band >= 0;
    if (o.nir_band >= image.bands) throw Error("--nir-band", "the image has only " + std::to_string(image.bands) + " bands");
    if (!rgb && !nir) return {};
    const std::size_t n = image.pixel_count();
    std::vector<uint8_t> out(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
        const double r = image.band_data(0)[i];
        const double exg = rgb ? excess_green(r, image.band_data(1)[i], image.band_data(2)[i]) : -1.0;
        const double ndvi = nir ? ndvi_of(image.band_data(o.nir_band)[i], r) : -1.0;
        out[i] = (rgb && exg > o.max_vegetation_index) || (nir && ndvi > o.max_ndvi) ? 2
                 : (rgb && exg > o.weak_vegetation_index) || (nir && ndvi > o.weak_ndvi) ? 1
                                                                                          : 0;
    }
    return out;
}

std::vector<SegmentFeatures> segment_spectra(const Image<float>& image, const Image<uint32_t>& labels, uint32_t count,
                                             const SegmentClassifierOptions& o) {
    o.validate();
    const std::size_t n = labels.pixel_count();
    if (image.pixel_count() != n) throw Error("segment features", "image and segments differ in size");
    if (o.nir_band >= image.bands) throw Error("--nir-band", "the image has only " + std::to_string(image.bands) + " bands");
    const bool rgb = image.bands >= 3;
    const bool nir = o.nir_band >= 0;
    std::vector<double> sum_r(count + 1, 0), sum_g(count + 1, 0), sum_b(count + 1, 0), sum_nir(count + 1, 0), area(count + 1, 0);
    // Brightness reference: 99th percentile of the mean band value (sampled).
    const int colour_bands = std::min(image.bands, 3);
    std::vector<float> sample;
    for (std::size_t i = 0; i < n; i += std::max<std::size_t>(1, n / 200000)) {
        double s = 0;
        for (int b = 0; b < colour_bands; ++b) s += image.band_data(b)[i];
        sample.push_back(static_cast<float>(s / colour_bands));
    }
    std::sort(sample.begin(), sample.end());
    const double ref = sample.empty() ? 1.0 : std::max(1e-6, static_cast<double>(sample[sample.size() * 99 / 100]));
    for (std::size_t i = 0; i < n; ++i) {
        const uint32_t l = labels.data[i];
        if (!l) continue;
        area[l] += 1;
        sum_r[l] += image.band_data(0)[i];
        if (rgb) sum_g[l] += image.band_data(1)[i], sum_b[l] += image.band_data(2)[i];
        if (nir) sum_nir[l] += image.band_data(o.nir_band)[i];
    }
    std::vector<SegmentFeatures> f(count + 1);
    for (uint32_t l = 1; l <= count; ++l) {
        if (area[l] == 0) continue;
        SegmentFeatures& s = f[l];
        s.area_m2 = area[l] * o.gsd_m * o.gsd_m;
        const double r = sum_r[l] / area[l], g = rgb ? sum_g[l] / area[l] : r, b = rgb ? sum_b[l] / area[l] : r;
        s.brightness = (r + g + b) / 3.0 / ref;
        s.vegetation_index = rgb ? excess_green(r, g, b) : 0.0;
        const double ni = nir ? sum_nir[l] / area[l] : 0.0;
        s.ndvi = nir ? ndvi_of(ni, r) : 0.0;
        s.vegetation = (rgb && s.vegetation_index > o.max_vegetation_index) || (nir && s.ndvi > o.max_ndvi);
        s.shadow = s.brightness < o.min_brightness;
    }
    return f;
}

std::vector<SegmentFeatures> classify_segments(const Image<float>& image, const Image<uint32_t>& labels, uint32_t count,
                                               const SegmentClassifierOptions& o, std::vector<uint8_t>& mask) {
    std::vector<SegmentFeatures> f = segment_spectra(image, labels, count, o);
    const std::size_t n = labels.pixel_count();
    std::vector<uint8_t> candidate(count + 1, 0);
    for (uint32_t l = 1; l <= count; ++l)
        candidate[l] = f[l].area_m2 > 0 && !f[l].vegetation && !f[l].shadow && f[l].area_m2 <= o.max_area_m2;
    // Shapes: candidate segments are grouped greedily with their neighbours
    // (roof facets, lit and shaded halves) as long as the group stays about as
    // rectangular as its parts; a roof next to a paved or bare patch of the
    // same colour therefore keeps its own outline. Groups that pass the shape
    // rules are buildings.
    const int w = labels.width, h = labels.height;
    const GeoTransform pixel_grid{0.0, o.gsd_m, 0.0, -o.gsd_m};
    const auto polygons = vectorize_all(labels, pixel_grid);
    std::vector<std::vector<MapPoint>> hull(count + 1);
    for (uint32_t l = 1; l <= count; ++l)
        if (candidate[l] && l < polygons.size())
            for (const Polygon& p : polygons[l]) hull[l].insert(hull[l].end(), p.outer.begin(), p.outer.end());
    for (uint32_t l = 1; l <= count; ++l) hull[l] = convex_hull(hull[l]);
    struct Shape {
        double rectangularity = 0.0, elongation = 0.0;
    };
    auto shape_of = [&](const std::vector<MapPoint>& pts, double area_m2) {
        Shape sh;
        if (pts.size() < 3) return sh;
        try {
            const OrientedRectangle rect = minimum_area_rectangle(Polygon{pts, {}});
            sh.rectangularity = area_m2 / std::max(1e-9, rect.length * rect.width);
            sh.elongation = rect.length / std::max(1e-9, rect.width);
        } catch (const Error&) {
        }
        return sh;
    };
    std::vector<uint32_t> parent(count + 1);
    for (uint32_t l = 0; l <= count; ++l) parent[l] = l;
    auto find = [&](uint32_t a) {
        while (parent[a] != a) a = parent[a] = parent[parent[a]];
        return a;
    };
    std::vector<double> group_area(count + 1, 0.0);
    std::vector<Shape> group_shape(count + 1);
    for (uint32_t l = 1; l <= count; ++l)
        if (candidate[l]) group_area[l] = f[l].area_m2, group_shape[l] = shape_of(hull[l], f[l].area_m2);
    // Shared boundary lengths between candidate segments (pixel edges).
    std::map<std::pair<uint32_t, uint32_t>, long> shared;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const uint32_t a = labels.data[k];
            if (!a || !candidate[a]) continue;
            if (x + 1 < w) {
                const uint32_t b = labels.data[k + 1];
                if (b && b != a && candidate[b]) ++shared[{std::min(a, b), std::max(a, b)}];
            }
            if (y + 1 < h) {
                const uint32_t b = labels.data[k + static_cast<std::size_t>(w)];
                if (b && b != a && candidate[b]) ++shared[{std::min(a, b), std::max(a, b)}];
            }
        }
    std::vector<std::tuple<long, uint32_t, uint32_t>> pairs;
    for (const auto& [ab, len] : shared) pairs.emplace_back(-len, ab.first, ab.second);
    std::sort(pairs.begin(), pairs.end());  // longest shared boundary first, ties by ids
    for (const auto& [neg_len, a0, b0] : pairs) {
        const uint32_t a = find(a0), b = find(b0);
        if (a == b) continue;
        const double area_m2 = group_area[a] + group_area[b];
        if (area_m2 > o.max_area_m2) continue;
        std::vector<MapPoint> pts = hull[a];
        pts.insert(pts.end(), hull[b].begin(), hull[b].end());
        pts = convex_hull(pts);
        const Shape sh = shape_of(pts, area_m2);
        const double worst = std::min(group_shape[a].rectangularity, group_shape[b].rectangularity);
        if (sh.rectangularity < o.min_rectangularity || sh.rectangularity < worst - o.max_rectangularity_loss) continue;
        const uint32_t into = std::min(a, b), from = std::max(a, b);
        parent[from] = into;
        group_area[into] = area_m2, group_shape[into] = sh, hull[into] = std::move(pts);
        hull[from].clear();
    }
    std::vector<uint8_t> group_ok(count + 1, 0), rectilinear_candidate(count + 1, 0);
    for (uint32_t l = 1; l <= count; ++l) {
        if (!candidate[l] || find(l) != l) continue;
        const double a_m2 = group_area[l];
        const bool sized = a_m2 >= o.min_area_m2 && a_m2 <= o.max_area_m2 && group_shape[l].elongation <= o.max_elongation;
        group_ok[l] = sized && group_shape[l].rectangularity >= o.min_rectangularity;
        rectilinear_candidate[l] = sized && !group_ok[l] && o.min_rectilinear_iou < 1.0;
    }
    std::vector<uint32_t> comp(n, 0);
    for (std::size_t i = 0; i < n; ++i)
        if (const uint32_t l = labels.data[i]; l && candidate[l]) comp[i] = find(l);
    // L, T, U and courtyard buildings are not rectangular but rectilinear: a
    // few rectangles aligned with their dominant direction cover them.
    if (std::find(rectilinear_candidate.begin(), rectilinear_candidate.end(), 1) != rectilinear_candidate.end()) {
        Image<uint32_t> groups(w, h, 1, 0u);
        for (std::size_t i = 0; i < n; ++i)
            if (comp[i] && rectilinear_candidate[comp[i]]) groups.data[i] = comp[i];
        const auto group_polygons = vectorize_all(groups, pixel_grid);
        RecursiveFitOptions ro;
        ro.max_rectangles = o.max_rectilinear_rectangles - 1;
        ro.min_rectangle_area = 4.0;  // m² (the pixel grid is in metres)
        for (uint32_t l = 1; l <= count; ++l) {
            if (!rectilinear_candidate[l] || l >= group_polygons.size() || group_polygons[l].size() != 1) continue;
            try {
                const RecursiveFit fit = recursive_rectangle_fit(group_polygons[l][0], ro);
                group_ok[l] = fit.accuracy.iou >= o.min_rectilinear_iou;
            } catch (const Error&) {
            }
        }
    }
    std::vector<uint8_t> comp_ok(count + 1, 0);
    for (uint32_t l = 1; l <= count; ++l) comp_ok[l] = group_ok[l];
    mask.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
        mask[i] = comp[i] && comp_ok[comp[i]];
        if (mask[i]) f[labels.data[i]].building = true;
    }
    return f;
}

}  // namespace cityforge
