#include <catch2/catch.hpp>
#include <cmath>

#include "core/statistics.hpp"

using namespace cityforge;

TEST_CASE("The trimmed plane finds a tilted plane through 10 % gross outliers, refuses a line and too few points", "[core][plane]") {
    std::vector<std::array<double, 3>> p;
    for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 10; ++x) {
            const double z = 0.3 * x - 0.2 * y + 5.0 + (((x * 7 + y * 3) % 5) - 2) * 0.01;  // +-2 cm of noise
            p.push_back({double(x), double(y), (x + y) % 10 == 0 ? z + 4.0 : z});         // one point in ten 4 m off
        }
    const std::optional<TrimmedPlane> fit = fit_trimmed_plane(p);
    REQUIRE(fit);
    CHECK(fit->a == Approx(0.3).margin(0.01));
    CHECK(fit->b == Approx(-0.2).margin(0.01));
    CHECK(fit->c == Approx(5.0).margin(0.03));
    long outliers = 0;
    for (std::size_t i = 0; i < p.size(); ++i) outliers += !fit->inlier[i];
    CHECK(outliers == 10);
    // A line of points holds no plane; nor do five points.
    std::vector<std::array<double, 3>> line;
    for (int i = 0; i < 10; ++i) line.push_back({double(i), 2.0 * i, 1.0});
    CHECK_FALSE(fit_trimmed_plane(line));
    CHECK_FALSE(fit_trimmed_plane({p.begin(), p.begin() + 5}));
    // The spread limit: points 0.5 m across refuse a 1 m^2 spread.
    std::vector<std::array<double, 3>> strip;
    for (int i = 0; i < 20; ++i) strip.push_back({double(i), 0.5 * (i % 2), 0.0});
    TrimmedPlaneOptions o;
    o.min_spread_sq = 1.0;
    CHECK_FALSE(fit_trimmed_plane(strip, o));
    CHECK(fit_trimmed_plane(strip));
}
