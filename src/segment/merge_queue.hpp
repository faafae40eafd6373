#pragma once
// The merge queue of region merging (segment/region_merging.cpp): candidate
// merges ordered by (cost, lower key, higher key), popped lowest first,
// exactly. In a header of its own so tests can drive it directly.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <new>
#include <vector>

#include "core/prefetch.hpp"

namespace cityforge {
namespace merge_queue {

/// Unsigned 128-bit integer (the queue's sort key).
__extension__ typedef unsigned __int128 uint128;

// A candidate merge: (cost, lower key, higher key) orders the queue, the
// nodes name the regions. The loop accepts a popped entry if both regions
// are alive, still have these keys, and the cost is still the pair's
// current cost: then it is the entry a fresh push would make, so stale
// entries need no version stamps.
struct QueueEntry {
    uint64_t order;  // the cost as an unsigned integer ordered as the cost (see make)
    uint64_t keys;   // lower key << 32 | higher key
    uint32_t a, b;   // nodes of the lower and the higher key when pushed
    // The entry of cost c. The cost's bits are mapped to an integer in the
    // order of the doubles (negative: all bits flipped; otherwise the sign
    // bit set), with -0 taken as +0 (equal costs compare equal as before),
    // so (cost, keys) compares as one 128-bit integer, without branches.
    static QueueEntry make(double c, uint64_t keys, uint32_t a, uint32_t b) {
        uint64_t u;
        c += 0.0;  // -0 -> +0
        std::memcpy(&u, &c, sizeof u);
        return {u >> 63 ? ~u : u | (uint64_t(1) << 63), keys, a, b};
    }
    // The cost the entry was made with (-0 comes back as +0).
    double cost() const {
        const uint64_t u = order >> 63 ? order & ~(uint64_t(1) << 63) : ~order;
        double c;
        std::memcpy(&c, &u, sizeof c);
        return c;
    }
    // (cost, keys) as one integer: entries pop in ascending rank.
    uint128 rank() const { return uint128(order) << 64 | keys; }
    bool operator>(const QueueEntry& o) const { return rank() > o.rank(); }
};

// Allocator of cache-line-aligned blocks (for the heap below).
template <typename T>
struct LineAllocator {
    using value_type = T;
    LineAllocator() noexcept = default;
    template <typename U>
    LineAllocator(const LineAllocator<U>&) noexcept {}
    T* allocate(std::size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), std::align_val_t(64))); }
    void deallocate(T* p, std::size_t) noexcept { ::operator delete(p, std::align_val_t(64)); }
    template <typename U>
    bool operator==(const LineAllocator<U>&) const noexcept { return true; }
    template <typename U>
    bool operator!=(const LineAllocator<U>&) const noexcept { return false; }
};

// Min-heap of candidate merges: a 4-ary heap (half the depth of a binary
// heap), lowest entry first. A pop prefetches the children of all four
// children while it compares them, so the walk down the heap does not wait
// for one memory read per level. Its first entries can be looked at, to
// prefetch what the next merges touch.
class Heap4 {
    static constexpr std::size_t kPad = 0;  // slots before the root

public:
    Heap4() = default;
    // Replaces the contents with `entries` (heapified in place).
    template <typename It>
    void assign(It first, It last) {
        h_.clear();
        h_.resize(kPad);
        h_.insert(h_.end(), first, last);
        for (std::size_t i = size() / 4 + 1; i-- > 0;)
            if (i < size()) sift_down(i);
    }
    bool empty() const { return h_.size() == kPad; }
    std::size_t size() const { return h_.size() - kPad; }
    const QueueEntry& top() const { return h_[kPad]; }
    const QueueEntry& entry(std::size_t i) const { return h_[kPad + i]; }
    void push(const QueueEntry& e) {
        std::size_t i = size();
        h_.push_back(e);
        QueueEntry* h = h_.data() + kPad;
        while (i > 0) {
            const std::size_t parent = (i - 1) / 4;
            if (!(h[parent] > e)) break;
            h[i] = h[parent];
            i = parent;
        }
        h[i] = e;
    }
    // Removes the top: the hole left at the root walks down to a leaf by
    // the lowest child (no comparison with the entry that fills it), then
    // the heap's last entry moves into the hole and up; it belongs near the
    // leaves, so this compares less than sifting it down from the root.
    void pop() {
        const QueueEntry last = h_.back();
        h_.pop_back();
        if (empty()) return;
        QueueEntry* h = h_.data() + kPad;
        const std::size_t n = size();
        std::size_t i = 0;
        for (;;) {
            const std::size_t first = 4 * i + 1;
            if (first >= n) break;
            for (std::size_t c = 4 * first + 1; c < 4 * first + 17 && c < n; c += 4)
                prefetch_line(h + c), prefetch_line(h + c + 3);
            const std::size_t best = lowest_child(h, first, n);
            h[i] = h[best];
            i = best;
        }
        const uint128 r = last.rank();
        while (i > 0) {
            const std::size_t parent = (i - 1) / 4;
            if (!(h[parent].rank() > r)) break;
            h[i] = h[parent];
            i = parent;
        }
        h[i] = last;
    }

private:
    // Index of the lowest of the children first .. first + 3 (those < n),
    // chosen by conditional moves rather than branches.
    static std::size_t lowest_child(const QueueEntry* h, std::size_t first, std::size_t n) {
        std::size_t best = first;
        uint128 r = h[first].rank();
        const std::size_t end = std::min(first + 4, n);
        for (std::size_t c = first + 1; c < end; ++c) {
            const uint128 rc = h[c].rank();
            const bool lower = rc < r;
            best = lower ? c : best;
            r = lower ? rc : r;
        }
        return best;
    }
    void sift_down(std::size_t i) {
        QueueEntry* h = h_.data() + kPad;
        const QueueEntry e = h[i];
        const std::size_t n = size();
        for (;;) {
            const std::size_t first = 4 * i + 1;
            if (first >= n) break;
            const std::size_t best = lowest_child(h, first, n);
            if (!(e > h[best])) break;
            h[i] = h[best];
            i = best;
        }
        h[i] = e;
    }
    std::vector<QueueEntry, LineAllocator<QueueEntry>> h_;
};


// Min-queue of candidate merges, exact: costs are bucketed by a monotone map
// (cost -> bucket index: floor((cost - lo) / width), clamped, the last
// bucket an overflow); only the entries of buckets up to the current one
// are in a 4-ary heap, the later buckets are plain arrays. Every entry in
// the heap costs less than every entry outside it, so the heap's top is the
// queue's lowest entry, and pops come in exactly the order of one heap of
// everything. The heap stays small (a bucket's worth), so popping walks a
// few cache-resident levels instead of a deep heap of every entry; a push
// above the current bucket is an append. When the overflow is reached, its
// entries are spread over a new set of buckets between their extremes.
class MergeQueue {
public:
    /// Regular buckets per spread (the overflow comes after them).
    static constexpr std::size_t kBuckets = 4096;
    // A queue holding `entries` (any order).
    explicit MergeQueue(const std::vector<QueueEntry>& entries) {
        count_ = entries.size();
        spread(entries.begin(), entries.end());
        refill();
    }
    // True when no entry is queued.
    bool empty() const { return count_ == 0; }
    // Entries queued (pushed and not yet popped).
    std::size_t size() const { return count_; }
    // The lowest entry; only when !empty().
    const QueueEntry& top() const { return near_.top(); }
    // Entries of the heap part (entry(0) is the top; 1..4 its children).
    std::size_t near_size() const { return near_.size(); }
    const QueueEntry& entry(std::size_t i) const { return near_.entry(i); }
    // Queues e (any cost, also below entries already popped).
    void push(const QueueEntry& e) {
        ++count_;
        const std::size_t b = bucket_of(e.cost());
        if (b <= current_) near_.push(e);
        else {
            buckets_[b].push_back(e);
            // The queue had run empty (the last pop found nothing to refill
            // from): the heap must hold the top again before it is read.
            if (near_.empty()) refill();
        }
    }
    // Removes the lowest entry; only when !empty().
    void pop() {
        near_.pop();
        --count_;
        if (near_.empty()) refill();
    }

private:
    std::size_t bucket_of(double c) const {
        if (!(c >= lo_)) return 0;  // below the range (and NaN): the first bucket
        const double x = (c - lo_) * inv_width_;
        return x >= double(kBuckets) ? kBuckets : static_cast<std::size_t>(x);
    }
    // New buckets over [min, max] of the given entries, which all cost more
    // than anything popped so far; current_ = 0.
    template <typename It>
    void spread(It first, It last) {
        double lo = INFINITY, hi = -INFINITY;
        for (It i = first; i != last; ++i) lo = std::min(lo, i->cost()), hi = std::max(hi, i->cost());
        lo_ = lo;
        inv_width_ = hi > lo && std::isfinite(hi - lo) ? double(kBuckets) / (hi - lo) : 0.0;
        std::vector<std::vector<QueueEntry>> fresh(kBuckets + 1);
        for (It i = first; i != last; ++i) fresh[bucket_of(i->cost())].push_back(*i);
        buckets_.swap(fresh);
        current_ = 0;
        near_.assign(buckets_[0].begin(), buckets_[0].end());
        std::vector<QueueEntry>().swap(buckets_[0]);
    }
    // The heap is empty: move on to the next bucket holding entries.
    void refill() {
        while (near_.empty() && count_ > 0) {
            if (current_ + 1 < kBuckets) {
                ++current_;
                std::vector<QueueEntry>& b = buckets_[current_];
                near_.assign(b.begin(), b.end());
                std::vector<QueueEntry>().swap(b);
            } else {  // the overflow: spread it over new buckets
                std::vector<QueueEntry> rest;
                rest.swap(buckets_[kBuckets]);
                spread(rest.begin(), rest.end());
            }
        }
    }
    Heap4 near_;
    std::vector<std::vector<QueueEntry>> buckets_;
    std::size_t current_ = 0, count_ = 0;
    double lo_ = 0.0, inv_width_ = 0.0;
};

}  // namespace merge_queue
}  // namespace cityforge
