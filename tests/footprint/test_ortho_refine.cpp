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
    const std::vector<uint8_t> green(s.valid.size(), 2);
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

namespace {
// A grey flat roof [20, 49] x [15, 44] with a tree crown [50, 64] x [15, 44]
// against it (weakly green, its heights a rough dome about 9 m), on grass;
// the heights' cells cover both (a photo cloud: no point classes).
// `roof_is_crown`: the roof is crown too; `green_roof`: the roof
// itself has the crown's weak green colour (a planar green roof); `gable`:
// the roof is a gable, its ridge along x, 30 degrees.
Scene crown_scene(bool roof_is_crown, bool green_roof, bool gable = false) {
    const int w = 80, h = 60;
    Scene s = empty_scene(w, h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool roof = x >= 20 && x <= 49 && y >= 15 && y <= 44;
            const bool tree = (x >= 50 && x <= 64 && y >= 15 && y <= 44) || (roof && roof_is_crown);
            const float noise = static_cast<float>((x * 7 + y * 13) % 9) - 4.0f;
            float rgb[3] = {60.0f, 130.0f, 50.0f};                                          // grass: ExG 0.40
            if (roof) rgb[0] = 150.0f, rgb[1] = 150.0f, rgb[2] = 145.0f;                   // grey: ExG 0.01
            if (roof && green_roof) rgb[0] = 100.0f, rgb[1] = 125.0f, rgb[2] = 105.0f;     // ExG 0.14
            if (tree) rgb[0] = 85.0f, rgb[1] = 105.0f, rgb[2] = 80.0f;                     // ExG 0.16
            for (int b = 0; b < 3; ++b) s.colours.at(b, x, y) = rgb[b] + noise;
            // The crown: a dome with leaves 0.6 m up and down pixel by pixel.
            const float dome = 9.0f - 0.02f * static_cast<float>((x - 57) * (x - 57) + (y - 30) * (y - 30)) / 4.0f;
            const float leaves = ((x * 3 + y * 5) % 4 < 2) ? 0.6f : -0.6f;
            const float roof_z = gable ? 9.0f - 0.5f * 0.577f * std::abs(static_cast<float>(y) - 29.5f) : 9.0f;
            s.ndsm.at(0, x, y) = tree ? dome + leaves : roof ? roof_z : 0.1f;
            const bool cell = roof || tree;
            s.cells.cells[static_cast<std::size_t>(y) * w + x] = cell;
            if (cell) s.cells.step_dsm.at(0, x, y) = s.ndsm.at(0, x, y);
        }
    return s;
}
// Levels of vegetation_pixels for the scene's colours: ExG above 0.25 -> 2, above 0.08 -> 1.
std::vector<uint8_t> vegetation_levels(const Scene& s) {
    std::vector<uint8_t> v(s.valid.size(), 0);
    for (std::size_t k = 0; k < v.size(); ++k) {
        const double r = s.colours.band_data(0)[k], g = s.colours.band_data(1)[k], b = s.colours.band_data(2)[k];
        const double exg = (2 * g - r - b) / (r + g + b);
        v[k] = exg > 0.25 ? 2 : exg > 0.08 ? 1 : 0;
    }
    return v;
}
long pixels_of(const BuildingMask& m, int x0, int x1) {
    long n = 0;
    for (int y = 0; y < 60; ++y)
        for (int x = x0; x <= x1; ++x) n += m.labels.at(0, x, y) != 0;
    return n;
}
}  // namespace

TEST_CASE("Without point classes a crown against a roof is cut off and a building of crown alone dropped", "[footprint][ortho][crown]") {
    OrthoRefineOptions o;
    {
        const Scene s = crown_scene(false, false);
        BuildingMask m = mask_of(s.cells, 80, 60);
        REQUIRE(m.count == 1);
        CHECK(refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, vegetation_levels(s), o) == 0);
        CHECK(pixels_of(m, 20, 49) >= 880);  // the roof: 900 pixels
        CHECK(pixels_of(m, 50, 79) <= 20);   // the crown's 450 are gone
        // Off: the crown stays with the roof (the heights' outline is kept).
        OrthoRefineOptions off = o;
        off.max_crown_plane_sigma_m = 0.0;
        BuildingMask k = mask_of(s.cells, 80, 60);
        refine_buildings_with_ortho(k, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, vegetation_levels(s), off);
        CHECK(pixels_of(k, 50, 79) >= 400);
    }
    {
        const Scene s = crown_scene(true, false);  // nothing but crown
        BuildingMask m = mask_of(s.cells, 80, 60);
        REQUIRE(m.count == 1);
        CHECK(refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, vegetation_levels(s), o) == 1);
        CHECK(pixels_of(m, 0, 79) == 0);
    }
    {
        // A planar roof of the same weak green keeps its pixels: colour alone is no crown.
        for (const bool gable : {false, true}) {
            const Scene s = crown_scene(false, true, gable);
            BuildingMask m = mask_of(s.cells, 80, 60);
            CHECK(refine_buildings_with_ortho(m, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, vegetation_levels(s), o) == 0);
            CHECK(pixels_of(m, 20, 49) >= 880);
        }
    }
    o.max_crown_plane_sigma_m = -1.0;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("crown_plane_sigma_m"));
}

TEST_CASE("With a classified cloud, pixels of a segment running on beyond the roof are peeled off where the cloud measured no roof", "[footprint][ortho][crown]") {
    // A dark roof [20, 49] x [15, 44] and a dark crown [50, 59] x [20, 39]
    // against it, of one colour in the ortho (one segment); the classified
    // cloud measured the crown's cells as not building (ground returns
    // under it: 3 per cell), the roof's as building (4 roof points per cell).
    const int w = 80, h = 60;
    Scene s = empty_scene(w, h);
    s.cells.used_classes = true;
    s.cells.roof_points.assign(s.valid.size(), 0);
    s.cells.ground_points.assign(s.valid.size(), 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const bool roof = x >= 20 && x <= 49 && y >= 15 && y <= 44;
            const bool crown = x >= 50 && x <= 59 && y >= 20 && y <= 39;
            const float noise = static_cast<float>((x * 7 + y * 13) % 9) - 4.0f;
            const float v = roof || crown ? 40.0f : 140.0f;
            for (int b = 0; b < 3; ++b) s.colours.at(b, x, y) = v + noise;
            s.ndsm.at(0, x, y) = roof ? 6.0f : crown ? 5.0f : 0.1f;
            s.cells.cells[k] = roof;
            if (roof) s.cells.step_dsm.at(0, x, y) = 6.0f, s.cells.roof_points[k] = 4, s.cells.ground_points[k] = 0;
        }
    auto crown_pixels = [](const BuildingMask& m) {
        long n = 0;
        for (int y = 20; y <= 39; ++y)
            for (int x = 50; x <= 59; ++x) n += m.labels.at(0, x, y) != 0;
        return n;
    };
    OrthoRefineOptions o;
    o.ndsm_band_weight = 0.0;  // the image alone: roof and crown are one segment
    BuildingMask peeled = mask_of(s.cells, w, h);
    refine_buildings_with_ortho(peeled, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, {}, o);
    CHECK(crown_pixels(peeled) == 0);
    CHECK(pixels_of(peeled, 20, 49) == 900);
    o.cloud_peel_rings = 0;  // the outline ring alone goes back to the cloud
    BuildingMask ring = mask_of(s.cells, w, h);
    refine_buildings_with_ortho(ring, s.cells, s.colours, s.valid, s.ndsm, 20.0, {}, {}, o);
    CHECK(crown_pixels(ring) > 100);
}

TEST_CASE("A tree too sparse to be judged segment by segment is dropped as a crown as a whole", "[footprint][ortho][crown]") {
    // A photo cloud's crown [50, 64] x [15, 44] and nothing else: weak green
    // colours, rough heights; the ortho's segments are 2 x 2 pixels (given),
    // too few samples each for the local roughness, so only the whole
    // building can show that it is a crown.
    const Scene s = crown_scene(false, false);
    Scene t = empty_scene(80, 60);
    Image<uint32_t> segments(80, 60, 1, 0u);
    for (int y = 0; y < 60; ++y)
        for (int x = 0; x < 80; ++x) {
            const bool tree = x >= 50 && x <= 64 && y >= 15 && y <= 44;
            for (int b = 0; b < 3; ++b) t.colours.at(b, x, y) = s.colours.at(b, x, y);
            t.ndsm.at(0, x, y) = tree ? s.ndsm.at(0, x, y) : 0.1f;
            t.cells.cells[static_cast<std::size_t>(y) * 80 + x] = tree;
            if (tree) t.cells.step_dsm.at(0, x, y) = t.ndsm.at(0, x, y);
            segments.at(0, x, y) = static_cast<uint32_t>((y / 2) * 40 + x / 2 + 1);
        }
    OrthoRefineOptions o;
    BuildingMask m = mask_of(t.cells, 80, 60);
    REQUIRE(m.count == 1);
    // Off (above 1): the segments alone keep it.
    OrthoRefineOptions off = o;
    off.min_crown_building_colour_share = 1.5;
    BuildingMask k = m;
    CHECK(refine_buildings_with_ortho(k, t.cells, t.colours, t.valid, t.ndsm, 20.0, segments, vegetation_levels(t), off) == 0);
    CHECK(pixels_of(k, 50, 64) >= 400);
    CHECK(refine_buildings_with_ortho(m, t.cells, t.colours, t.valid, t.ndsm, 20.0, segments, vegetation_levels(t), o) == 1);
    CHECK(pixels_of(m, 0, 79) == 0);
    // A planar roof of the same weak green, cut into the same small segments, stays.
    const Scene g = crown_scene(false, true);
    Scene r = g;
    for (int y = 0; y < 60; ++y)
        for (int x = 50; x < 80; ++x) {  // the roof alone: no crown beside it
            r.ndsm.at(0, x, y) = 0.1f;
            r.cells.cells[static_cast<std::size_t>(y) * 80 + x] = 0;
            r.cells.step_dsm.at(0, x, y) = NAN;
            for (int b = 0; b < 3; ++b) r.colours.at(b, x, y) = g.colours.at(b, 10, y);
        }
    BuildingMask roof = mask_of(r.cells, 80, 60);
    REQUIRE(roof.count == 1);
    CHECK(refine_buildings_with_ortho(roof, r.cells, r.colours, r.valid, r.ndsm, 20.0, segments, vegetation_levels(r), o) == 0);
    CHECK(pixels_of(roof, 20, 49) >= 880);
    o.min_crown_building_colour_share = 0.0;
    CHECK_THROWS_WITH(o.validate(), Catch::StartsWith("min_crown_building_colour_share"));
}
