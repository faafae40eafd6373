#include <catch2/catch.hpp>
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "cloud/cloud_filters.hpp"
#include "core/large_buffer.hpp"
#include "core/memory.hpp"
#include "core/random.hpp"

using namespace cityforge;

namespace {
constexpr std::size_t kMiB = std::size_t(1) << 20;
// Restores the cache's limit and empties it on both ends of a test.
struct FreshCache {
    std::size_t limit = large_buffer_cache_limit();
    FreshCache() { release_large_buffer_cache(); }
    ~FreshCache() {
        release_large_buffer_cache();
        set_large_buffer_cache_limit(limit);
    }
};
}  // namespace

TEST_CASE("the large block cache hands a freed block out again, the smallest that fits, and empties itself before allocating", "[core][large_buffer]") {
    FreshCache fresh;
    set_large_buffer_cache_limit(std::size_t(1) << 30);
    const auto before = large_buffer_cache_stats();
    void* a = acquire_cached_block(10 * kMiB + 1);  // a 12 MiB block
    REQUIRE(reinterpret_cast<std::uintptr_t>(a) % kCachedBlockAlign == 0);
    std::memset(a, 0x5a, 10 * kMiB + 1);
    CHECK(large_buffer_cache_stats().allocated_bytes - before.allocated_bytes == 12 * kMiB);
    return_cached_block(a, 10 * kMiB + 1);
    CHECK(large_buffer_cache_stats().cached_bytes == 12 * kMiB);

    // The same block again, stale bytes and all: nothing allocated.
    void* b = acquire_cached_block(12 * kMiB);
    CHECK(b == a);
    CHECK(static_cast<unsigned char*>(b)[12345] == 0x5a);
    CHECK(large_buffer_cache_stats().allocated_bytes - before.allocated_bytes == 12 * kMiB);
    CHECK(large_buffer_cache_stats().cached_bytes == 0);
    return_cached_block(b, 12 * kMiB);

    // A smaller request gets the block whole; the next one a block of its own.
    void* c = acquire_cached_block(5 * kMiB);
    CHECK(c == a);
    void* d = acquire_cached_block(6 * kMiB);
    CHECK(d != a);
    return_cached_block(c, 5 * kMiB);  // back at its whole size
    return_cached_block(d, 6 * kMiB);
    CHECK(large_buffer_cache_stats().cached_blocks == 2);
    CHECK(large_buffer_cache_stats().cached_bytes == 18 * kMiB);
    void* e = acquire_cached_block(5 * kMiB);  // the smaller of the two
    CHECK(e == d);
    return_cached_block(e, 5 * kMiB);
    return_cached_block(e, 5 * kMiB);  // a second return of one block is ignored
    return_cached_block(reinterpret_cast<char*>(e) + 64, 5 * kMiB);  // so is a pointer never handed out
    CHECK(large_buffer_cache_stats().cached_blocks == 2);

    // A request no cached block holds: the cache is freed first, then a new block.
    const auto mid = large_buffer_cache_stats();
    void* f = acquire_cached_block(20 * kMiB);
    const auto after = large_buffer_cache_stats();
    CHECK(after.cached_bytes == 0);
    CHECK(after.freed_bytes - mid.freed_bytes == 18 * kMiB);
    CHECK(after.allocated_bytes - mid.allocated_bytes == 20 * kMiB);
    return_cached_block(f, 20 * kMiB);
    release_large_buffer_cache();
    CHECK(large_buffer_cache_stats().cached_bytes == 0);
    CHECK(large_buffer_cache_stats().cached_blocks == 0);

    // A cached block more than twice a request + 64 MiB is not handed out for
    // it (a small tile must not take a large tile's blocks): a block of its own.
    void* big = acquire_cached_block(200 * kMiB);  // never touched: no memory
    return_cached_block(big, 200 * kMiB);
    const auto cached_big = large_buffer_cache_stats();
    REQUIRE(cached_big.cached_bytes == 200 * kMiB);
    void* small = acquire_cached_block(60 * kMiB);
    CHECK(small != big);
    CHECK(large_buffer_cache_stats().reused_bytes == cached_big.reused_bytes);
    CHECK(large_buffer_cache_stats().allocated_bytes - cached_big.allocated_bytes == 60 * kMiB);
    return_cached_block(small, 60 * kMiB);
    // Within twice + 64 MiB it is.
    void* again = acquire_cached_block(60 * kMiB);
    CHECK(again == small);
    return_cached_block(again, 60 * kMiB);
    release_large_buffer_cache();
}

TEST_CASE("the large block cache keeps to its limit", "[core][large_buffer]") {
    FreshCache fresh;
    set_large_buffer_cache_limit(16 * kMiB);
    void* a = acquire_cached_block(8 * kMiB);
    void* b = acquire_cached_block(8 * kMiB);  // a block of its own: the cache is empty
    void* c = acquire_cached_block(8 * kMiB);
    return_cached_block(a, 8 * kMiB);
    return_cached_block(b, 8 * kMiB);
    CHECK(large_buffer_cache_stats().cached_bytes == 16 * kMiB);
    const auto full = large_buffer_cache_stats();
    return_cached_block(c, 8 * kMiB);  // over the limit: freed
    CHECK(large_buffer_cache_stats().cached_bytes == 16 * kMiB);
    CHECK(large_buffer_cache_stats().freed_bytes - full.freed_bytes == 8 * kMiB);
    set_large_buffer_cache_limit(8 * kMiB);  // a lower limit frees down to it
    CHECK(large_buffer_cache_stats().cached_bytes <= 8 * kMiB);
    set_large_buffer_cache_limit(0);  // caching off
    CHECK(large_buffer_cache_stats().cached_bytes == 0);
    void* d = acquire_cached_block(8 * kMiB);
    return_cached_block(d, 8 * kMiB);
    CHECK(large_buffer_cache_stats().cached_bytes == 0);
}

TEST_CASE("the large block cache never hands one block out twice, under tbb::parallel_for", "[core][large_buffer]") {
    FreshCache fresh;
    set_large_buffer_cache_limit(std::size_t(1) << 30);
    for (const int threads : {1, 2, 4}) {
        INFO(threads << " threads");
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        // Tasks take blocks of several sizes, hold them while they fill every
        // page with their own id, check the ids and give them back; the ranges
        // held at any one time must not overlap.
        constexpr std::size_t kTasks = 32;
        std::vector<std::pair<std::uintptr_t, std::uintptr_t>> held(kTasks);
        std::vector<int> ok(kTasks, 0);
        tbb::parallel_for(std::size_t(0), kTasks, [&](std::size_t t) {
            const std::size_t bytes = (4 + 2 * (t % 4)) * kMiB;
            bool good = true;
            for (int round = 0; round < 3; ++round) {
                auto* p = static_cast<uint64_t*>(acquire_cached_block(bytes));
                const std::size_t words = bytes / sizeof(uint64_t);
                for (std::size_t w = 0; w < words; w += 512) p[w] = t * 1000 + static_cast<std::size_t>(round);
                for (std::size_t w = 0; w < words; w += 512) good &= p[w] == t * 1000 + static_cast<std::size_t>(round);
                if (round == 2) held[t] = {reinterpret_cast<std::uintptr_t>(p), reinterpret_cast<std::uintptr_t>(p) + bytes};
                else return_cached_block(p, bytes);
            }
            ok[t] = good;
        });
        CHECK(std::count(ok.begin(), ok.end(), 1) == static_cast<long>(kTasks));
        std::vector<std::pair<std::uintptr_t, std::uintptr_t>> sorted = held;
        std::sort(sorted.begin(), sorted.end());
        for (std::size_t t = 1; t < kTasks; ++t) CHECK(sorted[t - 1].second <= sorted[t].first);
        for (std::size_t t = 0; t < kTasks; ++t) return_cached_block(reinterpret_cast<void*>(held[t].first), held[t].second - held[t].first);
        release_large_buffer_cache();
    }
}

TEST_CASE("cached_array holds small arrays on the heap and large ones in cached blocks", "[core][large_buffer]") {
    FreshCache fresh;
    set_large_buffer_cache_limit(std::size_t(1) << 30);
    {
        CachedArray<double> small = cached_array<double>(100);
        small[99] = 1.5;
        CHECK(small[99] == 1.5);
        CHECK(large_buffer_cache_stats().cached_bytes == 0);
    }
    CHECK(large_buffer_cache_stats().cached_bytes == 0);  // small arrays never enter the cache
    const double* first = nullptr;
    {
        CachedArray<double> big = cached_array<double>(kMiB);  // 8 MiB
        big[kMiB - 1] = 2.0;
        first = big.get();
    }
    CHECK(large_buffer_cache_stats().cached_bytes == 8 * kMiB);
    CachedArray<uint32_t> again = cached_array<uint32_t>(2 * kMiB);  // the same 8 MiB
    CHECK(static_cast<const void*>(again.get()) == static_cast<const void*>(first));
}

TEST_CASE("canonical_order and filter_outliers give the same flags from cached blocks full of stale bytes as from fresh memory, and empty the cache", "[core][large_buffer][cloud][filters]") {
    FreshCache fresh;
    // 4.5 M points: the permutation (18 and 36 MB), the filter's mean
    // distances and point order (36, 18 MB) and its grid's cells (~1.25 M:
    // their first positions, z ranges; 5 MB each) are all blocks of 4 MiB or more.
    PointCloud base;
    Rng rng(23);
    for (int i = 0; i < 4500000; ++i) {
        base.x.push_back(rng.uniform(0, 700)), base.y.push_back(rng.uniform(0, 700));
        base.z.push_back(10 + 0.05 * rng.normal() + (i % 997 == 0 ? rng.uniform(-30, 30) : 0.0));
        base.classification.push_back(1), base.intensity.push_back(static_cast<uint16_t>(i % 7)), base.return_number.push_back(1),
            base.number_of_returns.push_back(1);
    }
    const auto run = [&] {
        PointCloud c = base;
        canonical_order(c);
        OutlierFilterResult r = filter_outliers(c, OutlierFilterOptions{});
        CHECK(large_buffer_cache_stats().cached_bytes == 0);  // emptied at the filter's end
        return std::make_pair(std::move(c), std::move(r));
    };
    set_large_buffer_cache_limit(0);  // every block fresh (zeroed) memory
    const auto [fresh_cloud, fresh_result] = run();
    set_large_buffer_cache_limit(std::size_t(1) << 30);
    {  // the cache seeded with blocks of 0xff bytes, one for each array of canonical_order and the filter
        std::vector<std::pair<void*, std::size_t>> stale;
        for (const std::size_t mib : {8, 8, 8, 24, 40}) stale.emplace_back(acquire_cached_block(mib * kMiB), mib * kMiB);
        for (const auto& [p, bytes] : stale) std::memset(p, 0xff, bytes), return_cached_block(p, bytes);
    }
    const auto seeded = large_buffer_cache_stats();
    const auto [cloud, result] = run();
    // Every array of both steps from the stale blocks: the permutation's two,
    // then the filter's mean distances, point order, cell starts, z ranges.
    CHECK(large_buffer_cache_stats().allocated_bytes == seeded.allocated_bytes);
    CHECK(large_buffer_cache_stats().reused_bytes - seeded.reused_bytes == (24 + 40 + 40 + 24 + 8 + 8 + 8) * kMiB);
    CHECK(cloud.x == fresh_cloud.x);
    CHECK(cloud.z == fresh_cloud.z);
    CHECK(result.keep == fresh_result.keep);
    CHECK(result.limit == fresh_result.limit);
    CHECK(result.removed_statistical == fresh_result.removed_statistical);
    CHECK(result.removed_statistical > 1000);
}

TEST_CASE("the large block cache's default limit is a quarter of the memory this process may use", "[core][large_buffer]") {
    // Every test restores the limit it found (FreshCache), so the default
    // holds here whatever ran before in this process.
    const double usable = usable_memory_bytes();
    REQUIRE(usable > 0);
    CHECK(large_buffer_cache_limit() == static_cast<std::size_t>(usable / 4));
}
