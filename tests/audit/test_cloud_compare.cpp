#include <catch2/catch.hpp>
#include <fstream>

#include "audit/cloud_compare.hpp"
#include "core/error.hpp"
#include "pipeline/audit_run.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;

namespace {
PointCloud grid(double dx, double dy, double dz) {
    PointCloud c;
    for (int i = 0; i < 40; ++i)
        for (int j = 0; j < 40; ++j) {
            c.x.push_back(1000.0 + i + dx), c.y.push_back(2000.0 + j + dy), c.z.push_back(5.0 + dz);
            c.classification.push_back(1), c.intensity.push_back(0), c.return_number.push_back(1), c.number_of_returns.push_back(1);
        }
    return c;
}
}  // namespace

TEST_CASE("Clouds offset by a known vector give the known chamfer distance and F-scores", "[audit][clouds]") {
    const PointCloud a = grid(0, 0, 0), b = grid(0.3, 0.4, 0.0);  // every nearest neighbour at 0.5 m
    const CloudComparison c = compare_clouds(b, a, {0.4, 0.6});
    CHECK(c.mean_pred_to_ref == Approx(0.5));
    CHECK(c.mean_ref_to_pred == Approx(0.5));
    CHECK(c.chamfer == Approx(1.0));
    CHECK(c.chamfer_squared == Approx(0.5));
    CHECK(c.scores[0].f_score == 0.0);
    CHECK(c.scores[1].f_score == Approx(1.0));
    const CloudComparison same = compare_clouds(a, a, {0.01});
    CHECK(same.chamfer == 0.0);
    CHECK(same.scores[0].f_score == 1.0);
    CHECK_THROWS_WITH(compare_clouds(PointCloud{}, a, {1.0}), Catch::Contains("empty"));
}

TEST_CASE("audit clouds writes its reports and refuses a cloud without CRS against one with", "[audit][clouds]") {
    ScratchDir dir("audit_clouds");
    {
        std::ofstream f(dir / "a.xyz");
        for (int i = 0; i < 30; ++i)
            for (int j = 0; j < 30; ++j) f << 1000 + i << " " << 2000 + j << " 5\n";
    }
    {
        std::ofstream f(dir / "b.xyz");
        for (int i = 0; i < 30; ++i)
            for (int j = 0; j < 30; ++j) f << 1000.3 + i << " " << 2000.4 + j << " 5\n";
    }
    CloudAuditOptions o;
    o.taus_m = {0.6};
    const CloudAuditReport r = audit_clouds(dir / "b.xyz", dir / "a.xyz", dir / "out", o);
    CHECK(r.comparison.chamfer == Approx(1.0));
    CHECK(test::slurp(r.output.markdown_path).find("chamfer") != std::string::npos);
    CHECK(test::slurp(r.output.json_path).find("\"f_score\": 1.0") != std::string::npos);
    CHECK_THROWS_WITH(audit_clouds(dir / "b.xyz", test::shared_data("autzen_oregon/autzen_trim.las"), dir / "x", o),
                      Catch::Contains("b.xyz") && Catch::Contains("no CRS"));
    const auto cli = test::run_cli("audit clouds --pred " + (dir / "b.xyz") + " --ref " + (dir / "a.xyz") + " --tau 0.4,0.6 --out " + (dir / "cli"));
    CHECK(cli.exit_code == 0);
    CHECK(cli.out.find("chamfer 1.0000 m") != std::string::npos);
    CHECK(test::validate_json(test::source_dir() + "/schemas/audit_report.schema.json", dir / "cli/report.json").exit_code == 0);
    CHECK(test::slurp(dir / "cli/report.html").find("<svg") != std::string::npos);
    // Gates per tau: every point is 0.5 m from the other cloud.
    CHECK(test::run_cli("audit clouds --pred " + (dir / "b.xyz") + " --ref " + (dir / "a.xyz") + " --tau 0.4,0.6 --out " + (dir / "g1") +
                        " --fail-below f@0.6=0.99 --fail-above chamfer=1.01").exit_code == 0);
    const auto gated = test::run_cli("audit clouds --pred " + (dir / "b.xyz") + " --ref " + (dir / "a.xyz") + " --tau 0.4,0.6 --out " + (dir / "g2") +
                                     " --fail-below f@0.4=0.5");
    CHECK(gated.exit_code == 4);
    CHECK(gated.err.find("f@0.4 0 < 0.5") != std::string::npos);
}
