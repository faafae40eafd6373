#include <catch2/catch.hpp>
#include <algorithm>

#include "model/building_model.hpp"
#include "model/solid.hpp"

using namespace cityforge;

namespace {
Polygon rect(double x0, double y0, double x1, double y1) { return Polygon{{{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}}, {}}; }
bool has_error(const std::vector<std::string>& errors, const std::string& code) {
    return std::any_of(errors.begin(), errors.end(), [&](const std::string& e) { return e.rfind(code, 0) == 0; });
}
}  // namespace

TEST_CASE("LOD1 prism - volume is footprint area times height - valid closed outward shell", "[model]") {
    const Solid s = extrude_prism(rect(100, 200, 110, 220), 3.0, 8.0);
    CHECK(s.faces.size() == 6);
    CHECK(solid_volume(s) == Approx(10.0 * 20.0 * 5.0));
    CHECK(validate_solid(s).empty());
    CHECK(face_area(s.faces.front()) == Approx(200.0));
    CHECK(s.faces.front().type == SurfaceType::ground);
    CHECK(s.faces.back().type == SurfaceType::roof);
}

TEST_CASE("LOD1 prism over a courtyard footprint has an inner wall ring and the right volume", "[model]") {
    Polygon p = rect(0, 0, 30, 30);
    p.holes.push_back({{10, 10}, {10, 20}, {20, 20}, {20, 10}});  // clockwise hole
    const Solid s = extrude_prism(p, 0.0, 12.0);
    CHECK(s.faces.size() == 2 + 4 + 4);
    CHECK(s.faces.back().holes.size() == 1);   // roof with the courtyard opening
    CHECK(s.faces.front().holes.size() == 1);  // ground too
    // Four walls stand on the courtyard's edges and face into it (outward from the solid).
    int inner_walls = 0;
    for (const Face& f : s.faces) {
        if (f.type != SurfaceType::wall) continue;
        const bool on_hole = std::all_of(f.outer.begin(), f.outer.end(), [](const Point3& q) { return q.x >= 10 && q.x <= 20 && q.y >= 10 && q.y <= 20; });
        inner_walls += on_hole;
    }
    CHECK(inner_walls == 4);
    CHECK(solid_volume(s) == Approx((900.0 - 100.0) * 12.0));
    CHECK(validate_solid(s).empty());
}

TEST_CASE("Solid validation finds open shells - flipped faces - non-planar - repeated and crossing vertices", "[model]") {
    const Solid good = extrude_prism(rect(0, 0, 10, 10), 0.0, 5.0);
    Solid open = good;
    open.faces.pop_back();
    CHECK(has_error(validate_solid(open), "302"));
    Solid flipped = good;
    std::reverse(flipped.faces[2].outer.begin(), flipped.faces[2].outer.end());
    CHECK(has_error(validate_solid(flipped), "307"));
    Solid inward = good;
    for (Face& f : inward.faces) std::reverse(f.outer.begin(), f.outer.end());
    const auto inward_errors = validate_solid(inward);
    CHECK(has_error(inward_errors, "307"));
    CHECK_FALSE(has_error(inward_errors, "302"));
    Solid bent = good;
    bent.faces.back().outer.push_back(bent.faces.back().outer.back());  // a repeated vertex
    CHECK(has_error(validate_solid(bent), "102"));
    Solid warped = good;
    for (Face& f : warped.faces)
        for (Point3& q : f.outer)
            if (q.x == 10 && q.y == 10 && q.z == 5.0) q.z = 5.5;  // lift one roof corner: roof and two walls warp
    CHECK(has_error(validate_solid(warped), "203"));
    Solid crossing = good;
    std::swap(crossing.faces.back().outer[1], crossing.faces.back().outer[2]);  // bow-tie roof
    CHECK(has_error(validate_solid(crossing), "104"));
    CHECK(has_error(validate_solid(Solid{}), "301"));
}

TEST_CASE("complete_building - heights make a valid LOD1 - missing heights say why", "[model]") {
    ModelCrs crs;
    crs.horizontal_epsg = 28992, crs.vertical_epsg = 5709;
    Building b;
    b.id = "a";
    b.footprint = {rect(0, 0, 10, 10)};
    b.ground_z = 1.0, b.height_m = 6.0;
    complete_building(b, crs);
    CHECK(b.status == "ok");
    REQUIRE(b.lod1.size() == 1);
    CHECK(b.lod1_volume == Approx(600.0));
    CHECK(*b.roof_z == Approx(7.0));
    Building n;
    n.footprint = {rect(0, 0, 10, 10)};
    n.ground_z = 1.0;
    complete_building(n, crs);
    CHECK(n.status == "no_height");
    CHECK(n.reason == "height unknown");
    CHECK(n.lod1.empty());
    // Feet: a 20 ft z unit turns 6 m into 19.685 ft above ground.
    ModelCrs feet = crs;
    feet.z_unit_m = 0.3048;
    Building f = b;
    complete_building(f, feet);
    CHECK(*f.roof_z == Approx(1.0 + 6.0 / 0.3048));
    CHECK(crs.gml_srs_name() == "urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709");
    crs.compound_epsg = 7415;
    CHECK(crs.cityjson_reference_system() == "https://www.opengis.net/def/crs/EPSG/0/7415");
}

TEST_CASE("SolidsDistance and FaceHeight give the values of distance_to_solid and face_z_at, faster", "[model]") {
    // Two prisms (one with a courtyard) and points around, inside, above and far away.
    Polygon court = rect(20, 0, 40, 20);
    court.holes.push_back({{25, 5}, {25, 15}, {35, 15}, {35, 5}});
    const std::vector<Solid> solids{extrude_prism(rect(0, 0, 10, 10), 0.0, 5.0), extrude_prism(court, 1.0, 9.0)};
    const SolidsDistance distance(solids);
    int n = 0;
    for (double x = -7.3; x < 48; x += 1.7)
        for (double y = -6.1; y < 27; y += 2.3)
            for (double z = -3.9; z < 14; z += 2.9) {
                const Point3 p{x, y, z};
                double want = INFINITY;
                for (const Solid& s : solids) want = std::min(want, distance_to_solid(s, p));
                CHECK(distance(p) == want);  // the same arithmetic: equal, not approximately
                ++n;
            }
    CHECK(n > 1000);
    CHECK(SolidsDistance({})(Point3{0, 0, 0}) == INFINITY);
    // Heights: the courtyard prism's roof is at 9 m (its ground at 1 m) over its ring, nothing
    // over the courtyard; walls (vertical) have no height anywhere.
    int roofs = 0;
    for (const Face& f : solids[1].faces) {
        const FaceHeight height(f);
        if (f.type == SurfaceType::wall) {
            CHECK_FALSE(height(22.0, 2.0).has_value());
            continue;
        }
        if (f.type == SurfaceType::ground) {
            CHECK(height(22.0, 2.0).value_or(-1.0) == Approx(1.0));
            continue;
        }
        ++roofs;
        REQUIRE(height(22.0, 2.0).has_value());
        CHECK(*height(22.0, 2.0) == Approx(9.0));
        CHECK_FALSE(height(30.0, 10.0).has_value());  // the courtyard
        CHECK_FALSE(height(45.0, 10.0).has_value());  // beyond the ring
    }
    CHECK(roofs == 1);
}
