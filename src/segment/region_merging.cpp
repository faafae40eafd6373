#include "segment/region_merging.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <atomic>
#include <sys/mman.h>
#include <memory>
#include <new>
#include <type_traits>
#include <tbb/task_arena.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#include <xmmintrin.h>
#endif
#include <tbb/combinable.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_for.h>

#include "core/resource_usage.hpp"
#include "core/prefetch.hpp"
#include "segment/merge_queue.hpp"
#include "core/error.hpp"
#include "core/parallel.hpp"

namespace cityforge {

std::string to_string(QueueStrategy s) {
    switch (s) {
        case QueueStrategy::rag: return "rag";
        case QueueStrategy::nng: return "nng";
        case QueueStrategy::mutual: return "mutual";
    }
    return "mutual";
}

QueueStrategy queue_strategy_from_string(const std::string& s) {
    if (s == "rag") return QueueStrategy::rag;
    if (s == "nng") return QueueStrategy::nng;
    if (s == "mutual") return QueueStrategy::mutual;
    throw Error("--strategy", "must be rag, nng or mutual, not '" + s + "'");
}

void RegionMergingOptions::validate(int bands) const {
    if (scales.empty()) throw Error("--scales", "at least one scale is needed");
    for (std::size_t i = 0; i < scales.size(); ++i) {
        if (!(scales[i] > 0.0) || !std::isfinite(scales[i])) throw Error("--scales", "every scale must be > 0");
        if (i > 0 && !(scales[i] > scales[i - 1])) throw Error("--scales", "scales must be strictly increasing");
    }
    if (!(color_weight >= 0.0 && color_weight <= 1.0)) throw Error("--color-weight", "must be between 0 and 1");
    if (!(compactness >= 0.0 && compactness <= 1.0)) throw Error("--compactness", "must be between 0 and 1");
    if (!band_weights.empty() && static_cast<int>(band_weights.size()) != bands)
        throw Error("--band-weights", "has " + std::to_string(band_weights.size()) + " values but the image has " +
                                          std::to_string(bands) + " band(s)");
    double sum = 0.0;
    for (double w : band_weights) {
        if (!(w >= 0.0) || !std::isfinite(w)) throw Error("--band-weights", "weights must be finite and >= 0");
        sum += w;
    }
    if (!band_weights.empty() && sum <= 0.0) throw Error("--band-weights", "at least one weight must be > 0");
}

Image<uint32_t> relabel(const Image<uint32_t>& labels, const std::vector<uint32_t>& table) {
    Image<uint32_t> out(labels.width, labels.height, 1, 0u);
    const uint32_t* in = labels.band_data(0);
    uint32_t* o = out.band_data(0);
    parallel_for_each_index(labels.pixel_count(), [&](std::size_t i) { o[i] = table[in[i]]; });
    return out;
}

namespace {

__extension__ typedef __int128 int128;  // exact sums of squared fixed-point values

// √x for x >= 0 or NaN: the same correctly rounded value as std::sqrt, without
// the errno check GCC wraps around std::sqrt (a compare and a branch per root).
inline double root(double x) {
#if defined(__SSE2__)
    return _mm_cvtsd_f64(_mm_sqrt_sd(_mm_setzero_pd(), _mm_set_sd(x)));
#else
    return std::sqrt(x);
#endif
}
// popcount(u) + popcount(v) without a call: the x86-64 baseline has no
// POPCNT instruction, and GCC turns __builtin_popcountll into a call to
// libgcc's __popcountdi2 (two per run in the graph's scan: 2.9 M calls on
// 4 MP of fine seeds). Bit-parallel counts, summed in 4-bit fields.
inline int bit_count_sum(uint64_t u, uint64_t v) {
#if defined(__POPCNT__)
    return __builtin_popcountll(u) + __builtin_popcountll(v);
#else
    constexpr uint64_t m1 = 0x5555555555555555ull, m2 = 0x3333333333333333ull, m4 = 0x0F0F0F0F0F0F0F0Full;
    u -= (u >> 1) & m1, v -= (v >> 1) & m1;
    u = (u & m2) + ((u >> 2) & m2), v = (v & m2) + ((v >> 2) & m2);  // 4-bit fields of at most 4 each
    uint64_t s = u + v;                                               // at most 8: still fits
    s = (s & m4) + ((s >> 4) & m4);                                   // bytes of at most 16
    return static_cast<int>((s * 0x0101010101010101ull) >> 56);
#endif
}
// bit_count_sum of a run's two masks (bits r0 .. r1 - 1 at most set): a run
// of 16 pixels or fewer (nearly all: 2.8 pixels on average with the finest
// seeds) is counted by four lookups in a byte table after a shift, instead
// of the 64-bit bit-parallel count.
inline int run_bit_count(uint64_t u, uint64_t v, int r0, int r1) {
    static constexpr auto kBits = [] {
        std::array<uint8_t, 256> t{};
        for (int i = 1; i < 256; ++i) t[i] = static_cast<uint8_t>(t[i / 2] + (i & 1));
        return t;
    }();
    if (r1 - r0 > 16) return bit_count_sum(u, v);
    u >>= r0, v >>= r0;  // now below 2^16
    return kBits[u & 255] + kBits[u >> 8] + kBits[v & 255] + kBits[v >> 8];
}
// Backs the pages of [p, p + bytes) (rounded out to whole pages, all in
// one mapping) in one call instead of one page fault each
// (MADV_POPULATE_WRITE, Linux 5.14 and later). A hint: where the kernel
// refuses it, the pages fault in as they are first written, as before.
inline void populate_for_write(void* p, std::size_t bytes) {
#if defined(MADV_POPULATE_WRITE)
    constexpr std::uintptr_t kPage = 4096;  // the smallest page: rounding to it never leaves the mapping
    const std::uintptr_t first = reinterpret_cast<std::uintptr_t>(p) & ~(kPage - 1);
    const std::uintptr_t last = reinterpret_cast<std::uintptr_t>(p) + bytes;
    if (bytes) ::madvise(reinterpret_cast<void*>(first), last - first, MADV_POPULATE_WRITE);
#else
    (void)p, (void)bytes;
#endif
}
// A boundary pair of the graph's build and the edges it adds: (pair key,
// shared edges), packed in 12 bytes (the pair arrays of 4 MP of fine seeds
// hold ~0.94 M of them, written once and read twice).
struct __attribute__((packed)) PairCount {
    uint64_t first;   // lower node << 32 | higher node
    uint32_t second;  // shared pixel edges
};
static_assert(sizeof(PairCount) == 12, "packed pair entries");
using merge_queue::MergeQueue;
using merge_queue::QueueEntry;
using merge_queue::uint128;

// One entry of a region's adjacency: a neighbouring node and the length of
// the shared boundary. Lists are flat arrays sorted by node.
struct Neighbour {
    uint32_t id;      // node
    uint32_t shared;  // boundary length in pixel edges
    double cost;      // fusion cost of the edge, cached by the nearest-neighbour strategies
                      // (no initialiser: the inline room is not written before the lists are filled)
};

// Region graph. A region lives in a node (storage slot); when two regions
// merge, the one with the longer adjacency list keeps its slot (so a region
// with thousands of neighbours is never copied and fewer neighbours' lists
// are rewritten), and the merged region takes the lower of the two keys
// (key = lowest input label). Keys alone decide every tie, so the merge
// sequence is the one defined in the header whatever slot a region lives in
// and however nodes are numbered.
//
// Everything the merge loop reads about a node sits in one cache-aligned
// record: NodeHead (80 bytes), Σ and Σ² per band (48 bytes for 3 bands: the
// two make two cache lines), then room for the adjacency of a typical
// region (12 neighbours for 3 bands in 320 bytes; longer lists move to a
// heap block). A cost evaluation, a nearest-neighbour offer or an adjacency
// edit touches one record per neighbour, and the records of all neighbours
// are prefetched together before they are used: the loop is bound by these
// memory reads more than by arithmetic. The shape terms l·√n and n·l/b
// are stored (set by derive() whenever n, l or the box change: a cost then
// takes 4 square roots and 2 divisions instead of 6 and 4); to keep the
// head and sums in two lines, area and perimeter are 32-bit integers (exact
// counts, converted to double where the cost uses them: the same values as
// before, bit for bit) and a dead region is one of area 0.
struct NodeHead {
    double colour = 0;             // Σ_b w_b n σ_b
    double nn_cost = INFINITY;     // cost to the nearest neighbour
    double lsq = 0, smooth = 0;    // l·√n and n·l/b (b = bounding-box perimeter), set by derive()
    uint32_t n = 0, l = 0;         // area (pixels; 0 = no region: dead or without pixels), perimeter (pixel edges)
    int32_t x0 = INT32_MAX, y0 = INT32_MAX, x1 = -1, y1 = -1;  // bounding box, pixels
    uint32_t nn = 0;               // nearest neighbour node (0 = none)
    uint32_t key = 0;              // lowest input label of the region
    uint32_t degree = 0;
    uint32_t capacity = 0;
    Neighbour* list = nullptr;     // sorted adjacency: the record's inline slots or a heap block
};

static_assert(sizeof(NodeHead) == 80, "NodeHead and 3 bands of sums fill two cache lines");

// Read-only view of a node's adjacency.
struct NeighbourSpan {
    const Neighbour* first;
    const Neighbour* last;
    const Neighbour* begin() const { return first; }
    const Neighbour* end() const { return last; }
    std::size_t size() const { return static_cast<std::size_t>(last - first); }
};

class RegionGraph {
    struct alignas(64) Line {
        Line() {}  // left uninitialised: every record is constructed in place below
        std::byte bytes[64];
    };

public:
    RegionGraph(const Image<float>& image, const Image<uint32_t>& labels, uint32_t n_regions, const RegionMergingOptions& o)
        : bands_(image.bands), n_(n_regions + 1), wc_(o.color_weight), wcmp_(o.compactness) {
        weights_.assign(bands_, 1.0 / bands_);
        if (!o.band_weights.empty()) {
            double s = 0.0;
            for (double w : o.band_weights) s += w;
            for (int b = 0; b < bands_; ++b) weights_[b] = o.band_weights[b] / s;
        }
        const std::size_t fixed_bytes = sizeof(NodeHead) + 2 * sizeof(double) * bands_;
        lines_ = (fixed_bytes + 10 * sizeof(Neighbour) + sizeof(Line) - 1) / sizeof(Line);
        inline_capacity_ = static_cast<uint32_t>((lines_ * sizeof(Line) - fixed_bytes) / sizeof(Neighbour));
        storage_.resize(static_cast<std::size_t>(n_) * lines_);
        // The records' first touch (page faults and zeroing, most of the
        // construction) needs no node numbers: it runs beside the
        // numbering, whose fast path is one thread's pass (4 MP Autzen
        // seeds with both cores free: the two 35-37 -> 30-33 ms wall).
        tbb::parallel_invoke([&] { number_nodes(labels); }, [&] { construct_records(); });
        build(image, labels);
    }

    // Node order. The merge loop reads the records of a region and of its
    // neighbours, all close together in the image; on 4 KB pages, records
    // of neighbours far apart in memory cost one TLB miss each (the dearest
    // part of a read on a virtual machine). Regions are numbered by the cell
    // of their first pixel (raster order): 8 x 8 pixel cells in Morton order
    // within blocks of 64 x 64 pixels, blocks left to right within stripes
    // of kStripe rows, stripes top to bottom; within a cell by label. A
    // region keeps its label as its key, and keys alone decide every tie, so
    // the numbering changes no result. Fills node_of_label_ and label_of_node_.
    static constexpr int kStripe = 64;
    static_assert(kStripe == 64, "blocks are 64 x 64 pixels: kStripe rows of 64-pixel-wide blocks (cell_of, build's scan)");
    void number_nodes(const Image<uint32_t>& labels) {
        const int w = labels.width, h = labels.height;
        const uint32_t* lab = labels.band_data(0);
        const int stripes = (h + kStripe - 1) / kStripe;
        const uint64_t none = UINT64_MAX;
        std::vector<std::atomic<uint64_t>> first(n_);
        for (auto& f : first) f.store(none, std::memory_order_relaxed);
        // Labels numbered in raster order of first appearance (the
        // watershed's are): a label above every one met so far is then the
        // next one, met at its first pixel, so one pass comparing each label
        // with the largest so far finds every first pixel without a search
        // of runs or atomic updates (4 MP Autzen seeds: numbering 20 -> 11
        // ms CPU, one core instead of two).
        // Any other order (or a label out of range) falls back to the
        // parallel search of runs below.
        if (first_pixels_in_raster_order(labels, first)) return finish_numbering(w, stripes, first);
        std::atomic<uint32_t> too_large{0};
        tbb::parallel_for(0, stripes, [&](int st) {
            for (int y = st * kStripe; y < std::min(h, (st + 1) * kStripe); ++y) {
                const uint32_t* row = lab + std::size_t(y) * w;
                uint32_t previous = 0;
                for (int x = 0; x < w; ++x) {
                    const uint32_t l = row[x];
                    if (l == previous) continue;
                    previous = l;
                    if (l >= n_) {
                        too_large.store(l, std::memory_order_relaxed);
                        continue;
                    }
                    const uint64_t at = uint64_t(y) << 32 | uint32_t(x);
                    uint64_t now = first[l].load(std::memory_order_relaxed);
                    while (at < now && !first[l].compare_exchange_weak(now, at, std::memory_order_relaxed)) {
                    }
                }
            }
        });
        if (too_large.load()) throw Error("region merging", "label " + std::to_string(too_large.load()) + " exceeds the region count");
        finish_numbering(w, stripes, first);
    }
    // The fast path of number_nodes: true (and `first` filled) if every
    // label of the raster is the largest met so far or the next one, in
    // raster order, and below n_; false (`first` partly written: the caller
    // searches again) otherwise.
    bool first_pixels_in_raster_order(const Image<uint32_t>& labels, std::vector<std::atomic<uint64_t>>& first) const {
        const int w = labels.width, h = labels.height;
        const uint32_t* lab = labels.band_data(0);
        uint32_t largest = 0;
        for (int y = 0; y < h; ++y) {
            const uint32_t* row = lab + std::size_t(y) * w;
            int x = 0;
#if defined(__SSE2__)
            // Four labels at a time: the rare group holding a label above
            // the largest so far is looked at one label at a time.
            const __m128i bias = _mm_set1_epi32(INT32_MIN);  // unsigned order as signed
            for (; x + 4 <= w; x += 4) {
                const __m128i v = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i*>(row + x)), bias);
                const __m128i above = _mm_cmpgt_epi32(v, _mm_set1_epi32(static_cast<int32_t>(largest ^ 0x80000000u)));
                if (!_mm_movemask_epi8(above)) continue;
                for (int k = x; k < x + 4; ++k) {
                    if (row[k] <= largest) continue;
                    if (row[k] != largest + 1 || row[k] >= n_) return false;
                    largest = row[k];
                    first[largest].store(uint64_t(y) << 32 | uint32_t(k), std::memory_order_relaxed);
                }
            }
#endif
            for (; x < w; ++x) {
                if (row[x] <= largest) continue;
                if (row[x] != largest + 1 || row[x] >= n_) return false;
                largest = row[x];
                first[largest].store(uint64_t(y) << 32 | uint32_t(x), std::memory_order_relaxed);
            }
        }
        return true;
    }
    // Nodes numbered from the first pixel of every label (number_nodes).
    void finish_numbering(int w, int stripes, const std::vector<std::atomic<uint64_t>>& first) {
        const uint64_t none = UINT64_MAX;
        const uint64_t blocks = (uint64_t(w) + 63) / 64;
        const uint64_t cells = uint64_t(stripes) * blocks * 64 + 1;  // + 1: labels without pixels, last
        auto cell_of = [&](uint32_t l) -> uint64_t {
            const uint64_t at = first[l].load(std::memory_order_relaxed);
            if (at == none) return cells - 1;
            const uint32_t y = static_cast<uint32_t>(at >> 32), x = static_cast<uint32_t>(at);
            const uint32_t cx = (x >> 3) & 7, cy = (y % kStripe) >> 3;
            // Morton code of the cell within its block: the 3 bits of cx at
            // even positions, those of cy at odd ones
            static constexpr uint8_t spread[8] = {0, 1, 4, 5, 16, 17, 20, 21};
            const uint32_t m = spread[cx] | uint32_t(spread[cy]) << 1;
            return (uint64_t(y / kStripe) * blocks + x / 64) * 64 + m;
        };
        std::vector<uint32_t> start(cells + 1, 0);
        for (uint32_t l = 1; l < n_; ++l) ++start[cell_of(l) + 1];
        for (uint64_t c = 0; c < cells; ++c) start[c + 1] += start[c];
        nodes_above_stripe_.resize(stripes + 1);
        for (int s = 0; s <= stripes; ++s) nodes_above_stripe_[s] = start[uint64_t(s) * blocks * 64];
        blocks_per_stripe_ = static_cast<uint32_t>(blocks);
        block_first_node_.resize(std::size_t(stripes) * blocks + 1);
        for (std::size_t k = 0; k < block_first_node_.size(); ++k) block_first_node_[k] = 1 + start[k * 64];
        node_of_label_.assign(n_, 0);
        label_of_node_.assign(n_, 0);
        for (uint32_t l = 1; l < n_; ++l) {
            const uint32_t node = 1 + start[cell_of(l)]++;
            node_of_label_[l] = node, label_of_node_[node] = l;
        }
    }

    // Integer accumulators of a region, in 64-bit words: area, perimeter,
    // x0, y0, x1, y1, Σq per band, then Σq² per band as (low, high) halves
    // of a 128-bit sum. They live in the room of the record's inline
    // adjacency (not yet used; 120 of 176 bytes for 3 bands), so no
    // per-thread copies of all regions' totals are allocated; with many
    // bands, beside the records (outside_acc_).
    std::size_t acc_words() const { return 6 + 3 * static_cast<std::size_t>(bands_); }
    bool acc_in_record() const { return acc_words() * sizeof(int64_t) <= inline_capacity_ * sizeof(Neighbour); }
    void init_accumulators(int64_t* A) const {
        std::fill(A, A + acc_words(), 0);
        A[2] = A[3] = INT32_MAX, A[4] = A[5] = -1;
    }
    // The records constructed, each written once before the scan (its
    // head, its accumulators) and once after it (build). Each task backs
    // its range's pages first, in one call (populate_for_write): 341,401
    // records (109 MB) took 57 -> 48 ms CPU with the numbering beside them,
    // graph CPU -6 to -9.5 ms paired in three sets of 14-16 alternating runs
    // (session 20).
    void construct_records() {
        const std::size_t words = acc_words();
        const bool in_record = acc_in_record();
        if (!in_record) outside_acc_ = LargeVector<int64_t>(std::size_t(n_) * words);
        tbb::parallel_for(tbb::blocked_range<uint32_t>(0, n_, 1 << 14), [&](const tbb::blocked_range<uint32_t>& rr) {
            populate_for_write(head_ptr(rr.begin()), std::size_t(rr.size()) * lines_ * sizeof(Line));
            for (uint32_t r = rr.begin(); r != rr.end(); ++r) {
                NodeHead* R = new (head_ptr(r)) NodeHead();
                R->list = nullptr, R->capacity = 0;  // the inline list is constructed after the scan
                init_accumulators(in_record ? new (inline_bytes(r)) int64_t[words] : outside_acc_.data() + std::size_t(r) * words);
            }
        });
    }

    // Region statistics and adjacency from the label raster, in parallel over
    // row blocks. Band values are accumulated as exact integers (fixed point,
    // 2^-k grey levels) so the totals do not depend on how rows were split
    // between threads: same labels and image -> same statistics, bit for bit.
    void build(const Image<float>& image, const Image<uint32_t>& labels) {
        const int w = labels.width, h = labels.height;
        const uint32_t* lab = labels.band_data(0);
        const uint32_t* node = node_of_label_.data();  // label -> node (number_nodes)
        // The largest |v| (NaN values left out, as std::max(m, |v|) leaves
        // them out) and whether any value is NaN, four lanes at a time.
        struct Extent {
            float max_abs = 0.0f;
            bool nan = false;
        };
        const Extent extent = tbb::parallel_reduce(
            tbb::blocked_range<std::size_t>(0, image.data.size(), 1 << 16), Extent{},
            [&](const tbb::blocked_range<std::size_t>& r, Extent e) {
                std::size_t i = r.begin();
                float m = e.max_abs;
#if defined(__SSE2__)
                // max(|v|, m) takes m when v is NaN, as std::max(m, |v|) does.
                const __m128 sign = _mm_set1_ps(-0.0f);
                __m128 m4 = _mm_set1_ps(m), nan4 = _mm_setzero_ps();
                for (; i + 4 <= r.end(); i += 4) {
                    const __m128 v = _mm_loadu_ps(image.data.data() + i);
                    m4 = _mm_max_ps(_mm_andnot_ps(sign, v), m4);
                    nan4 = _mm_or_ps(nan4, _mm_cmpunord_ps(v, v));
                }
                alignas(16) float lanes[4];
                _mm_store_ps(lanes, m4);
                for (float v : lanes) m = std::max(m, v);
                e.nan = e.nan || _mm_movemask_ps(nan4) != 0;
#endif
                for (; i != r.end(); ++i) m = std::max(m, std::abs(image.data[i])), e.nan = e.nan || std::isnan(image.data[i]);
                e.max_abs = m;
                return e;
            },
            [](Extent a, Extent b) { return Extent{std::max(a.max_abs, b.max_abs), a.nan || b.nan}; });
        const float max_abs = extent.max_abs;
        double fixed = 1.0;  // largest power of two keeping |v| * fixed <= 2^24
        while (max_abs * fixed * 2.0 <= 16777216.0 && fixed < 65536.0) fixed *= 2.0;
        while (max_abs * fixed > 16777216.0) fixed *= 0.5;
        // Band values as fixed-point integers q = round(v * fixed), halves
        // away from zero. With fixed >= 1 (a power of two) and no NaN, v *
        // fixed is exact in float (|v| * fixed <= 2^24) and q is found four
        // values at a time (truncation, then the rounding of the exact
        // fraction): the same integers as the double formula, bit for bit.
#if defined(__SSE2__)
        const bool quantise_rows = fixed >= 1.0 && !extent.nan;
#else
        const bool quantise_rows = false;
#endif
        const std::size_t words = acc_words();
        const bool in_record = acc_in_record();
        LargeVector<int64_t>& outside = outside_acc_;
        auto acc = [&](uint32_t r) {
            return in_record ? std::launder(reinterpret_cast<int64_t*>(inline_bytes(r))) : outside.data() + std::size_t(r) * words;
        };
        auto init_acc = [&](int64_t* A) { init_accumulators(A); };
        // Row bands (on stripe boundaries). A band owns the nodes above every
        // node of the bands before it (with nodes numbered by the stripe of
        // their first pixel, nearly all of its nodes) and adds their pixels
        // straight into the region's accumulator; no other band sees them.
        // Labels of earlier bands (regions crossing its top edge) are summed
        // in a small per-band table and added afterwards. Integer sums and
        // min/max: the totals do not depend on the split.
        const int n_bands = std::clamp(h / 32, 1, 4 * tbb::this_task_arena::max_concurrency());
        auto band_row = [&](int j) {  // on stripe boundaries (see number_nodes): each band owns its stripes' regions
            if (j >= n_bands) return h;
            return std::min(h, static_cast<int>(static_cast<int64_t>(h) * j / n_bands + kStripe / 2) / kStripe * kStripe);
        };
        struct Band {
            uint32_t owned_from = 0;                           // labels >= this are owned
            std::vector<std::pair<uint32_t, std::size_t>> foreign_index;  // (label, offset in foreign), unsorted
            std::vector<int64_t> foreign;
            std::vector<uint32_t> slot;                        // small open-addressing table: label -> entry + 1
            std::vector<PairCount> pairs;                      // (pair key, shared edges)
        };
        std::vector<Band> band_data(n_bands);
        // Band j owns the nodes whose first pixel is in its rows (numbered
        // after all those of earlier rows: number_nodes).
        for (int j = 1; j < n_bands; ++j) band_data[j].owned_from = nodes_above_stripe_[(band_row(j) + kStripe - 1) / kStripe] + 1;
        tbb::parallel_for(0, n_bands, [&](int j) {
            Band& B = band_data[j];
            // Room for the band's boundary pairs up front (about half a pair
            // per pixel with the finest seeds): pages never written are never
            // backed, and the array is not copied as it grows.
            B.pairs.reserve(std::size_t(band_row(j + 1) - band_row(j)) * std::size_t(w) * 3 / 4 + 64);
            // Two regions meet on many rows: a pair met recently (a small
            // direct-mapped table of pair -> entry) adds to its entry instead
            // of a new one (4 MP Autzen seeds: 2.22 M entries -> 0.94 M, 0.92 M distinct).
            constexpr int kRecentBits = 12;
            std::vector<uint64_t> recent_key(std::size_t(1) << kRecentBits, UINT64_MAX);
            std::vector<std::size_t> recent_entry(std::size_t(1) << kRecentBits, 0);
            auto foreign_acc = [&](uint32_t a) {
                if (B.slot.empty()) B.slot.assign(1024, 0);
                std::size_t mask = B.slot.size() - 1, i = (a * 2654435761u) & mask;
                while (B.slot[i] && B.foreign_index[B.slot[i] - 1].first != a) i = (i + 1) & mask;
                if (!B.slot[i]) {
                    B.foreign_index.push_back({a, B.foreign.size()});
                    B.foreign.resize(B.foreign.size() + words);
                    init_acc(B.foreign.data() + B.foreign_index.back().second);
                    B.slot[i] = static_cast<uint32_t>(B.foreign_index.size());
                    if (2 * B.foreign_index.size() > B.slot.size()) {  // grow and rehash
                        B.slot.assign(2 * B.slot.size(), 0);
                        mask = B.slot.size() - 1;
                        for (std::size_t e = 0; e < B.foreign_index.size(); ++e) {
                            std::size_t k = (B.foreign_index[e].first * 2654435761u) & mask;
                            while (B.slot[k]) k = (k + 1) & mask;
                            B.slot[k] = static_cast<uint32_t>(e + 1);
                        }
                    }
                    return B.foreign.data() + B.foreign_index.back().second;
                }
                return B.foreign.data() + B.foreign_index[B.slot[i] - 1].second;
            };
            // By blocks of kStripe x kStripe pixels, as the nodes are
            // numbered (number_nodes): the accumulators (cold: first read
            // here) of the next block's own nodes are loaded while this
            // block is scanned, a slice per row (loading a few nodes ahead
            // of the first one met did not hide the misses: nodes are in
            // Morton order of 8 x 8 cells, a row meets them out of order,
            // and 28 % of the scan waited on these loads; 4 MP Autzen seeds:
            // scan 113 -> 90 ms CPU), and the few hundred records a block
            // adds to stay in cache while its rows are read.
            // A run's sums are kept in registers for the usual band counts
            // (Bands > 0; 0 = any count), its Σq² in 64 bits (|q| <= 2^24
            // and a run has at most kStripe pixels: < 2^55), added to the
            // region's 128-bit total once per run.
            constexpr int kRowsAhead = 2;
            const uint32_t owned_end = j + 1 < n_bands ? band_data[j + 1].owned_from : n_;
            // acc() with its base and stride in locals: the scan's stores into
            // accumulators (int64) could alias the members acc() reads, so
            // the compiler reloaded them for every run.
            const uint32_t owned_from = B.owned_from;
            std::byte* const acc_base = in_record ? inline_bytes(0) : reinterpret_cast<std::byte*>(outside.data());
            const std::size_t acc_stride = in_record ? lines_ * sizeof(Line) : words * sizeof(int64_t);
            auto own_acc = [acc_base, acc_stride](uint32_t r) {
                return std::launder(reinterpret_cast<int64_t*>(acc_base + std::size_t(r) * acc_stride));
            };
            auto scan = [&](auto bands_tag) {
                constexpr int Bands = decltype(bands_tag)::value;
                const int nb = Bands ? Bands : bands_;
                std::vector<const float*> band_ptrs(nb);
                for (int b = 0; b < nb; ++b) band_ptrs[b] = image.band_data(b);
                const float* const* band_ptr = band_ptrs.data();
                // What the per-run code reads of the captures, as locals: the
                // scan is a function of its own (not inlined into the band's
                // task), and its stores into accumulators and pair entries
                // could alias what the captures point at, so every use
                // reloaded them through the closure.
                const uint32_t* const node_of = node;
                const auto acc_of = own_acc;
                const uint32_t own_from = owned_from, own_end = owned_end;
                uint64_t* const recent_k = recent_key.data();
                std::size_t* const recent_e = recent_entry.data();
                auto add_pair = [&](uint64_t k) {  // the table's arrays in locals
                    const std::size_t slot = static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ull) >> (64 - kRecentBits));
                    if (recent_k[slot] == k) {
                        ++B.pairs[recent_e[slot]].second;
                    } else {
                        recent_k[slot] = k, recent_e[slot] = B.pairs.size();
                        B.pairs.push_back({k, 1});
                    }
                };
                std::vector<int64_t> wide(Bands ? 0 : 2 * std::size_t(nb));  // a run's sums, any band count
                bool first_block = true;
                // With quantise_rows, a stripe's band values are quantised
                // first, row by row (the hardware streams whole rows; the
                // blocks' short rows it does not), into this buffer the
                // blocks then read from cache.
                // (not zeroed: every row is written before a block reads it)
                const std::size_t quantised_size = Bands > 0 && quantise_rows ? std::size_t(nb) * kStripe * std::size_t(w) : 0;
                const std::unique_ptr<int32_t[]> quantised_buffer(quantised_size ? new int32_t[quantised_size] : nullptr);
                int32_t* const quantised = quantised_buffer.get();  // null: not quantised
                for (int ys = band_row(j); ys < band_row(j + 1); ys += kStripe) {
#if defined(__SSE2__)
                if (quantised) {
                    const __m128 f4 = _mm_set1_ps(static_cast<float>(fixed));
                    const __m128 half = _mm_set1_ps(0.5f), minus_half = _mm_set1_ps(-0.5f);
                    for (int y = ys; y < std::min(band_row(j + 1), ys + kStripe); ++y)
                        for (int b = 0; b < nb; ++b) {
                            const float* src = band_ptr[b] + std::size_t(y) * w;
                            int32_t* q = quantised + (std::size_t(b) * kStripe + std::size_t(y - ys)) * w;
                            int t = 0;
                            for (; t + 4 <= w; t += 4) {
                                const __m128 v = _mm_mul_ps(_mm_loadu_ps(src + t), f4);
                                const __m128i whole = _mm_cvttps_epi32(v);
                                const __m128 frac = _mm_sub_ps(v, _mm_cvtepi32_ps(whole));
                                const __m128i up = _mm_castps_si128(_mm_cmpge_ps(frac, half));         // -1 where frac >= 0.5
                                const __m128i down = _mm_castps_si128(_mm_cmple_ps(frac, minus_half));  // -1 where frac <= -0.5
                                _mm_storeu_si128(reinterpret_cast<__m128i*>(q + t), _mm_add_epi32(_mm_sub_epi32(whole, up), down));
                            }
                            for (; t < w; ++t) {
                                const double v = src[t] * fixed;
                                q[t] = static_cast<int32_t>(v + (v >= 0.0 ? 0.5 : -0.5));
                            }
                        }
                }
#endif
                for (int xs = 0; xs < w; xs += kStripe) {
                const std::size_t block = std::size_t(ys / kStripe) * blocks_per_stripe_ + std::size_t(xs / kStripe);
                // The accumulators of the block's own nodes (numbered by
                // block: number_nodes) are loaded a block ahead, a slice per
                // row, so no row waits on a burst of them; the first block
                // of the band loads its own at once.
                auto prefetch_nodes = [&](uint32_t from, uint32_t to) {
                    for (uint32_t r = std::max(from, own_from); r < std::min(to, own_end); ++r) {
                        prefetch_line(acc_of(r));
                        prefetch_line(acc_of(r) + 8);
                    }
                };
                if (first_block) prefetch_nodes(block_first_node_[block], block_first_node_[block + 1]), first_block = false;
                const uint32_t next_first = block + 1 < block_first_node_.size() ? block_first_node_[block + 1] : n_;
                const uint32_t next_count = block + 2 < block_first_node_.size() ? block_first_node_[block + 2] - next_first : 0;
                for (int y = ys; y < std::min(band_row(j + 1), ys + kStripe); ++y) {
                    prefetch_nodes(next_first + uint32_t(uint64_t(next_count) * (y - ys) / kStripe),
                                   next_first + uint32_t(uint64_t(next_count) * (y - ys + 1) / kStripe));
                    const uint32_t* row = lab + std::size_t(y) * w;
                    const uint32_t* above = y > 0 ? row - w : nullptr;
                    const uint32_t* below = y < h - 1 ? row + w : nullptr;
                    const int x_end = std::min(w, xs + kStripe);
                    // A block's rows are short (kStripe pixels, a new page
                    // each): the hardware does not stream them, so the
                    // bands and labels kRowsAhead rows down are loaded now.
                    if (y + kRowsAhead < h) {
                        const std::size_t ahead = std::size_t(y + kRowsAhead) * w;
                        for (int px = xs; px < x_end; px += 16) {
                            prefetch_line(lab + ahead + px);
                            if (!quantised)
                                for (int b = 0; b < nb; ++b) prefetch_line(band_ptr[b] + ahead + px);
                        }
                    }
                    // So are the quantised values of the block row kRowsAhead
                    // down (written for the whole stripe, they have mostly left
                    // the core's caches by the time a block reads them).
                    if (quantised && y + kRowsAhead < std::min(band_row(j + 1), ys + kStripe))
                        for (int b = 0; b < nb; ++b) {
                            const int32_t* q = quantised + (std::size_t(b) * kStripe + std::size_t(y + kRowsAhead - ys)) * w;
                            for (int px = xs; px < x_end; px += 16) prefetch_line(q + px);
                        }
                    // The block row (n <= 64 pixels) as bit masks: run starts,
                    // nodata, and pixels whose label differs above or below
                    // (and below from a region, not nodata). Runs are then
                    // found with bit scans and their perimeter by counting
                    // bits, instead of a branch per pixel that the boundaries
                    // of fine seeds make unpredictable.
                    const int n = x_end - xs;
                    uint64_t starts = 1, nodata = 0, up_diff = 0, down_diff = 0, down_pair = 0;
                    int i0 = 0;
#if defined(__SSE2__)
                    {
                        const __m128i zero4 = _mm_setzero_si128();
                        auto bits = [](__m128i eq) { return static_cast<uint64_t>(_mm_movemask_ps(_mm_castsi128_ps(eq))); };
                        for (; i0 + 4 <= n; i0 += 4) {
                            const __m128i l = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + xs + i0));
                            // lane 0 of the first group has no left neighbour in the row: a run start anyway
                            const __m128i left = xs + i0 > 0 ? _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + xs + i0 - 1))
                                                             : _mm_slli_si128(l, 4);
                            const __m128i u = above ? _mm_loadu_si128(reinterpret_cast<const __m128i*>(above + xs + i0)) : zero4;
                            const __m128i d = below ? _mm_loadu_si128(reinterpret_cast<const __m128i*>(below + xs + i0)) : zero4;
                            const uint64_t d_differs = ~bits(_mm_cmpeq_epi32(d, l)) & 15u;
                            starts |= (~bits(_mm_cmpeq_epi32(l, left)) & 15u) << i0;
                            nodata |= bits(_mm_cmpeq_epi32(l, zero4)) << i0;
                            up_diff |= (~bits(_mm_cmpeq_epi32(u, l)) & 15u) << i0;
                            down_diff |= d_differs << i0;
                            down_pair |= (d_differs & ~bits(_mm_cmpeq_epi32(d, zero4))) << i0;
                        }
                    }
#endif
                    for (; i0 < n; ++i0) {
                        const uint32_t l = row[xs + i0];
                        const uint32_t u = above ? above[xs + i0] : 0, d = below ? below[xs + i0] : 0;
                        starts |= uint64_t(i0 > 0 && l != row[xs + i0 - 1]) << i0;
                        nodata |= uint64_t(l == 0) << i0;
                        up_diff |= uint64_t(u != l) << i0;
                        down_diff |= uint64_t(d != l) << i0;
                        down_pair |= uint64_t(d != l && d != 0) << i0;
                    }
                    // Prefix sums of the row's fixed-point band values and
                    // their squares (quantise_rows): a run's sums are two
                    // differences, with no loop over its pixels.
                    int64_t prefix[Bands ? Bands : 1][2][kStripe + 1];
                    const bool prefixed = Bands > 0 && quantise_rows;
                    if constexpr (Bands > 0) {
#if defined(__SSE2__)
                        if (prefixed) {
                            for (int b = 0; b < Bands; ++b) {
                                const int32_t* q = quantised + (std::size_t(b) * kStripe + std::size_t(y - ys)) * w + xs;
                                int t = 0;
                                int64_t* ps = prefix[b][0];
                                int64_t* pq = prefix[b][1];
                                ps[0] = pq[0] = 0;
#pragma GCC unroll 4
                                for (; t < n; ++t) {
                                    const int64_t v = q[t];
                                    ps[t + 1] = ps[t] + v, pq[t + 1] = pq[t] + v * v;
                                }
                            }
                        }
#endif
                    }
                    uint64_t rest = starts;
                    int last_p = -2;  // a run of pixels over the same vertical neighbour pair collapses into one entry
                    uint64_t last_k = 0;
                    while (rest) {
                        const int r0 = __builtin_ctzll(rest);
                        rest &= rest - 1;
                        const int r1 = rest ? __builtin_ctzll(rest) : n;
                        if (nodata >> r0 & 1) continue;
                        // A run of pixels of region a within the block: x .. end - 1.
                        const int x = xs + r0, end = xs + r1;
                        const uint32_t la = row[x];  // label; a = its node
                        const uint32_t a = node_of[la];
                        const uint64_t run = (r1 == 64 ? ~uint64_t(0) : (uint64_t(1) << r1) - 1) & ~((uint64_t(1) << r0) - 1);
                        // the run's ends on the region's border (inside the block row: always), and its
                        // pixels whose upper or lower neighbour is another label
                        int64_t perimeter = (r0 > 0 || x == 0 || row[x - 1] != la) + (r1 < n || end == w || row[end] != la);
                        perimeter += run_bit_count(up_diff & run, down_diff & run, r0, r1);
                        int64_t fixed_sums[2 * (Bands ? Bands : 1)];
                        int64_t* const sum = Bands ? fixed_sums : wide.data();
                        int64_t* const sumsq = sum + nb;
                        if (prefixed) {
                            for (int b = 0; b < nb; ++b) {
                                sum[b] = prefix[Bands ? b : 0][0][r1] - prefix[Bands ? b : 0][0][r0];
                                sumsq[b] = prefix[Bands ? b : 0][1][r1] - prefix[Bands ? b : 0][1][r0];
                            }
                        } else {
                            std::fill(sum, sum + 2 * nb, int64_t(0));
                            for (int px = x; px < end; ++px) {
                                const std::size_t at = std::size_t(y) * w + px;
                                for (int b = 0; b < nb; ++b) {
                                    const double v = band_ptr[b][at] * fixed;  // round half away from zero
                                    const auto q = static_cast<int64_t>(v + (v >= 0.0 ? 0.5 : -0.5));
                                    sum[b] += q;
                                    sumsq[b] += q * q;
                                }
                            }
                        }
                        for (uint64_t p_bits = down_pair & run; p_bits; p_bits &= p_bits - 1) {
                            const int p = __builtin_ctzll(p_bits);
                            const uint64_t k = key(a, node_of[below[xs + p]]);
                            if (p == last_p + 1 && k == last_k && !B.pairs.empty() && B.pairs.back().first == k) ++B.pairs.back().second;
                            else add_pair(k);
                            last_p = p, last_k = k;
                        }
                        if (end < w && row[end] && row[end] != la) add_pair(key(a, node_of[row[end]]));
                        int64_t* A = a >= own_from ? acc_of(a) : foreign_acc(a);
                        A[0] += end - x, A[1] += perimeter;
                        A[2] = std::min<int64_t>(A[2], x), A[3] = std::min<int64_t>(A[3], y);
                        A[4] = std::max<int64_t>(A[4], end - 1), A[5] = std::max<int64_t>(A[5], y);
                        // Σq² of the run (>= 0, < 2^55) added to the 128-bit total as
                        // a low word and a carry into the high one: the same sum as
                        // the 128-bit addition, without the register spills GCC
                        // made of it (a third of this update's instructions).
                        for (int b = 0; b < nb; ++b) {
                            A[6 + b] += sum[b];
                            int64_t* half = A + 6 + nb + 2 * b;
                            const uint64_t low = static_cast<uint64_t>(half[0]);
                            const uint64_t added = low + static_cast<uint64_t>(sumsq[b]);
                            half[0] = static_cast<int64_t>(added);
                            half[1] += added < low;
                        }
                    }
                }
                }
                }
            };
            switch (bands_) {  // the band loop unrolled for the usual band counts
                case 1: scan(std::integral_constant<int, 1>{}); break;
                case 3: scan(std::integral_constant<int, 3>{}); break;
                case 4: scan(std::integral_constant<int, 4>{}); break;
                default: scan(std::integral_constant<int, 0>{});
            }
        });
        // The crossing regions' sums, band by band (integer sums: any order).
        for (Band& B : band_data) {
            for (const auto& [a, offset] : B.foreign_index) {
                int64_t* A = acc(a);
                const int64_t* F = B.foreign.data() + offset;
                A[0] += F[0], A[1] += F[1];
                A[2] = std::min(A[2], F[2]), A[3] = std::min(A[3], F[3]), A[4] = std::max(A[4], F[4]), A[5] = std::max(A[5], F[5]);
                for (int b = 0; b < bands_; ++b) {
                    A[6 + b] += F[6 + b];
                    int64_t* half = A + 6 + bands_ + 2 * b;
                    const int64_t* fh = F + 6 + bands_ + 2 * b;
                    const auto added = (static_cast<uint128>(static_cast<uint64_t>(half[0])) |
                                        static_cast<uint128>(static_cast<uint64_t>(half[1])) << 64) +
                                       (static_cast<uint128>(static_cast<uint64_t>(fh[0])) |
                                        static_cast<uint128>(static_cast<uint64_t>(fh[1])) << 64);
                    half[0] = static_cast<int64_t>(static_cast<uint64_t>(added));
                    half[1] = static_cast<int64_t>(static_cast<uint64_t>(added >> 64));
                }
            }
            std::vector<int64_t>().swap(B.foreign);
        }
        // Totals into the node records (with the region's key, whether it
        // has pixels, and its colour term); the inline adjacency gets its room back.
        alive_count_ = tbb::parallel_reduce(
            tbb::blocked_range<uint32_t>(0, n_, 1 << 14), uint32_t(0),
            [&](const tbb::blocked_range<uint32_t>& rr, uint32_t alive) {
            for (uint32_t r = rr.begin(); r != rr.end(); ++r) {
                const int64_t* A = acc(r);
                NodeHead& R = head(r);
                double* S = new (sums_ptr(r)) double[2 * static_cast<std::size_t>(bands_)];
                R.n = static_cast<uint32_t>(A[0]), R.l = static_cast<uint32_t>(A[1]);
                R.x0 = static_cast<int32_t>(A[2]), R.y0 = static_cast<int32_t>(A[3]);
                R.x1 = static_cast<int32_t>(A[4]), R.y1 = static_cast<int32_t>(A[5]);
                for (int b = 0; b < bands_; ++b) {
                    const int64_t* half = A + 6 + bands_ + 2 * b;
                    const auto sq = static_cast<int128>(static_cast<uint128>(static_cast<uint64_t>(half[0])) |
                                                        static_cast<uint128>(static_cast<uint64_t>(half[1])) << 64);
                    S[2 * b] = static_cast<double>(A[6 + b]) / fixed;
                    // (a value that fits 64 bits converts as one: the same rounding,
                    // without libgcc's 128-bit conversion call)
                    const bool fits = half[1] == (half[0] >> 63);
                    S[2 * b + 1] = (fits ? static_cast<double>(half[0]) : static_cast<double>(sq)) / (fixed * fixed);
                }
                R.list = new (inline_bytes(r)) Neighbour[inline_capacity_];
                R.capacity = inline_capacity_;
                R.key = label_of_node_[r];
                alive += R.n > 0;
                derive(r);
            }
            return alive;
            },
            [](uint32_t a, uint32_t b) { return a + b; });
        LargeVector<int64_t>().swap(outside_acc_);
        // Boundary pairs bucketed by their lower region (counting sort, no
        // comparison sort of all pairs), then each bucket sorted by the
        // higher region with its duplicate pairs summed: the result does not
        // depend on how rows were split between threads.
        struct Upper {
            uint32_t id, shared;
        };
        // Scratch arrays of the build are plain vectors (small pages): the
        // first touch of pages is what they cost, and small pages are found
        // among recently freed memory more often than fresh huge pages.
        // In parallel by bands: a band's pairs have their lower region in
        // the band's own node range (counted and placed by that band alone)
        // except for the few whose both regions reach in from earlier bands
        // (placed afterwards, in band order).
        std::vector<uint64_t> start(std::size_t(n_) + 1, 0);
        std::vector<std::vector<PairCount>> crossing(n_bands);
        tbb::parallel_for(0, n_bands, [&](int j) {
            const uint64_t own = band_data[j].owned_from;
            for (const auto& q : band_data[j].pairs) {
                if ((q.first >> 32) >= own) ++start[(q.first >> 32) + 1];
                else crossing[j].push_back(q);
            }
        });
        for (const auto& c : crossing)
            for (const auto& q : c) ++start[(q.first >> 32) + 1];
        for (uint32_t r = 0; r < n_; ++r) start[r + 1] += start[r];
        std::vector<Upper> upper(start[n_]);
        // start[r] serves as r's fill cursor (it ends at start[r + 1]; shifted back below).
        tbb::parallel_for(0, n_bands, [&](int j) {
            const uint64_t own = band_data[j].owned_from;
            for (const auto& q : band_data[j].pairs)
                if ((q.first >> 32) >= own) upper[start[q.first >> 32]++] = {static_cast<uint32_t>(q.first & 0xFFFFFFFFu), q.second};
            std::vector<PairCount>().swap(band_data[j].pairs);
        });
        for (const auto& c : crossing)
            for (const auto& q : c) upper[start[q.first >> 32]++] = {static_cast<uint32_t>(q.first & 0xFFFFFFFFu), q.second};
        for (uint32_t r = n_; r > 0; --r) start[r] = start[r - 1];
        start[0] = 0;
        // Each bucket sorted by the higher region, duplicates summed; by
        // chunks of lower regions, each counting how many lower neighbours
        // it gives every region. A list is then its lower neighbours, chunk
        // by chunk, each chunk's in ascending order (so sorted, whatever
        // thread wrote them), then its own bucket.
        const int chunks = std::clamp(tbb::this_task_arena::max_concurrency(), 1, 8);
        auto chunk_begin = [&](int c) { return static_cast<uint32_t>(uint64_t(n_) * uint64_t(c) / uint64_t(chunks)); };
        std::vector<uint32_t> unique(n_, 0);
        std::vector<std::vector<uint32_t>> from_chunk(chunks);  // lower neighbours given per region, then slots
        std::vector<uint64_t> chunk_pairs(chunks, 0);           // distinct pairs whose lower region is in the chunk
        tbb::parallel_for(0, chunks, [&](int c) {
            std::vector<uint32_t>& count = from_chunk[c];
            count.assign(n_, 0);
            for (uint32_t r = chunk_begin(c); r < chunk_begin(c + 1); ++r) {
                Upper* first = upper.data() + start[r];
                Upper* last = upper.data() + start[r + 1];
                if (last - first > 32) std::sort(first, last, [](const Upper& p, const Upper& q) { return p.id < q.id; });
                else  // most buckets hold a handful of pairs
                    for (Upper* i = first + 1; i < last; ++i)
                        for (Upper* j = i; j > first && (j - 1)->id > j->id; --j) std::swap(*j, *(j - 1));
                Upper* out = first;
                for (Upper* i = first; i < last; ++i) {
                    if (out != first && (out - 1)->id == i->id) (out - 1)->shared += i->shared;
                    else *out++ = *i;
                }
                unique[r] = static_cast<uint32_t>(out - first);
                chunk_pairs[c] += unique[r];
                for (const Upper* i = first; i != out; ++i) ++count[i->id];
            }
        });
        adjacent_pairs_ = 0;
        for (uint64_t p : chunk_pairs) adjacent_pairs_ += p;
        // Per region: each chunk's count turned into the chunk's first slot,
        // and the number of lower neighbours (a list is they, then the
        // region's own bucket); a list longer than the record's room gets
        // its heap block here, before any chunk writes into it (the others
        // are in the records, which this pass does not touch).
        std::vector<uint32_t> lower_count(n_);
        // 1 if no lower neighbour of the region lies in an earlier chunk than
        // its own: its list is then complete when its chunk reaches it
        std::vector<uint8_t> complete_in_chunk(n_);
        std::vector<uint32_t> chunk_bounds(chunks + 1);
        for (int c = 0; c <= chunks; ++c) chunk_bounds[c] = chunk_begin(c);
        tbb::combinable<std::vector<uint32_t>> long_lists;  // regions given a heap block here
        tbb::parallel_for(tbb::blocked_range<uint32_t>(0, n_, 1 << 12), [&](const tbb::blocked_range<uint32_t>& rr) {
            for (uint32_t r = rr.begin(); r != rr.end(); ++r) {
                uint32_t lower = 0;
                for (int c = 0; c < chunks; ++c) {
                    const uint32_t k = from_chunk[c][r];
                    from_chunk[c][r] = lower;
                    if (r >= chunk_bounds[c] && r < chunk_bounds[c + 1]) complete_in_chunk[r] = lower == 0;
                    lower += k;
                }
                lower_count[r] = lower;
                if (lower + unique[r] > inline_capacity_) {
                    grow(r, lower + unique[r]);
                    long_lists.local().push_back(r);
                }
            }
        });
        long_lists.combine_each([&](const std::vector<uint32_t>& v) { heap_owners_.insert(heap_owners_.end(), v.begin(), v.end()); });
        // By chunks of lower regions: each bucket copied in with the fusion
        // cost of each edge (scored once, by the lower region; cost() is
        // symmetric bit for bit), and the same entry given to the higher
        // region at its slot for the chunk while that region's record is
        // in cache for the cost (one pass instead of a second one that
        // loads every higher region's record again; 4 MP Autzen seeds: list
        // fill and lower entries 47 -> 32 ms CPU).
        // Each region's nearest neighbour is found (rescan_nn) as soon as
        // its list is complete, while its record is in cache: at its own
        // turn when all its lower neighbours are in its chunk (nearly all
        // regions), else after the pass.
        constexpr uint32_t kScoreAhead = 4;
        tbb::combinable<std::vector<uint32_t>> later;  // regions with lower neighbours in earlier chunks
        tbb::parallel_for(0, chunks, [&](int c) {
            std::vector<uint32_t>& slot = from_chunk[c];
            const uint32_t chunk_end = chunk_begin(c + 1);
            for (uint32_t a = chunk_begin(c); a < chunk_end; ++a) {
                // The records scored kScoreAhead regions on (their higher
                // neighbours' heads, sums and first list line) start loading now.
                if (a + kScoreAhead < chunk_end)
                    for (const Upper* i = upper.data() + start[a + kScoreAhead]; i != upper.data() + start[a + kScoreAhead + 1]; ++i)
                        prefetch_node(i->id, 3);
                NodeHead& A = head(a);
                A.degree = lower_count[a] + unique[a];
                Neighbour* out = A.list + lower_count[a];
                for (const Upper* i = upper.data() + start[a]; i != upper.data() + start[a] + unique[a]; ++i) {
                    const double c_ab = cost(a, i->id, i->shared);
                    *out++ = {i->id, i->shared, c_ab};
                    head(i->id).list[slot[i->id]++] = {a, i->shared, c_ab};
                }
                if (complete_in_chunk[a]) rescan_nn(a);
                else later.local().push_back(a);
            }
        });
        later.combine_each([&](const std::vector<uint32_t>& v) {
            for (uint32_t a : v) rescan_nn(a);
        });
    }

    static uint64_t key(uint32_t a, uint32_t b) {
        return a < b ? (uint64_t(a) << 32 | b) : (uint64_t(b) << 32 | a);
    }
    uint32_t size() const { return n_; }
    // Edges of the initial adjacency graph (distinct pairs of adjacent regions).
    uint64_t adjacent_pairs() const { return adjacent_pairs_; }
    uint32_t alive_count() const { return alive_count_; }
    bool alive(uint32_t r) const { return head(r).n > 0; }
    // Cost cached on a's side of edge (a, b); NaN if they are not adjacent.
    double edge_cost(uint32_t a, uint32_t b) {
        NodeHead& A = head(a);
        const Neighbour* it = find(A, b);
        return it != A.list + A.degree && it->id == b ? it->cost : std::nan("");
    }
    uint32_t key_of(uint32_t r) const { return head(r).key; }
    NeighbourSpan neighbours(uint32_t r) const { return {head(r).list, head(r).list + head(r).degree}; }
    // Starts loading the records of r's neighbours (they are about to be read).
    void prefetch_node(uint32_t r, int lines) const {
        const std::byte* p = storage_[static_cast<std::size_t>(r) * lines_].bytes;
        for (int l = 0; l < lines; ++l) prefetch_line(p + l * sizeof(Line));
    }
    // Starts loading the records of r's first kPrefetchAhead neighbours
    // (at most: a region of thousands of neighbours would evict its own
    // lines before they are used, and a stale queue entry of such a region
    // would cost thousands of loads for nothing) into the second-level
    // cache: they are read one merge later, and the ~80 lines of a pair's
    // neighbourhood requested into the first level at once would stall the
    // loop on full miss buffers (a third of the loop's samples sat on these
    // prefetches). 341,401 seeds: merging thread 0.33-0.35 -> 0.28-0.30 s CPU.
    static constexpr uint32_t kPrefetchAhead = 16;
    void prefetch_neighbours(uint32_t r) const {
        switch (lines_) {  // the line loop unrolled for the usual record sizes (1 band: 4 lines; 3 or 4 bands: 5)
            case 4: return prefetch_neighbours_lines<4>(r);
            case 5: return prefetch_neighbours_lines<5>(r);
            default: return prefetch_neighbours_lines<0>(r);
        }
    }
    template <std::size_t Lines>  // 0 = lines_
    void prefetch_neighbours_lines(uint32_t r) const {
        const std::size_t lines = Lines ? Lines : lines_;
        const NeighbourSpan list = neighbours(r);
        const Neighbour* end = list.first + std::min<std::size_t>(list.size(), kPrefetchAhead);
        for (const Neighbour* k = list.first; k != end; ++k) {
            const std::byte* p = storage_[static_cast<std::size_t>(k->id) * lines].bytes;
            for (std::size_t l = 0; l < lines; ++l) prefetch_line_l2(p + l * sizeof(Line));
        }
    }
    // Only regions that were given a heap block can hold one (a walk of
    // every record here cost 4 ms on 341,401 regions).
    ~RegionGraph() {
        for (uint32_t r : heap_owners_) release(r);
    }
    RegionGraph(const RegionGraph&) = delete;
    RegionGraph& operator=(const RegionGraph&) = delete;

    // Baatz–Schäpe fusion cost of two adjacent regions sharing `shared`
    // pixel edges. Symmetric in (a, b) bit for bit.
    [[gnu::always_inline]] double cost(uint32_t a, uint32_t b, uint32_t shared) const {
        switch (bands_) {  // the band loop unrolled for the usual band counts
            case 1: return cost_bands<1>(a, b, shared);
            case 3: return cost_bands<3>(a, b, shared);
            case 4: return cost_bands<4>(a, b, shared);
            default: return cost_bands<0>(a, b, shared);
        }
    }
    template <int Bands>  // 0 = bands_
    [[gnu::always_inline]] double cost_bands(uint32_t a, uint32_t b, uint32_t shared) const {
        const int bands = Bands ? Bands : bands_;
        const NodeHead& A = head(a);
        const NodeHead& B = head(b);
        const double* SA = sums(a);
        const double* SB = sums(b);
        const double nm = double(A.n) + double(B.n);
        const double inv = 1.0 / nm;
        double hc = 0.0;
        int k = 0;
#if defined(__SSE2__)
        // Two bands at a time in the lanes of SSE2 registers: the same
        // operations on the same values as the scalar loop below, so the
        // same doubles (max(var, 0) gives +0 for NaN, -0 and 0 as
        // std::max(0.0, var) does; the sums into hc stay in band order).
        const __m128d iv = _mm_set1_pd(inv);
        for (; k + 2 <= bands; k += 2) {
            const __m128d p0 = _mm_add_pd(_mm_loadu_pd(SA + 2 * k), _mm_loadu_pd(SB + 2 * k));          // Σ, Σ² of band k
            const __m128d p1 = _mm_add_pd(_mm_loadu_pd(SA + 2 * k + 2), _mm_loadu_pd(SB + 2 * k + 2));  // of band k + 1
            const __m128d m = _mm_mul_pd(_mm_unpacklo_pd(p0, p1), iv);
            const __m128d var = _mm_sub_pd(_mm_mul_pd(_mm_unpackhi_pd(p0, p1), iv), _mm_mul_pd(m, m));
            const __m128d r = _mm_mul_pd(_mm_loadu_pd(weights_.data() + k), _mm_sqrt_pd(_mm_max_pd(var, _mm_setzero_pd())));
            hc += _mm_cvtsd_f64(r);
            hc += _mm_cvtsd_f64(_mm_unpackhi_pd(r, r));
        }
#endif
        for (; k < bands; ++k) {
            const double m = (SA[2 * k] + SB[2 * k]) * inv;
            const double var = (SA[2 * k + 1] + SB[2 * k + 1]) * inv - m * m;
            hc += weights_[k] * root(std::max(0.0, var));
        }
        hc = hc * nm - (A.colour + B.colour);
        if (wc_ >= 1.0) return hc;
        const double lm = double(A.l) + double(B.l) - 2.0 * shared;
        const double bbm = 2.0 * ((std::max(A.x1, B.x1) - std::min(A.x0, B.x0) + 1) + (std::max(A.y1, B.y1) - std::min(A.y0, B.y0) + 1));
        const double h_cmpct = lm * root(nm) - (A.lsq + B.lsq);
        const double h_smooth = nm * lm / bbm - (A.smooth + B.smooth);
        return wc_ * hc + (1.0 - wc_) * (wcmp_ * h_cmpct + (1.0 - wcmp_) * h_smooth);
    }

    // Nearest neighbour of r (lowest (cost, key)) from the cached edge costs
    // (exact: build() caches each edge's cost on both sides, and an edge's
    // cost changes only when one of its regions merges, when merge()
    // rewrites it on both sides). build() finds every region's first one
    // as soon as its list is complete.
    void rescan_nn(uint32_t r) {
        uint32_t best = 0, best_key = UINT32_MAX;  // best_key loaded only on a tie
        double best_cost = INFINITY;
        for (const Neighbour& k : neighbours(r)) {
            if (k.cost < best_cost) {
                best = k.id, best_cost = k.cost, best_key = UINT32_MAX;
            } else if (k.cost == best_cost) {
                if (best_key == UINT32_MAX) best_key = key_of(best);
                if (key_of(k.id) < best_key) best = k.id, best_key = key_of(k.id);
            }
        }
        set_nn(r, best, best_cost);
    }
    // Makes `candidate` r's nearest neighbour if it beats the current one on (cost, key).
    bool offer_candidate(uint32_t r, uint32_t candidate, double c) {
        NodeHead& R = head(r);
        if (c < R.nn_cost || (c == R.nn_cost && (R.nn == 0 || key_of(candidate) < key_of(R.nn)))) {
            R.nn = candidate, R.nn_cost = c;
            return true;
        }
        return false;
    }
    void set_nn(uint32_t r, uint32_t best, double c) { head(r).nn = best, head(r).nn_cost = c; }
    uint32_t nn(uint32_t r) const { return head(r).nn; }
    double nn_cost(uint32_t r) const { return head(r).nn_cost; }

    // Merges regions a and b; returns the node m of the merged region. In
    // the same pass over m's neighbours (each neighbour's record is read
    // once): the new fusion cost of every edge of m, cached on both sides;
    // the neighbours' lists (t replaced by s); m's nearest neighbour; and,
    // with `track_nn`, the neighbours whose nearest neighbour was a or b get
    // a fresh one (rescan_nn) and go to `rescan`, those whose nearest
    // neighbour became m to `changed`.
    // Aligned to a cache line: where its loop falls otherwise moves with
    // the code before it, and that alone moved the merging thread by ~7 ms
    // (+2.7 %) on 341,401 seeds between builds that changed only the scan.
    [[gnu::aligned(64)]] uint32_t merge(uint32_t a, uint32_t b, bool track_nn, std::vector<uint32_t>& changed, std::vector<uint32_t>& rescan) {
        const uint32_t s = head(a).degree >= head(b).degree ? a : b;  // survivor slot
        const uint32_t t = s == a ? b : a;                            // dies
        // The records of both lists' neighbours are read below (scored, and
        // their lists edited): the first kPrefetchAhead were loaded into
        // L2 when the pair was next in the queue (merge_regions), the rest
        // are loaded kPrefetchAhead entries ahead of use.
        prefetch_neighbours(t), prefetch_neighbours(s);
        NodeHead& S = head(s);
        NodeHead& T = head(t);
        const uint32_t shared = find(S, t)->shared;
        double* SS = sums(s);
        const double* ST = sums(t);
        S.n = S.n + T.n;  // < 2^32: merge_regions refuses larger images
        for (int k = 0; k < 2 * bands_; ++k) SS[k] = SS[k] + ST[k];
        S.l = S.l + T.l - 2 * shared;  // every shared edge is on both perimeters: >= 0
        S.x0 = std::min(S.x0, T.x0), S.x1 = std::max(S.x1, T.x1);
        S.y0 = std::min(S.y0, T.y0), S.y1 = std::max(S.y1, T.y1);
        derive(s);
        S.key = std::min(S.key, T.key);
        // Union of the two sorted lists without s and t; for each neighbour
        // K: the cost of (m, K), and K's entry for t moved to s (one shift
        // within its sorted list) or summed into its entry for s.
        scratch_.clear();
        scratch_.reserve(std::size_t(S.degree) + T.degree);
        uint32_t best = 0, best_key = UINT32_MAX;
        double best_cost = INFINITY;
        const Neighbour *is = S.list, *it = T.list;
        const Neighbour *es = S.list + S.degree, *et = T.list + T.degree;
        const Neighbour *ps = is + std::min<std::size_t>(S.degree, kPrefetchAhead);
        const Neighbour *pt = it + std::min<std::size_t>(T.degree, kPrefetchAhead);
        while (is != es || it != et) {
            if (ps != es && ps < is + kPrefetchAhead) prefetch_node((ps++)->id, static_cast<int>(lines_));
            if (pt != et && pt < it + kPrefetchAhead) prefetch_node((pt++)->id, static_cast<int>(lines_));
            Neighbour next;
            int from;  // 1 = s only, 2 = t only, 3 = both
            if (it == et || (is != es && is->id < it->id)) next = *is++, from = 1;
            else if (is == es || it->id < is->id) next = *it++, from = 2;
            else next = {is->id, is->shared + it->shared, 0.0}, ++is, ++it, from = 3;
            if (next.id == s || next.id == t) continue;
            const double c = next.cost = cost(s, next.id, next.shared);
            NodeHead& K = head(next.id);
            Neighbour* const end = K.list + K.degree;
            if (from == 1) {
                find(K, s)->cost = c;
            } else {
                Neighbour* it_t = find(K, t);
                Neighbour* it_s = find(K, s);  // with from == 2: where s goes
                if (from == 3) {
                    it_s->shared += it_t->shared, it_s->cost = c;
                    std::move(it_t + 1, end, it_t);
                    --K.degree;
                } else {
                    const Neighbour moved{s, it_t->shared, c};
                    if (it_s <= it_t) std::move_backward(it_s, it_t, it_t + 1), *it_s = moved;
                    else std::move(it_t + 1, it_s, it_t), *(it_s - 1) = moved;
                }
            }
            if (c < best_cost || (c == best_cost && K.key < best_key)) best = next.id, best_cost = c, best_key = K.key;
            if (track_nn) {
                // A neighbour that pointed at the merged pair always needs a
                // fresh nearest neighbour (and entry): found now (its list
                // is final), and the record of that neighbour, which its
                // queue offer reads after the merge, starts loading.
                if (K.nn == a || K.nn == b) {
                    rescan_nn(next.id);
                    prefetch_node(K.nn, 1);
                    rescan.push_back(next.id);
                } else if (offer_candidate(next.id, s, c)) changed.push_back(next.id);
            }
            scratch_.push_back(next);
        }
        reserve(s, static_cast<uint32_t>(scratch_.size()));
        std::copy(scratch_.begin(), scratch_.end(), S.list);
        S.degree = static_cast<uint32_t>(scratch_.size());
        set_nn(s, best, best_cost);
        release(t);
        T.n = 0;  // dead
        --alive_count_;
        return s;
    }

    // Invariants of the graph: totals over alive regions equal the totals of
    // the initial regions, adjacency is sorted and symmetric with equal shared lengths.
    void verify(const std::vector<double>& totals) const {
        std::vector<double> now(totals.size(), 0.0);
        for (uint32_t r = 1; r < n_; ++r) {
            if (!alive(r)) {
                if (head(r).degree) throw Error("region merging", "dead region " + std::to_string(r) + " still has neighbours");
                continue;
            }
            now[0] += head(r).n;
            for (int b = 0; b < bands_; ++b) now[1 + b] += sums(r)[2 * b], now[1 + bands_ + b] += sums(r)[2 * b + 1];
            const NeighbourSpan list = neighbours(r);
            for (std::size_t i = 0; i < list.size(); ++i) {
                const Neighbour& k = list.first[i];
                if (i > 0 && !(list.first[i - 1].id < k.id)) throw Error("region merging", "adjacency of " + std::to_string(r) + " is not sorted");
                if (!alive(k.id)) throw Error("region merging", "region " + std::to_string(r) + " borders a dead region");
                const NeighbourSpan other = neighbours(k.id);
                const auto it = std::lower_bound(other.begin(), other.end(), r, [](const Neighbour& q, uint32_t id) { return q.id < id; });
                if (it == other.end() || it->id != r || it->shared != k.shared)
                    throw Error("region merging", "adjacency of " + std::to_string(r) + " and " + std::to_string(k.id) + " is not symmetric");
            }
        }
        for (std::size_t i = 0; i < totals.size(); ++i)
            if (std::abs(now[i] - totals[i]) > 1e-9 * std::max(1.0, std::abs(totals[i])))
                throw Error("region merging", "region statistics no longer add up to the image totals");
    }
    std::vector<double> totals() const {
        std::vector<double> t(1 + 2 * static_cast<std::size_t>(bands_), 0.0);
        for (uint32_t r = 1; r < n_; ++r) {
            if (!alive(r)) continue;
            t[0] += head(r).n;
            for (int b = 0; b < bands_; ++b) t[1 + b] += sums(r)[2 * b], t[1 + bands_ + b] += sums(r)[2 * b + 1];
        }
        return t;
    }

private:
    std::byte* head_ptr(uint32_t r) { return storage_[static_cast<std::size_t>(r) * lines_].bytes; }
    std::byte* sums_ptr(uint32_t r) { return head_ptr(r) + sizeof(NodeHead); }
    NodeHead& head(uint32_t r) { return *std::launder(reinterpret_cast<NodeHead*>(head_ptr(r))); }
    const NodeHead& head(uint32_t r) const {
        return *std::launder(reinterpret_cast<const NodeHead*>(storage_[static_cast<std::size_t>(r) * lines_].bytes));
    }
    double* sums(uint32_t r) { return std::launder(reinterpret_cast<double*>(sums_ptr(r))); }
    const double* sums(uint32_t r) const {
        return std::launder(reinterpret_cast<const double*>(storage_[static_cast<std::size_t>(r) * lines_].bytes + sizeof(NodeHead)));
    }
    // First entry of h's list with id >= `id` (std::lower_bound's answer).
    // Without branches on the ids: in merge() the searched lists are short
    // and where the id falls is data-dependent, so the branches of
    // std::lower_bound mispredicted (callgrind, 341,401 seeds: 5.8 M of
    // merge()'s 13.9 M mispredicted branches); the halving here is a
    // conditional move.
    static Neighbour* find(NodeHead& h, uint32_t id) {
        Neighbour* base = h.list;
        std::size_t n = h.degree;
        if (n == 0) return base;
        while (n > 1) {
            const std::size_t half = n / 2;
            base += (base[half].id < id) ? half : 0;
            n -= half;
        }
        return base + (base->id < id);
    }
    std::byte* inline_bytes(uint32_t r) { return sums_ptr(r) + 2 * sizeof(double) * bands_; }
    Neighbour* inline_list(uint32_t r) { return std::launder(reinterpret_cast<Neighbour*>(inline_bytes(r))); }
    // Room for `count` neighbours in r's list (contents kept); a list moved
    // out of the record is noted for the destructor.
    void reserve(uint32_t r, uint32_t count) {
        NodeHead& h = head(r);
        if (count <= h.capacity) return;
        if (h.list == inline_list(r)) heap_owners_.push_back(r);
        grow(r, count);
    }
    // reserve() without the note (the caller notes r: the build's parallel pass).
    void grow(uint32_t r, uint32_t count) {
        NodeHead& h = head(r);
        if (count <= h.capacity) return;
        const uint32_t capacity = std::max(count, 2 * h.capacity);
        auto* block = static_cast<Neighbour*>(std::malloc(sizeof(Neighbour) * capacity));
        if (!block) throw std::bad_alloc();
        std::copy(h.list, h.list + h.degree, block);
        if (h.list != inline_list(r)) std::free(h.list);
        h.list = block, h.capacity = capacity;
    }
    void release(uint32_t r) {
        NodeHead& h = head(r);
        if (h.list && h.list != inline_list(r)) std::free(h.list);
        h.list = inline_list(r), h.capacity = inline_capacity_, h.degree = 0;
    }
    // Derived term of r: Σ_b w_b n σ_b.
    void derive(uint32_t r) {
        NodeHead& R = head(r);
        const double* S = sums(r);
        if (!R.n) {
            R.lsq = R.smooth = 0.0;
            return;
        }
        const double n = R.n, l = R.l;
        R.lsq = l * root(n);
        R.smooth = n * l / (2.0 * ((R.x1 - R.x0 + 1) + (R.y1 - R.y0 + 1)));
        const double inv = 1.0 / n;
        double t = 0.0;
        for (int b = 0; b < bands_; ++b) {
            const double m = S[2 * b] * inv;
            const double var = S[2 * b + 1] * inv - m * m;
            t += weights_[b] * root(std::max(0.0, var));
        }
        R.colour = t * n;
    }

    int bands_;
    uint32_t n_;
    double wc_, wcmp_;
    std::vector<double> weights_;
    std::size_t lines_ = 1;        // cache lines per node record
    // Node records. Small pages: the merge loop reads them at random and
    // would take fewer TLB misses on huge pages, but on a virtual machine a
    // fresh huge page is one the host must back anew (free 2 MB blocks are
    // handed back to it), while small pages come from recently freed
    // memory. Measured on 1.1 M records (355 MB): first touch 0.8-2.5 s CPU
    // on huge pages against 0.14-0.7 s on small ones, merging ~0.3 s slower.
    std::vector<Line> storage_;
    uint32_t inline_capacity_ = 0;
    std::vector<Neighbour> scratch_;
    std::vector<uint32_t> node_of_label_, label_of_node_;  // see number_nodes
    std::vector<uint32_t> nodes_above_stripe_;  // [s]: nodes whose first pixel is above stripe s (number_nodes)
    std::vector<uint32_t> block_first_node_;  // [k]: first node of block k (stripe by stripe, left to right; number_nodes)
    uint32_t blocks_per_stripe_ = 0;
    uint32_t alive_count_ = 0;
    LargeVector<int64_t> outside_acc_;   // the build's accumulators when they do not fit in the records (many bands)
    std::vector<uint32_t> heap_owners_;  // regions given a heap block (some since released): the destructor frees theirs
    uint64_t adjacent_pairs_ = 0;        // distinct adjacent pairs of the initial regions (build)
};

}  // namespace

RegionMergingResult merge_regions(const Image<float>& image, const Image<uint32_t>& labels, uint32_t region_count,
                                  const RegionMergingOptions& o, const Progress& progress) {
    o.validate(image.bands);
    if (labels.width != image.width || labels.height != image.height)
        throw Error("region merging", "label raster and image differ in size");
    if (labels.pixel_count() >= (std::size_t(1) << 32))  // areas and perimeters are 32-bit counts (NodeHead)
        throw Error("region merging", "images of 2^32 pixels or more are not supported; merge tiles of it");
    RegionMergingResult result;
    const auto t_graph = std::chrono::steady_clock::now();
    const double c_graph = process_cpu_seconds();
    RegionGraph g(image, labels, region_count, o);
    const uint32_t n = g.size();
    result.adjacent_pairs = g.adjacent_pairs();
    std::vector<uint32_t> uf(n);  // absorbed node -> node it merged into (union-find)
    for (uint32_t r = 0; r < n; ++r) uf[r] = r;
    auto find = [&](uint32_t x) {
        while (uf[x] != x) x = uf[x] = uf[uf[x]];
        return x;
    };

    result.graph_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_graph).count();
    result.graph_cpu_seconds = process_cpu_seconds() - c_graph;
    const std::vector<double> initial_totals = o.verify_invariants ? g.totals() : std::vector<double>{};
    // The regions of the previous level in the order of their labels there
    // (ascending key): [k - 1] = node of region k, 0 for an input label
    // without pixels (at the first scale, whose previous level is the
    // input). Filled by the first scale's pass over the records.
    std::vector<uint32_t> previous_order(n > 0 ? n - 1 : 0, 0), order;
    // root node -> label at this level while a level's labels are given
    // (0 = none yet; cleared again afterwards); allocated once (a fresh
    // zeroed vector of 1.1 M entries per scale was ~1-2 ms of page faults each)
    std::vector<uint32_t> compact(n, 0);
    // Nodes alive at the start of the scale, ascending: the per-scale loops
    // visit them, not every record of the over-segmentation (1.1 M records
    // of 320 bytes when 10 k regions are left). Not used by the first scale.
    std::vector<uint32_t> live;
    uint32_t previous_count = region_count;
    std::vector<uint32_t> changed, rescan;
    std::vector<uint32_t> offered;  // mutual: lower nodes of the pairs pushed by the current merge
    for (std::size_t s = 0; s < o.scales.size(); ++s) {
        const auto t0 = std::chrono::steady_clock::now();
        const double c0 = thread_cpu_seconds();
        const double threshold = o.scales[s] * o.scales[s];
        ScaleLevel level;
        level.scale = o.scales[s];
        level.regions_before = g.alive_count();
        std::vector<QueueEntry> initial;
        auto entry = [&](uint32_t a, uint32_t b, double c) {
            uint64_t ka = g.key_of(a), kb = g.key_of(b);
            if (ka > kb) std::swap(a, b), std::swap(ka, kb);
            return QueueEntry::make(c, ka << 32 | kb, a, b);
        };
        // r's nearest-neighbour pair if the strategy queues it.
        auto queued_nn = [&](uint32_t r) {
            const uint32_t k = g.nn(r);
            if (!k || !(g.nn_cost(r) < threshold)) return false;
            return o.strategy != QueueStrategy::mutual || g.nn(k) == r;
        };
        auto queue_initial = [&](uint32_t r) {
            if (o.strategy == QueueStrategy::rag) {
                for (const Neighbour& k : g.neighbours(r))
                    if (k.id > r) initial.push_back(entry(r, k.id, k.cost));
            } else if ((o.strategy == QueueStrategy::nng || g.nn(r) > r) && queued_nn(r)) {
                initial.push_back(entry(r, g.nn(r), g.nn_cost(r)));  // mutual pairs once, from their lower node
            }
        };
        constexpr uint32_t kEntriesAhead = 8;
        if (s == 0) {
            // One pass over all records, on one thread: the regions and
            // their entries (build() found every region's nearest neighbour
            // where its list was in cache: this pass reads the heads only,
            // but for rag; on 1.1 M Autzen seeds 110-206 -> 64-78 M cycles).
            // A mutual pair is queued when its higher node is reached: the
            // same entry as from the lower node (the edge's cost is the same
            // double on both sides), and the queue pops by (cost, keys)
            // whatever order the entries came in.
            const int lines_ahead = o.strategy == QueueStrategy::rag ? 4 : 1;  // rag reads the lists, the others the heads
            for (uint32_t r = 1; r < n; ++r) {
                if (r + kEntriesAhead < n) g.prefetch_node(r + kEntriesAhead, lines_ahead);
                if (!g.alive(r)) continue;
                previous_order[g.key_of(r) - 1] = r;  // the key is the region's input label
                if (o.strategy != QueueStrategy::mutual) {
                    queue_initial(r);
                } else {
                    const uint32_t k = g.nn(r);
                    if (k && k < r && g.nn(k) == r && g.nn_cost(r) < threshold) initial.push_back(entry(k, r, g.nn_cost(r)));
                }
            }
        } else {
            for (uint32_t r : live) queue_initial(r);
        }
        level.initial_queue_length = initial.size();
        level.queue_pushes = initial.size();
        MergeQueue heap(initial);
        std::vector<QueueEntry>().swap(initial);
        auto push_pair = [&](uint32_t a, uint32_t b, double c) {
            heap.push(entry(a, b, c));
            ++level.queue_pushes;
        };
        // With the mutual queue a pair is offered from both its regions when
        // both are the merged region or its neighbours: the second push would
        // be the same entry (same keys, same cost), popped right after the
        // first and dropped as stale, so it is not made.
        auto offer_nn = [&](uint32_t r) {
            if (!queued_nn(r)) return;
            const uint32_t k = g.nn(r);
            if (o.strategy == QueueStrategy::mutual) {
                const uint32_t lower = std::min(r, k);
                if (std::find(offered.begin(), offered.end(), lower) != offered.end()) return;
                offered.push_back(lower);
            }
            push_pair(r, k, g.nn_cost(r));
        };
        // Is e the entry of a current pair at its current cost? Then it is
        // the entry a fresh push would make (keys and cost equal).
        auto current = [&](const QueueEntry& e, uint32_t a, uint32_t b) {
            switch (o.strategy) {
                case QueueStrategy::mutual: return g.nn(a) == b && g.nn(b) == a && g.nn_cost(a) == e.cost();
                case QueueStrategy::nng:
                    return (g.nn(a) == b && g.nn_cost(a) == e.cost()) || (g.nn(b) == a && g.nn_cost(b) == e.cost());
                case QueueStrategy::rag: return g.edge_cost(a, b) == e.cost();
            }
            return false;
        };
        while (!heap.empty() && g.alive_count() > o.min_regions) {
            const QueueEntry e = heap.top();
            heap.pop();
            // The next pops are most likely the next merges: start loading
            // their records (and their neighbours') while this one is done.
            if (!heap.empty()) {
                g.prefetch_neighbours(heap.entry(0).a);
                g.prefetch_neighbours(heap.entry(0).b);
            }
            for (std::size_t i = 1; i < 5 && i < heap.near_size(); ++i) {  // the next top is one of these
                g.prefetch_node(heap.entry(i).a, 4);
                g.prefetch_node(heap.entry(i).b, 4);
            }
            const uint32_t a = e.a, b = e.b;
            if (!g.alive(a) || !g.alive(b) || (uint64_t(g.key_of(a)) << 32 | g.key_of(b)) != e.keys || !current(e, a, b)) continue;
            if (!(e.cost() < threshold)) break;  // rag holds every pair: the cheapest is too dear
            changed.clear(), rescan.clear(), offered.clear();
            const uint32_t m = g.merge(a, b, o.strategy != QueueStrategy::rag, changed, rescan);
            uf[m == a ? b : a] = m;
            ++level.merges;
            level.max_degree = std::max(level.max_degree, static_cast<uint32_t>(g.neighbours(m).size()));
            if (o.strategy == QueueStrategy::rag) {
                for (const Neighbour& k : g.neighbours(m)) push_pair(m, k.id, k.cost);
                continue;
            }
            if (o.strategy == QueueStrategy::mutual)  // the offers read the nearest neighbours' records (rescan's: merge() loaded them)
                for (uint32_t k : changed) g.prefetch_node(g.nn(k), 1);
            offer_nn(m);
            for (uint32_t k : rescan) offer_nn(k);
            for (uint32_t k : changed) offer_nn(k);
        }
        level.regions_after = g.alive_count();
        if (o.verify_invariants) g.verify(initial_totals);
        // Contiguous labels of this level in ascending key, and the
        // hierarchy links, in one pass over the previous level's regions in
        // ascending key: a region of this level is first met at its part of
        // the lowest key, which is its key, so labels given in the order
        // regions are met ascend with the key (no sort, and no key read
        // from the records).
        level.parent.assign(previous_count + 1, 0);
        uint32_t next = 0;
        order.clear();
        order.reserve(g.alive_count());
        for (uint32_t k = 0; k < previous_count; ++k) {
            const uint32_t r = previous_order[k];
            if (!r) continue;  // an input label without pixels
            const uint32_t root = find(r);
            if (!compact[root]) compact[root] = ++next, order.push_back(root);
            level.parent[k + 1] = compact[root];
        }
        for (uint32_t r : order) compact[r] = 0;
        // An input label's region at this level is the parent of its region
        // at the previous level (at the first scale, of the label itself:
        // the previous level is the input): one
        // pass through a table of the previous level's regions instead of
        // a walk of the union-find from every input label's node (1.1 M
        // Autzen seeds: ~12 ms at every scale).
        level.label_of_input.resize(n);
        if (s == 0) {
            std::copy(level.parent.begin(), level.parent.end(), level.label_of_input.begin());
        } else {
            const std::vector<uint32_t>& below = result.levels.back().label_of_input;
            for (uint32_t l = 0; l < n; ++l) level.label_of_input[l] = level.parent[below[l]];
        }
        live.assign(order.begin(), order.end());
        std::sort(live.begin(), live.end());
        previous_order.swap(order);
        previous_count = next;
        level.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        level.cpu_seconds = thread_cpu_seconds() - c0;
        result.levels.push_back(std::move(level));
        progress(double(s + 1) / double(o.scales.size()), "merging");
    }
    return result;
}

Image<uint32_t> segment_at_scale(const Image<float>& image, const std::vector<uint8_t>& valid, const WatershedOptions& watershed,
                                 double scale, uint32_t& count, const Progress& progress) {
    const Oversegmentation over = watershed_oversegment(image, valid, watershed, progress.sub(0.0, 0.6));
    count = 0;
    if (over.region_count == 0) return over.labels;
    RegionMergingOptions rmo;
    rmo.scales = {scale};
    rmo.band_weights = watershed.band_weights;
    const RegionMergingResult merged = merge_regions(image, over.labels, over.region_count, rmo, progress.sub(0.6, 1.0));
    count = merged.levels[0].regions_after;
    return relabel(over.labels, merged.levels[0].label_of_input);
}

}  // namespace cityforge
