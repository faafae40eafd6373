#include <catch2/catch.hpp>
#include <algorithm>
#include <random>
#include <vector>

#include "segment/merge_queue.hpp"

using cityforge::merge_queue::MergeQueue;
using cityforge::merge_queue::QueueEntry;

namespace {
QueueEntry entry(double cost, uint32_t lower, uint32_t higher) {
    return QueueEntry::make(cost, uint64_t(lower) << 32 | higher, lower, higher);
}
// Pops everything; returns the ranks in pop order.
std::vector<cityforge::merge_queue::uint128> drain(MergeQueue& q) {
    std::vector<cityforge::merge_queue::uint128> out;
    while (!q.empty()) {
        out.push_back(q.top().rank());
        q.pop();
    }
    return out;
}
}  // namespace

TEST_CASE("merge queue: a pop that empties the queue, then pushes only to later buckets", "[segment][merge_queue]") {
    // Costs 0 and 1.9 spread over the buckets: (1.9 - 0) * (kBuckets / 1.9)
    // rounds below kBuckets, so 1.9 sits in the last regular bucket, not in
    // the overflow. Popping it takes the last queued entry with nothing to
    // refill from; a push dearer than 1.9 then lands in the overflow, a
    // later bucket, and must still be what top() and pop() see (b24c079:
    // the heap stayed empty and was read).
    const double hi = 1.9;
    REQUIRE((hi - 0.0) * (double(MergeQueue::kBuckets) / (hi - 0.0)) < double(MergeQueue::kBuckets));
    MergeQueue q({entry(hi, 3, 4), entry(0.0, 1, 2)});
    REQUIRE(q.size() == 2);
    CHECK(q.top().cost() == 0.0);
    q.pop();
    CHECK(q.top().cost() == hi);
    CHECK(q.top().a == 3);
    q.pop();
    CHECK(q.empty());
    q.push(entry(5.0, 7, 9));
    REQUIRE_FALSE(q.empty());
    CHECK(q.top().cost() == 5.0);
    CHECK(q.top().a == 7);
    CHECK(q.top().b == 9);
    q.push(entry(7.5, 2, 8));
    q.push(entry(6.0, 1, 5));
    CHECK(q.top().cost() == 5.0);
    q.pop();
    CHECK(q.top().cost() == 6.0);
    q.pop();
    CHECK(q.top().cost() == 7.5);
    q.pop();
    CHECK(q.empty());
    // Dry again, now with a push back below everything popped so far.
    q.push(entry(-1.0, 4, 6));
    REQUIRE(q.size() == 1);
    CHECK(q.top().cost() == -1.0);
    q.pop();
    CHECK(q.empty());
}

TEST_CASE("merge queue pops exactly in (cost, keys) order through overflows and dry spells", "[segment][merge_queue]") {
    std::mt19937_64 rng(12345);
    for (int round = 0; round < 12; ++round) {
        // A few distinct costs (many ties broken by the keys) or spread ones;
        // pops interleaved with pushes at, above and below the current top,
        // running the queue empty now and then.
        const bool ties = round % 2 == 0;
        std::uniform_real_distribution<double> spread_cost(-5.0, 50.0 + 1000.0 * round);
        auto cost = [&] { return ties ? double(rng() % 7) * 0.25 : spread_cost(rng); };
        std::vector<QueueEntry> initial;
        for (int i = 0; i < 200 + 50 * round; ++i) initial.push_back(entry(cost(), uint32_t(rng() % 1000), uint32_t(1000 + rng() % 1000)));
        std::vector<QueueEntry> reference = initial;  // the entries queued, as a plain list
        MergeQueue q(initial);
        std::size_t pops = 0;
        // The queue's top is the reference's lowest entry; both drop it.
        auto pop_lowest = [&] {
            const auto lowest = std::min_element(reference.begin(), reference.end(),
                                                 [](const QueueEntry& x, const QueueEntry& y) { return x.rank() < y.rank(); });
            REQUIRE(q.top().rank() == lowest->rank());
            reference.erase(lowest);
            q.pop();
            ++pops;
        };
        for (int step = 0; step < 2500; ++step) {
            const unsigned what = unsigned(rng() % 10);
            if (what < 5 && !q.empty()) {
                pop_lowest();
            } else if (what < 9) {
                // Mostly dearer than the top (the merge loop's pushes), sometimes
                // far above every queued cost (the overflow), sometimes below.
                double c = cost();
                if (what == 8) c = c * 100.0 + 1e4;
                if (what == 7 && !q.empty()) c = q.top().cost() - 1.0;
                const QueueEntry e = entry(c, uint32_t(rng() % 1000), uint32_t(1000 + rng() % 1000));
                q.push(e);
                reference.push_back(e);
            } else {
                while (!q.empty()) pop_lowest();  // run dry, then go on pushing
            }
            REQUIRE(q.size() == reference.size());
            REQUIRE(q.empty() == reference.empty());
        }
        std::sort(reference.begin(), reference.end(), [](const QueueEntry& x, const QueueEntry& y) { return x.rank() < y.rank(); });
        std::vector<cityforge::merge_queue::uint128> expected;
        for (const QueueEntry& e : reference) expected.push_back(e.rank());
        CHECK(drain(q) == expected);
        CHECK(pops > 1000);
    }
}

TEST_CASE("merge queue entries order by cost, then keys, with -0 as +0", "[segment][merge_queue]") {
    CHECK(entry(-2.5, 1, 2).rank() < entry(-1.0, 1, 2).rank());
    CHECK(entry(-1.0, 5, 6).rank() < entry(0.0, 1, 2).rank());
    CHECK(entry(0.0, 1, 2).rank() < entry(1e-300, 1, 2).rank());
    CHECK(entry(3.0, 1, 9).rank() < entry(3.0, 2, 3).rank());
    CHECK(entry(-0.0, 1, 2).rank() == entry(0.0, 1, 2).rank());
    for (double c : {-1e9, -3.25, -0.0, 0.0, 1e-12, 2.0, 7e200}) CHECK(entry(c, 1, 2).cost() == c);
}
