#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

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
    const auto j = nlohmann::json::parse(test::slurp(rep.json_path));
    CHECK(j["totals"]["f1"] == 1.0);
    CHECK(j["matches"].size() == static_cast<std::size_t>(s.buildings));
    CHECK(test::slurp(rep.markdown_path).find("| F1 | 1 |") != std::string::npos);
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
