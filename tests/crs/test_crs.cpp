#include <catch2/catch.hpp>

#include <vector>

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

TEST_CASE("Heights are never relabelled with another datum by a no-op transformation", "[crs][errors]") {
    // Seattle, UTM 10N. PROJ carries the EGM96 geoid grid (egm96_15.gtx, Debian's proj-data): EGM96 heights
    // to WGS 84 ellipsoidal heights subtract about 22.3 m there (h = H + N, N = -22.3 m).
    std::vector<double> x{550000.0}, y{5270000.0}, z{100.0};
    transform_points(crs_from_user_input("EPSG:32610+5773", "a"), crs_from_user_input("EPSG:4979", "b"), x, y, z, "points");
    CHECK(z[0] == Approx(77.7).margin(0.2));
    CHECK(x[0] == Approx(-122.335).margin(0.001));

    // EGM96 to NAVD88 needs NOAA's GEOID18 grid, which Debian does not ship: PROJ's only operation is a
    // "ballpark" one that leaves heights as they are. That must be refused, naming both vertical CRSs.
    x = {550000.0}, y = {5270000.0}, z = {100.0};
    CHECK_THROWS_WITH(
        transform_points(crs_from_user_input("EPSG:32610+5773", "a"), crs_from_user_input("EPSG:32610+5703", "b"), x, y, z, "cloud.las"),
        Catch::StartsWith("cloud.las: heights cannot be transformed from EPSG:5773 to EPSG:5703: PROJ has no grid"));
    // NAP to ellipsoidal heights without the Dutch geoid grid: refused too.
    x = {85000.0}, y = {446000.0}, z = {10.0};
    CHECK_THROWS_WITH(
        transform_points(crs_from_user_input("EPSG:7415", "a"), crs_from_user_input("EPSG:4979", "b"), x, y, z, "tiles"),
        Catch::Contains("from EPSG:5709 to ellipsoidal heights"));

    // Heights of no stated reference, or to a 2-D CRS: horizontal only, z as given.
    x = {550000.0}, y = {5270000.0}, z = {100.0};
    transform_points(crs_from_user_input("EPSG:32610", "a"), crs_from_user_input("EPSG:32610+5703", "b"), x, y, z, "points");
    CHECK(z[0] == 100.0);
    x = {85000.0}, y = {446000.0}, z = {10.0};
    transform_points(crs_from_user_input("EPSG:7415", "a"), crs_from_user_input("EPSG:4326", "b"), x, y, z, "points");
    CHECK(z[0] == 10.0);
    CHECK(y[0] == Approx(52.0).margin(0.05));
    // The same vertical CRS on both sides: unchanged heights, the horizontal part transformed.
    x = {1.0e6}, y = {1.0e6}, z = {10.0};
    transform_points(crs_from_user_input("EPSG:2994+5703", "a"), crs_from_user_input("EPSG:26910+5703", "b"), x, y, z, "points");
    CHECK(z[0] == Approx(10.0).margin(1e-6));
}

TEST_CASE("A custom projection without an EPSG code still takes the heights' vertical CRS", "[crs]") {
    // A user-defined Lambert conformal conic (no EPSG code matches it), as GeoTIFFs from other software carry.
    const CrsInfo custom = crs_from_user_input(
        "+proj=lcc +lat_1=43 +lat_2=45.5 +lat_0=41.75 +lon_0=-120.123 +x_0=400000 +y_0=0 +ellps=GRS80 +units=m +no_defs", "ortho.tif");
    REQUIRE_FALSE(custom.horizontal_epsg);
    REQUIRE(z_crs_label(custom) == "unknown (metre)");
    const CrsInfo navd88 = crs_from_user_input("EPSG:5703", "cloud");
    const CrsInfo both = combine_with_vertical(custom, navd88);
    CHECK(both.vertical_epsg == 5703);
    CHECK(z_crs_label(both) == "EPSG:5703");
    CHECK(same_horizontal_crs(both, custom));
    CHECK(both.linear_unit_m == 1.0);
    // Points in the compound go to lon/lat as in the custom CRS alone; NAVD88 heights stay NAVD88 heights.
    std::vector<double> x{400000.0}, y{100000.0}, z{50.0};
    transform_points(both, crs_from_user_input("EPSG:4269+5703", "b"), x, y, z, "points");
    CHECK(x[0] == Approx(-120.123).margin(1e-6));
    CHECK(z[0] == Approx(50.0).margin(1e-6));
    // Already compound, or nothing to add: unchanged.
    CHECK(combine_with_vertical(both, crs_from_user_input("EPSG:5773", "c")).vertical_epsg == 5703);
    CHECK(combine_with_vertical(custom, crs_from_user_input("EPSG:32610", "d")).wkt == custom.wkt);
}
