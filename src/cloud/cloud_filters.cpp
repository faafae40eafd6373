#include "cloud/cloud_filters.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <functional>
#include <iterator>
#include <limits>
#include <memory>
#include <numeric>
#include <tuple>
#include <utility>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "core/prefetch.hpp"
#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "core/grid_size.hpp"
#include "core/large_buffer.hpp"
#include "core/memory.hpp"
#include "core/morphology.hpp"

namespace cityforge {

void OutlierFilterOptions::validate() const {
    if (k_neighbours < 1 || k_neighbours > 100) throw Error("--sor-k", "must be between 1 and 100");
    if (!(std_multiplier > 0.0)) throw Error("--sor-std", "must be > 0");
    if (!(max_mean_distance >= 0.0)) throw Error("outlier_limit_m", "must be >= 0");
    if (!(isolated_radius >= 0.0)) throw Error("--isolated-radius", "must be >= 0");
    if (isolated_min_neighbours < 0) throw Error("--isolated-min", "must be >= 0");
}

void GroundFilterOptions::validate() const {
    if (!(cell > 0.0)) throw Error("--smrf-cell", "must be > 0");
    if (!(slope >= 0.0)) throw Error("--smrf-slope", "must be >= 0");
    if (!(window >= cell)) throw Error("--smrf-window", "must be at least one cell");
    if (!(elevation_threshold > 0.0)) throw Error("--smrf-threshold", "must be > 0");
}


namespace {

__extension__ typedef unsigned __int128 SortKey;

// The bits of a double as an unsigned integer in the order of the values (not
// NaN): a < b exactly when ordered_bits(a) < ordered_bits(b); -0 and +0 alike.
inline uint64_t ordered_bits(double v) {
    const auto b = std::bit_cast<uint64_t>(v + 0.0);  // -0 + 0 = +0
    return b >> 63 ? ~b : b | (uint64_t(1) << 63);
}

// Sorts a[0 .. m) (distinct keys) ascending: quicksort whose partition has no
// branch on the comparisons (those of random keys are unpredictable; an
// element is swapped whatever the outcome and the boundary moves by it),
// insertion sort below 16 elements, std::sort past `depth` levels.
void sort_keys(SortKey* a, std::size_t m, int depth) {
    while (m > 16) {
        if (depth-- == 0) {
            std::sort(a, a + m);
            return;
        }
        SortKey& mid = a[m / 2];
        if (mid < a[0]) std::swap(mid, a[0]);
        if (a[m - 1] < mid) std::swap(a[m - 1], mid);
        if (mid < a[0]) std::swap(mid, a[0]);
        std::swap(a[0], mid);  // the median of three as the pivot
        const SortKey p = a[0];
        std::size_t lt = 1;  // a[1 .. lt) < p <= a[lt .. j)
        for (std::size_t j = 1; j < m; ++j) {
            const SortKey e = a[j];
            const bool smaller = e < p;
            a[j] = a[lt], a[lt] = e;
            lt += smaller;
        }
        std::swap(a[0], a[lt - 1]);
        const std::size_t left = lt - 1, right = m - lt;
        if (left < right) sort_keys(a, left, depth), a += lt, m = right;
        else sort_keys(a + lt, right, depth), m = left;
    }
    for (std::size_t i = 1; i < m; ++i) {
        const SortKey v = a[i];
        std::size_t j = i;
        for (; j > 0 && v < a[j - 1]; --j) a[j] = a[j - 1];
        a[j] = v;
    }
}

// Sorts a[0 .. m) (distinct keys below 2^width) into out[0 .. m): counted
// into 256 parts by their top 8 of those bits, each part then by sort_keys
// (parts of a few keys: the mispredicted comparisons of a quicksort's first
// levels replaced by one counting pass).
void radix_sort_keys(const SortKey* a, SortKey* out, std::size_t m, int width) {
    const int shift = std::max(width - 8, 0);
    std::array<uint32_t, 257> start{};
    for (std::size_t k = 0; k < m; ++k) ++start[static_cast<std::size_t>(a[k] >> shift) + 1];
    for (std::size_t d = 0; d < 256; ++d) start[d + 1] += start[d];
    std::array<uint32_t, 256> fill;
    std::copy(start.begin(), start.end() - 1, fill.begin());
    for (std::size_t k = 0; k < m; ++k) out[fill[static_cast<std::size_t>(a[k] >> shift)]++] = a[k];
    for (std::size_t d = 0; d < 256; ++d) {
        const std::size_t size = start[d + 1] - start[d];
        if (size > 1) sort_keys(out + start[d], size, 2 * static_cast<int>(std::bit_width(size)) + 8);
    }
}

// Uninitialised arrays from LargeBufferAllocator: large ones on transparent
// huge pages (fresh 4 kB pages cost 1.8-2.0 system s more at 60 M points).
// The temporary arrays of canonical_order and filter_outliers come from the
// block cache instead (cached_array, same pages): see filter_outliers.
template <class T>
struct LargeDelete {
    std::size_t n;
    void operator()(T* p) const noexcept { LargeBufferAllocator<T>().deallocate(p, n); }
};
template <class T>
using LargeArray = std::unique_ptr<T[], LargeDelete<T>>;
template <class T>
LargeArray<T> large_array(std::size_t n) {
    return LargeArray<T>(LargeBufferAllocator<T>().allocate(n), LargeDelete<T>{n});
}

template <class Index>
struct Permutation {
    CachedArray<Index> order;      ///< order[rank] = index of the point of that rank
    CachedArray<uint64_t> scratch;  ///< at least n entries, free for the caller
};

// The permutation that sorts the points by canonical_order's key: order[r] is
// the index of the point of rank r. Index: uint32_t while n fits, else size_t.
// The point indices are first spread into buckets of ~1024 points by x (a
// non-decreasing function of x, so every bucket holds a range of the final
// order), then each bucket is sorted in parallel in cache: x and y as one
// 128-bit integer above the index (x and y relative to the bucket's smallest,
// in order-preserving bits; counted by its top 8 bits, then quicksorted
// without branches), the whole key (through the index) only for ties of x
// and y. (An indirect sort on the full key missed the cache on every
// comparison: 28 % of a `heights` run.) Fresh memory: the permutation and the
// scratch buffer, 12 bytes a point when n < 2^32 (fresh pages are dear on a
// VM: the former 24-byte copy of every point and a buffer of 8 took most of
// this step's time at 60 M points); both go back to the block cache at the
// end, where filter_outliers takes them again. Points equal in every attribute are
// interchangeable, so the result does not depend on the thread count.
template <class Index, class Less>
Permutation<Index> canonical_permutation(const PointCloud& c, Less&& key_less) {
    const std::size_t n = c.size();
    constexpr std::size_t kGrain = 1u << 16;
    using Range = std::pair<double, double>;
    const auto [minx, maxx] = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, kGrain), Range{INFINITY, -INFINITY},
        [&](const tbb::blocked_range<std::size_t>& r, Range v) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) v.first = std::min(v.first, c.x[i]), v.second = std::max(v.second, c.x[i]);
            return v;
        },
        [](Range a, Range b) { return Range{std::min(a.first, b.first), std::max(a.second, b.second)}; });
    std::size_t buckets = std::clamp<std::size_t>(n / 1024, 1, std::size_t(1) << 22);
    const double scale = double(buckets) / (maxx - minx);
    if (!std::isfinite(scale) || !(scale > 0)) buckets = 1;
    auto bucket_of = [&](double x) -> std::size_t {
        const double v = (x - minx) * scale;  // non-decreasing in x
        return buckets == 1 || !(v >= 0) ? 0 : v >= double(buckets - 1) ? buckets - 1 : static_cast<std::size_t>(v);
    };
    // Counting sort into the buckets by fixed chunks of points, in parallel:
    // chunk j's points of bucket b follow those of chunks 0 .. j - 1, so every
    // bucket lists its points by index, as one pass would.
    const std::size_t chunks = std::min<std::size_t>(16, (n + kGrain - 1) / kGrain), chunk = (n + chunks - 1) / chunks;
    std::vector<Index> at(chunks * buckets, 0);  // at[j * buckets + b]
    std::vector<std::size_t> first(buckets + 1, 0);
    tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t j) {
        Index* count = at.data() + j * buckets;
        for (std::size_t i = j * chunk; i < std::min(n, (j + 1) * chunk); ++i) ++count[bucket_of(c.x[i])];
    });
    for (std::size_t b = 0, sum = 0; b < buckets; ++b) {
        first[b] = sum;
        for (std::size_t j = 0; j < chunks; ++j) sum += std::exchange(at[j * buckets + b], static_cast<Index>(sum));
        first[b + 1] = sum;
    }
    // Not zero-filled: every entry is written below.
    auto order = cached_array<Index>(n);
    struct XY {
        double x, y;
    };
    // The buckets in two groups, split at the bucket holding rank n / 2: each
    // group's coordinates are copied in bucket order into the scratch buffer
    // (16 bytes a point) by one pass over the points, then its buckets sorted
    // from there. (Gathering them from the cloud bucket by bucket missed the
    // cache on every point.) The scratch holds 8 bytes a point (later used to
    // permute the attributes), a bucket more when the split is uneven.
    const std::size_t split = static_cast<std::size_t>(std::upper_bound(first.begin(), first.end(), n / 2) - first.begin()) - 1;
    auto scratch = cached_array<uint64_t>(std::max(n, 2 * (n - first[split])));
    XY* copy = reinterpret_cast<XY*>(scratch.get());
    auto less = [&](const std::pair<XY, Index>& a, const std::pair<XY, Index>& b) {
        if (a.first.x < b.first.x) return true;
        if (b.first.x < a.first.x) return false;
        if (a.first.y < b.first.y) return true;
        if (b.first.y < a.first.y) return false;
        return key_less(a.second, b.second);
    };
    for (const auto& [b0, b1] : {std::pair{std::size_t(0), split}, std::pair{split, buckets}}) {
        tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t j) {
            Index* fill = at.data() + j * buckets;
            for (std::size_t i = j * chunk; i < std::min(n, (j + 1) * chunk); ++i) {
                const std::size_t b = bucket_of(c.x[i]);
                if (b < b0 || b >= b1) continue;
                const Index at_rank = fill[b]++;
                order[at_rank] = static_cast<Index>(i);
                copy[at_rank - first[b0]] = {c.x[i], c.y[i]};
            }
        });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(b0, b1, 16), [&](const tbb::blocked_range<std::size_t>& r) {
            std::vector<std::pair<XY, Index>> xy;  // one bucket at a time
            std::vector<SortKey> keys, sorted_keys;
            for (std::size_t b = r.begin(); b != r.end(); ++b) {
                const std::size_t from = first[b], m = first[b + 1] - from;
                if (m < 2) continue;
                Index* ids = order.get() + from;
                auto point = [&](std::size_t k) { return copy[from - first[b0] + k]; };
                if constexpr (sizeof(Index) == 4) {
                    keys.resize(m);
                    uint64_t lox = UINT64_MAX, hix = 0, loy = UINT64_MAX, hiy = 0;
                    bool nan = false;
                    for (std::size_t k = 0; k < m; ++k) {
                        const XY p = point(k);
                        nan |= std::isnan(p.x) | std::isnan(p.y);
                        const uint64_t ux = ordered_bits(p.x), uy = ordered_bits(p.y);
                        lox = std::min(lox, ux), hix = std::max(hix, ux), loy = std::min(loy, uy), hiy = std::max(hiy, uy);
                        keys[k] = SortKey(ux) << 64 | uy;
                    }
                    const int wy = static_cast<int>(std::bit_width(hiy - loy));
                    if (!nan && static_cast<int>(std::bit_width(hix - lox)) + wy <= 96) {
                        // (x, y, index) in one integer: dx above dy above the index.
                        for (std::size_t k = 0; k < m; ++k)
                            keys[k] = SortKey(uint64_t(keys[k] >> 64) - lox) << (wy + 32) | SortKey(uint64_t(keys[k]) - loy) << 32 | ids[k];
                        sorted_keys.resize(m);
                        radix_sort_keys(keys.data(), sorted_keys.data(), m, static_cast<int>(std::bit_width(hix - lox)) + wy + 32);
                        for (std::size_t k = 0; k < m; ++k) ids[k] = static_cast<Index>(sorted_keys[k]);
                        for (std::size_t k = 0, e; k < m; k = e) {  // points of equal x and y by their whole key
                            for (e = k + 1; e < m && sorted_keys[e] >> 32 == sorted_keys[k] >> 32;) ++e;
                            if (e - k > 1) std::sort(ids + k, ids + e, key_less);
                        }
                        continue;
                    }
                }
                xy.resize(m);
                for (std::size_t k = 0; k < m; ++k) xy[k] = {point(k), ids[k]};
                std::sort(xy.begin(), xy.end(), less);
                for (std::size_t k = 0; k < m; ++k) ids[k] = xy[k].second;
            }
        });
    }
    return {std::move(order), std::move(scratch)};
}

}  // namespace

void canonical_order(PointCloud& c) {
    const std::size_t n = c.size();
    const bool gps = c.has_gps_time(), rgb = c.has_color();
    auto key = [&](std::size_t i) {
        return std::make_tuple(c.x[i], c.y[i], c.z[i], gps ? c.gps_time[i] : 0.0, c.intensity[i], c.classification[i], c.return_number[i],
                               c.number_of_returns[i], rgb ? c.red[i] : 0, rgb ? c.green[i] : 0, rgb ? c.blue[i] : 0);
    };
    constexpr std::size_t kGrain = 1u << 16;
    if (n < 2) return;
    const bool sorted = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(1, n, kGrain), true,
        [&](const tbb::blocked_range<std::size_t>& r, bool ok) {
            for (std::size_t i = r.begin(); ok && i != r.end(); ++i) ok = !(key(i) < key(i - 1));
            return ok;
        },
        [](bool a, bool b) { return a && b; });
    if (sorted) return;
    auto key_less = [&](std::size_t a, std::size_t b) { return key(a) < key(b); };
    // The attributes are gathered in rank order through the scratch buffer of
    // 8 bytes a point; the small ones packed into 8 bytes a point first, so a
    // point is fetched from its random place once for (nearly) all of them,
    // not once per attribute (7 gathers -> 2 with colour, 4 -> 1 without).
    // Each gather prefetches the source 64 ranks ahead (the loads miss the
    // cache; a loop of a few more instructions kept too few of them in
    // flight: the small attributes' gather took 2.5 times a double's). Raw
    // pointers are held in locals: a store through uint8_t * may alias
    // anything, and pointers read from memory would be reloaded every time.
    auto apply = [&](const auto& perm) {
        const auto* const order = perm.order.get();
        uint64_t* const scratch = perm.scratch.get();
        auto ranges = [&](auto&& f) {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kGrain), [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
        };
        double* const out = reinterpret_cast<double*>(scratch);
        for (std::vector<double>* v : {&c.x, &c.y, &c.z, &c.gps_time}) {
            if (v->empty()) continue;
            double* const values = v->data();
            ranges([=](std::size_t from, std::size_t to) {
                for (std::size_t i = from; i < to; ++i) {
                    if (i + 64 < to) prefetch_line(values + order[i + 64]);
                    out[i] = values[order[i]];
                }
            });
            ranges([=](std::size_t from, std::size_t to) { std::copy(out + from, out + to, values + from); });
        }
        uint64_t* const packed = scratch;
        uint16_t* const intensity = c.intensity.data();
        uint8_t *const cls = c.classification.data(), *const ret = c.return_number.data(), *const nret = c.number_of_returns.data();
        uint16_t *const red = c.red.data(), *const green = c.green.data(), *const blue = c.blue.data();
        ranges([=](std::size_t from, std::size_t to) {
            if (rgb)
                for (std::size_t i = from; i < to; ++i)
                    packed[i] = uint64_t(intensity[i]) | uint64_t(cls[i]) << 16 | uint64_t(ret[i]) << 24 | uint64_t(nret[i]) << 32 | uint64_t(red[i]) << 40;
            else
                for (std::size_t i = from; i < to; ++i)
                    packed[i] = uint64_t(intensity[i]) | uint64_t(cls[i]) << 16 | uint64_t(ret[i]) << 24 | uint64_t(nret[i]) << 32;
        });
        ranges([=](std::size_t from, std::size_t to) {
            const uint64_t* const pk = packed;
            const auto* const o = order;
            uint16_t *const it = intensity, *const rd = red;
            uint8_t *const cl = cls, *const rn = ret, *const nr = nret;
            for (std::size_t i = from; i < to; ++i) {
                if (i + 64 < to) prefetch_line(pk + o[i + 64]);
                const uint64_t w = pk[o[i]];
                it[i] = static_cast<uint16_t>(w), cl[i] = static_cast<uint8_t>(w >> 16);
                rn[i] = static_cast<uint8_t>(w >> 24), nr[i] = static_cast<uint8_t>(w >> 32);
                if (rgb) rd[i] = static_cast<uint16_t>(w >> 40);
            }
        });
        if (!rgb) return;
        ranges([=](std::size_t from, std::size_t to) {
            for (std::size_t i = from; i < to; ++i) packed[i] = uint64_t(green[i]) | uint64_t(blue[i]) << 16;
        });
        ranges([=](std::size_t from, std::size_t to) {
            const uint64_t* const pk = packed;
            const auto* const o = order;
            uint16_t *const gr = green, *const bl = blue;
            for (std::size_t i = from; i < to; ++i) {
                if (i + 64 < to) prefetch_line(pk + o[i + 64]);
                const uint64_t w = pk[o[i]];
                gr[i] = static_cast<uint16_t>(w), bl[i] = static_cast<uint16_t>(w >> 16);
            }
        });
    };
    if (n <= std::numeric_limits<uint32_t>::max()) apply(canonical_permutation<uint32_t>(c, key_less));
    else apply(canonical_permutation<std::size_t>(c, key_less));
}

namespace {

struct XYBounds {
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
};
// The x / y extent of the points with kept(i), in parallel blocks (minima and
// maxima: the same whatever the thread count). minx == INFINITY: no point.
template <class Kept>
XYBounds kept_bounds(const PointCloud& c, Kept&& kept) {
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, c.size(), 1u << 16), XYBounds{},
        [&](const tbb::blocked_range<std::size_t>& r, XYBounds b) {
            for (std::size_t i = r.begin(); i != r.end(); ++i)
                if (kept(i)) b.minx = std::min(b.minx, c.x[i]), b.maxx = std::max(b.maxx, c.x[i]), b.miny = std::min(b.miny, c.y[i]), b.maxy = std::max(b.maxy, c.y[i]);
            return b;
        },
        [](XYBounds a, const XYBounds& b) {
            return XYBounds{std::min(a.minx, b.minx), std::min(a.miny, b.miny), std::max(a.maxx, b.maxx), std::max(a.maxy, b.maxy)};
        });
}

// The largest float not above v (v as a float when that is exact, else the
// float next below it): float bounds that enclose double values.
float float_at_most(double v) {
    float f = static_cast<float>(v);
    if (double(f) > v) {  // step one float down (towards -inf)
        const auto bits = std::bit_cast<uint32_t>(f);
        f = f == 0.0f ? -std::numeric_limits<float>::denorm_min() : std::bit_cast<float>(f > 0.0f ? bits - 1 : bits + 1);
    }
    return f;
}

// The k smallest values offered so far, ascending (+inf while fewer were
// offered). An insertion is branch-free: slot j takes min(b[j], max(b[j-1], d)),
// which leaves the list unchanged for d >= its largest value. K > 0: k = K
// known at compile time, held in pairs of doubles (registers when the object
// stays local); K == 0: any k, in a caller's buffer of 2 (k + 1) doubles.
template <std::size_t K>
class SmallestK {
public:
    SmallestK(std::size_t k, double* buffer) : k_(K > 0 ? K : k), buf_(buffer) {
        if constexpr (K > 0) {
            for (V& v : b_) v = V{INFINITY, INFINITY};
        } else {
            buf_[0] = buf_[k_ + 1] = -INFINITY;
            std::fill(buf_ + 1, buf_ + 1 + k_, INFINITY);
        }
    }
    double largest() const {
        if constexpr (K > 0) return b_[(K - 1) / 2][(K - 1) % 2];
        else return cur()[k_ - 1];
    }
    void insert(double d) {
        if constexpr (K > 0) {
            const V dv = {d, d};
            for (std::size_t r = kPairs; r-- > 0;) {  // downwards: b[r - 1] is still the old one
                const V before = r == 0 ? V{-INFINITY, b_[0][0]} : __builtin_shuffle(b_[r - 1], b_[r], M{1, 2});  // b[j - 1]
                const V raised = before < dv ? dv : before;                                                  // max(b[j - 1], d)
                b_[r] = raised < b_[r] ? raised : b_[r];                                                     // min(b[j], ...)
            }
        } else {
            const double* __restrict from = cur();
            double* __restrict to = flip_ ? buf_ + 1 : buf_ + k_ + 2;
            for (std::size_t j = 0; j < k_; ++j) to[j] = std::min(from[j], std::max(from[j - 1], d));
            flip_ = !flip_;
        }
    }
    /// Copies the k values, ascending, to out[0 .. k).
    void write(double* out) const {
        if constexpr (K > 0) {
            for (std::size_t j = 0; j < K; ++j) out[j] = b_[j / 2][j % 2];
        } else {
            std::copy(cur(), cur() + k_, out);
        }
    }

private:
    using V = double __attribute__((vector_size(16)));
    using M = int64_t __attribute__((vector_size(16)));
    static constexpr std::size_t kPairs = (K + 1) / 2;
    // K == 0: two lists of 1 + k (entry 0 is -inf); an insertion writes the other one.
    const double* cur() const { return buf_ + (flip_ ? k_ + 2 : 1); }
    std::size_t k_;
    double* buf_;
    bool flip_ = false;
    V b_[K > 0 ? kPairs : 1];
};

// The cells of a grid of nx x ny cells over a cloud's extent, stored column
// by column and each column only over its band: the rows from the lowest to
// the highest that hold a point of that column. A cloud along a diagonal
// corridor, or two towns far apart, then costs cells for the ground it covers,
// not for its bounding box. Cell (cx, cy) is cell `base[cx] + cy - lo[cx]`
// when lo[cx] <= cy <= hi[cx], else empty (an empty column has lo > hi).
struct BandedGrid {
    double minx = 0, miny = 0, cx_size = 1, cy_size = 1;
    int nx = 1, ny = 1;
    std::vector<int> lo, hi;          // per column, its band of rows
    std::vector<std::size_t> base;    // per column, its first cell; base[nx] = cells
    int col(double x) const { return std::min(nx - 1, static_cast<int>((x - minx) / cx_size)); }
    int row(double y) const { return std::min(ny - 1, static_cast<int>((y - miny) / cy_size)); }
    bool holds(int cx, int cy) const { return cy >= lo[static_cast<std::size_t>(cx)] && cy <= hi[static_cast<std::size_t>(cx)]; }
    std::size_t index(int cx, int cy) const { return base[static_cast<std::size_t>(cx)] + static_cast<std::size_t>(cy - lo[static_cast<std::size_t>(cx)]); }
    std::size_t cells() const { return base.back(); }
};

// Cells of `cell` metres (capped at 65535 a side) over the box.
BandedGrid grid_over(double minx, double miny, double maxx, double maxy, double cell) {
    BandedGrid g;
    g.minx = minx, g.miny = miny;
    g.nx = static_cast<int>(std::min(65535.0, std::floor((maxx - minx) / cell) + 1));
    g.ny = static_cast<int>(std::min(65535.0, std::floor((maxy - miny) / cell) + 1));
    g.cx_size = (maxx - minx) / g.nx > cell ? (maxx - minx) / g.nx : cell;
    g.cy_size = (maxy - miny) / g.ny > cell ? (maxy - miny) / g.ny : cell;
    return g;
}

// Sets g's bands (lo, hi, base) to the rows each column's points occupy,
// from every `stride`-th point (px, py: the coordinates along g's columns and
// rows); returns the cells of the layout.
std::size_t set_bands(BandedGrid& g, const double* px, const double* py, std::size_t n, std::size_t stride) {
    struct Band {
        std::vector<int> lo, hi;
    };
    const auto nxs = static_cast<std::size_t>(g.nx);
    const std::size_t samples = (n + stride - 1) / stride;
    Band band = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, samples, 1u << 16), Band{std::vector<int>(nxs, g.ny), std::vector<int>(nxs, -1)},
        [&](const tbb::blocked_range<std::size_t>& r, Band acc) {
            for (std::size_t s = r.begin(); s != r.end(); ++s) {
                const auto cx = static_cast<std::size_t>(g.col(px[s * stride]));
                const int cy = g.row(py[s * stride]);
                acc.lo[cx] = std::min(acc.lo[cx], cy), acc.hi[cx] = std::max(acc.hi[cx], cy);
            }
            return acc;
        },
        [](Band a, const Band& o) {  // minima and maxima: the same for any thread count
            for (std::size_t q = 0; q < a.lo.size(); ++q) a.lo[q] = std::min(a.lo[q], o.lo[q]), a.hi[q] = std::max(a.hi[q], o.hi[q]);
            return a;
        });
    g.lo = std::move(band.lo), g.hi = std::move(band.hi);
    g.base.assign(nxs + 1, 0);
    for (std::size_t q = 0; q < nxs; ++q) g.base[q + 1] = g.base[q] + (g.hi[q] >= g.lo[q] ? static_cast<std::size_t>(g.hi[q] - g.lo[q] + 1) : 0);
    return g.cells();
}

// The k smallest squared distances (3-D, Euclidean) from every point to the
// points of the cloud, itself included, from a 2-D grid of columns: the points
// of each cell and of its 8 neighbours are gathered once into a contiguous
// block and their squared distances to every point of the cell computed in one
// vectorised loop; a point whose k-th distance is farther than the edge of that
// 3 x 3 block scans further rings of cells until no unseen cell can hold a
// closer point (cells are pruned by their z range, so isolated points far above
// or below the surface stay cheap). Distances are computed in double from the
// source coordinates, so they do not depend on a local origin, on the thread
// count, on the grid or on the order candidates are offered; which of several
// equidistant points is counted does not change the k smallest distances.
// `visit(i, d2, count)` gets point i's `count` (<= k) smallest squared
// distances in ascending order. Cells are numbered column by column: for
// points in canonical order (sorted by x) building the grid and gathering
// blocks then walk memory almost in order. The cell size follows the density
// over the ground the points cover (a banded grid, BandedGrid), so a corridor
// or a few stray points far away do not make the cells of the whole cloud
// coarse. K: k when known at compile time, else 0.
template <std::size_t K, class Visit>
void grid_knn(const PointCloud& c, std::size_t k, Visit&& visit) {
    const std::size_t n = c.size();
    if (n == 0 || k == 0) return;
    const XYBounds bb = kept_bounds(c, [](std::size_t) { return true; });
    require_finite_extent(bb.minx, bb.miny, bb.maxx, bb.maxy, "outlier filter");  // the grid itself is capped below
    // About 0.4 k points per cell on average (the 3 x 3 block holds ~3.6 k;
    // instructions in the search on a 400 m town at 8 pts/m²: 0.3 k +4 %,
    // 0.5 k +7 %, 0.25 k +20 %, 0.2 k +46 %).
    const double per_point = std::max(1.0, 0.4 * double(k)) / double(n);
    // A cloud (nearly) without extent along one axis (every point on one row
    // or column) has a 1-D density: cells of the 2-D rule would be far smaller
    // than the point spacing (1e-7 for one exact row), and the ring search ran
    // for ever. Such a grid is one cell thick. On any other cloud the 2-D cell
    // is the larger one (the short side spans more than one 1-D cell).
    const auto cell_for = [&](double area) {
        area = std::max(area, 1e-12);
        double cell = std::isfinite(area) ? std::sqrt(area * per_point)
                                          : std::sqrt(bb.maxx - bb.minx) * std::sqrt(bb.maxy - bb.miny) * std::sqrt(per_point);
        const double long_side = std::max(bb.maxx - bb.minx, bb.maxy - bb.miny);
        if (std::isfinite(long_side)) cell = std::max({cell, long_side * per_point, long_side / 65535.0});
        if (!(cell > 0.0) || !std::isfinite(cell)) cell = 1.0;
        return cell;
    };
    // The density over the bounding box first; where the points' bands (from
    // every 8th point) cover under half of it, over the bands instead, in the
    // orientation with fewer cells (x and y swap: distances do not change).
    bool swap = false;
    double cell = cell_for((bb.maxx - bb.minx) * (bb.maxy - bb.miny));
    bool banded = false;
    {
        BandedGrid by_col = grid_over(bb.minx, bb.miny, bb.maxx, bb.maxy, cell), by_row = grid_over(bb.miny, bb.minx, bb.maxy, bb.maxx, cell);
        const double full = double(by_col.nx) * double(by_col.ny);
        if (full >= 64.0) {
            const std::size_t stride = n >= (1u << 16) ? 8 : 1;
            const std::size_t col_cells = set_bands(by_col, c.x.data(), c.y.data(), n, stride);
            const std::size_t row_cells = set_bands(by_row, c.y.data(), c.x.data(), n, stride);
            const std::size_t fewer = std::min(col_cells, row_cells);
            if (double(fewer) < 0.5 * full) {
                banded = true, swap = row_cells < col_cells;
                cell = cell_for(double(fewer) * by_col.cx_size * by_col.cy_size);
            }
        }
    }
    const double* cxp = swap ? c.y.data() : c.x.data();
    const double* cyp = swap ? c.x.data() : c.y.data();
    const double* czp = c.z.data();
    BandedGrid g = swap ? grid_over(bb.miny, bb.minx, bb.maxy, bb.maxx, cell) : grid_over(bb.minx, bb.miny, bb.maxx, bb.maxy, cell);
    if (banded) {
        set_bands(g, cxp, cyp, n, 1);  // the exact band of every column, from every point
    } else {  // every column whole: the plain column-major grid
        g.lo.assign(static_cast<std::size_t>(g.nx), 0), g.hi.assign(static_cast<std::size_t>(g.nx), g.ny - 1);
        g.base.resize(static_cast<std::size_t>(g.nx) + 1);
        for (std::size_t q = 0; q < g.base.size(); ++q) g.base[q] = q * static_cast<std::size_t>(g.ny);
    }
    const double minx = g.minx, miny = g.miny, cx_size = g.cx_size, cy_size = g.cy_size;
    const int nx = g.nx, ny = g.ny;
    auto cell_index = [&g](int cx, int cy) { return g.index(cx, cy); };  // column-major, within the column's band
    const std::size_t cells = g.cells();
    constexpr std::size_t kGrain = 1u << 16;
    // Uninitialised arrays on huge pages from the block cache (canonical
    // order's permutation: `order` first, it fits that one's `order`), first
    // written in parallel (fresh 4 kB pages zeroed by the calling thread were
    // about 16 % of a whole-cloud run's samples).
    auto order = cached_array<uint32_t>(n);  // point indices cell by cell
    auto start = cached_array<uint32_t>(cells + 1);  // start[q]: cell q's first position in `order`; start[cells] = n
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells + 1, kGrain), [&](const tbb::blocked_range<std::size_t>& r) {
        std::fill(start.get() + r.begin(), start.get() + r.end(), 0u);
    });
    {
        // Each point's cell, computed in the counting pass and again in the
        // placing pass (the same function of the same coordinates): cheaper
        // than 4 bytes a point of fresh memory to hold it (0.5 GB at 127 M points).
        const auto cell_of = [&](std::size_t i) { return cell_index(g.col(cxp[i]), g.row(cyp[i])); };
        // Counting sort, ascending index per cell. Points in canonical order
        // (sorted by the grid's column coordinate) fill whole columns in
        // runs, and columns own disjoint cells: the points then split into
        // blocks that end where a column does, each counted and placed on
        // its own (the same order as one pass over all points).
        std::vector<std::size_t> cuts{0};
        const bool by_columns = n >= 2 * kGrain && tbb::parallel_reduce(
            tbb::blocked_range<std::size_t>(1, n, kGrain), true,
            [&](const tbb::blocked_range<std::size_t>& r, bool ok) {
                for (std::size_t i = r.begin(); i != r.end() && ok; ++i) ok = cxp[i - 1] <= cxp[i];
                return ok;
            },
            std::logical_and<>());
        std::size_t scanned = 0;
        if (by_columns)
            for (std::size_t b = 4 * kGrain; b < n && scanned < n; b += 4 * kGrain) {
                std::size_t cut = std::max(b, scanned);  // never a point twice (one long column)
                while (cut < n && g.col(cxp[cut]) == g.col(cxp[cut - 1])) ++cut;
                scanned = cut;
                if (cut < n && cut > cuts.back()) cuts.push_back(cut);
            }
        cuts.push_back(n);
        const auto blocks = [&](auto&& body) {  // body(first, last) for each block, in parallel
            tbb::parallel_for(std::size_t(0), cuts.size() - 1, [&](std::size_t b) { body(cuts[b], cuts[b + 1]); });
        };
        // Counted into start[q], summed to each cell's end, then the points
        // placed from the last backwards, each at its cell's end moved one
        // down: ascending index per cell, and start[q] ends at the cell's
        // first position (no second array of cells for the fill positions).
        blocks([&](std::size_t a, std::size_t e) {
            for (std::size_t i = a; i < e; ++i) ++start[cell_of(i)];
        });
        for (std::size_t q = 0; q < cells; ++q) start[q + 1] += start[q];
        blocks([&](std::size_t a, std::size_t e) {
            for (std::size_t i = e; i-- > a;) order[--start[cell_of(i)]] = static_cast<uint32_t>(i);
        });
    }
    // Each cell's z range in floats that enclose its double z values (the
    // float next below / above when rounding went the other way).
    auto zlo = cached_array<float>(cells), zhi = cached_array<float>(cells);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells, kGrain / 4), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t q = r.begin(); q != r.end(); ++q) {
            double lo = INFINITY, hi = -INFINITY;
            for (uint32_t j = start[q]; j < start[q + 1]; ++j) lo = std::min(lo, czp[order[j]]), hi = std::max(hi, czp[order[j]]);
            zlo[q] = float_at_most(lo), zhi[q] = -float_at_most(-hi);
        }
    });
    // Consecutive cells of one column, structure of arrays.
    struct Run {
        const double *x, *y, *z;
        std::size_t size;
    };
    tbb::parallel_for(tbb::blocked_range<int>(0, nx, 8), [&](const tbb::blocked_range<int>& columns) {
        // The coordinates of columns cx - 2 .. cx + 2 in cell order, column xx
        // in slot xx % 5: each point is copied once per column range, and
        // every block of cells below is a run of one of them.
        struct Column {
            int xx = -1;
            uint32_t first = 0;  // its first position in `order`
            std::vector<double> x, y, z;
        };
        std::array<Column, 5> slots;
        const auto column = [&](int xx) -> const Column& {
            Column& s = slots[static_cast<std::size_t>(xx) % slots.size()];
            if (s.xx != xx) {
                const uint32_t from = start[g.base[static_cast<std::size_t>(xx)]], to = start[g.base[static_cast<std::size_t>(xx) + 1]];
                s.xx = xx, s.first = from;
                s.x.resize(to - from), s.y.resize(to - from), s.z.resize(to - from);
                for (uint32_t j = from; j < to; ++j) {
                    const uint32_t i = order[j];
                    s.x[j - from] = cxp[i], s.y[j - from] = cyp[i], s.z[j - from] = czp[i];
                }
            }
            return s;
        };
        const auto run = [&](int xx, int y_lo, int y_hi) {  // cells y_lo .. y_hi of column xx (those in its band)
            y_lo = std::max(y_lo, g.lo[static_cast<std::size_t>(xx)]), y_hi = std::min(y_hi, g.hi[static_cast<std::size_t>(xx)]);
            if (y_lo > y_hi) return Run{nullptr, nullptr, nullptr, 0};
            const Column& s = column(xx);
            const std::size_t a = start[cell_index(xx, y_lo)] - s.first, b = start[cell_index(xx, y_hi) + 1] - s.first;
            return Run{s.x.data() + a, s.y.data() + a, s.z.data() + a, b - a};
        };
        // The 3 x 3 cells around the current one copied into one block,
        // structure of arrays, the own cell first (its nearest candidates fill
        // the k smallest early).
        std::vector<double> bx, by, bz;
        std::size_t block_size = 0;
        const auto append = [&](const Run& r) {
            if (block_size + r.size > bx.size()) {  // grows rarely: blocks hold a few dozen points
                const std::size_t cap = std::max(2 * bx.size(), block_size + r.size);
                bx.resize(cap), by.resize(cap), bz.resize(cap);
            }
            std::copy(r.x, r.x + r.size, bx.data() + block_size);
            std::copy(r.y, r.y + r.size, by.data() + block_size);
            std::copy(r.z, r.z + r.size, bz.data() + block_size);
            block_size += r.size;
        };
        std::vector<Run> ring2;
        std::vector<double> dd, below, out(k), lists(K > 0 ? 0 : 2 * (k + 1));
        const auto room = [&](std::size_t m) {
            if (dd.size() < m) dd.resize(std::max(m, 2 * dd.size())), below.resize(dd.size());
        };
        // The previous point's k-th squared distance, widened by 1.5 (1.2
        // measured 2 % more instructions, 2: 4 %, 3: 12 %): neighbours have
        // similar densities.
        double guess = INFINITY;
        for (int cx = columns.begin(); cx != columns.end(); ++cx)
            for (int cy = g.lo[static_cast<std::size_t>(cx)]; cy <= g.hi[static_cast<std::size_t>(cx)]; ++cy) {
                const std::size_t q = cell_index(cx, cy);
                if (start[q] == start[q + 1]) continue;
                block_size = 0;
                const Run own = run(cx, cy, cy);
                append(own);
                const int ylo = std::max(0, cy - 1), yhi = std::min(ny - 1, cy + 1);
                for (int xx = std::max(0, cx - 1); xx <= std::min(nx - 1, cx + 1); ++xx)
                    if (xx != cx) append(run(xx, ylo, yhi));
                    else {
                        if (ylo < cy) append(run(xx, ylo, cy - 1));
                        if (yhi > cy) append(run(xx, cy + 1, yhi));
                    }
                room(block_size);
                const double x0 = minx + cx * cx_size, y0 = miny + cy * cy_size;
                for (std::size_t jp = 0; jp < own.size; ++jp) {
                    const double x = bx[jp], y = by[jp], z = bz[jp];
                    // The point itself is the nearest (distance 0, as a
                    // duplicate would be): the k - 1 smallest of the others
                    // follow it.
                    SmallestK<K == 0 ? 0 : K - 1> best(k - 1, lists.data());
                    std::size_t count = 1;  // candidates offered, the point included
                    // Offers ddp[0 .. m): the first ones until k are inserted,
                    // then only those below the k-th so far (gathered without
                    // branches, then inserted).
                    const auto offer = [&](const double* ddp, std::size_t m) __attribute__((always_inline)) {
                        std::size_t t = 0;
                        for (; t < m && count < k; ++t, ++count) best.insert(ddp[t]);
                        count += m - t;
                        const double largest = best.largest();
                        double* bp = below.data();
                        std::size_t nb = 0;
                        for (; t < m; ++t) bp[nb] = ddp[t], nb += ddp[t] < largest;
                        for (std::size_t u = 0; u < nb; ++u) best.insert(bp[u]);
                    };
                    // Whether cell (xx, yy) may hold a point closer than the
                    // k-th so far (its box, z range included).
                    const auto may_hold_closer = [&](int xx, int yy) __attribute__((always_inline)) {
                        if (count < k) return true;
                        const std::size_t qq = cell_index(xx, yy);
                        const double bx0 = minx + xx * cx_size, by0 = miny + yy * cy_size;
                        const double ddx = std::max({0.0, bx0 - x, x - (bx0 + cx_size)});
                        const double ddy = std::max({0.0, by0 - y, y - (by0 + cy_size)});
                        const double ddz = std::max({0.0, double(zlo[qq]) - z, z - double(zhi[qq])});
                        return !(ddx * ddx + ddy * ddy + ddz * ddz > best.largest());
                    };
                    {  // the block: squared distances in one vectorised loop
                        const double* bxp = bx.data();
                        const double* byp = by.data();
                        const double* bzp = bz.data();
                        double* ddp = dd.data();
                        for (std::size_t t = 0; t < block_size; ++t) {
                            const double dx = bxp[t] - x, dy = byp[t] - y, dz = bzp[t] - z;
                            ddp[t] = dx * dx + dy * dy + dz * dz;
                        }
                        ddp[jp] = ddp[0];  // the point itself left out: offered from 1
                        // Those below a guess (the previous point's k-th
                        // distance, widened): when they are k - 1 or more, the
                        // k - 1 smallest are among them.
                        const double* from = ddp + 1;
                        const std::size_t m = block_size - 1;
                        double* bp = below.data();
                        std::size_t nb = 0;
                        for (std::size_t t = 0; t < m; ++t) bp[nb] = from[t], nb += from[t] < guess;
                        if (nb + 1 >= k) {
                            for (std::size_t u = 0; u < nb; ++u) best.insert(bp[u]);
                            count += m;
                        } else {
                            offer(from, m);
                        }
                    }
                    // Distance from the point to the edge of the scanned block of
                    // rings 0..r: any unseen point is at least that far away. An
                    // axis of one cell has no unseen cells, so it does not bound
                    // the reach (a one-row grid grows it along x alone).
                    const double edge_x = std::min(x - x0, x0 + cx_size - x), edge_y = std::min(y - y0, y0 + cy_size - y);
                    const double edge = nx == 1 ? edge_y : ny == 1 ? edge_x : std::min(edge_x, edge_y);
                    const double step = nx == 1 ? cy_size : ny == 1 ? cx_size : std::min(cx_size, cy_size);
                    for (int r = 2;; ++r) {
                        const double reach = (r - 1) * step + std::max(0.0, edge);
                        if (count >= k && best.largest() <= reach * reach) break;
                        if (cx - r < 0 && cy - r < 0 && cx + r >= nx && cy + r >= ny) break;  // every cell seen
                        // Only the ring's cells inside the grid are visited: its
                        // left and right columns whole, the rows cy - r and
                        // cy + r of the columns between; cells that cannot hold
                        // a closer point are skipped.
                        if (r == 2) {  // its 16 cells from the columns held, offered at once
                            // Squared distances from the point to columns cx - 2 .. cx + 2 and rows cy - 2 .. cy + 2.
                            double col_d2[5], row_d2[5];
                            for (int u = 0; u < 5; ++u) {
                                const double bx0 = minx + (cx - 2 + u) * cx_size, by0 = miny + (cy - 2 + u) * cy_size;
                                const double ex = std::max({0.0, bx0 - x, x - (bx0 + cx_size)}), ey = std::max({0.0, by0 - y, y - (by0 + cy_size)});
                                col_d2[u] = ex * ex, row_d2[u] = ey * ey;
                            }
                            static constexpr int kRing2[16][2] = {{-2, -2}, {-2, -1}, {-2, 0}, {-2, 1}, {-2, 2}, {-1, -2}, {-1, 2}, {0, -2},
                                                                  {0, 2},   {1, -2},  {1, 2},  {2, -2}, {2, -1}, {2, 0},  {2, 1},  {2, 2}};
                            std::size_t m = 0;
                            for (const auto& [ox, oy] : kRing2) {
                                const int xx = cx + ox, yy = cy + oy;
                                if (xx < 0 || yy < 0 || xx >= nx || yy >= ny || !g.holds(xx, yy)) continue;
                                const std::size_t qq = cell_index(xx, yy);
                                if (start[qq] == start[qq + 1]) continue;
                                if (count >= k) {  // the cell's box, z range included, beyond the k-th so far
                                    const double ddz = std::max({0.0, double(zlo[qq]) - z, z - double(zhi[qq])});
                                    if (col_d2[ox + 2] + row_d2[oy + 2] + ddz * ddz > best.largest()) continue;
                                }
                                const Run cr = run(xx, yy, yy);
                                room(m + cr.size);
                                for (std::size_t t = 0; t < cr.size; ++t) {
                                    const double dx = cr.x[t] - x, dy = cr.y[t] - y, dz = cr.z[t] - z;
                                    dd[m + t] = dx * dx + dy * dy + dz * dz;
                                }
                                m += cr.size;
                            }
                            offer(dd.data(), m);
                            continue;
                        }
                        for (int xx = std::max(0, cx - r); xx <= std::min(nx - 1, cx + r); ++xx) {
                            const bool edge_col = xx == cx - r || xx == cx + r;
                            const int step_y = edge_col ? 1 : 2 * r;
                            const int band_lo = g.lo[static_cast<std::size_t>(xx)], band_hi = g.hi[static_cast<std::size_t>(xx)];
                            int yy = cy - r;
                            if (edge_col && yy < band_lo) yy = band_lo;
                            for (; yy <= std::min(band_hi, cy + r); yy += step_y) {
                                if (yy < band_lo) continue;
                                const std::size_t qq = cell_index(xx, yy);
                                if (start[qq] == start[qq + 1] || !may_hold_closer(xx, yy)) continue;
                                for (uint32_t j = start[qq]; j < start[qq + 1]; ++j, ++count) {
                                    const uint32_t i = order[j];
                                    const double dx = cxp[i] - x, dy = cyp[i] - y, dz = czp[i] - z;
                                    const double d2 = dx * dx + dy * dy + dz * dz;
                                    if (count < k || d2 < best.largest()) best.insert(d2);
                                }
                            }
                        }
                    }
                    out[0] = 0.0;
                    best.write(out.data() + 1);
                    guess = 1.5 * best.largest();
                    visit(order[start[q] + jp], static_cast<const double*>(out.data()), std::min(count, k));
                }
            }
    });
}

}  // namespace

// A radix selection over the floats' order-preserving bits: two counting
// passes of 16 bits, each in parallel (counts are exact, so the value does not
// depend on the thread count). nth_element on one thread was about a tenth of
// the filter's wall time on two cores.
float median_as_float(std::span<const double> v) {
    const std::size_t n = v.size();
    if (n == 0) throw Error("median", "internal: no values");
    const auto key = [](double d) {  // order-preserving bits of float(d)
        const auto b = std::bit_cast<uint32_t>(static_cast<float>(d));
        return b & 0x80000000u ? ~b : b | 0x80000000u;
    };
    using Counts = std::vector<uint64_t>;
    // Counts per thread (integers: their sum does not depend on which thread
    // counted what), so no 512 KB array is copied per range of values.
    const auto count = [&](auto&& bin_of) {  // bin_of(key) in 0..65535, or -1 to skip
        tbb::enumerable_thread_specific<Counts> local([] { return Counts(1u << 16, 0); });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
            Counts& c = local.local();
            for (std::size_t i = r.begin(); i != r.end(); ++i)
                if (const int b = bin_of(key(v[i])); b >= 0) ++c[static_cast<std::size_t>(b)];
        });
        Counts total(1u << 16, 0);
        for (const Counts& c : local)
            for (std::size_t q = 0; q < total.size(); ++q) total[q] += c[q];
        return total;
    };
    // The bin holding rank `rank` among `c`'s counts; `rank` becomes the rank within it.
    const auto bin_of_rank = [](const Counts& c, std::size_t& rank) {
        std::size_t q = 0;
        for (; c[q] <= rank; ++q) rank -= c[q];
        return static_cast<uint32_t>(q);
    };
    std::size_t rank = n / 2;
    const uint32_t high = bin_of_rank(count([](uint32_t k) { return static_cast<int>(k >> 16); }), rank);
    const uint32_t low = bin_of_rank(count([high](uint32_t k) { return k >> 16 == high ? static_cast<int>(k & 0xffffu) : -1; }), rank);
    const uint32_t k = high << 16 | low;
    return std::bit_cast<float>(k & 0x80000000u ? k & 0x7fffffffu : ~k);
}

double outlier_limit(std::span<const double> mean_dist, double std_multiplier) {
    const std::size_t n = mean_dist.size();
    if (n == 0) return 0.0;
    // Gross outliers (a few points kilometres away, or a z of -1700 m) would
    // set sigma alone: 3 of them among 100 000 points raise the limit tenfold
    // and let every ordinary outlier through. Points farther from their
    // neighbours than kGrossOutlierFactor x the median are left out of the
    // mean and sigma (they are over the limit anyway); a cloud without such
    // points gets the plain mean + m * sigma.
    const double median = median_as_float(mean_dist);
    const double gross = median > 0 ? kGrossOutlierFactor * median : INFINITY;
    // Sums in index order: the threshold does not depend on the thread count.
    double sum = 0.0, sum2 = 0.0;
    std::size_t used = 0;
    for (double d : mean_dist)
        if (d <= gross) sum += d, sum2 += d * d, ++used;
    const double mean = sum / static_cast<double>(used);
    const double sigma = std::sqrt(std::max(0.0, sum2 / static_cast<double>(used) - mean * mean));
    return mean + std_multiplier * sigma;
}

OutlierFilterResult filter_outliers(const PointCloud& c, const OutlierFilterOptions& o) {
    // The block cache emptied when this returns (declared first: destroyed
    // after every array below went back to it): the filter ends the chain of
    // reuse that canonical_order starts, so no cached block sits beside the
    // next step's memory (peak RSS, the streamed windows' budget).
    struct ReleaseCache {
        ~ReleaseCache() { release_large_buffer_cache(); }
    } release_at_end;
    o.validate();
    OutlierFilterResult r;
    const std::size_t n = c.size();
    r.keep.resize(n);
    constexpr std::size_t kGrain = 1u << 16;
    using Counts = std::pair<std::size_t, std::size_t>;  // (statistical, isolated), added in any order
    const auto add = [](Counts a, Counts b) { return Counts{a.first + b.first, a.second + b.second}; };
    r.removed_statistical = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, kGrain), std::size_t(0),
        [&](const tbb::blocked_range<std::size_t>& b, std::size_t noise) {
            for (std::size_t i = b.begin(); i != b.end(); ++i) {
                const bool is_noise = c.classification[i] == las_class::low_noise || c.classification[i] == las_class::high_noise;
                r.keep[i] = !is_noise, noise += is_noise;
            }
            return noise;
        },
        std::plus<>());
    if (!o.enabled || n < static_cast<std::size_t>(o.k_neighbours) + 1) return r;
    // One k-nearest-neighbour pass serves both filters: the isolated-point test
    // only needs the distance to the m-th neighbour (m = isolated_min_neighbours).
    // Only distances count (which of several equidistant points is a
    // neighbour changes none), so they do not depend on the window the cloud
    // was cut to.
    const std::size_t k = static_cast<std::size_t>(std::max(o.k_neighbours, o.isolated_min_neighbours)) + 1;  // self first
    const auto m = static_cast<std::size_t>(o.isolated_min_neighbours);
    // Written once for every point by the parallel search (first touch
    // there). From the block cache: canonical_order's scratch of 8 bytes a point.
    auto mean_dist = cached_array<double>(n);
    const bool test_isolated = o.isolated_radius > 0.0 && m > 0;
    // An isolated point is marked in r.keep's bit 1 (kIsolated) until the
    // limit is known, rather than in an array of its own (fresh memory).
    constexpr uint8_t kIsolated = 2;
    const auto visit = [&](std::size_t i, const double* best, std::size_t found) {
        // best[0] is the point itself (or a duplicate at distance 0).
        const std::size_t used = std::min(found, static_cast<std::size_t>(o.k_neighbours) + 1);
        double s = 0.0;
        for (std::size_t j = 1; j < used; ++j) s += std::sqrt(best[j]);
        mean_dist[i] = used > 1 ? s / static_cast<double>(used - 1) : 0.0;
        if (test_isolated && (found <= m || best[m] > o.isolated_radius * o.isolated_radius)) r.keep[i] |= kIsolated;
    };
    if (k == 9) grid_knn<9>(c, k, visit);  // the defaults: 8 neighbours and the point itself
    else grid_knn<0>(c, k, visit);
    const double limit = o.max_mean_distance > 0 ? o.max_mean_distance : outlier_limit({mean_dist.get(), n}, o.std_multiplier);
    r.limit = limit;
    const Counts removed = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, kGrain), Counts{0, 0},
        [&](const tbb::blocked_range<std::size_t>& b, Counts counts) {
            for (std::size_t i = b.begin(); i != b.end(); ++i) {
                const uint8_t v = r.keep[i];
                r.keep[i] = v & 1;
                if (!(v & 1)) continue;
                if (mean_dist[i] > limit) r.keep[i] = 0, ++counts.first;  // statistical first, as the noise classes
                else if (v & kIsolated) r.keep[i] = 0, ++counts.second;
            }
            return counts;
        },
        add);
    r.removed_statistical += removed.first, r.removed_isolated = removed.second;
    return r;
}

namespace {

constexpr uint32_t kNoGroup = std::numeric_limits<uint32_t>::max();  // a point in no group: not kept

// v / d for a grid's cell or block size d: a multiplication by 1 / d when d
// is a power of two (its inverse is exact and normal, so the product is the
// same number as the quotient), else the division. For the passes over
// every point.
class ExactQuotient {
public:
    explicit ExactQuotient(double d) : d_(d) {
        int exponent = 0;
        const double inv = std::frexp(d, &exponent) == 0.5 ? std::ldexp(1.0, 1 - exponent) : 0.0;
        by_inverse_ = std::isnormal(inv), inv_ = inv;
    }
    double operator()(double v) const { return by_inverse_ ? v * inv_ : v / d_; }

private:
    double d_, inv_ = 0.0;
    bool by_inverse_ = false;
};
// SMRF's blocks of 256 x 256 cells (x, y: block numbers from the grid's
// anchored corner), and how they group: occupied blocks closer than 4
// blocks (Chebyshev) join, and groups whose bounding boxes meet merge. `blocks`: the occupied ones, sorted, each once; returns each one's
// group id (0, 1, ... in the order of their first block) and sets `groups`.
using BlockKey = std::pair<int64_t, int64_t>;
constexpr double kGroundBlockCells = 256.0;
std::vector<uint32_t> group_blocks(const std::vector<BlockKey>& blocks, uint32_t& groups) {
    using Key = BlockKey;
    constexpr int64_t kJoin = 4;  // Chebyshev distance in blocks
    const std::size_t m = blocks.size();
    std::vector<std::size_t> parent(m);
    std::iota(parent.begin(), parent.end(), std::size_t(0));
    auto find = [&](std::size_t a) {
        while (parent[a] != a) a = parent[a] = parent[parent[a]];
        return a;
    };
    auto join = [&](std::size_t a, std::size_t b) {
        a = find(a), b = find(b);
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
    };
    for (std::size_t b = 0; b < m; ++b)
        for (int64_t dx = -kJoin; dx <= kJoin; ++dx) {
            // The blocks of column bx + dx within kJoin rows: one sorted range.
            const auto lo = std::lower_bound(blocks.begin(), blocks.end(), Key{blocks[b].first + dx, blocks[b].second - kJoin});
            for (auto it = lo; it != blocks.end() && it->first == blocks[b].first + dx && it->second <= blocks[b].second + kJoin; ++it)
                join(b, static_cast<std::size_t>(it - blocks.begin()));
        }
    // Groups whose bounding boxes (in blocks) meet are merged, until none do.
    struct Box {
        int64_t x0, y0, x1, y1;
    };
    std::vector<Box> box(m, Box{INT64_MAX, INT64_MAX, INT64_MIN, INT64_MIN});
    for (std::size_t b = 0; b < m; ++b) {
        Box& r = box[find(b)];
        r = {std::min(r.x0, blocks[b].first), std::min(r.y0, blocks[b].second), std::max(r.x1, blocks[b].first), std::max(r.y1, blocks[b].second)};
    }
    for (bool merged = true; merged;) {
        merged = false;
        std::vector<std::size_t> roots;
        for (std::size_t b = 0; b < m; ++b)
            if (find(b) == b) roots.push_back(b);
        for (std::size_t u = 0; u < roots.size() && !merged; ++u)
            for (std::size_t v = u + 1; v < roots.size() && !merged; ++v) {
                const Box &p = box[roots[u]], &q = box[roots[v]];
                if (p.x0 <= q.x1 && q.x0 <= p.x1 && p.y0 <= q.y1 && q.y0 <= p.y1) {
                    join(roots[u], roots[v]);
                    box[find(roots[u])] = {std::min(p.x0, q.x0), std::min(p.y0, q.y0), std::max(p.x1, q.x1), std::max(p.y1, q.y1)};
                    merged = true;
                }
            }
    }
    std::vector<uint32_t> id(m, kNoGroup);
    groups = 0;
    for (std::size_t b = 0; b < m; ++b)
        if (find(b) == b) id[b] = groups++;
    for (std::size_t b = 0; b < m; ++b) id[b] = id[find(b)];  // each block's group (find() edits parent: not in parallel)
    return id;
}

// SMRF over the points with kept(i) (all of them, or one group of
// split_ground_groups), on a grid over their bounding box `bb`
// (kept_bounds); sets g.is_ground and counts g.ground_points.
// `only_if_one_group`: the grid is one split_ground_groups would split up
// unless its points form one group; the blocks are then read off the
// minimum-z pass (no pass of their own) and, when they form more than one
// group, nothing is written and false returned (the caller splits). The
// grid's corner must not lie above `bb`'s (every cell number >= 0, so the
// blocks are the ones split_ground_groups finds).
template <class Kept>
bool smrf_grid(const PointCloud& c, Kept&& kept, const XYBounds& bb, const GroundFilterOptions& o, GroundResult& g, bool only_if_one_group = false) {
    const std::size_t n = c.size();
    // SMRF: minimum surface on a grid, holes filled from neighbours, then
    // progressive openings with growing windows; cells whose height drops by
    // more than slope * window * cell are non-ground.
    double minx = bb.minx, miny = bb.miny;
    const double maxx = bb.maxx, maxy = bb.maxy;
    if (minx == INFINITY) return true;  // no kept point
    // Cells anchored at multiples of the cell size: every window of a cloud
    // uses the same cells, so its ground does not depend on where it starts.
    minx = std::floor(minx / o.cell) * o.cell, miny = std::floor(miny / o.cell) * o.cell;
    // Bytes a cell: five grids of doubles, held from the minimum surface to
    // the classification (reused for every step: see below), and the object flags.
    constexpr double kBytesPerCell = 5 * 8 + 1;
    const GridSize size = checked_grid_size(minx, miny, maxx, maxy, o.cell, kBytesPerCell, "ground filter", 4e8);
    const int w = size.width, h = size.height;
    const std::size_t cells = static_cast<std::size_t>(w) * h;
    constexpr std::size_t kGrain = 1u << 16;
    // A point's cell: (v - origin) / cell (no division for a power-of-two cell).
    const ExactQuotient per_cell(o.cell);
    auto cell_of = [&](double v, double origin) { return per_cell(v - origin); };
    auto cell_x = [&](std::size_t i) { return std::min(w - 1, static_cast<int>(cell_of(c.x[i], minx))); };
    auto cell_y = [&](std::size_t i) { return std::min(h - 1, static_cast<int>(cell_of(c.y[i], miny))); };
    // Five grids of doubles, allocated once (fresh memory is dear on a VM:
    // each new grid is pages the kernel zeroes, 0.4 M page faults at 1.6e7
    // cells when every step had grids of its own) on transparent huge pages,
    // first touched in parallel; each step takes the ones free at that time.
    LargeArray<double> pool[5];
    pool[0] = large_array<double>(cells);
    auto parallel_cells = [&](auto&& body) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells, kGrain), [&](const tbb::blocked_range<std::size_t>& b) {
            for (std::size_t k = b.begin(); k != b.end(); ++k) body(k);
        });
    };
    // Minimum z of each cell, in parallel (a minimum does not depend on the
    // order points come in), on a column-major grid (points in canonical
    // order, sorted by x, then walk it almost in order), turned row-major
    // with NaN for empty cells.
    double* zmin = nullptr;
    {
        double* const by_column = pool[0].get();
        parallel_cells([&](std::size_t k) { by_column[k] = INFINITY; });
        // The occupied blocks (only_if_one_group): block of a cell = cell number / 256.
        const int64_t bx_end = only_if_one_group ? (static_cast<int64_t>(cell_of(maxx, minx)) >> 8) + 1 : 0;
        const int64_t by_end = only_if_one_group ? (static_cast<int64_t>(cell_of(maxy, miny)) >> 8) + 1 : 0;
        std::vector<uint8_t> occupied(static_cast<std::size_t>(bx_end * by_end), 0);
        auto min_z = [&](auto check_blocks) {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kGrain), [&](const tbb::blocked_range<std::size_t>& r) {
                for (std::size_t i = r.begin(); i != r.end(); ++i) {
                    if (!kept(i)) continue;
                    const double z = c.z[i];
                    const double qx = cell_of(c.x[i], minx), qy = cell_of(c.y[i], miny);
                    const int cx = std::min(w - 1, static_cast<int>(qx)), cy = std::min(h - 1, static_cast<int>(qy));
                    if constexpr (decltype(check_blocks)::value) {
                        const auto b = static_cast<std::size_t>((static_cast<int64_t>(qx) >> 8) * by_end + (static_cast<int64_t>(qy) >> 8));
                        std::atomic_ref<uint8_t>(occupied[b]).store(1, std::memory_order_relaxed);
                    }
                    std::atomic_ref<double> cell(by_column[static_cast<std::size_t>(cx) * h + cy]);
                    double now = cell.load(std::memory_order_relaxed);
                    while (z < now && !cell.compare_exchange_weak(now, z, std::memory_order_relaxed)) {
                    }
                }
            });
        };
        if (only_if_one_group) {
            min_z(std::true_type{});
            std::vector<BlockKey> blocks;
            for (std::size_t b = 0; b < occupied.size(); ++b)  // sorted, as split_ground_groups lists them
                if (occupied[b]) blocks.push_back(BlockKey{static_cast<int64_t>(b) / by_end, static_cast<int64_t>(b) % by_end});
            uint32_t groups = 0;
            group_blocks(blocks, groups);
            if (groups > 1) return false;
        } else {
            min_z(std::false_type{});
        }
        pool[1] = large_array<double>(cells);
        zmin = pool[1].get();
        tbb::parallel_for(tbb::blocked_range<int>(0, h, 64), [&](const tbb::blocked_range<int>& rows) {
            for (int x0 = 0; x0 < w; x0 += 64)
                for (int y = rows.begin(); y != rows.end(); ++y)
                    for (int x = x0; x < std::min(w, x0 + 64); ++x) {
                        const double v = by_column[static_cast<std::size_t>(x) * h + y];
                        zmin[static_cast<std::size_t>(y) * w + x] = std::isfinite(v) ? v : NAN;
                    }
        });
    }
    // Local: windows of a cloud agree.
    for (int k = 2; k < 5; ++k) pool[k] = large_array<double>(cells);
    fill_gaps(zmin, w, h, gap_fill_reach_cells(o.cell), nullptr, [&] { return std::pair<double*, double*>{pool[2].get(), pool[3].get()}; });
    // The openings: surface, eroded and opened grids and the morphology's
    // row pass, in the four grids besides zmin, swapped from window to window.
    auto object = large_array<uint8_t>(cells);
    double* surface = pool[2].get();
    double* eroded = pool[3].get();
    double* opened = pool[0].get();
    double* scratch = pool[4].get();
    parallel_cells([&](std::size_t k) { surface[k] = zmin[k], object[k] = 0; });
    const int max_r = std::max(1, static_cast<int>(std::ceil(o.window / o.cell)));
    for (int r = 1; r <= max_r; ++r) {
        morphology_square<double>(surface, w, h, r, true, eroded, scratch);
        morphology_square<double>(eroded, w, h, r, false, opened, scratch);
        const double threshold = o.slope * r * o.cell;
        parallel_cells([&](std::size_t k) {
            if (surface[k] - opened[k] > threshold) object[k] = 1;
        });
        std::swap(surface, opened);
    }
    // Provisional DTM: minimum surface at ground cells, object cells inpainted.
    double* const dtm = surface;
    parallel_cells([&](std::size_t k) { dtm[k] = object[k] ? NAN : zmin[k]; });
    object.reset();
    fill_gaps(dtm, w, h, gap_fill_reach_cells(o.cell), nullptr, [&] { return std::pair<double*, double*>{zmin, eroded}; });
    // Each cell's DTM height and how far from it a ground point may lie: the
    // threshold scaled by the DTM's local slope (steep terrain tolerates
    // more). Column-major, as the minimum z above.
    double* const band_z = opened;
    double* const band_tolerance = scratch;
    tbb::parallel_for(tbb::blocked_range<int>(0, w, 64), [&](const tbb::blocked_range<int>& columns) {
        for (int y = 0; y < h; ++y) {
            const double* row = dtm + static_cast<std::size_t>(y) * w;
            const double* up = dtm + static_cast<std::size_t>(std::min(h - 1, y + 1)) * w;
            const double* down = dtm + static_cast<std::size_t>(std::max(0, y - 1)) * w;
            for (int x = columns.begin(); x != columns.end(); ++x) {
                const double gx = (row[std::min(w - 1, x + 1)] - row[std::max(0, x - 1)]) / (2 * o.cell);
                const double gy = (up[x] - down[x]) / (2 * o.cell);
                const std::size_t k = static_cast<std::size_t>(x) * h + y;
                band_z[k] = row[x], band_tolerance[k] = o.elevation_threshold + o.elevation_scalar * std::sqrt(gx * gx + gy * gy);
            }
        }
    });
    g.ground_points += tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, kGrain), std::size_t(0),
        [&](const tbb::blocked_range<std::size_t>& r, std::size_t ground) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                if (!kept(i)) continue;
                const std::size_t k = static_cast<std::size_t>(cell_x(i)) * h + cell_y(i);
                const double z = band_z[k];
                if (std::isfinite(z) && std::abs(c.z[i] - z) <= band_tolerance[k]) g.is_ground[i] = 1, ++ground;
            }
            return ground;
        },
        [](std::size_t a, std::size_t b) { return a + b; });
    return true;
}

// Groups of kept points (ids 0, 1, ...; kNoGroup for a point not kept) whose
// ground is computed on a grid of its own: occupied blocks of 256 x 256
// cells closer than 4 blocks join, and groups whose bounding boxes meet merge.
// Two sites 12 km apart then cost two small grids instead of one of 1.5e8
// cells (12 GB) that is almost all empty. Returns each point's group, or no
// array when every kept point falls in one group (groups == 1: the caller
// then takes all kept points, as with a single grid).
template <class Kept>
LargeArray<uint32_t> split_ground_groups(const PointCloud& c, Kept&& kept, const XYBounds& bb, double minx, double miny, double cell,
                                         uint32_t& groups) {
    const std::size_t n = c.size();
    const double bsize = cell * kGroundBlockCells;
    using Key = BlockKey;
    // floor((v - origin) / bsize) without a call to floor (exact: |q| < 2^63).
    const ExactQuotient per_block(bsize);
    auto block_of = [per_block](double v, double origin) {
        const double q = per_block(v - origin);
        const auto t = static_cast<int64_t>(q);
        return t - static_cast<int64_t>(static_cast<double>(t) > q);
    };
    auto key_of = [&](std::size_t i) { return Key{block_of(c.x[i], minx), block_of(c.y[i], miny)}; };
    // The blocks' range (block_of does not decrease with v): every kept point's key lies in it.
    const int64_t kx0 = block_of(bb.minx, minx), ky0 = block_of(bb.miny, miny);
    const auto nbx = static_cast<uint64_t>(block_of(bb.maxx, minx) - kx0) + 1, nby = static_cast<uint64_t>(block_of(bb.maxy, miny) - ky0) + 1;
    // A byte a block when the blocks' rectangle is small (a town: 16 x 16
    // blocks for 4 x 4 km; one pass of two divisions a point; at most 4 MB
    // here and 16 MB of block groups below), else a sorted list of the
    // occupied ones (sites far apart).
    constexpr uint64_t kDenseBlocks = uint64_t(1) << 22;
    const bool dense = nbx <= kDenseBlocks && nby <= kDenseBlocks && nbx * nby <= kDenseBlocks;
    auto dense_of = [&](std::size_t i) { return static_cast<std::size_t>(block_of(c.x[i], minx) - kx0) * nby + static_cast<std::size_t>(block_of(c.y[i], miny) - ky0); };
    std::vector<Key> blocks;
    if (dense) {
        std::vector<uint8_t> occupied(static_cast<std::size_t>(nbx * nby), 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
            std::size_t last = std::size_t(-1);
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                if (!kept(i)) continue;
                const std::size_t b = dense_of(i);
                if (b != last) std::atomic_ref<uint8_t>(occupied[b]).store(1, std::memory_order_relaxed), last = b;
            }
        });
        for (std::size_t b = 0; b < occupied.size(); ++b)  // sorted by (x, y), as the list below
            if (occupied[b]) blocks.push_back(Key{kx0 + static_cast<int64_t>(b / nby), ky0 + static_cast<int64_t>(b % nby)});
    } else {
        // The occupied blocks (sorted, each once), from ranges of points in
        // parallel: each range's blocks sorted and made unique before they join
        // the others (points sorted by x alternate between the blocks of a
        // column: listing every change of block held ~0.9 keys a point, 1.9 GB
        // at 127 M points, sorted on one thread). A set: the same for any ranges.
        const auto unite = [](std::vector<Key> a, const std::vector<Key>& b) {
            std::vector<Key> u;
            u.reserve(a.size() + b.size());
            std::set_union(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(u));
            return u;
        };
        blocks = tbb::parallel_reduce(
            tbb::blocked_range<std::size_t>(0, n, 1u << 16), std::vector<Key>(),
            [&](const tbb::blocked_range<std::size_t>& r, std::vector<Key> acc) {
                std::vector<Key> here;
                for (std::size_t i = r.begin(); i != r.end(); ++i) {
                    if (!kept(i)) continue;
                    const Key k = key_of(i);  // once a point: two divisions
                    if (here.empty() || here.back() != k) here.push_back(k);
                }
                std::sort(here.begin(), here.end());
                here.erase(std::unique(here.begin(), here.end()), here.end());
                return unite(std::move(acc), here);
            },
            unite);
    }
    const std::vector<uint32_t> id = group_blocks(blocks, groups);
    const std::size_t m = blocks.size();
    if (groups <= 1) return {};
    // Each point's group, in parallel (every entry written: the array is not initialised).
    auto group = large_array<uint32_t>(n);
    if (dense) {
        std::vector<uint32_t> block_group(static_cast<std::size_t>(nbx * nby), kNoGroup);
        for (std::size_t b = 0; b < m; ++b)
            block_group[static_cast<std::size_t>(blocks[b].first - kx0) * nby + static_cast<std::size_t>(blocks[b].second - ky0)] = id[b];
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) group[i] = kept(i) ? block_group[dense_of(i)] : kNoGroup;
        });
        return group;
    }
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1u << 16), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i)
            group[i] = kept(i) ? id[static_cast<std::size_t>(std::lower_bound(blocks.begin(), blocks.end(), key_of(i)) - blocks.begin())] : kNoGroup;
    });
    return group;
}

}  // namespace

GroundResult classify_ground(const PointCloud& c, const std::vector<uint8_t>& keep, const GroundFilterOptions& o) {
    o.validate();
    GroundResult g;
    const std::size_t n = c.size();
    g.is_ground.assign(n, 0);
    auto kept = [&](std::size_t i) { return keep.empty() || keep[i]; };
    if (o.trust_classification) {
        std::size_t class2 = 0;
        for (std::size_t i = 0; i < n; ++i) class2 += c.classification[i] == las_class::ground && kept(i);
        if (class2 > 0) {
            for (std::size_t i = 0; i < n; ++i) g.is_ground[i] = c.classification[i] == las_class::ground && kept(i);
            g.from_classification = true;
            g.ground_points = class2;
            return g;
        }
    }
    if (n == 0) return g;
    // One grid over every kept point, unless that grid is large: then kept
    // points kilometres apart get a grid each (split_ground_groups). Clouds
    // of up to 4 x 4 km at 1 m cells always take the single grid.
    const XYBounds bb = kept_bounds(c, kept);
    double minx = bb.minx, miny = bb.miny;
    const double maxx = bb.maxx, maxy = bb.maxy;
    if (minx == INFINITY) return g;  // no kept point
    minx = std::floor(minx / o.cell) * o.cell, miny = std::floor(miny / o.cell) * o.cell;
    require_finite_extent(minx, miny, maxx, maxy, "ground filter");
    const double w = std::floor((maxx - minx) / o.cell) + 1.0, h = std::floor((maxy - miny) / o.cell) + 1.0;
    constexpr double kSingleGridCells = 1.6e7;
    if (w * h <= kSingleGridCells) {
        smrf_grid(c, kept, bb, o, g);
        return g;
    }
    if (w > 2.0e9 || h > 2.0e9) checked_grid_size(minx, miny, maxx, maxy, o.cell, 0.0, "ground filter", 4e8);  // throws: too large
    // A grid somewhat larger (a 4 x 4 km town at 1 m: 4001 x 4001 cells) is
    // most likely one group: tried whole, its blocks read off the minimum-z
    // pass, instead of a pass over the points to find them first (1.7 CPU s
    // at 127 M points); when they make more groups, the points are split as below.
    constexpr double kTryWholeCells = 2 * kSingleGridCells;
    if (w * h <= kTryWholeCells && minx <= bb.minx && miny <= bb.miny) {
        // Too large for this machine's memory as one grid: split first (a
        // cloud that is one group then meets the same error below; one of
        // several groups does not need the whole grid). The check comes
        // before anything is written to `g`.
        bool done = false;
        try {
            done = smrf_grid(c, kept, bb, o, g, true);
        } catch (const OutOfMemory&) {
        }
        if (done) return g;
    }
    uint32_t groups = 0;
    const LargeArray<uint32_t> group = split_ground_groups(c, kept, bb, minx, miny, o.cell, groups);
    if (!group) {  // one group: every kept point, on the grid over all of them
        smrf_grid(c, kept, bb, o, g);
        return g;
    }
    for (uint32_t k = 0; k < groups; ++k) {
        auto in_group = [&](std::size_t i) { return group[i] == k; };
        smrf_grid(c, in_group, kept_bounds(c, in_group), o, g);
    }
    return g;
}

}  // namespace cityforge
