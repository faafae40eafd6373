#include <catch2/catch.hpp>

#include "footprint/segment_classifier.hpp"

using namespace cityforge;

TEST_CASE("NDVI from a NIR band and ExG from RGB mark vegetation segments", "[footprint][classifier]") {
    // Segment 1: a grey roof; 2: a grey-green lawn that ExG alone misses but
    // NDVI (NIR high) catches; 3: bright green grass; 4: a dark shadow.
    const int w = 40, h = 10;
    Image<float> img(w, h, 4, 0.0f);
    Image<uint32_t> labels(w, h, 1, 0u);
    const float rgbn[4][4] = {{120, 118, 115, 90}, {100, 110, 95, 200}, {60, 140, 50, 210}, {10, 12, 10, 8}};
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const int s = x / 10;
            labels.at(0, x, y) = static_cast<uint32_t>(s + 1);
            for (int b = 0; b < 4; ++b) img.at(b, x, y) = rgbn[s][b];
        }
    SegmentClassifierOptions o;
    const auto rgb_only = segment_spectra(img, labels, 4, o);
    CHECK_FALSE(rgb_only[1].vegetation);
    CHECK_FALSE(rgb_only[2].vegetation);  // ExG (2*110-100-95)/305 = 0.08
    CHECK(rgb_only[3].vegetation);
    CHECK(rgb_only[4].shadow);
    o.nir_band = 3;
    const auto with_nir = segment_spectra(img, labels, 4, o);
    CHECK(with_nir[1].ndvi == Approx((90.0 - 120.0) / 210.0));
    CHECK_FALSE(with_nir[1].vegetation);
    CHECK(with_nir[2].vegetation);  // NDVI (200-100)/300 = 0.33
    CHECK(with_nir[3].vegetation);
    o.nir_band = 4;
    CHECK_THROWS_WITH(segment_spectra(img, labels, 4, o), Catch::StartsWith("--nir-band"));
}
