#pragma once
// Element-wise parallel loop over [0, n) in chunks (TBB). The body must only
// write element i, so the result never depends on scheduling.
#include <cstddef>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace cityforge {

template <typename Body>
void parallel_for_each_index(std::size_t n, Body&& body) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 14), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) body(i);
    });
}

}  // namespace cityforge
