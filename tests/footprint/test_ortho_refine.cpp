#include <catch2/catch.hpp>
#include <cmath>

#include "core/error.hpp"
#include "footprint/ortho_refine.hpp"

using namespace cityforge;

namespace {
struct Scene {
    Image<float> colours, ndsm;
    std::vector<uint8_t> valid;
    BuildingCells cells;
};
// An empty w x h scene: every cell with its own evidence, none building.
Scene empty_scene(int w, int h) {
    Scene s;
    s.colours = Image<float>(w, h, 3, 0.0f);
    s.ndsm = Image<float>(w, h, 1, 0.0f);
    s.valid.assign(static_cast<std::size_t>(w) * h, 1);
    s.cells.cells.assign(s.valid.size(), 0);
    s.cells.evidence.assign(s.valid.size(), 1);
    s.cells.step_dsm = Image<float>(w, h, 1, NAN);
    return s;
}
// A red roof [20, 49] x [15, 44] on textured grass, and the heights' cells of
// that roof one pixel too large on every side (a blurred cloud edge).
Scene roof_scene(bool contrast) {
    const int w = 80, h = 60;
    Scene s = empty_scene(w, h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool roof = x >= 20 && x <= 49 && y >= 15 && y <= 44;
            const bool cell = x >= 19 && x <= 50 && y >= 14 && y <= 45;
            const float noise = static_cast<float>((x * 7 + y * 13) % 9) - 4.0f;
            const float rgb[3] = {roof && contrast ? 200.0f : 80.0f, roof && contrast ? 80.0f : 120.0f, roof && contrast ? 70.0f : 60.0f};
            for (int b = 0; b < 3; ++b) s.colours.at(b, x, y) = rgb[b] + noise;
            s.ndsm.at(0, x, y) = cell ? 9.0f : 0.1f;
            s.cells.cells[static_cast<std::size_t>(y) * w + x] = cell;
            if (cell) s.cells.step_dsm.at(0, x, y) = 9.0f;
        }
    return s;
}
BuildingMask mask_of(const BuildingCells& c, int w, int h) {
    BuildingMaskOptions o;
    o.gsd_m = 0.5;
    return buildings_from_cells(c, w, h, o);
}
}  // namespace

TEST_CASE("A building of the heights is redrawn along the ortho's edge", "[footprint][ortho]") {
    const Scene s = roof_scene(true);
    BuildingMask m = mask_of(s.cells, 80, 60);
    REQUIRE(m.count == 1);
    OrthoRefineOptions o;
    refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, {}, o);
    long wrong = 0;
    for (int y = 0; y < 60; ++y)
        for (int x = 0; x < 80; ++x) wrong += (m.labels.at(0, x, y) == 1) != (x >= 20 && x <= 49 && y >= 15 && y <= 44);
    CHECK(wrong == 0);  // the cloud's extra ring of 124 pixels is gone
}

TEST_CASE("A redrawn building depends only on its own crop (tile invariance)", "[footprint][ortho]") {
    const Scene s = roof_scene(true);
    // The same scene seen through a window that starts at (7, 5).
    const int x0 = 7, y0 = 5, w = 80 - x0, h = 60 - y0;
    Scene win = empty_scene(w, h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            for (int b = 0; b < 3; ++b) win.colours.at(b, x, y) = s.colours.at(b, x + x0, y + y0);
            win.ndsm.at(0, x, y) = s.ndsm.at(0, x + x0, y + y0);
            win.cells.cells[static_cast<std::size_t>(y) * w + x] = s.cells.cells[static_cast<std::size_t>(y + y0) * 80 + x + x0];
            win.cells.step_dsm.at(0, x, y) = s.cells.step_dsm.at(0, x + x0, y + y0);
        }
    BuildingMask whole = mask_of(s.cells, 80, 60), part = mask_of(win.cells, w, h);
    OrthoRefineOptions o;
    o.margin_px = 5;  // the crop fits inside both windows
    refine_buildings_with_ortho(whole, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, {}, o);
    refine_buildings_with_ortho(part, win.cells, win.colours, win.valid, win.ndsm, 20.0, {}, {}, o);
    long differ = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) differ += (whole.labels.at(0, x + x0, y + y0) != 0) != (part.labels.at(0, x, y) != 0);
    CHECK(differ == 0);
}

TEST_CASE("Without an edge in the ortho a building keeps the heights' outline", "[footprint][ortho]") {
    const Scene s = roof_scene(false);  // the roof has the grass's colours
    BuildingMask m = mask_of(s.cells, 80, 60);
    const auto before = m.labels.data;
    OrthoRefineOptions o;
    o.ndsm_band_weight = 0.0;  // the image alone has nothing to draw with
    refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, {}, o);
    CHECK(m.labels.data == before);
}

TEST_CASE("Crowns by colour are vetoed and rasters of another size refused", "[footprint][ortho]") {
    const Scene s = roof_scene(true);
    BuildingMask m = mask_of(s.cells, 80, 60);
    const auto before = m.labels.data;
    // Every pixel looks like vegetation: no segment may become building, so
    // the redrawing strays and the heights' outline stays.
    const std::vector<uint8_t> green(s.valid.size(), 1);
    refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, green, OrthoRefineOptions{});
    CHECK(m.labels.data == before);
    const std::vector<uint8_t> short_valid(10, 1);
    CHECK_THROWS_WITH(refine_buildings_with_ortho(m, s.cells, s.colours, short_valid, s.ndsm, 20.0, {}, {}, OrthoRefineOptions{}),
                      Catch::Contains("rasters differ in size"));
}

TEST_CASE("A sparse (dark) roof keeps the ortho's edge where the cloud has only one ground point there", "[footprint][ortho][dark]") {
    // The ortho's roof is [20, 49] x [15, 44]. The classified cloud's cells
    // miss its outermost ring: there a pixel three-quarters roof caught one
    // ground point and no roof point. Ground elsewhere has 2 points per cell.
    auto scene = [](int roof_points_per_cell_x5) {
        Scene s = roof_scene(true);
        const int w = 80, h = 60;
        s.cells.used_classes = true;
        s.cells.roof_points.assign(s.valid.size(), 0), s.cells.ground_points.assign(s.valid.size(), 2);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                const bool inner = x >= 21 && x <= 48 && y >= 16 && y <= 43, roof = x >= 20 && x <= 49 && y >= 15 && y <= 44;
                s.cells.cells[k] = inner;
                s.cells.step_dsm.at(0, x, y) = inner ? 9.0f : NAN;
                s.ndsm.at(0, x, y) = roof ? 9.0f : 0.1f;
                if (inner) {
                    s.cells.ground_points[k] = 0;
                    // A dark roof returns 1 point in 5 cells; a bright one 2 per cell.
                    s.cells.roof_points[k] = roof_points_per_cell_x5 >= 5 ? static_cast<uint8_t>(roof_points_per_cell_x5 / 5) : (x + y) % 5 == 0;
                    s.cells.evidence[k] = s.cells.roof_points[k] > 0;
                } else if (roof) {
                    s.cells.ground_points[k] = 1;  // the ring: evidence of ground, weak on a dark roof
                }
            }
        return s;
    };
    auto wrong_pixels = [](const BuildingMask& m) {
        long wrong = 0;
        for (int y = 0; y < 60; ++y)
            for (int x = 0; x < 80; ++x) wrong += (m.labels.at(0, x, y) == 1) != (x >= 20 && x <= 49 && y >= 15 && y <= 44);
        return wrong;
    };
    const Scene dark = scene(1);
    OrthoRefineOptions o;
    BuildingMask m = mask_of(dark.cells, 80, 60);
    REQUIRE(m.count == 1);
    refine_buildings_with_ortho(m, dark.cells, dark.colours, dark.valid, dark.ndsm, 20.0, {}, {}, o);
    CHECK(wrong_pixels(m) == 0);  // the ortho's edge stays
    // With the cloud alone deciding the edges, the ring (116 pixels) is lost.
    o.ortho_edge_odds = 0.0;
    BuildingMask cloud_only = mask_of(dark.cells, 80, 60);
    refine_buildings_with_ortho(cloud_only, dark.cells, dark.colours, dark.valid, dark.ndsm, 20.0, {}, {}, o);
    CHECK(wrong_pixels(cloud_only) == 116);
    // A roof as bright as the ground (2 points per cell): one ground point is
    // strong evidence, the cloud's edge wins whatever the odds.
    const Scene bright = scene(10);
    o.ortho_edge_odds = 2.0;
    BuildingMask b = mask_of(bright.cells, 80, 60);
    refine_buildings_with_ortho(b, bright.cells, bright.colours, bright.valid, bright.ndsm, 20.0, {}, {}, o);
    CHECK(wrong_pixels(b) == 116);
    o.ortho_edge_odds = -1.0;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("--ortho-edge-odds"));
}
