#include <catch2/catch.hpp>
#include <cmath>
#include <set>

#include "footprint/building_mask.hpp"

using namespace cityforge;

namespace {
// A flat scene: ground at 0 m, boxes of given heights {x0, y0, x1, y1 (inclusive), z}.
struct Box {
    int x0, y0, x1, y1;
    float z;
};
Image<float> heights(int w, int h, const std::vector<Box>& boxes) {
    Image<float> img(w, h, 1, 0.0f);
    for (const Box& b : boxes)
        for (int y = b.y0; y <= b.y1; ++y)
            for (int x = b.x0; x <= b.x1; ++x) img.at(0, x, y) = b.z;
    return img;
}
BuildingMask one_building(const Image<float>& dsm) {
    BuildingMask m;
    m.labels = Image<uint32_t>(dsm.width, dsm.height, 1, 0u);
    for (std::size_t k = 0; k < dsm.data.size(); ++k) m.labels.data[k] = dsm.data[k] > 0.0f ? 1u : 0u;
    m.count = 1;
    return m;
}
std::set<uint32_t> labels_in(const BuildingMask& m, int x0, int y0, int x1, int y1) {
    std::set<uint32_t> s;
    for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) s.insert(m.labels.at(0, x, y));
    return s;
}
}  // namespace

TEST_CASE("Terraced houses of different heights are split along the step", "[footprint][split]") {
    // Three houses of 10 x 20 m side by side (0.5 m cells): 8 m, 12 m, 12.5 m.
    const Image<float> dsm = heights(80, 50, {{5, 5, 24, 44, 8.0f}, {25, 5, 44, 44, 12.0f}, {45, 5, 64, 44, 12.5f}});
    BuildingMask m = one_building(dsm);
    BuildingMaskOptions o;
    split_at_height_steps(m, dsm, o);
    CHECK(m.count == 2);  // 12 and 12.5 m differ by less than the 1.5 m step
    const auto a = labels_in(m, 5, 5, 24, 44), b = labels_in(m, 25, 5, 64, 44);
    REQUIRE(a.size() == 1);
    REQUIRE(b.size() == 1);
    CHECK(*a.begin() != *b.begin());
    o.split_step_m = 0.0;
    BuildingMask unsplit = one_building(dsm);
    split_at_height_steps(unsplit, dsm, o);
    CHECK(unsplit.count == 1);
}

TEST_CASE("Dormers - chimneys and gable slopes do not split a building", "[footprint][split]") {
    // A gable roof (1 m rise per cell across a 20 m wide house) with a 3 x 3 m
    // dormer 2 m above the slope and a 1 m chimney 4 m above the ridge.
    Image<float> dsm(60, 60, 1, 0.0f);
    for (int y = 5; y <= 44; ++y)
        for (int x = 5; x <= 44; ++x) dsm.at(0, x, y) = 6.0f + 0.4f * static_cast<float>(std::min(x - 5, 44 - x));
    for (int y = 20; y <= 25; ++y)
        for (int x = 10; x <= 15; ++x) dsm.at(0, x, y) += 2.0f;
    for (int y = 30; y <= 31; ++y)
        for (int x = 24; x <= 25; ++x) dsm.at(0, x, y) += 4.0f;
    BuildingMask m = one_building(dsm);
    split_at_height_steps(m, dsm, BuildingMaskOptions{});
    CHECK(m.count == 1);
}

TEST_CASE("Gaps in the DSM (dark roofs) do not split a building", "[footprint][split]") {
    Image<float> dsm = heights(60, 40, {{5, 5, 44, 34, 9.0f}});
    BuildingMask m = one_building(dsm);
    // Every second column of the roof without points, and a wide band too.
    for (int y = 5; y <= 34; ++y)
        for (int x = 5; x <= 44; ++x)
            if (x % 2 == 0 || (x >= 20 && x <= 27)) dsm.at(0, x, y) = NAN;
    split_at_height_steps(m, dsm, BuildingMaskOptions{});
    CHECK(m.count == 1);
}

TEST_CASE("A roof and a lower crown that meet across a gap of the DSM are split, a pitched roof across a gap is not", "[footprint][split]") {
    // A 20 m roof (0.5 m cells) and a 10 m crown beside it, with a 3 m band
    // between them where a photogrammetric cloud has no height: the heights
    // each side carries into the gap differ by 10 m.
    Image<float> dsm = heights(80, 40, {{5, 5, 34, 34, 20.0f}, {35, 5, 74, 34, 10.0f}});
    const BuildingMask whole = one_building(dsm);
    BuildingMask m = whole;
    for (int y = 5; y <= 34; ++y)
        for (int x = 32; x <= 37; ++x) dsm.at(0, x, y) = NAN;
    BuildingMaskOptions o;
    split_at_height_steps(m, dsm, o);
    CHECK(m.count == 2);
    const auto a = labels_in(m, 5, 5, 30, 34), b = labels_in(m, 40, 5, 74, 34);
    REQUIRE(a.size() == 1);
    REQUIRE(b.size() == 1);
    CHECK(*a.begin() != *b.begin());
    o.split_gap_step_m = 0.0;  // off: parts across a gap always stay one roof
    BuildingMask joined = whole;
    split_at_height_steps(joined, dsm, o);
    CHECK(joined.count == 1);
    // A gable roof rising 0.25 m per cell (27 degrees) with the same 3 m gap
    // across one slope: its sides carry heights 1.75 m apart into the gap.
    Image<float> gable(60, 40, 1, 0.0f);
    for (int y = 5; y <= 34; ++y)
        for (int x = 5; x <= 54; ++x) gable.at(0, x, y) = 6.0f + 0.25f * static_cast<float>(std::min(x - 5, 54 - x));
    BuildingMask g = one_building(gable);
    for (int y = 5; y <= 34; ++y)
        for (int x = 14; x <= 19; ++x) gable.at(0, x, y) = NAN;
    split_at_height_steps(g, gable, BuildingMaskOptions{});
    CHECK(g.count == 1);
}

TEST_CASE("A roof under an overhanging crown stays building", "[footprint][mask]") {
    // A 20 x 15 m roof at 9 m; a crown covers its east third. Under the crown,
    // cells hold crown points only, or crown points plus roof returns that
    // pierced it; east of the roof the crown is over ground.
    const int w = 80, h = 50;
    Image<float> ndsm(w, h, 1, 0.0f), dsm(w, h, 1, 0.0f), building(w, h, 1, 0.0f), vegetation(w, h, 1, 0.0f);
    for (int y = 10; y <= 39; ++y)
        for (int x = 10; x <= 49; ++x) ndsm.at(0, x, y) = 9.0f, building.at(0, x, y) = 1.0f;
    for (int y = 10; y <= 39; ++y)
        for (int x = 37; x <= 60; ++x) {
            ndsm.at(0, x, y) = 12.0f;
            const bool roof = x <= 49;
            const bool pierced = (x + 2 * y) % 3 == 0;  // a third of the cells see through the crown
            vegetation.at(0, x, y) = pierced ? 0.6f : 1.0f;
            building.at(0, x, y) = pierced ? (roof ? 1.0f : 0.0f) : NAN;
        }
    dsm = ndsm;
    BuildingMaskOptions o;
    const BuildingMask m = buildings_from_cells(building_cells(ndsm, dsm, building, vegetation, o), w, h, o);
    REQUIRE(m.count == 1);
    long roof_cells = 0, outside = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool truth = x >= 10 && x <= 49 && y >= 10 && y <= 39;
            if (m.labels.at(0, x, y)) (truth ? roof_cells : outside) += 1;
        }
    CHECK(roof_cells >= 40 * 30 * 97 / 100);  // the roof under the crown is kept
    CHECK(outside <= 30 * 2);                  // at most a cell's width spills past the roof edge under the crown
}

TEST_CASE("A dense crown beside a wall, with no return from under it, stays out of the building", "[footprint][mask]") {
    // A 20 x 15 m roof at 9 m (cells 10..49 x 10..39); a crown 3.5 m wide
    // against its east wall (cells 50..56 x 15..30) returns crown points
    // only. A second crown covers the roof's north-west corner (crown points
    // only there too): a roof may lie under it, inside the roof's rectangle.
    const int w = 80, h = 50;
    Image<float> ndsm(w, h, 1, 0.0f), building(w, h, 1, NAN), vegetation(w, h, 1, NAN);
    for (int y = 10; y <= 39; ++y)
        for (int x = 10; x <= 49; ++x) ndsm.at(0, x, y) = 9.0f, building.at(0, x, y) = 1.0f, vegetation.at(0, x, y) = 0.0f;
    auto crown = [&](int x0, int y0, int x1, int y1) {
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) ndsm.at(0, x, y) = 10.0f, building.at(0, x, y) = NAN, vegetation.at(0, x, y) = 1.0f;
    };
    crown(50, 15, 56, 30);
    crown(10, 10, 15, 15);
    for (int y = 0; y < h; ++y)  // ground elsewhere: measured, not building
        for (int x = 0; x < w; ++x)
            if (ndsm.at(0, x, y) == 0.0f) building.at(0, x, y) = 0.0f, vegetation.at(0, x, y) = 0.0f;
    const Image<float> dsm = ndsm;
    auto count = [&](const BuildingCells& c, int x0, int y0, int x1, int y1) {
        long n = 0;
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) n += c.cells[static_cast<std::size_t>(y) * w + x];
        return n;
    };
    BuildingMaskOptions o;
    const BuildingCells trimmed = building_cells(ndsm, dsm, building, vegetation, o);
    REQUIRE(trimmed.used_classes);
    CHECK(count(trimmed, 51, 15, 56, 30) == 0);   // beyond a cell from the wall: out
    CHECK(count(trimmed, 10, 10, 15, 15) >= 35);  // the corner under the crown: roof (the outermost corner cell may stay out)
    CHECK(count(trimmed, 10, 10, 49, 39) >= 1199);
    o.crown_fill_rectangle_cells = -1;  // off: the fill takes the crown beside the wall
    const BuildingCells filled = building_cells(ndsm, dsm, building, vegetation, o);
    CHECK(count(filled, 51, 15, 56, 30) >= 60);
}

TEST_CASE("Roofs the data hides are completed inside the building's rectangle, never over measured ground or another building", "[footprint][mask]") {
    // A 20 x 12 building with its lower-right 4 x 4 corner unmeasured (a
    // crown or a dark roof: no evidence), a measured-ground strip beyond it,
    // and a neighbour whose unmeasured cells lie outside the rectangle.
    const int w = 40, h = 24;
    BuildingCells cells;
    cells.cells.assign(static_cast<std::size_t>(w) * h, 0);
    cells.evidence.assign(cells.cells.size(), 1);  // measured ground everywhere ...
    BuildingMask mask;
    mask.labels = Image<uint32_t>(w, h, 1, 0u);
    mask.count = 2;
    for (int y = 2; y < 14; ++y)
        for (int x = 2; x < 22; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const bool corner = x >= 18 && y >= 10;
            if (corner) cells.evidence[k] = 0;  // ... but the hidden corner
            else mask.labels.data[k] = 1, cells.cells[k] = 1;
        }
    // Unmeasured cells outside the rectangle (below the building) stay out.
    for (int x = 2; x < 10; ++x) cells.evidence[static_cast<std::size_t>(15) * w + x] = 0;
    // Building 2, an L whose concave corner is measured ground.
    for (int y = 16; y < 22; ++y)
        for (int x = 26; x < 38; ++x)
            if (!(x >= 32 && y >= 19)) mask.labels.data[static_cast<std::size_t>(y) * w + x] = 2, cells.cells[static_cast<std::size_t>(y) * w + x] = 1;
    const BuildingMask before = mask;
    CHECK(complete_hidden_roofs(mask, cells, 0.25) == 16);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const bool corner = x >= 18 && x < 22 && y >= 10 && y < 14;
            CHECK(mask.labels.data[k] == (corner ? 1u : before.labels.data[k]));
        }
    // A growth beyond the share is refused (then the rectangle is no model of the building).
    BuildingMask strict = before;
    CHECK(complete_hidden_roofs(strict, cells, 0.05) == 0);
    CHECK(strict.labels.data == before.labels.data);
    BuildingMaskOptions bad;
    bad.hidden_completion_max_share = 1.5;
    CHECK_THROWS_WITH(bad.validate(), Catch::Contains("hidden_completion_max_share"));
}

TEST_CASE("A building stays one part: stray pixels cut off from it are dropped, whichever comes first", "[footprint][mask]") {
    // Building 1: a stray pixel at (1, 1) met first in raster order, a
    // diagonal-only pixel at (9, 3), and its 6 x 6 body at [3, 8] x [4, 9].
    // Building 2: two parts of 4 pixels each; the first in raster order stays.
    const int w = 20, h = 12;
    BuildingMask m;
    m.labels = Image<uint32_t>(w, h, 1, 0u);
    m.count = 2;
    m.labels.at(0, 1, 1) = 1;
    m.labels.at(0, 9, 3) = 1;
    for (int y = 4; y <= 9; ++y)
        for (int x = 3; x <= 8; ++x) m.labels.at(0, x, y) = 1;
    for (int x = 12; x <= 15; ++x) m.labels.at(0, x, 2) = 2;
    for (int x = 12; x <= 15; ++x) m.labels.at(0, x, 8) = 2;
    CHECK(keep_largest_parts(m) == 6);
    CHECK(m.labels.at(0, 1, 1) == 0u);
    CHECK(m.labels.at(0, 9, 3) == 0u);
    CHECK(labels_in(m, 3, 4, 8, 9) == std::set<uint32_t>{1u});
    CHECK(labels_in(m, 12, 2, 15, 2) == std::set<uint32_t>{2u});
    CHECK(labels_in(m, 12, 8, 15, 8) == std::set<uint32_t>{0u});
    CHECK(keep_largest_parts(m) == 0);  // already one part each
}
