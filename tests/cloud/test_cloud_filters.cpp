#include <catch2/catch.hpp>

#include "cloud/cloud_filters.hpp"
#include "cloud/las.hpp"
#include "core/random.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;

TEST_CASE("Statistical outlier removal drops far points and keeps a clean surface", "[cloud][filters]") {
    PointCloud c;
    Rng rng(5);
    for (int i = 0; i < 4000; ++i) {
        c.x.push_back(rng.uniform(0, 20)), c.y.push_back(rng.uniform(0, 20)), c.z.push_back(10 + 0.02 * rng.normal());
        c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    }
    const double outliers[3][3] = {{5, 5, 40}, {12, 3, -20}, {18, 18, 25}};
    for (const auto& p : outliers) {
        c.x.push_back(p[0]), c.y.push_back(p[1]), c.z.push_back(p[2]);
        c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    }
    const OutlierFilterResult r = filter_outliers(c, OutlierFilterOptions{});
    for (std::size_t i = 4000; i < 4003; ++i) CHECK_FALSE(r.keep[i]);
    CHECK(r.removed_statistical + r.removed_isolated < 60);  // the surface itself survives (<1.5 %)
}

TEST_CASE("SMRF ground agrees with the synthetic scene's exact ground class", "[cloud][ground]") {
    ScratchDir dir("smrf");
    make_town(dir, 200, 4, 4);
    const PointCloud c = read_las(dir / "cloud.las");
    GroundFilterOptions go;
    go.trust_classification = false;
    const GroundResult g = classify_ground(c, {}, go);
    CHECK_FALSE(g.from_classification);
    std::size_t agree = 0, truth_ground = 0, found_ground = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
        const bool t = c.classification[i] == las_class::ground;
        truth_ground += t;
        found_ground += g.is_ground[i];
        agree += t == static_cast<bool>(g.is_ground[i]);
    }
    INFO("truth ground " << truth_ground << ", SMRF ground " << found_ground);
    CHECK(double(agree) / double(c.size()) > 0.95);
    GroundFilterOptions trust;
    CHECK(classify_ground(c, {}, trust).from_classification);
}
