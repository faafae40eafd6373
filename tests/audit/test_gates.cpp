#include <catch2/catch.hpp>

#include "audit/gates.hpp"

using namespace cityforge;

TEST_CASE("Audit gates - parsing - unknown measures - minimum and maximum limits", "[audit][gates]") {
    const auto below = parse_gates("f1=0.8,iou=0.7", "--fail-below", true);
    REQUIRE(below.size() == 2);
    CHECK(below[0].measure == "f1");
    CHECK(below[0].limit == 0.8);
    CHECK(below[0].minimum);
    const auto above = parse_gates("mae=0.5", "--fail-above", false);
    REQUIRE(above.size() == 1);
    CHECK_FALSE(above[0].minimum);
    CHECK(parse_gates("", "--fail-below", true).empty());
    CHECK_THROWS_WITH(parse_gates("f1", "--fail-below", true), Catch::Contains("--fail-below") && Catch::Contains("NAME=VALUE"));
    CHECK_THROWS_WITH(parse_gates("f1=abc", "--fail-below", true), Catch::Contains("bad number"));
    CHECK_THROWS_WITH(parse_gates("f1=0.5x", "--fail-below", true), Catch::Contains("bad number"));
    CHECK_THROWS_WITH(check_gate_names(below, {"f1", "precision"}), Catch::Contains("unknown measure 'iou'") && Catch::Contains("f1, precision"));

    std::vector<AuditGate> gates = below;
    gates.push_back(above[0]);
    const GateOutcome ok = evaluate_gates(gates, {{"f1", 0.9}, {"iou", 0.7}, {"mae", 0.5}});
    CHECK(ok.passed);  // limits themselves pass
    const GateOutcome bad = evaluate_gates(gates, {{"f1", 0.79}, {"iou", 0.9}, {"mae", 0.51}});
    CHECK_FALSE(bad.passed);
    REQUIRE(bad.failed.size() == 2);
    CHECK(bad.failed[0] == "f1 0.79 < 0.8");
    CHECK(bad.failed[1] == "mae 0.51 > 0.5");
    const GateOutcome absent = evaluate_gates(below, {{"f1", 0.9}});
    CHECK_FALSE(absent.passed);
    CHECK(absent.failed[0] == "iou not measured");
}
