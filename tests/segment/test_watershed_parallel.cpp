// The watershed with dynamics (h > 0, the default of segment and footprints)
// against the sequential flooding written out plainly, on real and synthetic
// images, with and without nodata, on 1 and 2 threads: the labels must be
// the same to the pixel, whatever the thread count.
#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <tbb/global_control.h>

#include "raster/raster.hpp"
#include "segment/watershed.hpp"
#include "synth_fixture.hpp"
#include "segment/watershed_reference.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::reference_dynamics;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;

namespace {
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

TEST_CASE("Watershed without dynamics equals the sequential flooding where colour distances tie, overflow or are NaN - 1 and 2 threads", "[watershed][segment][determinism]") {
    // h 0 picks among the seeds of a pixel's lower neighbours by colour
    // distance, the first neighbour on ties, never a NaN or infinite one.
    uint32_t state = 977u;
    auto next = [&]() { return state = state * 1664525u + 1013904223u, state >> 16; };
    Image<float> ties(203, 157, 3, 0.0f);  // four colours: equal distances everywhere
    for (float& v : ties.data) v = static_cast<float>(next() % 4) * 40.0f;
    Image<float> huge(131, 77, 3, 0.0f);   // squares overflow to infinity, gradients saturate
    for (float& v : huge.data) v = (next() % 3 == 0 ? 3e38f : 1e19f) * static_cast<float>(next() % 5) * (next() % 2 ? 1.0f : -1.0f);
    Image<float> with_nan(97, 61, 3, 0.0f);  // NaN in one band here and there
    for (float& v : with_nan.data) v = static_cast<float>(next() % 64);
    for (std::size_t i = 0; i < with_nan.pixel_count(); i += 13) with_nan.band_data(1)[i] = NAN;
    Image<float> one_band(121, 43, 1, 0.0f), five_bands(66, 35, 5, 0.0f);
    for (float& v : one_band.data) v = static_cast<float>(next() % 6);
    for (float& v : five_bands.data) v = static_cast<float>(next() % 3) * 7.0f;
    for (const Image<float>* img : {&ties, &huge, &with_nan, &one_band, &five_bands})
        for (double smoothing : {0.0, 1.0}) {
            WatershedOptions wo;
            wo.h_minima = 0.0;
            wo.smoothing_sigma_px = smoothing;
            check_against_reference(*img, {}, wo);
            check_against_reference(*img, with_holes(img->pixel_count()), wo);
        }
}

TEST_CASE("Band normalisation with NaN or infinite samples stretches as nth_element over the sample does", "[watershed][segment]") {
    // Expected: test::reference_normalisation, nth_element at the 0.5th and
    // then the 99.5th percentile's rank over the same regular sample (with
    // NaN their order is that of the library's nth_element).
    Image<float> img(1300, 900, 3, 0.0f);  // 1.17 M pixels: a sample of every pixel
    uint32_t state = 4242u;
    for (std::size_t i = 0; i < img.data.size(); ++i) {
        state = state * 1664525u + 1013904223u;
        img.data[i] = static_cast<float>(state % 1000) * 0.25f;
    }
    for (std::size_t i = 0; i < img.pixel_count(); i += 97) img.band_data(0)[i] = NAN;  // NaN here and there
    for (std::size_t i = 0; i < img.pixel_count(); i += 7) img.band_data(1)[i] = (i / 7) % 2 ? INFINITY : -INFINITY;  // 14 % infinite
    img.band_data(2)[5000] = NAN;  // a single NaN
    std::vector<uint8_t> valid(img.pixel_count(), 1);
    for (std::size_t i = 0; i < valid.size(); i += 5) valid[i] = 0;
    for (const auto& v : {std::vector<uint8_t>{}, valid}) {
        Image<float> got = img;
        normalize_bands(got, v);
        const Image<float> want = test::reference_normalisation(img, v);
        std::size_t differ = 0;  // bitwise: NaN stays NaN
        for (std::size_t i = 0; i < got.data.size(); ++i) differ += std::memcmp(&got.data[i], &want.data[i], sizeof(float)) != 0;
        CHECK(differ == 0);
    }
}
