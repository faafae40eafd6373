#include <catch2/catch.hpp>

#include <cmath>

#include <tbb/global_control.h>

#include "cloud/cloud_filters.hpp"
#include "cloud/surface_support.hpp"
#include "core/random.hpp"

using namespace cityforge;

namespace {
void add_point(PointCloud& c, double x, double y, double z, uint8_t cls) {
    c.x.push_back(x), c.y.push_back(y), c.z.push_back(z);
    c.classification.push_back(cls);
    c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
}

// Dense ground (16 pts/m2) over 40 x 40 m, a sparse tilted roof (0.8 pts/m2,
// 30 degrees, 6-12 m up: a dark roof returning a twentieth of the pulses)
// over 12 x 12 m, spikes 5-40 m above the ground and the roof, and one point
// classified noise lying on the ground.
struct Scene {
    PointCloud cloud;
    std::vector<std::size_t> roof, spikes;
    std::size_t noise = 0;
};
Scene make_scene() {
    Scene s;
    uint64_t h = 17;
    auto u = [&h] { return unit_from_hash(h = splitmix64(h)); };
    for (double y = 0; y < 40; y += 0.25)
        for (double x = 0; x < 40; x += 0.25) {
            const bool under_roof = x >= 14 && x < 26 && y >= 14 && y < 26;
            if (!under_roof) add_point(s.cloud, x + 0.2 * u(), y + 0.2 * u(), 0.02 * (u() - 0.5), las_class::ground);
        }
    for (int i = 0; i < 115; ++i) {
        const double x = 14 + 12 * u(), y = 14 + 12 * u();
        s.roof.push_back(s.cloud.size());
        add_point(s.cloud, x, y, 6.0 + std::tan(30.0 * M_PI / 180.0) * (x - 14) + 0.03 * (u() - 0.5), las_class::building);
    }
    for (int i = 0; i < 12; ++i) {
        const double x = 2 + 36 * u(), y = 2 + 36 * u();
        s.spikes.push_back(s.cloud.size());
        add_point(s.cloud, x, y, 5.0 + 35.0 * u() + (x >= 14 && x < 26 && y >= 14 && y < 26 ? 13.0 : 0.0), las_class::unclassified);
    }
    s.noise = s.cloud.size();
    add_point(s.cloud, 5.1, 5.1, 0.0, las_class::low_noise);
    return s;
}
}  // namespace

TEST_CASE("A sparse roof removed by the statistical outlier test is put back - spikes and noise stay removed, for any thread count",
          "[cloud][filters][surface]") {
    const Scene s = make_scene();
    OutlierFilterOptions oo;
    const OutlierFilterResult r = filter_outliers(s.cloud, oo);
    // The global limit is set by the dense ground: the sparse roof goes with the spikes.
    std::size_t roof_removed = 0;
    for (const std::size_t i : s.roof) roof_removed += !r.keep[i];
    REQUIRE(roof_removed > s.roof.size() / 3);
    for (const std::size_t i : s.spikes) REQUIRE(r.keep[i] == 0);

    std::vector<uint8_t> keep_1 = r.keep, keep_2 = r.keep;
    std::size_t restored_1 = 0, restored_2 = 0;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        restored_1 = restore_surface_points(s.cloud, keep_1, SurfaceSupportOptions{});
    }
    {
        tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
        restored_2 = restore_surface_points(s.cloud, keep_2, SurfaceSupportOptions{});
    }
    CHECK(keep_1 == keep_2);
    CHECK(restored_1 == restored_2);
    std::size_t roof_kept = 0;
    for (const std::size_t i : s.roof) roof_kept += keep_1[i];
    CHECK(roof_kept >= s.roof.size() * 9 / 10);  // all but roof corners with fewer than 3 neighbours within 2 m
    for (const std::size_t i : s.spikes) CHECK(keep_1[i] == 0);
    CHECK(keep_1[s.noise] == 0);
    // Nothing the filter kept is touched; every restored point was removed.
    for (std::size_t i = 0; i < keep_1.size(); ++i)
        if (r.keep[i]) REQUIRE(keep_1[i] == 1);

    std::vector<uint8_t> keep_off = r.keep;
    SurfaceSupportOptions bad;
    bad.radius = 0;
    CHECK_THROWS_WITH(restore_surface_points(s.cloud, keep_off, bad), Catch::Contains("radius"));
}
