#include <catch2/catch.hpp>

#include "cloud/cloud_reader.hpp"
#include "cloud/las.hpp"
#include "pipeline/cloud_windows.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;

namespace {
// `n` points on a square of `side` metres, plus one point at each far corner
// of a `spread` m box when `spread` > 0.
std::string write_cloud(const ScratchDir& dir, const std::string& name, int n, double side, double spread) {
    PointCloud c;
    auto add = [&](double x, double y) {
        c.x.push_back(500000.0 + x), c.y.push_back(4400000.0 + y), c.z.push_back(10.0);
        c.intensity.push_back(0), c.classification.push_back(1), c.return_number.push_back(1), c.number_of_returns.push_back(1);
    };
    const int row = static_cast<int>(std::ceil(std::sqrt(n)));
    for (int i = 0; i < n; ++i) add(side * (i % row) / row, side * (i / row) / row);
    if (spread > 0) add(spread, spread), add(-spread, -spread);
    const std::string path = dir / name;
    LasWriter w(path, {0.01, 0.01, 0.01}, {500000.0, 4400000.0, 0.0}, "");
    w.write(c);
    w.close();
    return path;
}
}  // namespace

TEST_CASE("read_cloud_by_windows: more points than the budget, or a header box large and sparse - never with a budget of 0", "[cloud][windows]") {
    ScratchDir dir("cloud_windows_rule");
    const std::string dense = write_cloud(dir, "dense.las", 1000, 40.0, 0.0);      // 1,681 cells of 1 m
    const std::string spread = write_cloud(dir, "spread.las", 1000, 40.0, 50.0);   // 10,201 cells for 1,002 points
    CHECK(read_cloud_by_windows(CloudReader(dense), 500, 1.0));       // the point count
    CHECK_FALSE(read_cloud_by_windows(CloudReader(dense), 1500, 1.0));  // 1,681 cells > 1,500 but not 4 per point
    CHECK(read_cloud_by_windows(CloudReader(spread), 1500, 1.0));      // large and sparse
    CHECK_FALSE(read_cloud_by_windows(CloudReader(spread), 1500, 0.0));  // count only
    CHECK_FALSE(read_cloud_by_windows(CloudReader(spread), 20000, 1.0)); // within the budget
    CHECK_FALSE(read_cloud_by_windows(CloudReader(spread), 0, 1.0));     // never
}
