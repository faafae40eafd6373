#pragma once
// Applying a detector with one and with two threads must give the same bytes:
// the one check every detection test makes, in one place.
#include <catch2/catch.hpp>
#include <tbb/global_control.h>

#include <string>

#include "pipeline/footprints_run.hpp"
#include "test_support.hpp"

namespace cityforge::test {

/// Runs `footprints` with `options` on one thread into `one_thread_path` and
/// on two into `two_threads_path`, checks that both files hold the same
/// bytes and returns the one-thread report.
inline FootprintsReport run_footprints_1_and_2_threads(const std::string& one_thread_path, const std::string& two_threads_path,
                                                      const FootprintsRunOptions& options) {
    FootprintsReport report;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        report = run_footprints(one_thread_path, options);
    }
    {
        tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
        run_footprints(two_threads_path, options);
    }
    CHECK(slurp(one_thread_path) == slurp(two_threads_path));
    return report;
}

}  // namespace cityforge::test
