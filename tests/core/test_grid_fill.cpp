#include <catch2/catch.hpp>
#include <cmath>
#include <limits>
#include <vector>

#include "core/grid_fill.hpp"

using namespace cityforge;

TEST_CASE("fill_from_neighbours closes small gaps pass by pass and leaves large empty areas empty", "[grid][fill]") {
    // 7 x 7 grid, two values per cell: filled in columns 0..2, empty in 3..6,
    // plus a one-cell hole at (1, 1).
    const int w = 7, h = 7;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    std::vector<float> g(2 * w * h, nan);
    for (int r = 0; r < h; ++r)
        for (int q = 0; q < 3; ++q) g[2 * (r * w + q)] = float(q), g[2 * (r * w + q) + 1] = float(10 * r);
    g[2 * (1 * w + 1)] = nan, g[2 * (1 * w + 1) + 1] = nan;
    std::vector<float> one = g;
    fill_from_neighbours(one, w, h, 2, 1);
    // The hole: mean of its 8 neighbours (columns 0..2, rows 0..2).
    CHECK(one[2 * (1 * w + 1)] == Approx(1.0));
    CHECK(one[2 * (1 * w + 1) + 1] == Approx(10.0));
    // One pass grows the filled area by one column (cells with >= 3 filled neighbours) and no further.
    for (int r = 1; r < h - 1; ++r) CHECK(!std::isnan(one[2 * (r * w + 3)]));
    for (int r = 0; r < h; ++r) CHECK(std::isnan(one[2 * (r * w + 4)]));
    // Order-free: from the state before the pass, so column 3 takes the mean of columns 2 only.
    CHECK(one[2 * (3 * w + 3)] == Approx(2.0));
    CHECK(one[2 * (3 * w + 3) + 1] == Approx(30.0));
    std::vector<float> many = g;
    fill_from_neighbours(many, w, h, 2, 50);
    for (std::size_t k = 0; k < many.size(); ++k) CHECK(!std::isnan(many[k]));
    CHECK_THROWS(fill_from_neighbours(many, w, h, 5, 1));
}
