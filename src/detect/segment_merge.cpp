#include "detect/segment_merge.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include "core/error.hpp"

namespace cityforge::detect {

std::vector<std::string> pair_feature_names(int context_levels, bool pixel_map) {
    std::vector<std::string> f{"log_boundary_m",  "boundary_share_min", "boundary_share_max", "step_bright_mean", "step_band_mean",
                               "mean_diff_bright", "mean_diff_bands",   "std_bright_max",     "log_area_min_m2",  "log_area_max_m2",
                               "union_rect_fill", "part_rect_fill_min", "union_elongation",   "part_elongation_max"};
    for (int l = 0; l < context_levels; ++l) f.push_back("same_ctx" + std::to_string(l + 1));
    if (pixel_map)
        for (const char* n : {"pmap_boundary", "pmap_min_seg", "pmap_max_seg", "pmap_dip"}) f.emplace_back(n);
    return f;
}

namespace {

struct Moments {
    double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
    void add(const Moments& o) { n += o.n, sx += o.sx, sy += o.sy, sxx += o.sxx, sxy += o.sxy, syy += o.syy; }
    // Eigenvalues of the covariance (a pixel is a unit square: + 1/12 each axis).
    void eig(double& l1, double& l2) const {
        const double mx = sx / n, my = sy / n;
        const double vx = sxx / n - mx * mx + 1.0 / 12.0, vy = syy / n - my * my + 1.0 / 12.0, cxy = sxy / n - mx * my;
        const double tr = vx + vy, d = std::sqrt(std::max(0.0, 0.25 * (vx - vy) * (vx - vy) + cxy * cxy));
        l1 = std::max(1.0 / 12.0, 0.5 * tr + d), l2 = std::max(1.0 / 12.0, 0.5 * tr - d);
    }
    // Area over the area of the rectangle with the same second moments (1 for a rectangle).
    double rect_fill() const {
        double l1, l2;
        eig(l1, l2);
        return n / (12.0 * std::sqrt(l1 * l2));
    }
    double elongation() const {
        double l1, l2;
        eig(l1, l2);
        return std::sqrt(l1 / l2);
    }
};

struct PairAcc {
    double edges = 0, step_bright = 0, step_bands = 0, pmap = 0;
};

}  // namespace

SegmentPairs segment_pairs(const Image<float>& img, const SceneSegments& s, double gsd_m, const std::vector<float>* pmap) {
    const int w = s.labels.width, h = s.labels.height, nb = img.bands;
    if (img.width != w || img.height != h) throw Error("segment pairs", "internal: image and labels differ in size");
    if (pmap && pmap->size() != s.labels.data.size()) throw Error("segment pairs", "internal: pixel map size");
    const std::size_t n = std::size_t(w) * h;
    const uint32_t* L = s.labels.data.data();
    std::vector<float> bright(n, 0.0f);
    for (int b = 0; b < nb; ++b) {
        const float* v = img.band_data(b);
        for (std::size_t i = 0; i < n; ++i) bright[i] += v[i] / float(nb);
    }
    const uint32_t count = s.count;
    std::vector<Moments> mom(count + 1);
    std::vector<double> perim(count + 1, 0.0), sum_b(count + 1, 0.0), sum_bb(count + 1, 0.0), sum_p(count + 1, 0.0);
    std::vector<double> band_sum(std::size_t(count + 1) * nb, 0.0);
    std::unordered_map<uint64_t, PairAcc> acc;
    auto edge = [&](std::size_t i, std::size_t j) {
        const uint32_t la = L[i], lb = L[j];
        if (la == lb) return;
        if (la) perim[la] += 1;
        if (lb) perim[lb] += 1;
        if (!la || !lb) return;
        const uint32_t a = std::min(la, lb), b = std::max(la, lb);
        PairAcc& p = acc[(uint64_t(a) << 32) | b];
        p.edges += 1;
        p.step_bright += std::abs(double(bright[i]) - bright[j]);
        double sb = 0;
        for (int k = 0; k < nb; ++k) sb += std::abs(double(img.band_data(k)[i]) - img.band_data(k)[j]);
        p.step_bands += sb / nb;
        if (pmap) p.pmap += 0.5 * (double((*pmap)[i]) + (*pmap)[j]);
    };
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t i = std::size_t(y) * w + x;
            const uint32_t l = L[i];
            if (l) {
                Moments& m = mom[l];
                m.n += 1, m.sx += x, m.sy += y, m.sxx += double(x) * x, m.sxy += double(x) * y, m.syy += double(y) * y;
                sum_b[l] += bright[i], sum_bb[l] += double(bright[i]) * bright[i];
                for (int k = 0; k < nb; ++k) band_sum[std::size_t(l) * nb + k] += img.band_data(k)[i];
                if (pmap) sum_p[l] += (*pmap)[i];
                // Image edges count as boundary.
                if (x == 0 || x == w - 1) perim[l] += 1;
                if (y == 0 || y == h - 1) perim[l] += 1;
            }
            if (x + 1 < w) edge(i, i + 1);
            if (y + 1 < h) edge(i, i + std::size_t(w));
        }
    std::vector<uint64_t> keys;
    keys.reserve(acc.size());
    for (const auto& kv : acc) keys.push_back(kv.first);
    std::sort(keys.begin(), keys.end());
    const int levels = int(s.context.size());
    SegmentPairs out;
    out.cols = pair_feature_names(levels, pmap != nullptr).size();
    out.values.reserve(keys.size() * out.cols);
    const double m2 = gsd_m * gsd_m;
    for (const uint64_t key : keys) {
        const uint32_t a = uint32_t(key >> 32), b = uint32_t(key & 0xffffffffu);
        const PairAcc& p = acc.at(key);
        out.a.push_back(a), out.b.push_back(b);
        const Moments &ma = mom[a], &mb = mom[b];
        Moments u = ma;
        u.add(mb);
        const double mean_a = sum_b[a] / ma.n, mean_b = sum_b[b] / mb.n;
        const double sd_a = std::sqrt(std::max(0.0, sum_bb[a] / ma.n - mean_a * mean_a)), sd_b = std::sqrt(std::max(0.0, sum_bb[b] / mb.n - mean_b * mean_b));
        double diff_bands = 0;
        for (int k = 0; k < nb; ++k) diff_bands += std::abs(band_sum[std::size_t(a) * nb + k] / ma.n - band_sum[std::size_t(b) * nb + k] / mb.n);
        const double share_a = p.edges / std::max(1.0, perim[a]), share_b = p.edges / std::max(1.0, perim[b]);
        std::vector<double> r{std::log1p(p.edges * gsd_m),
                              std::min(share_a, share_b),
                              std::max(share_a, share_b),
                              p.step_bright / p.edges,
                              p.step_bands / p.edges,
                              std::abs(mean_a - mean_b),
                              diff_bands / nb,
                              std::max(sd_a, sd_b),
                              std::log1p(std::min(ma.n, mb.n) * m2),
                              std::log1p(std::max(ma.n, mb.n) * m2),
                              u.rect_fill(),
                              std::min(ma.rect_fill(), mb.rect_fill()),
                              u.elongation(),
                              std::max(ma.elongation(), mb.elongation())};
        for (int l = 0; l < levels; ++l) r.push_back(s.context[std::size_t(l)][a] == s.context[std::size_t(l)][b] ? 1.0 : 0.0);
        if (pmap) {
            const double pa = sum_p[a] / ma.n, pb = sum_p[b] / mb.n, pe = p.pmap / p.edges;
            r.push_back(pe), r.push_back(std::min(pa, pb)), r.push_back(std::max(pa, pb)), r.push_back(std::min(pa, pb) - pe);
        }
        for (const double v : r) out.values.push_back(static_cast<float>(v));
    }
    return out;
}

std::vector<uint32_t> merge_groups(const SegmentPairs& pairs, const std::vector<float>& prob, const std::vector<uint8_t>& building, double threshold) {
    if (prob.size() != pairs.size()) throw Error("merge groups", "internal: one probability per pair");
    std::vector<uint32_t> parent(building.size());
    std::iota(parent.begin(), parent.end(), 0u);
    auto find = [&](uint32_t x) {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
    };
    for (std::size_t k = 0; k < pairs.size(); ++k) {
        const uint32_t a = pairs.a[k], b = pairs.b[k];
        if (a >= building.size() || b >= building.size()) throw Error("merge groups", "internal: pair label out of range");
        if (!building[a] || !building[b] || !(prob[k] >= threshold)) continue;
        const uint32_t ra = find(a), rb = find(b);
        if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);  // the root is the smallest label
    }
    std::vector<uint32_t> g(building.size());
    for (uint32_t k = 0; k < g.size(); ++k) g[k] = find(k);
    return g;
}

std::vector<int8_t> pair_labels(const SegmentPairs& pairs, const SceneSegments& s, const std::vector<float>& share,
                                const std::vector<uint32_t>& rid, double min_share) {
    if (rid.size() != s.labels.data.size()) throw Error("pair labels", "internal: reference raster size");
    // Dominant reference of each segment (most pixels; ties: the lower id).
    std::vector<std::unordered_map<uint32_t, uint32_t>> cnt(s.count + 1);
    for (std::size_t i = 0; i < rid.size(); ++i)
        if (s.labels.data[i] && rid[i]) cnt[s.labels.data[i]][rid[i]]++;
    std::vector<uint32_t> dom(s.count + 1, 0);
    for (uint32_t k = 1; k <= s.count; ++k) {
        uint32_t bc = 0;
        for (const auto& [r, c] : cnt[k])
            if (c > bc || (c == bc && r < dom[k])) bc = c, dom[k] = r;
    }
    std::vector<int8_t> y(pairs.size(), -1);
    for (std::size_t k = 0; k < pairs.size(); ++k) {
        const uint32_t a = pairs.a[k], b = pairs.b[k];
        if (!(share[a] >= min_share && share[b] >= min_share) || !dom[a] || !dom[b]) continue;
        y[k] = dom[a] == dom[b] ? 1 : 0;
    }
    return y;
}

}  // namespace cityforge::detect
