// The watershed with dynamics (h > 0, the default of segment and footprints)
// against the sequential flooding written out plainly, on real and synthetic
// images, with and without nodata, on 1 and 2 threads: the labels must be
// the same to the pixel, whatever the thread count.
#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <map>
#include <tbb/global_control.h>

#include "raster/raster.hpp"
#include "segment/watershed.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
// The flooding with dynamics as specified, plainly: gradient levels (1/4
// grey level), valid pixels in (level, index) order; a pixel's flooded
// neighbours (up, left, right, down) give their basins (union-find roots,
// each through its first neighbour): none, a new basin with its minimum at
// this level; one, that basin; several, the basin of the neighbour closest
// in colour (the first on ties), after the basins shallower than h below
// this level are absorbed into the deepest (lowest minimum, then lowest
// root index), the closest one's absorber if it was absorbed. Labels in
// raster order of first appearance.
Oversegmentation reference_dynamics(const Image<float>& img, const std::vector<uint8_t>& valid, const WatershedOptions& wo) {
    const Image<float> g = multiband_gradient(img, wo);
    const int w = img.width, h = img.height;
    const std::size_t n = img.pixel_count();
    const auto h_levels = static_cast<uint32_t>(std::lround(wo.h_minima * 4.0));
    std::vector<std::pair<uint16_t, uint32_t>> order;
    for (std::size_t i = 0; i < n; ++i)
        if (valid.empty() || valid[i])
            order.push_back({static_cast<uint16_t>(std::min(65535.0f, g.data[i] * 4.0f)), static_cast<uint32_t>(i)});
    std::sort(order.begin(), order.end());
    constexpr uint32_t none = 0xFFFFFFFFu;
    std::vector<uint32_t> parent(n, none), minimum(n, 0);
    auto find = [&](uint32_t x) {
        while (parent[x] != x) x = parent[x];
        return x;
    };
    for (const auto& [lv, p] : order) {
        const int x = static_cast<int>(p % w), y = static_cast<int>(p / w);
        std::vector<uint32_t> roots, via;
        auto visit = [&](int qx, int qy) {
            if (qx < 0 || qy < 0 || qx >= w || qy >= h) return;
            const uint32_t q = static_cast<uint32_t>(qy * w + qx);
            if (parent[q] == none) return;
            const uint32_t r = find(q);
            if (std::find(roots.begin(), roots.end(), r) != roots.end()) return;
            roots.push_back(r), via.push_back(q);
        };
        visit(x, y - 1), visit(x - 1, y), visit(x + 1, y), visit(x, y + 1);
        if (roots.empty()) {
            parent[p] = p, minimum[p] = lv;
            continue;
        }
        uint32_t closest_root = roots[0];
        float closest = INFINITY;
        for (std::size_t k = 0; k < roots.size(); ++k) {
            float d = 0.0f;
            for (int b = 0; b < img.bands; ++b) {
                const float diff = img.band_data(b)[p] - img.band_data(b)[via[k]];
                d += diff * diff;
            }
            if (d < closest) closest = d, closest_root = roots[k];
        }
        const uint32_t deepest = *std::min_element(roots.begin(), roots.end(), [&](uint32_t a, uint32_t b) {
            return minimum[a] != minimum[b] ? minimum[a] < minimum[b] : a < b;
        });
        for (uint32_t r : roots)
            if (r != deepest && static_cast<uint32_t>(lv - minimum[r]) < h_levels) parent[r] = deepest;
        parent[p] = find(closest_root);
    }
    Oversegmentation out;
    out.labels = Image<uint32_t>(w, h, 1, 0u);
    std::map<uint32_t, uint32_t> label;
    for (std::size_t i = 0; i < n; ++i)
        if (parent[i] != none) out.labels.data[i] = label.emplace(find(static_cast<uint32_t>(i)), static_cast<uint32_t>(label.size() + 1)).first->second;
    out.region_count = static_cast<uint32_t>(label.size());
    return out;
}

// The library's labels on 1 and on 2 threads equal the reference's.
void check_against_reference(const Image<float>& img, const std::vector<uint8_t>& valid, const WatershedOptions& wo) {
    const Oversegmentation expected = reference_dynamics(img, valid, wo);
    for (int threads : {1, 2}) {
        Oversegmentation got;
        {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
            got = watershed_oversegment(img, valid, wo);
        }
        INFO("image " << img.width << " x " << img.height << " x " << img.bands << (valid.empty() ? "" : " with nodata") << ", h "
                      << wo.h_minima << ", smoothing " << wo.smoothing_sigma_px << ", " << threads << " thread(s)");
        CHECK(got.region_count == expected.region_count);
        std::size_t differ = got.labels.data.size() == expected.labels.data.size() ? 0 : expected.labels.data.size();
        for (std::size_t i = 0; i < std::min(got.labels.data.size(), expected.labels.data.size()); ++i)
            differ += got.labels.data[i] != expected.labels.data[i];
        CHECK(differ == 0);  // pixels whose label differs
    }
}

std::vector<uint8_t> with_holes(std::size_t n) {
    std::vector<uint8_t> v(n, 1);
    for (std::size_t i = 0; i < n; i += 7) v[i] = 0;        // scattered nodata
    for (std::size_t i = n / 3; i < n / 3 + 500 && i < n; ++i) v[i] = 0;  // a run across rows
    return v;
}
}  // namespace

TEST_CASE("Watershed with dynamics equals the sequential flooding on real Autzen windows - 1 and 2 threads", "[watershed][segment][determinism]") {
    RasterReader reader(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    // A residential block, a road edge with trees, and a larger mixed window.
    for (const PixelWindow& win : {PixelWindow{1200, 1400, 400, 300}, PixelWindow{300, 2500, 257, 311}, PixelWindow{1700, 900, 640, 480}}) {
        Image<float> img = reader.read<float>(win, {1, 2, 3});
        normalize_bands(img, {});
        for (double h : {1.0, 4.0, 10.0})
            for (double smoothing : {0.0, 1.0}) {
                WatershedOptions wo;
                wo.h_minima = h;
                wo.smoothing_sigma_px = smoothing;
                check_against_reference(img, {}, wo);
            }
        WatershedOptions defaults;
        check_against_reference(img, with_holes(img.pixel_count()), defaults);
        // Band weights: only the first band, then a single-band image.
        WatershedOptions weighted;
        weighted.band_weights = {1.0, 0.0, 0.5};
        check_against_reference(img, {}, weighted);
        Image<float> one(img.width, img.height, 1, 0.0f);
        std::copy(img.band_data(1), img.band_data(1) + img.pixel_count(), one.band_data(0));
        check_against_reference(one, {}, defaults);
    }
}

TEST_CASE("Watershed with dynamics equals the sequential flooding on a synthetic town and on plateaus, ramps and noise", "[watershed][segment][determinism]") {
    ScratchDir dir("watershed_parallel");
    make_town(dir, 200, 21, 0);  // 400 x 400 px
    Image<float> town = RasterReader(dir / "ortho.tif").read_all<float>();
    normalize_bands(town, {});
    Image<float> flat(41, 23, 3, 100.0f);   // one plateau: one basin
    Image<float> ramp(300, 200, 1, 0.0f);   // terraces falling right and down
    Image<float> noise(257, 129, 3, 0.0f);  // many shallow basins meeting at many levels
    for (int y = 0; y < 200; ++y)
        for (int x = 0; x < 300; ++x) ramp.at(0, x, y) = static_cast<float>(255 - ((x + y) / 3) % 256);
    uint32_t state = 12345u;
    for (float& v : noise.data) {
        state = state * 1664525u + 1013904223u;
        v = static_cast<float>((state >> 24) % 64) + 96.0f;
    }
    Image<float> column(1, 90, 3, 0.0f), row(97, 1, 3, 0.0f);
    for (int i = 0; i < 90; ++i) column.at(0, 0, i) = static_cast<float>((i * 37) % 101);
    for (int i = 0; i < 97; ++i) row.at(2, i, 0) = static_cast<float>((i * 53) % 97);
    for (const Image<float>* img : {&town, &flat, &ramp, &noise, &column, &row})
        for (double h : {0.5, 4.0, 30.0})
            for (double smoothing : {0.0, 1.0}) {
                WatershedOptions wo;
                wo.h_minima = h;
                wo.smoothing_sigma_px = smoothing;
                check_against_reference(*img, {}, wo);
                check_against_reference(*img, with_holes(img->pixel_count()), wo);
            }
}

TEST_CASE("Watershed with dynamics: fewer regions as h grows, every valid pixel labelled, nodata 0", "[watershed][segment]") {
    RasterReader reader(shared_data("autzen_oregon/autzen_ortho_1ft_epsg2994.tif"));
    Image<float> img = reader.read<float>({1200, 1400, 400, 300}, {1, 2, 3});
    normalize_bands(img, {});
    const std::vector<uint8_t> valid = with_holes(img.pixel_count());
    uint32_t previous = 0xFFFFFFFFu;
    for (double h : {0.0, 2.0, 4.0, 8.0, 16.0}) {
        WatershedOptions wo;
        wo.h_minima = h;
        const Oversegmentation over = watershed_oversegment(img, valid, wo);
        INFO("h " << h);
        CHECK(over.region_count <= previous);
        CHECK(over.region_count > 0);
        std::size_t bad = 0;
        std::vector<uint8_t> used(over.region_count + 1, 0);
        for (std::size_t i = 0; i < valid.size(); ++i) {
            const uint32_t l = over.labels.data[i];
            bad += valid[i] ? (l == 0 || l > over.region_count) : l != 0;
            if (l <= over.region_count) used[l] = 1;
        }
        CHECK(bad == 0);
        CHECK(std::count(used.begin() + 1, used.end(), 1) == over.region_count);  // labels 1..N all used
        previous = over.region_count;
    }
    CHECK(previous < 2000);  // h 16 leaves few basins in a 400 x 300 window
}
