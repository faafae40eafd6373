#include <catch2/catch.hpp>
#include <atomic>
#include <string>
#include <tbb/global_control.h>

#include "core/error.hpp"
#include "core/parallel.hpp"

using namespace cityforge;

TEST_CASE("parallel_tasks_in_order runs every task and rethrows the first failure in task order, on 1 and 2 threads", "[core][parallel]") {
    for (const int threads : {1, 2}) {
        INFO(threads << " threads");
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        for (const std::size_t grain : {std::size_t(1), std::size_t(8)}) {
            std::atomic<int> ran{0};
            std::string message;
            try {
                parallel_tasks_in_order(100, grain, [&](std::size_t i) {
                    ++ran;
                    if (i == 70 || i == 30 || i == 99) throw Error("task " + std::to_string(i), "failed");
                });
            } catch (const Error& e) {
                message = e.what();
            }
            CHECK(ran == 100);
            CHECK(message == "task 30: failed");
        }
        std::atomic<int> ran{0};
        CHECK_NOTHROW(parallel_tasks_in_order(0, 1, [&](std::size_t) { ++ran; }));
        CHECK_NOTHROW(parallel_tasks_in_order(5, 0, [&](std::size_t) { ++ran; }));
        CHECK(ran == 5);
    }
}
