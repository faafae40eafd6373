#pragma once
// Tests' comparison of two point clouds, array by array (every attribute,
// exact values): one helper for the readers' tests.
#include <catch2/catch.hpp>

#include "cloud/point_cloud.hpp"

namespace cityforge::test {

/// Every array of `a` equals `b`'s (sizes first: REQUIRE; the arrays: CHECK).
inline void check_same_cloud(const PointCloud& a, const PointCloud& b) {
    REQUIRE(a.size() == b.size());
    CHECK(a.x == b.x);
    CHECK(a.y == b.y);
    CHECK(a.z == b.z);
    CHECK(a.intensity == b.intensity);
    CHECK(a.classification == b.classification);
    CHECK(a.return_number == b.return_number);
    CHECK(a.number_of_returns == b.number_of_returns);
    CHECK(a.gps_time == b.gps_time);
    CHECK(a.red == b.red);
    CHECK(a.green == b.green);
    CHECK(a.blue == b.blue);
}

}  // namespace cityforge::test
