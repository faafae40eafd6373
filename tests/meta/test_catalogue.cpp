// The test catalogue itself: ctest registers each Catch2 test case by name
// (catch_discover_tests), and CMake reads a ';' in a name as a list
// separator, so such a test is registered under half its name, matches
// nothing when ctest runs it, and "passes" without running.
#include <catch2/catch.hpp>
#include <string>

TEST_CASE("Test names hold no semicolon (ctest would register and run a test under half its name, matching nothing)", "[meta]") {
    const auto& tests = Catch::getRegistryHub().getTestCaseRegistry().getAllTests();
    REQUIRE(tests.size() > 100);
    for (const Catch::TestCase& t : tests) {
        INFO(t.getTestCaseInfo().name);
        CHECK(t.getTestCaseInfo().name.find(';') == std::string::npos);
    }
}
