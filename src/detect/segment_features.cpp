#include "detect/segment_features.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "core/error.hpp"
#include "segment/region_merging.hpp"

namespace cityforge::detect {

void DetectorSegmentationOptions::validate(int bands) const {
    watershed.validate(bands);
    if (scales.empty()) throw Error("segmentation.scales", "give at least one scale");
    for (std::size_t i = 0; i < scales.size(); ++i) {
        if (!(scales[i] > 0.0)) throw Error("segmentation.scales", "must be > 0");
        if (i > 0 && !(scales[i] > scales[i - 1])) throw Error("segmentation.scales", "must be strictly increasing");
    }
    if (!(color_weight >= 0.0 && color_weight <= 1.0)) throw Error("segmentation.color_weight", "must be in [0, 1]");
    if (!(reference_gsd_m >= 0.0 && reference_gsd_m <= 100.0)) throw Error("segmentation.reference_gsd_m", "must be in [0, 100] metres (0 = off)");
}

std::vector<double> DetectorSegmentationOptions::scales_at(double gsd_m) const {
    std::vector<double> out = scales;
    if (reference_gsd_m > 0.0)
        for (double& v : out) v *= reference_gsd_m / gsd_m;
    return out;
}

SceneSegments segment_scene(const Image<float>& normalised, const std::vector<uint8_t>& valid, const DetectorSegmentationOptions& o,
                            const Progress& progress, double gsd_m) {
    o.validate(normalised.bands);
    if (o.reference_gsd_m > 0.0 && !(gsd_m > 0.0)) throw Error("segmentation", "internal: scales relative to a GSD need the image's GSD");
    SceneSegments s;
    const Oversegmentation over = watershed_oversegment(normalised, valid, o.watershed, progress.sub(0.0, 0.5));
    const std::size_t levels = o.scales.size();
    s.context.resize(levels - 1);
    s.context_labels.resize(levels - 1);
    s.context_counts.assign(levels - 1, 0);
    if (over.region_count == 0) {
        s.labels = over.labels;
        for (auto& l : s.context_labels) l = over.labels;
        return s;
    }
    RegionMergingOptions rmo;
    rmo.scales = o.scales_at(gsd_m);
    rmo.band_weights = o.watershed.band_weights;
    rmo.color_weight = o.color_weight;
    const RegionMergingResult m = merge_regions(normalised, over.labels, over.region_count, rmo, progress.sub(0.5, 1.0));
    s.labels = relabel(over.labels, m.levels[0].label_of_input);
    s.count = m.levels[0].regions_after;
    std::vector<uint32_t> chain(s.count + 1);
    for (uint32_t k = 0; k <= s.count; ++k) chain[k] = k;
    for (std::size_t l = 1; l < levels; ++l) {
        for (uint32_t k = 1; k <= s.count; ++k) chain[k] = m.levels[l].parent[chain[k]];
        s.context[l - 1] = chain;
        s.context_labels[l - 1] = relabel(over.labels, m.levels[l].label_of_input);
        s.context_counts[l - 1] = m.levels[l].regions_after;
    }
    return s;
}

std::size_t split_segments_by_map(SceneSegments& s, const std::vector<float>& map, double threshold, std::size_t min_pixels) {
    const int w = s.labels.width, h = s.labels.height;
    const std::size_t n = std::size_t(w) * std::size_t(h);
    if (map.size() != n) throw Error("split_segments_by_map", "internal: the map is not the size of the segments");
    std::vector<std::size_t> left(std::size_t(s.count) + 1, 0);  // pixels each segment keeps
    for (std::size_t i = 0; i < n; ++i) ++left[s.labels.data[i]];
    std::vector<uint8_t> seen(n, 0);
    std::vector<std::size_t> piece, stack;
    const uint32_t before = s.count;
    for (std::size_t start = 0; start < n; ++start) {
        const uint32_t k = s.labels.data[start];
        if (k == 0 || k > before || seen[start] || !(map[start] >= threshold)) continue;
        // The 4-connected piece of segment k at or above the threshold.
        piece.clear();
        stack.assign(1, start);
        seen[start] = 1;
        while (!stack.empty()) {
            const std::size_t i = stack.back();
            stack.pop_back();
            piece.push_back(i);
            const int r = int(i / std::size_t(w)), c = int(i % std::size_t(w));
            const std::size_t nb[4] = {c > 0 ? i - 1 : n, c + 1 < w ? i + 1 : n, r > 0 ? i - std::size_t(w) : n, r + 1 < h ? i + std::size_t(w) : n};
            for (const std::size_t j : nb)
                if (j < n && !seen[j] && s.labels.data[j] == k && map[j] >= threshold) seen[j] = 1, stack.push_back(j);
        }
        if (piece.size() < min_pixels || left[k] < piece.size() + min_pixels || left[k] == piece.size()) continue;
        left[k] -= piece.size();
        const uint32_t id = ++s.count;
        for (const std::size_t i : piece) s.labels.data[i] = id;
        for (auto& chain : s.context) chain.push_back(chain[k]);
    }
    return s.count - before;
}

std::vector<std::string> feature_names(const BandLayout& layout, int context_levels, bool pixel_map) {
    std::vector<std::string> f;
    for (int b = 0; b < layout.bands; ++b) {
        const std::string name = b == layout.ndsm_band ? "ndsm" : "band" + std::to_string(b + 1);
        f.push_back(name + "_mean");
        f.push_back(name + "_std");
    }
    const int image_bands = layout.bands - (layout.ndsm_band >= 0 ? 1 : 0);  // colours and NIR
    for (const char* n : {"bright_mean", "bright_std", "bright_p10", "bright_p50", "bright_p90"}) f.emplace_back(n);
    if (image_bands >= 3)
        for (const char* n : {"chroma_r", "chroma_g", "chroma_b", "exg", "saturation"}) f.emplace_back(n);
    if (layout.nir_band >= 0) f.emplace_back("ndvi");
    for (const char* n : {"grad_mean", "grad_std", "edge_density", "coherence", "boundary_grad", "boundary_contrast", "lbp_flat",
                          "lbp_uniform", "lbp_noise"})
        f.emplace_back(n);
    for (const char* n : {"log_area_m2", "log_length_m", "log_width_m", "compactness", "rectangularity", "elongation", "perimeter_ratio"})
        f.emplace_back(n);
    for (const char* n : {"nb_bright_diff_mean", "nb_bright_diff_min", "nb_bright_diff_max", "nb_std_diff", "dark_share", "dark_side_1",
                          "dark_side_2", "dark_side_3", "dark_side_4"})
        f.emplace_back(n);
    if (image_bands >= 3) f.emplace_back("nb_vegetation_share");
    for (int l = 0; l < context_levels; ++l) {
        const std::string p = "ctx" + std::to_string(l + 1) + "_";
        for (const char* n : {"log_area_m2", "share", "rectangularity", "compactness", "elongation", "bright_mean", "bright_std", "bright_diff"})
            f.push_back(p + n);
    }
    if (pixel_map) {
        for (const char* n : {"pix_mean", "pix_std", "pix_p10", "pix_p50", "pix_p90", "pix_share_05", "pix_boundary", "pix_nb_diff_mean",
                              "pix_nb_max"})
            f.emplace_back(n);
        for (int l = 0; l < context_levels; ++l) f.push_back("ctx" + std::to_string(l + 1) + "_pix_mean");
    }
    return f;
}

namespace {

// Area, perimeter and principal-axis extents of every region of a label raster.
struct Shapes {
    std::vector<double> n, cx, cy, perimeter, length, width;
};

Shapes region_shapes(const Image<uint32_t>& labels, uint32_t count) {
    const int w = labels.width, h = labels.height;
    Shapes s;
    s.n.assign(count + 1, 0.0), s.cx.assign(count + 1, 0.0), s.cy.assign(count + 1, 0.0), s.perimeter.assign(count + 1, 0.0);
    std::vector<double> sxx(count + 1, 0.0), syy(count + 1, 0.0), sxy(count + 1, 0.0);
    const uint32_t* L = labels.data.data();
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const uint32_t a = L[std::size_t(y) * w + x];
            if (!a) continue;
            s.n[a] += 1.0, s.cx[a] += x, s.cy[a] += y;
            sxx[a] += double(x) * x, syy[a] += double(y) * y, sxy[a] += double(x) * y;
            int edges = 0;
            edges += x == 0 || L[std::size_t(y) * w + x - 1] != a;
            edges += x == w - 1 || L[std::size_t(y) * w + x + 1] != a;
            edges += y == 0 || L[std::size_t(y - 1) * w + x] != a;
            edges += y == h - 1 || L[std::size_t(y + 1) * w + x] != a;
            s.perimeter[a] += edges;
        }
    std::vector<double> ux(count + 1, 1.0), uy(count + 1, 0.0);
    for (uint32_t k = 1; k <= count; ++k) {
        if (s.n[k] == 0.0) continue;
        s.cx[k] /= s.n[k], s.cy[k] /= s.n[k];
        const double a = sxx[k] / s.n[k] - s.cx[k] * s.cx[k], c = syy[k] / s.n[k] - s.cy[k] * s.cy[k],
                     b = sxy[k] / s.n[k] - s.cx[k] * s.cy[k];
        const double theta = 0.5 * std::atan2(2.0 * b, a - c);
        ux[k] = std::cos(theta), uy[k] = std::sin(theta);
    }
    std::vector<double> umin(count + 1, INFINITY), umax(count + 1, -INFINITY), vmin(count + 1, INFINITY), vmax(count + 1, -INFINITY);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const uint32_t a = L[std::size_t(y) * w + x];
            if (!a) continue;
            const double dx = x - s.cx[a], dy = y - s.cy[a];
            const double u = dx * ux[a] + dy * uy[a], v = -dx * uy[a] + dy * ux[a];
            umin[a] = std::min(umin[a], u), umax[a] = std::max(umax[a], u);
            vmin[a] = std::min(vmin[a], v), vmax[a] = std::max(vmax[a], v);
        }
    s.length.assign(count + 1, 0.0), s.width.assign(count + 1, 0.0);
    for (uint32_t k = 1; k <= count; ++k) {
        if (s.n[k] == 0.0) continue;
        const double l1 = umax[k] - umin[k] + 1.0, l2 = vmax[k] - vmin[k] + 1.0;
        s.length[k] = std::max(l1, l2), s.width[k] = std::min(l1, l2);
    }
    return s;
}

// Mean and standard deviation of `channel` per region.
void region_mean_std(const float* channel, const Image<uint32_t>& labels, uint32_t count, std::vector<double>& mean,
                     std::vector<double>& sd) {
    std::vector<double> n(count + 1, 0.0), s(count + 1, 0.0), ss(count + 1, 0.0);
    const std::size_t np = labels.pixel_count();
    for (std::size_t i = 0; i < np; ++i) {
        const uint32_t a = labels.data[i];
        if (!a) continue;
        const double v = channel[i];
        n[a] += 1.0, s[a] += v, ss[a] += v * v;
    }
    mean.assign(count + 1, 0.0), sd.assign(count + 1, 0.0);
    for (uint32_t k = 1; k <= count; ++k)
        if (n[k] > 0) {
            mean[k] = s[k] / n[k];
            sd[k] = std::sqrt(std::max(0.0, ss[k] / n[k] - mean[k] * mean[k]));
        }
}

double safe_log(double v) { return std::log(std::max(v, 1e-6)); }

// The bin of a histogram (`bins` counts summing to n) where the cumulative
// count first reaches q * n; `bins` when it never does (rounding).
int percentile_bin(const uint32_t* hist, int bins, double n, double q) {
    const double target = q * n;
    double acc = 0.0;
    for (int bin = 0; bin < bins; ++bin) {
        acc += hist[bin];
        if (acc >= target) return bin;
    }
    return bins;
}

}  // namespace

FeatureMatrix segment_features(const Image<float>& img, const std::vector<uint8_t>& valid, const SceneSegments& seg,
                               const BandLayout& layout, double gsd_m, const std::vector<float>* pixel_probability) {
    if (img.bands != layout.bands) throw Error("segment features", "image has " + std::to_string(img.bands) + " bands, layout " + std::to_string(layout.bands));
    if (!(gsd_m > 0.0)) throw Error("segment features", "GSD must be > 0");
    const int w = img.width, h = img.height;
    const std::size_t np = img.pixel_count();
    const uint32_t count = seg.count;
    const Image<uint32_t>& labels = seg.labels;
    const uint32_t* L = labels.data.data();
    const int B = img.bands;
    const int image_bands = B - (layout.ndsm_band >= 0 ? 1 : 0);  // colours and NIR
    const int colour_bands = layout.nir_band >= 0 ? image_bands - 1 : image_bands;

    // Brightness: mean of the colour bands (0..255).
    std::vector<float> bright(np, 0.0f);
    for (int b = 0, c = 0; b < B; ++b) {
        if (b == layout.nir_band || b == layout.ndsm_band) continue;
        ++c;
        const float* v = img.band_data(b);
        for (std::size_t i = 0; i < np; ++i) bright[i] += v[i];
    }
    for (float& v : bright) v /= static_cast<float>(std::max(1, colour_bands));

    // Band and brightness statistics.
    std::vector<std::vector<double>> bmean(B), bsd(B);
    for (int b = 0; b < B; ++b) region_mean_std(img.band_data(b), labels, count, bmean[b], bsd[b]);
    std::vector<double> brmean, brsd;
    region_mean_std(bright.data(), labels, count, brmean, brsd);
    const Shapes shape = region_shapes(labels, count);

    // Brightness histograms (32 bins) for percentiles.
    std::vector<uint32_t> hist(std::size_t(count + 1) * 32, 0);
    for (std::size_t i = 0; i < np; ++i)
        if (const uint32_t a = L[i]) ++hist[std::size_t(a) * 32 + std::clamp(int(bright[i] / 8.0f), 0, 31)];

    // Texture: Sobel on brightness, structure tensor, edges, LBP, boundaries.
    std::vector<double> gsum(count + 1, 0.0), gss(count + 1, 0.0), edge(count + 1, 0.0), jxx(count + 1, 0.0), jyy(count + 1, 0.0),
        jxy(count + 1, 0.0), bgs(count + 1, 0.0), bgn(count + 1, 0.0), lflat(count + 1, 0.0), luni(count + 1, 0.0);
    auto at = [&](int x, int y) { return bright[std::size_t(std::clamp(y, 0, h - 1)) * w + std::clamp(x, 0, w - 1)]; };
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            const uint32_t a = L[i];
            if (!a) continue;
            const float p00 = at(x - 1, y - 1), p10 = at(x, y - 1), p20 = at(x + 1, y - 1), p01 = at(x - 1, y), p21 = at(x + 1, y),
                        p02 = at(x - 1, y + 1), p12 = at(x, y + 1), p22 = at(x + 1, y + 1);
            const double gx = (p20 + 2.0 * p21 + p22 - p00 - 2.0 * p01 - p02) / 8.0;
            const double gy = (p02 + 2.0 * p12 + p22 - p00 - 2.0 * p10 - p20) / 8.0;
            const double g = std::sqrt(gx * gx + gy * gy);
            gsum[a] += g, gss[a] += g * g, edge[a] += g > 12.0;
            jxx[a] += gx * gx, jyy[a] += gy * gy, jxy[a] += gx * gy;
            // LBP with a tolerance of 4 grey levels: flat (no bit set or all
            // set), uniform (at most 2 transitions), noise (others).
            const float c = bright[i];
            const std::array<float, 8> ring{p00, p10, p20, p21, p22, p12, p02, p01};
            int bits = 0, transitions = 0;
            std::array<int, 8> bit{};
            for (int k = 0; k < 8; ++k) bit[k] = ring[k] > c + 4.0f, bits += bit[k];
            for (int k = 0; k < 8; ++k) transitions += bit[k] != bit[(k + 1) % 8];
            if (bits == 0 || bits == 8) lflat[a] += 1.0;
            else if (transitions <= 2) luni[a] += 1.0;
            const bool boundary = (x > 0 && L[i - 1] != a) || (x < w - 1 && L[i + 1] != a) || (y > 0 && L[i - w] != a) || (y < h - 1 && L[i + w] != a);
            if (boundary) bgs[a] += g, bgn[a] += 1.0;
        }

    // Context: neighbours across every pixel edge, by side (0 E, 1 S, 2 W, 3 N).
    std::vector<double> exg(count + 1, 0.0);
    if (colour_bands >= 3)
        for (uint32_t k = 1; k <= count; ++k) {
            const double s = bmean[0][k] + bmean[1][k] + bmean[2][k] + 1e-6;
            exg[k] = (2.0 * bmean[1][k] - bmean[0][k] - bmean[2][k]) / s;
        }
    std::vector<std::array<double, 4>> side_edges(count + 1, {0, 0, 0, 0}), side_dark(count + 1, {0, 0, 0, 0});
    std::vector<double> nb_diff(count + 1, 0.0), nb_min(count + 1, INFINITY), nb_max(count + 1, -INFINITY), nb_sd(count + 1, 0.0),
        nb_veg(count + 1, 0.0), nb_edges(count + 1, 0.0);
    auto pair = [&](uint32_t a, uint32_t b, int side_of_b) {
        const double d = brmean[b] - brmean[a];
        nb_edges[a] += 1.0, nb_diff[a] += d, nb_sd[a] += brsd[b] - brsd[a];
        nb_min[a] = std::min(nb_min[a], d), nb_max[a] = std::max(nb_max[a], d);
        side_edges[a][side_of_b] += 1.0;
        if (brmean[b] < 0.7 * brmean[a] && brmean[b] < 90.0) side_dark[a][side_of_b] += 1.0;
        if (exg[b] > 0.06) nb_veg[a] += 1.0;
    };
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            const uint32_t a = L[i];
            if (!a) continue;
            if (x < w - 1)
                if (const uint32_t b = L[i + 1]; b && b != a) pair(a, b, 0), pair(b, a, 2);
            if (y < h - 1)
                if (const uint32_t b = L[i + w]; b && b != a) pair(a, b, 1), pair(b, a, 3);
        }

    // Context regions.
    const std::size_t levels = seg.context.size();
    std::vector<Shapes> cshape(levels);
    std::vector<std::vector<double>> cmean(levels), csd(levels);
    for (std::size_t l = 0; l < levels; ++l) {
        cshape[l] = region_shapes(seg.context_labels[l], seg.context_counts[l]);
        region_mean_std(bright.data(), seg.context_labels[l], seg.context_counts[l], cmean[l], csd[l]);
    }

    // Pixel building-probability map: per segment mean, spread, a 20-bin
    // histogram (percentiles, share >= 0.5), its boundary pixels and the
    // neighbours' means; per context region the mean.
    const bool pix = pixel_probability != nullptr;
    std::vector<double> pmean, psd, pbound(count + 1, 0.0), pbn(count + 1, 0.0), pnb(count + 1, 0.0), pnbmax(count + 1, 0.0);
    std::vector<uint32_t> phist;
    std::vector<std::vector<double>> cpmean(levels);
    if (pix) {
        if (pixel_probability->size() != np) throw Error("segment features", "internal: pixel probability map size");
        const float* P = pixel_probability->data();
        region_mean_std(P, labels, count, pmean, psd);
        phist.assign(std::size_t(count + 1) * 20, 0);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t i = std::size_t(y) * w + x;
                const uint32_t a = L[i];
                if (!a) continue;
                ++phist[std::size_t(a) * 20 + std::clamp(int(P[i] * 20.0f), 0, 19)];
                const bool boundary = (x > 0 && L[i - 1] != a) || (x < w - 1 && L[i + 1] != a) || (y > 0 && L[i - w] != a) || (y < h - 1 && L[i + w] != a);
                if (boundary) pbound[a] += P[i], pbn[a] += 1.0;
            }
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t i = std::size_t(y) * w + x;
                const uint32_t a = L[i];
                if (!a) continue;
                auto nb = [&](uint32_t b) {
                    if (!b || b == a) return;
                    pnb[a] += pmean[b] - pmean[a], pnb[b] += pmean[a] - pmean[b];
                    pnbmax[a] = std::max(pnbmax[a], pmean[b]), pnbmax[b] = std::max(pnbmax[b], pmean[a]);
                };
                if (x < w - 1) nb(L[i + 1]);
                if (y < h - 1) nb(L[i + w]);
            }
        for (std::size_t l = 0; l < levels; ++l) {
            std::vector<double> sd;
            region_mean_std(P, seg.context_labels[l], seg.context_counts[l], cpmean[l], sd);
        }
    }

    FeatureMatrix fm;
    fm.rows = count;
    fm.cols = feature_names(layout, int(levels), pix).size();
    fm.values.assign(fm.rows * fm.cols, NAN);
    fm.centroid_col.assign(count, 0.0), fm.centroid_row.assign(count, 0.0), fm.pixel_count.assign(count, 0);
    const double px_m2 = gsd_m * gsd_m;
    for (uint32_t k = 1; k <= count; ++k) {
        float* row = fm.values.data() + std::size_t(k - 1) * fm.cols;
        std::size_t c = 0;
        auto put = [&](double v) { row[c++] = std::isfinite(v) ? static_cast<float>(v) : NAN; };
        const double n = shape.n[k];
        fm.centroid_col[k - 1] = shape.cx[k], fm.centroid_row[k - 1] = shape.cy[k], fm.pixel_count[k - 1] = uint32_t(n);
        if (n == 0) continue;
        for (int b = 0; b < B; ++b) put(bmean[b][k]), put(bsd[b][k]);
        put(brmean[k]), put(brsd[k]);
        {
            const uint32_t* hk = hist.data() + std::size_t(k) * 32;
            auto pct = [&](double q) { return std::min(percentile_bin(hk, 32, n, q), 31) * 8.0 + 4.0; };  // bin centres, 0..255
            put(pct(0.1)), put(pct(0.5)), put(pct(0.9));
        }
        if (image_bands >= 3) {
            const double r = bmean[0][k], g = bmean[1][k], bl = bmean[2][k], s = r + g + bl + 1e-6;
            put(r / s), put(g / s), put(bl / s), put(exg[k]);
            const double mx = std::max({r, g, bl}), mn = std::min({r, g, bl});
            put((mx - mn) / (mx + 1.0));
        }
        if (layout.nir_band >= 0) {
            const double nir = bmean[layout.nir_band][k], red = bmean[0][k];
            put((nir - red) / (nir + red + 1e-6));
        }
        const double gm = gsum[k] / n;
        put(gm), put(std::sqrt(std::max(0.0, gss[k] / n - gm * gm))), put(edge[k] / n);
        const double tr = jxx[k] + jyy[k];
        put(tr > 0 ? std::sqrt((jxx[k] - jyy[k]) * (jxx[k] - jyy[k]) + 4.0 * jxy[k] * jxy[k]) / tr : 0.0);
        const double bg = bgn[k] > 0 ? bgs[k] / bgn[k] : 0.0;
        put(bg), put(bg / (gm + 1.0));
        put(lflat[k] / n), put(luni[k] / n), put(1.0 - (lflat[k] + luni[k]) / n);
        const double area_m2 = n * px_m2, perim_m = shape.perimeter[k] * gsd_m;
        const double len = shape.length[k], wid = shape.width[k];
        put(safe_log(area_m2)), put(safe_log(len * gsd_m)), put(safe_log(wid * gsd_m));
        put(4.0 * M_PI * area_m2 / (perim_m * perim_m)), put(n / (len * wid)), put(len / wid), put(shape.perimeter[k] / (2.0 * (len + wid)));
        const double ne = nb_edges[k];
        if (ne > 0) put(nb_diff[k] / ne), put(nb_min[k]), put(nb_max[k]), put(nb_sd[k] / ne);
        else put(0), put(0), put(0), put(0);
        std::array<double, 4> share{};
        double dark = 0.0, all = 0.0;
        for (int s = 0; s < 4; ++s) {
            share[s] = side_edges[k][s] > 0 ? side_dark[k][s] / side_edges[k][s] : 0.0;
            dark += side_dark[k][s], all += side_edges[k][s];
        }
        std::sort(share.begin(), share.end(), std::greater<>());
        put(all > 0 ? dark / all : 0.0);
        for (double v : share) put(v);
        if (image_bands >= 3) put(ne > 0 ? nb_veg[k] / ne : 0.0);
        for (std::size_t l = 0; l < levels; ++l) {
            const uint32_t p = seg.context[l][k];
            const Shapes& cs = cshape[l];
            const double cn = cs.n[p];
            if (!p || cn == 0) {
                for (int j = 0; j < 8; ++j) put(NAN);
                continue;
            }
            const double ca = cn * px_m2, cp = cs.perimeter[p] * gsd_m;
            put(safe_log(ca)), put(n / cn), put(cn / (cs.length[p] * cs.width[p])), put(4.0 * M_PI * ca / (cp * cp)),
                put(cs.length[p] / cs.width[p]), put(cmean[l][p]), put(csd[l][p]), put(brmean[k] - cmean[l][p]);
        }
        if (pix) {
            const uint32_t* hk = phist.data() + std::size_t(k) * 20;
            auto pct = [&](double q) { return (std::min(percentile_bin(hk, 20, n, q), 19) + 0.5) / 20.0; };  // bin centres, 0..1
            double above = 0.0;
            for (int bin = 10; bin < 20; ++bin) above += hk[bin];
            put(pmean[k]), put(psd[k]), put(pct(0.1)), put(pct(0.5)), put(pct(0.9)), put(above / n);
            put(pbn[k] > 0 ? pbound[k] / pbn[k] : pmean[k]);
            put(ne > 0 ? pnb[k] / ne : 0.0), put(pnbmax[k]);
            for (std::size_t l = 0; l < levels; ++l) {
                const uint32_t p = seg.context[l][k];
                put(p && p < cpmean[l].size() ? cpmean[l][p] : NAN);
            }
        }
        if (c != fm.cols) throw Error("segment features", "internal: feature count mismatch");
    }
    (void)valid;
    return fm;
}

std::vector<float> building_share(const SceneSegments& s, const std::vector<uint8_t>& truth) {
    std::vector<double> n(s.count + 1, 0.0), b(s.count + 1, 0.0);
    for (std::size_t i = 0; i < s.labels.data.size(); ++i)
        if (const uint32_t a = s.labels.data[i]) n[a] += 1.0, b[a] += truth[i] ? 1.0 : 0.0;
    std::vector<float> share(s.count + 1, 0.0f);
    for (uint32_t k = 1; k <= s.count; ++k) share[k] = n[k] > 0 ? static_cast<float>(b[k] / n[k]) : 0.0f;
    return share;
}

}  // namespace cityforge::detect
