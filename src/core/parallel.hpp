#pragma once
// Element-wise parallel loop over [0, n) in chunks (TBB). The body must only
// write element i, so the result never depends on scheduling.
#include <cstddef>
#include <exception>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <vector>

namespace cityforge {

template <typename Body>
void parallel_for_each_index(std::size_t n, Body&& body) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 14), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) body(i);
    });
}

/// Runs task(i) for every i in [0, n) in parallel, at most `grain` indices
/// per TBB task. Every task runs even when another throws; then the
/// exception of the lowest failing index is rethrown, so which error is
/// reported (and which tasks' work was done) never depends on scheduling.
template <typename Task>
void parallel_tasks_in_order(std::size_t n, std::size_t grain, Task&& task) {
    std::vector<std::exception_ptr> failed(n);
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, n, grain == 0 ? 1 : grain),
        [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                try {
                    task(i);
                } catch (...) {
                    failed[i] = std::current_exception();
                }
            }
        },
        tbb::simple_partitioner());
    for (const std::exception_ptr& e : failed)
        if (e) std::rethrow_exception(e);
}

}  // namespace cityforge
