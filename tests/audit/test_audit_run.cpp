#include <catch2/catch.hpp>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/audit_run.hpp"
#include "synth/synth.hpp"
#include "synth_fixture.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::make_town;
using cityforge::test::ScratchDir;

TEST_CASE("audit footprints - truth against itself - reprojected copy - report files", "[audit][cli]") {
    ScratchDir dir("audit_fp");
    const SynthResult s = make_town(dir, 150, 1, 0);
    const FootprintAuditReport same = audit_footprints(s.truth_path, s.truth_path, dir / "a", {});
    CHECK(same.scores.f1 == 1.0);
    CHECK(same.scores.mean_iou == Approx(1.0));
    CHECK_FALSE(same.reprojected);
    const std::string moved = dir / "truth_32651.geojson";
    REQUIRE(std::system(("ogr2ogr -q -t_srs EPSG:32651 " + moved + " " + s.truth_path).c_str()) == 0);
    const FootprintAuditReport rep = audit_footprints(moved, s.truth_path, dir / "b", {});
    CHECK(rep.reprojected);
    CHECK(rep.scores.f1 == 1.0);
    CHECK(rep.scores.mean_iou > 0.999);
    const auto j = nlohmann::json::parse(test::slurp(rep.output.json_path));
    CHECK(j["totals"]["f1"] == 1.0);
    CHECK(j["matches"].size() == static_cast<std::size_t>(s.buildings));
    CHECK(test::slurp(rep.output.markdown_path).find("| F1 | 1 |") != std::string::npos);
    CHECK(j["totals"]["mean_polis"].get<double>() < 0.01);
    const auto valid = test::validate_json(test::source_dir() + "/schemas/audit_report.schema.json", rep.output.json_path);
    CHECK(valid.exit_code == 0);
    INFO(valid.out + valid.err);
    // The HTML page is self-contained: inline SVG charts, no network reference.
    const std::string html = test::slurp(rep.output.html_path);
    CHECK(html.find("<svg") != std::string::npos);
    CHECK(html.find("src=\"http") == std::string::npos);
    CHECK(html.find("href=\"http") == std::string::npos);
    // With --ortho the map sits on an embedded PNG of the ortho.
    FootprintAuditOptions with_ortho;
    with_ortho.ortho_path = s.ortho_path;
    const FootprintAuditReport pic = audit_footprints(moved, s.truth_path, dir / "pic", with_ortho);
    CHECK(test::slurp(pic.output.html_path).find("href=\"data:image/png;base64,iVBORw0KGgo") != std::string::npos);
    const auto cli = test::run_cli("audit footprints --pred " + moved + " --ref " + s.truth_path + " --out " + (dir / "c"));
    CHECK(cli.exit_code == 0);
    CHECK(cli.out.find("F1 1.0000") != std::string::npos);
    // CI gates: passing and failing thresholds, and a malformed one.
    CHECK(test::run_cli("audit footprints --pred " + moved + " --ref " + s.truth_path + " --out " + (dir / "g1") + " --fail-below f1=0.99,iou=0.99").exit_code == 0);
    const auto gated = test::run_cli("audit footprints --pred " + s.truth_path + " --ref " + moved + " --out " + (dir / "g2") + " --iou 0.5 --fail-below iou=1.01");
    CHECK(gated.exit_code == 4);
    CHECK(gated.err.find("audit failed its gates: iou") != std::string::npos);
    CHECK(test::run_cli("audit footprints --pred " + moved + " --ref " + s.truth_path + " --out " + (dir / "g3") + " --fail-below f1").exit_code == 1);
    const auto bad = test::run_cli("audit footprints --pred " + (dir / "none.gpkg") + " --ref " + s.truth_path + " --out " + (dir / "d"));
    CHECK(bad.exit_code != 0);
    CHECK(bad.err.find("none.gpkg: file not found") != std::string::npos);
}

namespace {
// A square of side `side` metres at (x, y) with a raw_area_m2 attribute.
std::string square_feature(int id, double x, double y, double side, double raw_area) {
    std::ostringstream f;
    f.precision(12);
    f << R"({"type":"Feature","properties":{"id":)" << id << R"(,"raw_area_m2":)" << raw_area
      << R"(},"geometry":{"type":"Polygon","coordinates":[[[)" << x << "," << y << "],[" << x + side << "," << y << "],[" << x + side << ","
      << y + side << "],[" << x << "," << y + side << "],[" << x << "," << y << "]]]}}";
    return f.str();
}
void write_layer(const std::string& path, const std::vector<std::string>& features) {
    std::ofstream f(path);
    f << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32616"}},"features":[)";
    for (std::size_t i = 0; i < features.size(); ++i) f << (i ? "," : "") << features[i];
    f << "]}";
}
}  // namespace

TEST_CASE("audit rectangles - known area errors from the attribute and from original polygons", "[audit][rectangles]") {
    ScratchDir dir("audit_rect");
    // Fitted 10x10 squares (100 m2) whose originals were 99, 100 and 102 m2:
    // errors +1.0101 %, 0 %, -1.9608 %.
    write_layer(dir / "fitted.geojson", {square_feature(1, 700000, 3700000, 10, 99), square_feature(2, 700020, 3700000, 10, 100),
                                         square_feature(3, 700040, 3700000, 10, 102)});
    const RectangleAuditReport r = audit_rectangles(dir / "fitted.geojson", dir / "a", {});
    REQUIRE(r.rows.size() == 3);
    CHECK(r.rows[0].error_pct == Approx(100.0 / 99.0 * 100.0 - 100.0));
    CHECK(r.rows[1].error_pct == Approx(0.0).margin(1e-9));
    CHECK(r.rows[2].error_m2 == Approx(-2.0));
    CHECK(r.mean_abs_error_pct == Approx((1.0 / 99.0 * 100.0 + 2.0 / 102.0 * 100.0) / 3.0));
    CHECK(r.max_abs_error_pct == Approx(2.0 / 102.0 * 100.0));
    CHECK(test::validate_json(test::source_dir() + "/schemas/audit_report.schema.json", r.output.json_path).exit_code == 0);
    // Against original polygons: a 10 x 10.5 original for the first square.
    write_layer(dir / "orig.geojson", {square_feature(7, 700000, 3700000, 10.5, 0)});
    RectangleAuditOptions o;
    o.original_path = dir / "orig.geojson";
    const RectangleAuditReport m = audit_rectangles(dir / "fitted.geojson", dir / "b", o);
    REQUIRE(m.rows.size() == 1);
    CHECK(m.rows[0].original_m2 == Approx(110.25));
    CHECK(m.rows[0].iou == Approx(100.0 / 110.25));
    // CLI, with gates in both directions.
    const auto pass = test::run_cli("audit rectangles --in " + (dir / "fitted.geojson") + " --out " + (dir / "c") + " --fail-above max_abs_error_pct=2");
    CHECK(pass.exit_code == 0);
    CHECK(pass.out.find("over 3 of 3 footprints") != std::string::npos);
    const auto fail = test::run_cli("audit rectangles --in " + (dir / "fitted.geojson") + " --out " + (dir / "d") + " --fail-above mean_abs_error_pct=0.5");
    CHECK(fail.exit_code == 4);
    const auto unknown = test::run_cli("audit rectangles --in " + (dir / "fitted.geojson") + " --out " + (dir / "e") + " --fail-below f1=0.5");
    CHECK(unknown.exit_code == 1);
    CHECK(unknown.err.find("unknown measure 'f1'") != std::string::npos);
    const auto nofield = test::run_cli("audit rectangles --in " + (dir / "orig.geojson") + " --original-area-field area0 --out " + (dir / "f"));
    CHECK(nofield.exit_code == 1);
    CHECK(nofield.err.find("orig.geojson: has no field 'area0'") != std::string::npos);
}
