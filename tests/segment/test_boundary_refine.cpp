#include <catch2/catch.hpp>

#include "segment/boundary_refine.hpp"

using namespace cityforge;

TEST_CASE("Boundary refinement moves watershed edge jitter back onto the colour edge", "[segment][refine]") {
    // A bright roof (x < 20) next to dark ground; the labels put a wavy edge
    // one pixel off on either side of the true edge.
    const int w = 40, h = 30;
    Image<float> img(w, h, 1, 0.0f);
    Image<uint32_t> labels(w, h, 1, 0u);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            img.at(0, x, y) = x < 20 ? 200.0f + static_cast<float>((x * 7 + y * 3) % 5) : 60.0f + static_cast<float>((x * 3 + y) % 5);
            const int edge = 20 + (y % 3) - 1;  // 19, 20 or 21
            labels.at(0, x, y) = x < edge ? 1u : 2u;
        }
    refine_segment_boundaries(img, 1, labels, 2, 2);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) CHECK(labels.at(0, x, y) == (x < 20 ? 1u : 2u));
}

TEST_CASE("Boundary refinement keeps nodata and is stable on clean edges", "[segment][refine]") {
    Image<float> img(10, 10, 1, 0.0f);
    Image<uint32_t> labels(10, 10, 1, 0u);
    for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 10; ++x) {
            img.at(0, x, y) = x < 5 ? 10.0f : 90.0f;
            labels.at(0, x, y) = x == 0 ? 0u : x < 5 ? 1u : 2u;
        }
    const Image<uint32_t> before = labels;
    refine_segment_boundaries(img, 1, labels, 2, 3);
    CHECK(labels.data == before.data);
}
