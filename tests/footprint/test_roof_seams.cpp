#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <set>

#include "footprint/roof_seams.hpp"

using namespace cityforge;

namespace {
// A row 80 x 20 cells (0.5 m: 40 m x 10 m) at (10, 10) on a 100 x 40 grid.
constexpr int kW = 100, kH = 40, kX0 = 10, kY0 = 10, kX1 = 89, kY1 = 29;

BuildingMask row_mask() {
    BuildingMask m;
    m.labels = Image<uint32_t>(kW, kH, 1, 0u);
    for (int y = kY0; y <= kY1; ++y)
        for (int x = kX0; x <= kX1; ++x) m.labels.at(0, x, y) = 1;
    m.count = 1;
    return m;
}
// Deterministic pixel noise of +-amp grey levels.
float noise(int x, int y, int band, float amp) {
    uint32_t h = static_cast<uint32_t>(x) * 73856093u ^ static_cast<uint32_t>(y) * 19349663u ^ static_cast<uint32_t>(band) * 83492791u;
    h ^= h >> 13, h *= 0x5bd1e995u, h ^= h >> 15;
    return amp * (static_cast<float>(h % 2001u) / 1000.0f - 1.0f);
}
// RGB of the roof at a cell: base + per-house offset (house boundaries at the given x) + noise.
Image<float> colours(const std::vector<int>& seams_x, const std::vector<float>& offsets, float amp) {
    Image<float> img(kW, kH, 3, 90.0f);
    for (int y = 0; y < kH; ++y)
        for (int x = 0; x < kW; ++x) {
            std::size_t house = 0;
            while (house < seams_x.size() && x >= seams_x[house]) ++house;
            for (int b = 0; b < 3; ++b) img.at(b, x, y) = 150.0f + offsets[house] + static_cast<float>(b) * 4.0f + noise(x, y, b, amp);
        }
    return img;
}
Image<float> flat_heights(float z) {
    Image<float> h(kW, kH, 1, 0.0f);
    for (int y = kY0; y <= kY1; ++y)
        for (int x = kX0; x <= kX1; ++x) h.at(0, x, y) = z;
    return h;
}
std::set<uint32_t> labels_in(const BuildingMask& m, int x0, int y0, int x1, int y1) {
    std::set<uint32_t> s;
    for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) s.insert(m.labels.at(0, x, y));
    return s;
}
}  // namespace

TEST_CASE("Terraces of one height split at the colour seams between their roofs", "[footprint][seams]") {
    BuildingMask m = row_mask();
    // Three flat houses, 15 / 12.5 / 12.5 m wide, roofs 12 and 9 grey levels apart, pixel noise +-6.
    const Image<float> c = colours({40, 65}, {0.0f, 12.0f, 3.0f}, 6.0f);
    RoofSeamOptions o;
    o.enabled = true;
    CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 2);
    REQUIRE(m.count == 3);
    CHECK(labels_in(m, kX0, kY0, 38, kY1).size() == 1);
    CHECK(labels_in(m, 41, kY0, 63, kY1).size() == 1);
    CHECK(labels_in(m, 66, kY0, kX1, kY1).size() == 1);
    CHECK(m.labels.at(0, 20, 20) != m.labels.at(0, 50, 20));
    CHECK(m.labels.at(0, 50, 20) != m.labels.at(0, 80, 20));
    // The seam follows the colour edge to the cell.
    CHECK(m.labels.at(0, 39, 15) == m.labels.at(0, 20, 20));
    CHECK(m.labels.at(0, 40, 15) == m.labels.at(0, 50, 20));
    // Switched off: one building.
    BuildingMask off = row_mask();
    o.enabled = false;
    CHECK(split_at_roof_seams(off, c, {}, flat_heights(8.0f), o) == 0);
    CHECK(off.count == 1);
}

TEST_CASE("Pitched terraces split at the valleys between ridges across the row, whatever the colours", "[footprint][seams]") {
    BuildingMask m = row_mask();
    const Image<float> c = colours({}, {0.0f}, 4.0f);
    // Four gables 10 m wide (20 cells), ridges across the row, pitch 35 deg: eaves 6 m, ridges 9.5 m.
    Image<float> h = flat_heights(0.0f);
    for (int y = kY0; y <= kY1; ++y)
        for (int x = kX0; x <= kX1; ++x) {
            const double in_house = std::fmod(double(x - kX0) + 0.5, 20.0) * 0.5;  // metres from the house's left wall
            h.at(0, x, y) = static_cast<float>(6.0 + std::tan(35.0 * 3.14159265 / 180.0) * (5.0 - std::abs(in_house - 5.0)));
        }
    RoofSeamOptions o;
    o.enabled = true;
    CHECK(split_at_roof_seams(m, c, {}, h, o) == 3);
    CHECK(m.count == 4);
}

TEST_CASE("No split at a ridge, a shadow edge over part of the width, or a gradual shading change", "[footprint][seams]") {
    RoofSeamOptions o;
    o.enabled = true;
    SECTION("a gable whose ridge runs across the axis: its slopes shade differently") {
        BuildingMask m = row_mask();
        const Image<float> c = colours({50}, {0.0f, -40.0f}, 5.0f);
        Image<float> h = flat_heights(0.0f);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = kX0; x <= kX1; ++x) h.at(0, x, y) = static_cast<float>(6.0 + 0.6 * (20.0 - std::abs((x - 50) * 0.5)));
        CHECK(split_at_roof_seams(m, c, {}, h, o) == 0);
        CHECK(m.count == 1);
    }
    SECTION("a straight shadow edge over a third of the width") {
        BuildingMask m = row_mask();
        Image<float> c = colours({}, {0.0f}, 5.0f);
        for (int y = kY0; y < kY0 + 7; ++y)
            for (int x = 50; x <= kX1; ++x)
                for (int b = 0; b < 3; ++b) c.at(b, x, y) *= 0.6f;
        CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 0);
        CHECK(m.count == 1);
    }
    SECTION("a flat roof whose colour changes slowly along the row") {
        BuildingMask m = row_mask();
        Image<float> c = colours({}, {0.0f}, 5.0f);
        for (int y = 0; y < kH; ++y)
            for (int x = 0; x < kW; ++x)
                for (int b = 0; b < 3; ++b) c.at(b, x, y) += 0.5f * static_cast<float>(x);
        CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 0);
        CHECK(m.count == 1);
    }
}

TEST_CASE("Pitched terraces split where a ridge along the row meets a house whose ridge runs across it", "[footprint][seams]") {
    BuildingMask m = row_mask();
    const Image<float> c = colours({}, {0.0f}, 4.0f);  // one colour: only the roof's shape tells
    // House A (x 10-49, 20 m): ridge along the row at y = 20 (mid-width); house
    // B (x 50-89, 20 m): ridge across the row at x = 70. Pitch 35 deg, eaves 6 m.
    const double t = std::tan(35.0 * 3.14159265 / 180.0);
    Image<float> h = flat_heights(0.0f);
    for (int y = kY0; y <= kY1; ++y)
        for (int x = kX0; x <= kX1; ++x) {
            const double across = std::abs((y + 0.5) - 20.0) * 0.5, along = std::abs((x + 0.5) - 70.0) * 0.5;  // metres from each ridge
            h.at(0, x, y) = static_cast<float>(x < 50 ? 6.0 + t * (5.0 - across) : 6.0 + t * (10.0 - along));
        }
    RoofSeamOptions o;
    CHECK(split_at_roof_seams(m, c, {}, h, o) == 1);
    REQUIRE(m.count == 2);
    CHECK(labels_in(m, kX0, kY0, 48, kY1).size() == 1);
    CHECK(labels_in(m, 51, kY0, kX1, kY1).size() == 1);
    CHECK(m.labels.at(0, 30, 20) != m.labels.at(0, 70, 20));
}

TEST_CASE("No split of a hip roof's end, nor of a sparse, noisy roof at a dip of one slice", "[footprint][seams]") {
    RoofSeamOptions o;
    const Image<float> c = colours({}, {0.0f}, 4.0f);
    const double t = std::tan(30.0 * 3.14159265 / 180.0);
    SECTION("a hip: the ridge along the row fades into the end facets") {
        BuildingMask m = row_mask();
        Image<float> h = flat_heights(0.0f);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = kX0; x <= kX1; ++x) {
                const double to_side = 5.0 - std::abs((y + 0.5) - 20.0) * 0.5, to_end = std::min(x + 0.5 - kX0, kX1 + 1 - (x + 0.5)) * 0.5;
                h.at(0, x, y) = static_cast<float>(6.0 + t * std::min(to_side, to_end));
            }
        CHECK(split_at_roof_seams(m, c, {}, h, o) == 0);
        CHECK(m.count == 1);
    }
    SECTION("a gable along the row measured at a fifth of its cells, one slice with a low point") {
        // A dark roof: few returns, so each slice's mean height depends on
        // where its points fall on the facets; noise, not a valley.
        BuildingMask m = row_mask();
        Image<float> h(kW, kH, 1, NAN);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = kX0; x <= kX1; ++x) {
                if (noise(x, y, 7, 1.0f) < 0.6f) continue;  // a fifth of the cells measured
                h.at(0, x, y) = static_cast<float>(6.0 + t * (5.0 - std::abs((y + 0.5) - 20.0) * 0.5));
            }
        for (int y = kY0; y <= kY1; ++y)
            if (!std::isnan(h.at(0, 45, y))) h.at(0, 45, y) = 5.0f;
        CHECK(split_at_roof_seams(m, c, {}, h, o) == 0);
        CHECK(m.count == 1);
    }
}

TEST_CASE("Terraces stepping down a slope split at a faint colour seam where the roof steps, blurred by the cloud", "[footprint][seams]") {
    RoofSeamOptions o;
    o.enabled = true;
    // Two flat houses whose roofs differ by 3.5 grey levels (pixel noise +-6):
    // too faint a colour step alone (below 5x the slices' noise) ...
    const Image<float> c = colours({50}, {0.0f, 3.5f}, 6.0f);
    SECTION("one level: no split") {
        BuildingMask m = row_mask();
        CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 0);
        CHECK(m.count == 1);
    }
    SECTION("... but the roof steps 0.4 m there (houses of one eave on sloping ground), the step spread over two cells") {
        BuildingMask m = row_mask();
        Image<float> h = flat_heights(8.0f);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = 49; x <= kX1; ++x) h.at(0, x, y) = x == 49 ? 8.13f : x == 50 ? 8.27f : 8.4f;
        CHECK(split_at_roof_seams(m, c, {}, h, o) == 1);
        REQUIRE(m.count == 2);
        CHECK(m.labels.at(0, 20, 20) != m.labels.at(0, 70, 20));
        CHECK(labels_in(m, kX0, kY0, 47, kY1).size() == 1);
        CHECK(labels_in(m, 52, kY0, kX1, kY1).size() == 1);
    }
    SECTION("a step in height with no colour step is not a seam") {
        BuildingMask m = row_mask();
        Image<float> h = flat_heights(8.0f);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = 50; x <= kX1; ++x) h.at(0, x, y) = 8.4f;
        CHECK(split_at_roof_seams(m, colours({}, {0.0f}, 6.0f), {}, h, o) == 0);
        CHECK(m.count == 1);
    }
}

TEST_CASE("Roof colours read inside a ragged outline, and a cast shadow across the whole width is not a seam", "[footprint][seams]") {
    RoofSeamOptions o;
    o.enabled = true;
    SECTION("every other column one cell wider, its extra cell dark (wall, shadow): the seam 6 grey levels deep still splits") {
        BuildingMask m = row_mask();
        Image<float> c = colours({50}, {0.0f, 6.0f}, 6.0f);
        Image<float> h = flat_heights(8.0f);
        for (int x = kX0; x <= kX1; x += 2) {
            m.labels.at(0, x, kY1 + 1) = 1;
            h.at(0, x, kY1 + 1) = 8.0f;
            for (int b = 0; b < 3; ++b) c.at(b, x, kY1 + 1) = 60.0f;
        }
        CHECK(split_at_roof_seams(m, c, {}, h, o) == 1);
        REQUIRE(m.count == 2);
        CHECK(m.labels.at(0, 20, 20) != m.labels.at(0, 70, 20));
    }
    SECTION("a shadow edge across the whole width at a slant, the shade 0.6 of the light (not deep enough to be told by the ratio)") {
        BuildingMask m = row_mask();
        Image<float> c = colours({}, {0.0f}, 5.0f);
        for (int y = kY0; y <= kY1; ++y)
            for (int x = 45 + (y - kY0) / 2; x < kW; ++x)
                for (int b = 0; b < 3; ++b) c.at(b, x, y) *= 0.6f;
        CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 0);
        CHECK(m.count == 1);
    }
    SECTION("a neighbour's shadow over the whole width: every band dimmed by one factor") {
        BuildingMask m = row_mask();
        Image<float> c = colours({}, {0.0f}, 5.0f);
        for (int y = 0; y < kH; ++y)
            for (int x = 50; x < kW; ++x)
                for (int b = 0; b < 3; ++b) c.at(b, x, y) *= 0.45f;
        CHECK(split_at_roof_seams(m, c, {}, flat_heights(8.0f), o) == 0);
        CHECK(m.count == 1);
    }
}
