// One building's outline fitted (footprint/outline_fit): each fit on shapes
// with a known answer, in a CRS whose unit is not the metre.
#include <catch2/catch.hpp>
#include <cmath>

#include "core/error.hpp"
#include "footprint/outline_fit.hpp"
#include "footprint/vectorize.hpp"

using namespace cityforge;

namespace {
// The pixel outline (pixels of `size` CRS units) of the cells whose centres
// `inside` holds, on a 120 x 120 grid with its top-left corner at (0, 120 size).
template <typename F>
Polygon pixel_outline(double size, F inside) {
    Image<uint32_t> labels(120, 120, 1, 0u);
    for (int r = 0; r < 120; ++r)
        for (int c = 0; c < 120; ++c)
            if (inside((c + 0.5) * size, (120 - r - 0.5) * size)) labels.at(0, c, r) = 1;
    const auto polys = vectorize_region(labels, 1, GeoTransform{0.0, size, 120 * size, -size});
    REQUIRE(polys.size() == 1);
    return polys[0];
}
}  // namespace

TEST_CASE("Outline fits: a rotated rectangle, an L, a circle and the raw outline - the options' metres converted to CRS units",
          "[footprint][fit]") {
    // CRS units of 0.3048 m (international feet), pixels of 1.6404 ft = 0.5 m.
    const double ft = 0.3048, px = 0.5 / ft;
    OutlineFitOptions o;
    SECTION("a rectangle 20 m x 10 m turned by 30 degrees: the rectangle fit's orientation and area") {
        const double c = std::cos(30 * M_PI / 180), s = std::sin(30 * M_PI / 180), cx = 60 * px, cy = 60 * px;
        const Polygon pixels = pixel_outline(px, [&](double x, double y) {
            const double u = ((x - cx) * c + (y - cy) * s) * ft, v = (-(x - cx) * s + (y - cy) * c) * ft;
            return std::abs(u) < 10.0 && std::abs(v) < 5.0;
        });
        o.fit = FootprintFit::rectangle;
        const FittedOutline f = fit_building_outline(pixels, o, px, ft);
        CHECK(f.status == "ok");
        CHECK(f.fit == "rectangle");
        CHECK(f.outline.outer.size() == 4);
        const double orientation = std::fmod(f.orientation_deg + 180.0, 90.0);
        CHECK(std::min(std::abs(orientation - 30.0), 90.0 - std::abs(orientation - 30.0)) < 2.0);
        // The minimum-area rectangle encloses the pixel staircase: about half
        // a pixel's diagonal more on each side (~220 m² for 200 m²).
        const double area_m2 = polygon_area(f.outline) * ft * ft;
        CHECK(area_m2 > 200.0);
        CHECK(area_m2 < 225.0);
        CHECK(f.area_error_pct > 0.0);
        CHECK(f.area_error_pct < 12.0);
        CHECK(f.iou > 0.88);
    }
    SECTION("an L of 30 m x 20 m less a 15 m x 10 m corner: recursive gives six right-angled corners, 450 m²") {
        const Polygon pixels = pixel_outline(px, [&](double x, double y) {
            const double u = x * ft - 10.0, v = y * ft - 10.0;
            return u >= 0 && u < 30 && v >= 0 && v < 20 && !(u >= 15 && v >= 10);
        });
        o.fit = FootprintFit::recursive;
        const FittedOutline f = fit_building_outline(pixels, o, px, ft);
        CHECK(f.status == "ok");
        CHECK(f.fit == "recursive");
        CHECK(f.outline.outer.size() == 6);
        CHECK(polygon_area(f.outline) * ft * ft == Approx(450.0).epsilon(0.02));
        CHECK(f.iou > 0.97);
        // The rectangle fit of the same outline covers the missing corner.
        o.fit = FootprintFit::rectangle;
        CHECK(polygon_area(fit_building_outline(pixels, o, px, ft).outline) * ft * ft == Approx(600.0).epsilon(0.02));
    }
    SECTION("a circle of 9 m radius: recursive and regularised fits give the smooth outline, the rectangle fit does not") {
        const Polygon pixels = pixel_outline(px, [&](double x, double y) { return std::hypot(x * ft - 30, y * ft - 30) < 9.0; });
        for (FootprintFit fit : {FootprintFit::recursive, FootprintFit::regularised}) {
            o.fit = fit;
            const FittedOutline f = fit_building_outline(pixels, o, px, ft);
            INFO(to_string(fit));
            CHECK(f.status == "ok");
            CHECK(f.fit == "curved");
            CHECK(polygon_area(f.outline) * ft * ft == Approx(M_PI * 81).epsilon(0.03));
        }
        o.fit = FootprintFit::rectangle;
        CHECK(fit_building_outline(pixels, o, px, ft).fit == "rectangle");
    }
    SECTION("raw: the simplified pixel outline, no error against itself") {
        const Polygon pixels = pixel_outline(px, [&](double x, double y) { return std::hypot(x * ft - 30, y * ft - 30) < 9.0; });
        o.fit = FootprintFit::raw;
        const FittedOutline f = fit_building_outline(pixels, o, px, ft);
        CHECK(f.status == "ok");
        CHECK(f.fit == "raw");
        CHECK(f.area_error_pct == 0.0);
        CHECK(f.iou == 1.0);
        CHECK(polygon_area(f.outline) == Approx(polygon_area(f.raw)));
        CHECK(f.raw.outer.size() < pixels.outer.size());  // simplified (0.25 m tolerance) from the staircase
    }
}

TEST_CASE("Outline fits: the recursive and regularised fits' options in metres reach them in a foot CRS", "[footprint][fit]") {
    const double ft = 0.3048, px = 0.5 / ft;
    // 30 m x 20 m with a 5 m x 3 m notch (15 m²) in one corner.
    const Polygon notch = pixel_outline(px, [&](double x, double y) {
        const double u = x * ft - 10.0, v = y * ft - 10.0;
        return u >= 0 && u < 30 && v >= 0 && v < 20 && !(u >= 25 && v >= 17);
    });
    OutlineFitOptions o;
    o.fit = FootprintFit::recursive;
    o.recursive.tolerance_pct = 0.0;
    o.recursive.match_area_max_offset = 0.0;
    o.recursive.min_rectangle_area = 20.0;  // m²: the 15 m² notch is not cut (in ft² it would be)
    CHECK(fit_building_outline(notch, o, px, ft).outline.outer.size() == 4);
    o.recursive.min_rectangle_area = 10.0;  // m²: it is
    CHECK(fit_building_outline(notch, o, px, ft).outline.outer.size() == 6);
    // A 1 m step along one side: absorbed by a 3 m minimum edge, kept by a 0.25 m one.
    const Polygon step = pixel_outline(px, [&](double x, double y) {
        const double u = x * ft - 10.0, v = y * ft - 10.0;
        return u >= 0 && u < 30 && v >= 0 && v < (u < 15 ? 20 : 21);
    });
    o.fit = FootprintFit::regularised;
    o.regularize.min_edge = 3.0, o.regularize.merge_offset = 3.0, o.regularize.match_area_max_offset = 0.0;
    const FittedOutline coarse = fit_building_outline(step, o, px, ft);
    CHECK(coarse.fit == "regularised");
    CHECK(coarse.outline.outer.size() == 4);
    o.regularize.min_edge = 0.25, o.regularize.merge_offset = 0.25;
    CHECK(fit_building_outline(step, o, px, ft).outline.outer.size() == 6);
    // A zero pixel size or a unit that is not positive is refused.
    CHECK_THROWS_WITH(fit_building_outline(step, o, 0.0, ft), Catch::Contains("pixel size"));
    CHECK_THROWS_WITH(fit_building_outline(step, o, px, 0.0), Catch::Contains("metres per CRS unit"));
    o.simplify_m = -1.0;
    CHECK_THROWS_WITH(fit_building_outline(step, o, px, ft), Catch::Contains("simplify_m"));
}

TEST_CASE("Fit names: every fit reads back from its name - an unknown name is refused naming --fit", "[footprint][fit]") {
    for (FootprintFit f : {FootprintFit::raw, FootprintFit::rectangle, FootprintFit::recursive, FootprintFit::regularised})
        CHECK(footprint_fit_from_string(to_string(f)) == f);
    CHECK(footprint_fit_from_string("regularized") == FootprintFit::regularised);
    CHECK_THROWS_WITH(footprint_fit_from_string("square"), Catch::Contains("--fit") && Catch::Contains("square"));
}
