#include <catch2/catch.hpp>
#include <cmath>

#include "audit/footprint_match.hpp"

using namespace cityforge;

namespace {
std::vector<Polygon> square(double x, double y, double s) { return {Polygon{{{x, y}, {x + s, y}, {x + s, y + s}, {x, y + s}}, {}}}; }
}  // namespace

TEST_CASE("Footprint matching - identical sets - a shifted square with its PoLiS - a missing building", "[audit]") {
    const std::vector<std::vector<Polygon>> ref{square(0, 0, 10), square(20, 0, 10), square(40, 0, 10), square(60, 0, 10)};
    const FootprintScores same = match_footprints(ref, ref);
    CHECK(same.f1 == 1.0);
    CHECK(same.mean_iou == Approx(1.0));
    CHECK(same.mean_abs_area_error_pct == Approx(0.0));
    CHECK(same.area_completeness == Approx(1.0));
    CHECK(same.area_quality == Approx(1.0));
    // Shift one square by 2 m: IoU 80/120, still matched at 0.5.
    auto shifted = ref;
    shifted[1] = square(22, 0, 10);
    const FootprintScores sh = match_footprints(shifted, ref);
    REQUIRE(sh.true_positives == 4);
    CHECK(sh.matches[1].iou == Approx(80.0 / 120.0));
    // PoLiS of a square shifted by d along x is d / 2: two vertices of each
    // outline lie on the other's boundary, two are d away.
    CHECK(sh.matches[1].polis == Approx(1.0));
    CHECK(sh.matches[0].polis == Approx(0.0).margin(1e-12));
    CHECK(sh.mean_polis == Approx(0.25));
    // Diagonal shift (0.5, 0.5): one corner 0.5·√2 away, three 0.5 away, both ways.
    CHECK(polis_distance(square(0, 0, 10), square(0.5, 0.5, 10)) == Approx((std::sqrt(0.5) + 1.5) / 4.0));
    // Missing building: recall 3/4, precision 1.
    const std::vector<std::vector<Polygon>> three(ref.begin(), ref.begin() + 3);
    const FootprintScores miss = match_footprints(three, ref);
    CHECK(miss.recall == Approx(0.75));
    CHECK(miss.precision == Approx(1.0));
    CHECK(miss.f1 == Approx(2 * 0.75 / 1.75));
    CHECK(miss.object_quality == Approx(0.75));  // 3 / (3 + 0 + 1)
    CHECK(miss.area_completeness == Approx(0.75));
    CHECK(miss.area_correctness == Approx(1.0));
    // A 2x-too-big prediction has IoU 0.5 exactly and area error +100 %.
    const std::vector<std::vector<Polygon>> twice{{Polygon{{{0, 0}, {20, 0}, {20, 10}, {0, 10}}, {}}}};
    const FootprintScores big = match_footprints(twice, {square(0, 0, 10)});
    REQUIRE(big.true_positives == 1);
    CHECK(big.matches[0].area_error_pct == Approx(100.0));
}
