// Round and many-sided outlines told from rectilinear ones, and smoothed.
#include <catch2/catch.hpp>
#include <cmath>

#include "footprint/curved_outline.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

using namespace cityforge;

namespace {
constexpr double kPi = 3.14159265358979323846;
// The pixel outline (0.5 m pixels, along pixel edges) of the cells whose
// centres `inside` holds, on a 100 x 100 grid.
template <typename F>
Polygon pixel_outline(F inside) {
    Image<uint32_t> labels(100, 100, 1, 0u);
    for (int r = 0; r < 100; ++r)
        for (int c = 0; c < 100; ++c)
            if (inside((c + 0.5) * 0.5, 50.0 - (r + 0.5) * 0.5)) labels.at(0, c, r) = 1;
    const auto polys = vectorize_region(labels, 1, GeoTransform{0.0, 0.5, 50.0, -0.5});
    REQUIRE(polys.size() == 1);
    return polys[0];
}
Polygon exact_circle(double cx, double cy, double r) {
    Polygon p;
    for (int k = 0; k < 360; ++k) p.outer.push_back({cx + r * std::cos(k * kPi / 180), cy + r * std::sin(k * kPi / 180)});
    return p;
}
}  // namespace

TEST_CASE("Curved outlines: a circle and a hexagon are curved, rotated rectangles, an L and a cross are not - the smooth outline follows the circle",
          "[footprint][curved][fit]") {
    const CurvedOutlineOptions o;
    auto share = [&](const Polygon& pixels) {
        const Polygon coarse = simplify_polygon(smooth_pixel_outline(pixels, 0.5, o.simplify_px), o.classify_simplify_px * 0.5);
        return rectilinear_share(coarse, minimum_area_rectangle(coarse).orientation_deg, o.axis_tolerance_deg);
    };
    // A circle of 9 m radius.
    const Polygon circle = pixel_outline([](double x, double y) { return std::hypot(x - 25, y - 25) < 9.0; });
    CHECK(share(circle) < o.max_rectilinear_share);
    const Polygon smooth = smooth_pixel_outline(circle, 0.5, o.simplify_px);
    CHECK(polygon_is_valid(smooth));
    const Polygon truth = exact_circle(25, 25, 9.0);
    CHECK(polygon_iou(smooth, truth) > 0.98);
    CHECK(polygon_iou(smooth, truth) > polygon_iou(circle, truth));  // better than the staircase
    CHECK(curved_outline(circle, 0.5, o).has_value());
    // A regular hexagon, 10 m to the corners, rotated by 10 degrees: curved.
    // (A regular octagon fills 0.83 of its square, as ragged rectangles do:
    // it keeps the rectangle fits.)
    const Polygon hexagon = pixel_outline([](double x, double y) {
        for (int k = 0; k < 6; ++k) {
            const double a = (10.0 + 30.0 + 60.0 * k) * kPi / 180;
            if ((x - 25) * std::cos(a) + (y - 25) * std::sin(a) > 10.0 * std::cos(30.0 * kPi / 180)) return false;
        }
        return true;
    });
    CHECK(share(hexagon) < o.max_rectilinear_share);
    CHECK(curved_outline(hexagon, 0.5, o).has_value());
    // Rectangles at 0, 17 and 38 degrees, and an L.
    for (double deg : {0.0, 17.0, 38.0}) {
        const double a = deg * kPi / 180;
        const Polygon rect = pixel_outline([&](double x, double y) {
            const double u = (x - 25) * std::cos(a) + (y - 25) * std::sin(a), v = -(x - 25) * std::sin(a) + (y - 25) * std::cos(a);
            return std::abs(u) < 12.0 && std::abs(v) < 6.0;
        });
        INFO(deg << " degrees");
        CHECK(share(rect) > 0.8);
        CHECK_FALSE(curved_outline(rect, 0.5, o).has_value());
    }
    const Polygon ell = pixel_outline([](double x, double y) { return x > 10 && x < 40 && y > 10 && y < 40 && (x < 20 || y < 20); });
    CHECK(share(ell) > 0.9);
    CHECK_FALSE(curved_outline(ell, 0.5, o).has_value());
    // A ragged, concave real-world outline is not round: a cross.
    const Polygon cross = pixel_outline([](double x, double y) { return (std::abs(x - 25) < 3 && std::abs(y - 25) < 12) || (std::abs(y - 25) < 3 && std::abs(x - 25) < 12); });
    CHECK_FALSE(curved_outline(cross, 0.5, o).has_value());
    CHECK_THROWS_WITH(smooth_pixel_outline(circle, 0.0, 0.35), Catch::Contains("pixel size"));
}
