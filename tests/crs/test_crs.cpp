#include <catch2/catch.hpp>

#include "core/error.hpp"
#include "crs/crs.hpp"

using namespace cityforge;

TEST_CASE("Compound CRS splits into horizontal and vertical EPSG codes", "[crs]") {
    const CrsInfo c = crs_from_user_input("EPSG:7415", "--cloud-crs");
    CHECK(c.epsg == 7415);
    CHECK(c.horizontal_epsg == 28992);
    CHECK(c.vertical_epsg == 5709);
    CHECK(c.ogc_urn() == "urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709");
    CHECK(c.label() == "EPSG:28992+5709");
    CHECK_FALSE(c.geographic);
}

TEST_CASE("Units: feet and degrees", "[crs]") {
    CHECK(crs_from_user_input("EPSG:2994", "x").linear_unit_m == Approx(0.3048));
    const CrsInfo wgs = crs_from_user_input("EPSG:4326", "x");
    CHECK(wgs.geographic);
    // 0.5 m is about 4.5e-6 degrees of latitude; the geodesic GSD must come back near 0.5 m.
    const GeoTransform t{116.0, 4.5e-6, 40.0, -4.5e-6};
    const GroundSampleDistance g = ground_sample_distance(wgs, t, 100, 100);
    CHECK(g.y_m == Approx(0.4997).margin(0.002));
    CHECK(g.x_m == Approx(0.3834).margin(0.002));  // shrinks with cos(latitude)
}

TEST_CASE("Bad CRS text is refused naming where it came from", "[crs][errors]") {
    CHECK_THROWS_WITH(crs_from_user_input("EPSG:999999", "--cloud-crs"), Catch::StartsWith("--cloud-crs: cannot understand CRS"));
    CHECK(same_crs(crs_from_user_input("EPSG:32650", "a"), crs_from_user_input("EPSG:32650", "b")));
    CHECK_FALSE(same_crs(crs_from_user_input("EPSG:32650", "a"), crs_from_user_input("EPSG:32651", "b")));
}
