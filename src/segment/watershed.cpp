#include "segment/watershed.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <memory>
#include <numeric>
#include <string>
#include <sys/mman.h>
#include <atomic>
#include <tbb/parallel_for.h>
#include <unistd.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/prefetch.hpp"
#include "core/error.hpp"
#include "core/parallel.hpp"

namespace cityforge {

void WatershedOptions::validate(int bands) const {
    if (!band_weights.empty() && static_cast<int>(band_weights.size()) != bands)
        throw Error("--band-weights", "has " + std::to_string(band_weights.size()) + " values but the image has " +
                                          std::to_string(bands) + " band(s)");
    for (double w : band_weights)
        if (!(w >= 0.0) || !std::isfinite(w)) throw Error("--band-weights", "weights must be finite and >= 0");
    if (!band_weights.empty() && std::accumulate(band_weights.begin(), band_weights.end(), 0.0) <= 0.0)
        throw Error("--band-weights", "at least one weight must be > 0");
    if (!(smoothing_sigma_px >= 0.0 && smoothing_sigma_px <= 20.0)) throw Error("--smoothing", "must be between 0 and 20 pixels");
    if (!(h_minima >= 0.0 && h_minima <= 255.0)) throw Error("--h-minima", "must be between 0 and 255");
}

namespace {
// The 0.5th and 99.5th percentiles of a band from a regular sample (every
// step-th pixel, the valid ones): the values std::nth_element would put at
// ranks k_lo = 0.005 (m - 1) and then k_hi = 0.995 (m - 1) of the m samples,
// found by one counting pass over the top 16 bits of an order-preserving key
// and nth_element within the bucket(s) holding the two ranks, without
// copying the sample (~1 M values: a few ms). With NaN among the samples,
// the sample copied and plain nth_element at k_lo and then at k_hi (their
// order is not defined). False when no pixel is sampled.
bool sample_percentiles(const float* v, std::size_t n, std::size_t step, const uint8_t* valid, float& lo, float& hi) {
    auto key = [](float f) {
        uint32_t bits;
        std::memcpy(&bits, &f, sizeof bits);
        return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
    };
    auto for_each_sample = [&](auto&& body) {
        for (std::size_t i = 0; i < n; i += step)
            if (!valid || valid[i]) body(v[i]);
    };
    std::vector<uint32_t> count(65536, 0);
    std::size_t m = 0;
    bool nan = false;
    for_each_sample([&](float f) {
        nan = nan || std::isnan(f);
        ++count[key(f) >> 16];
        ++m;
    });
    if (m == 0) return false;
    const std::size_t k_lo = static_cast<std::size_t>(0.005 * static_cast<double>(m - 1));
    const std::size_t k_hi = static_cast<std::size_t>(0.995 * static_cast<double>(m - 1));
    if (nan) {
        std::vector<float> values;
        values.reserve(m);
        for_each_sample([&](float f) { values.push_back(f); });
        std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k_lo), values.end());
        lo = values[k_lo];
        std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k_hi), values.end());
        hi = values[k_hi];
        return true;
    }
    // The bucket holding rank k and k's rank within it.
    auto locate = [&](std::size_t k) {
        uint64_t below = 0;
        uint32_t bucket = 0;
        while (below + count[bucket] <= k) below += count[bucket++];
        return std::pair<uint32_t, std::size_t>(bucket, k - below);
    };
    const auto [b_lo, r_lo] = locate(k_lo);
    const auto [b_hi, r_hi] = locate(k_hi);
    std::vector<float> in_lo, in_hi;
    in_lo.reserve(count[b_lo]);
    if (b_hi != b_lo) in_hi.reserve(count[b_hi]);
    for_each_sample([&](float f) {
        const uint32_t b = key(f) >> 16;
        if (b == b_lo) in_lo.push_back(f);
        else if (b == b_hi) in_hi.push_back(f);
    });
    std::vector<float>& hi_bucket = b_hi == b_lo ? in_lo : in_hi;
    std::nth_element(in_lo.begin(), in_lo.begin() + static_cast<std::ptrdiff_t>(r_lo), in_lo.end());
    lo = in_lo[r_lo];
    std::nth_element(hi_bucket.begin(), hi_bucket.begin() + static_cast<std::ptrdiff_t>(r_hi), hi_bucket.end());
    hi = hi_bucket[r_hi];
    return true;
}
}  // namespace

void normalize_bands(Image<float>& image, const std::vector<uint8_t>& valid) {
    const std::size_t n = image.pixel_count();
    // Percentiles from a regular sample (at most ~1M values): deterministic and fast.
    const std::size_t step = std::max<std::size_t>(1, n / 1000000);
    for (int b = 0; b < image.bands; ++b) {
        float* v = image.band_data(b);
        float lo = 0.0f, hi = 0.0f;
        if (!sample_percentiles(v, n, step, valid.empty() ? nullptr : valid.data(), lo, hi)) continue;
        const float scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
        parallel_for_each_index(n, [&](std::size_t i) {
            v[i] = std::clamp((v[i] - lo) * scale, 0.0f, 255.0f);
        });
    }
}

namespace {
// A LargeVector of `count` elements on small pages (its allocation is marked
// no-huge before anything touches it). On a virtual machine a fresh huge page
// is one the host must back anew (free 2 MB blocks are handed back to it),
// while small pages mostly come from recently freed memory: measured on the
// 13 MP Autzen window, first touch of these buffers took 0.1-0.2 s CPU on
// huge pages and ~0.02 s on small ones, and the flooding, whose reads are
// prefetched, ran no slower.
template <typename T>
LargeVector<T> small_page_vector(std::size_t count) {
    LargeVector<T> v;
    v.reserve(count);
    const auto page = static_cast<uintptr_t>(sysconf(_SC_PAGESIZE));
    const auto first = reinterpret_cast<uintptr_t>(v.data()) & ~(page - 1);
    const auto last = reinterpret_cast<uintptr_t>(v.data() + count);
    if (count * sizeof(T) >= (std::size_t(4) << 20) && last > first) ::madvise(reinterpret_cast<void*>(first), last - first, MADV_NOHUGEPAGE);  // a hint
    return v;
}

// Normalised Gaussian kernel of standard deviation sigma (pixels), 2r + 1 taps.
std::vector<float> gaussian_kernel(double sigma, int& radius) {
    radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
    std::vector<float> k(2 * radius + 1);
    double sum = 0.0;
    for (int i = -radius; i <= radius; ++i) sum += k[i + radius] = static_cast<float>(std::exp(-0.5 * i * i / (sigma * sigma)));
    for (auto& x : k) x = static_cast<float>(x / sum);
    return k;
}

// Horizontal pass of the blur over one row (edges clamped).
inline void blur_row_horizontal(const float* row, float* t, int w, const std::vector<float>& k, int radius) {
    // Borders clamp; the interior runs without branches so it vectorises.
    auto clamped = [&](int x) {
        float s = 0.0f;
        for (int i = -radius; i <= radius; ++i) s += k[i + radius] * row[std::clamp(x + i, 0, w - 1)];
        return s;
    };
    const int lo = std::min(radius, w), hi = std::max(lo, w - radius);
    for (int x = 0; x < lo; ++x) t[x] = clamped(x);
    for (int x = lo; x < hi; ++x) t[x] = 0.0f;
    for (int i = -radius; i <= radius; ++i) {
        const float ki = k[i + radius];
        const float* src = row + i;
        for (int x = lo; x < hi; ++x) t[x] += ki * src[x];
    }
    for (int x = hi; x < w; ++x) t[x] = clamped(x);
}

// Vertical pass for row y: `hrow(r)` gives the horizontally blurred row r
// (r already clamped to the image).
template <typename RowOf>
inline void blur_row_vertical(int y, int h, float* o, int w, const std::vector<float>& k, int radius, const RowOf& hrow) {
    for (int x = 0; x < w; ++x) o[x] = 0.0f;
    for (int i = -radius; i <= radius; ++i) {
        const float* t = hrow(std::clamp(y + i, 0, h - 1));
        const float ki = k[i + radius];
        for (int x = 0; x < w; ++x) o[x] += ki * t[x];
    }
}

// Separable Gaussian blur of one band, edges clamped.
void gaussian_blur(const float* in, float* out, float* tmp_buffer, int w, int h, double sigma) {
    int radius = 0;
    const std::vector<float> k = gaussian_kernel(sigma, radius);
    tbb::parallel_for(0, h, [&](int y) {
        blur_row_horizontal(in + static_cast<std::size_t>(y) * w, tmp_buffer + static_cast<std::size_t>(y) * w, w, k, radius);
    });
    tbb::parallel_for(0, h, [&](int y) {
        blur_row_vertical(y, h, out + static_cast<std::size_t>(y) * w, w, k, radius,
                          [&](int r) { return tmp_buffer + static_cast<std::size_t>(r) * w; });
    });
}

// Adds w_b (gx² + gy²) of one band's Sobel operator to the row `g` (row y of
// a w-pixel image; a, m, c = rows y - 1, y, y + 1, clamped at the edges).
// Shared by multiband_gradient and the fused levels below, so both give the
// same floats bit for bit.
inline void add_sobel_row(const float* a, const float* m, const float* c, int w, float fw, float* g) {
    auto sobel = [&](int x, int x0, int x1) {
        const float gx = (a[x1] + 2 * m[x1] + c[x1]) - (a[x0] + 2 * m[x0] + c[x0]);
        const float gy = (c[x0] + 2 * c[x] + c[x1]) - (a[x0] + 2 * a[x] + a[x1]);
        g[x] += fw * (gx * gx + gy * gy);
    };
    sobel(0, 0, std::min(1, w - 1));
    for (int x = 1; x < w - 1; ++x) sobel(x, x - 1, x + 1);
    if (w > 1) sobel(w - 1, w - 2, w - 1);
}

// 1 / (8 √Σw): Sobel sums 8 weighted differences; this brings the gradient
// back to grey-level units.
float gradient_norm(const Image<float>& image, const WatershedOptions& options) {
    double wsum = 0.0;
    for (int b = 0; b < image.bands; ++b) wsum += options.band_weights.empty() ? 1.0 : options.band_weights[b];
    return static_cast<float>(1.0 / (8.0 * std::sqrt(std::max(wsum, 1e-12))));
}

// Flooding levels: the gradient in 1/kLevelsPerUnit grey levels, clamped to 16 bits.
constexpr float kLevelsPerUnit = 4.0f;
inline uint16_t gradient_level(float g) { return static_cast<uint16_t>(std::min(65535.0f, g * kLevelsPerUnit)); }

// One row of flooding levels from the summed squared Sobel responses `g`:
// out[x] = gradient_level(sqrt(g[x]) * norm). Four at a time with SSE2
// (std::sqrt stays scalar for errno; sqrtps is correctly rounded like
// sqrtss, minps(v, 65535) is std::min(65535, v) with NaN, and the
// truncation is the same), so the levels are the same bit for bit.
inline void quantise_row(const float* g, float norm, uint16_t* out, int w) {
    int x = 0;
#if defined(__SSE2__)
    const __m128 vn = _mm_set1_ps(norm), vl = _mm_set1_ps(kLevelsPerUnit), vmax = _mm_set1_ps(65535.0f);
    const __m128i bias = _mm_set1_epi32(32768), flip = _mm_set1_epi16(static_cast<short>(0x8000));
    auto four = [&](const float* q) {
        const __m128 v = _mm_min_ps(_mm_mul_ps(_mm_mul_ps(_mm_sqrt_ps(_mm_loadu_ps(q)), vn), vl), vmax);
        return _mm_sub_epi32(_mm_cvttps_epi32(v), bias);  // 0..65535, shifted into the signed 16-bit range
    };
    for (; x + 8 <= w; x += 8)
        _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm_xor_si128(_mm_packs_epi32(four(g + x), four(g + x + 4)), flip));
#endif
    for (; x < w; ++x) out[x] = gradient_level(std::sqrt(g[x]) * norm);
}

// Levels of row y without smoothing, all bands at once; g: w floats of scratch.
inline void unsmoothed_level_row(const Image<float>& image, const WatershedOptions& options, float norm, int y, float* g, uint16_t* out) {
    const int w = image.width, h = image.height;
    std::fill(g, g + w, 0.0f);
    const int y0 = std::max(0, y - 1), y1 = std::min(h - 1, y + 1);
    for (int b = 0; b < image.bands; ++b) {
        const double wb = options.band_weights.empty() ? 1.0 : options.band_weights[b];
        if (wb == 0.0) continue;
        const float* src = image.band_data(b);
        add_sobel_row(src + static_cast<std::size_t>(y0) * w, src + static_cast<std::size_t>(y) * w,
                      src + static_cast<std::size_t>(y1) * w, w, static_cast<float>(wb), g);
    }
    quantise_row(g, norm, out, w);
}

// The quantised gradient without the float gradient raster (no smoothing):
// row by row, all bands at once; the same levels as quantising
// multiband_gradient's output, bit for bit.
LargeVector<uint16_t> unsmoothed_gradient_levels(const Image<float>& image, const WatershedOptions& options) {
    const int w = image.width, h = image.height;
    LargeVector<uint16_t> level = small_page_vector<uint16_t>(image.pixel_count());
    level.resize(image.pixel_count());
    const float norm = gradient_norm(image, options);
    tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rows) {
        std::vector<float> g(static_cast<std::size_t>(w));
        for (int y = rows.begin(); y != rows.end(); ++y)
            unsmoothed_level_row(image, options, norm, y, g.data(), level.data() + static_cast<std::size_t>(y) * w);
    });
    return level;
}

// The quantised gradient of the smoothed bands without any full-size float
// raster (the blurred band, the blur's scratch and the gradient were three
// of them: 768 MB at 64 MP). Blocks of rows are blurred and differentiated
// with their halo in small buffers; every row goes through the same
// operations as in gaussian_blur and multiband_gradient, so the levels are
// the same bit for bit.
LargeVector<uint16_t> smoothed_gradient_levels(const Image<float>& image, const WatershedOptions& options) {
    const int w = image.width, h = image.height;
    LargeVector<uint16_t> level = small_page_vector<uint16_t>(image.pixel_count());
    level.resize(image.pixel_count());
    const float norm = gradient_norm(image, options);
    int radius = 0;
    const std::vector<float> k = gaussian_kernel(options.smoothing_sigma_px, radius);
    constexpr int kBlockRows = 64;
    const int blocks = (h + kBlockRows - 1) / kBlockRows;
    const std::size_t row = static_cast<std::size_t>(w);
    tbb::parallel_for(tbb::blocked_range<int>(0, blocks), [&](const tbb::blocked_range<int>& range) {
        std::vector<float> hb, sb, g;  // horizontally blurred rows, smoothed rows, gradient sums
        for (int blk = range.begin(); blk != range.end(); ++blk) {
            const int y0 = blk * kBlockRows, y1 = std::min(h, y0 + kBlockRows);
            const int sy0 = std::max(0, y0 - 1), sy1 = std::min(h, y1 + 1);              // smoothed rows the Sobel reads
            const int hy0 = std::max(0, sy0 - radius), hy1 = std::min(h, sy1 + radius);  // blurred rows the vertical pass reads
            hb.resize(static_cast<std::size_t>(hy1 - hy0) * row);
            sb.resize(static_cast<std::size_t>(sy1 - sy0) * row);
            g.assign(static_cast<std::size_t>(y1 - y0) * row, 0.0f);
            for (int b = 0; b < image.bands; ++b) {
                const double wb = options.band_weights.empty() ? 1.0 : options.band_weights[b];
                if (wb == 0.0) continue;
                const float* src = image.band_data(b);
                for (int r = hy0; r < hy1; ++r) blur_row_horizontal(src + r * row, hb.data() + (r - hy0) * row, w, k, radius);
                for (int r = sy0; r < sy1; ++r)
                    blur_row_vertical(r, h, sb.data() + (r - sy0) * row, w, k, radius,
                                      [&](int q) { return hb.data() + static_cast<std::size_t>(q - hy0) * row; });
                auto smoothed = [&](int r) { return sb.data() + static_cast<std::size_t>(r - sy0) * row; };
                for (int y = y0; y < y1; ++y)
                    add_sobel_row(smoothed(std::max(0, y - 1)), smoothed(y), smoothed(std::min(h - 1, y + 1)), w,
                                  static_cast<float>(wb), g.data() + static_cast<std::size_t>(y - y0) * row);
            }
            for (int y = y0; y < y1; ++y) {
                const float* gy = g.data() + static_cast<std::size_t>(y - y0) * row;
                uint16_t* out = level.data() + static_cast<std::size_t>(y) * row;
                quantise_row(gy, norm, out, w);
            }
        }
    });
    return level;
}

// The flooding without dynamics (h = 0), in any order and on any number of
// threads, with exactly the result of the sequential flooding in (level,
// index) order. Without dynamics no basin is ever absorbed, so a pixel's
// basin seed is decided when it is flooded and never changes, and it is a
// function of its neighbours flooded before it alone: those that come first
// in (level, index) order ("lower"; nodata never is). Up, left, right, down:
// their seeds without repeats, each taken through the first neighbour that
// has it; none: the pixel is a new seed; one: that seed; several: the one
// whose neighbour is closest in colour (the first on ties). So seeds are
// found by a depth-first walk down this order: a pixel waits on a stack
// until its lower neighbours have their seeds. Row blocks are walked in
// parallel, in raster order within a block (the walk goes on into other
// blocks where it must); two threads that reach the same pixel write the
// same seed, so the result does not depend on the thread count or timing.
// The walk reads the image nearly in raster order instead of in level
// order (every pixel a cache miss), and needs no sort of the pixels.
//
// Everything the walk needs of a pixel that is not flooded yet is packed in
// its own parent entry (images of fewer than 2^31 - 1 pixels, so a seed, a
// pixel index, never has the top bit): kUnflooded | colour ranks << 4 |
// lower neighbours (bit 0 up, 1 left, 2 right, 3 down); nodata holds kNone.
// The colour ranks (2 bits per neighbour, same order) place the four
// neighbours by colour distance, the first on ties, so the closest of any
// subset is one table look-up: the walk reads neither the bands nor a
// separate mask, and no level raster is kept.
constexpr uint32_t kUnflooded = 0x80000000u;
constexpr uint32_t kNoData = 0xFFFFFFFFu;

// kPick[subset][ranks]: the neighbour of `subset` (bit per neighbour) with the lowest rank.
constexpr std::array<std::array<uint8_t, 256>, 16> make_pick_table() {
    std::array<std::array<uint8_t, 256>, 16> t{};
    for (unsigned subset = 1; subset < 16; ++subset)
        for (unsigned ranks = 0; ranks < 256; ++ranks) {
            unsigned best = 0, best_rank = 4;
            for (unsigned j = 0; j < 4; ++j)
                if (((subset >> j) & 1u) && ((ranks >> (2 * j)) & 3u) < best_rank) best = j, best_rank = (ranks >> (2 * j)) & 3u;
            t[subset][ranks] = static_cast<uint8_t>(best);
        }
    return t;
}
constexpr std::array<std::array<uint8_t, 256>, 16> kPick = make_pick_table();

// The walk's starting state of every pixel of rows [y0, y1), written to
// parent[]. `level_row(y)` gives the levels of row y (rows y0 - 1 ... y1
// are asked for, clamped to the image). Colour distances are those of the
// sequential flooding: Σ over all bands of (p - q)², in band order, from
// 0.0f; (p - q)² = (q - p)² bit for bit, so each is computed once per pair.
// A distance that is NaN or infinite never wins there (strict <, from
// INFINITY) and the first neighbour is kept: keys min(d, ∞) (NaN -> ∞) with
// ties to the first neighbour give the same choice.
template <typename LevelRow>
void descent_states_rows(const Image<float>& image, const uint8_t* valid, int y0, int y1, const LevelRow& level_row,
                         std::vector<float>& scratch, uint32_t* parent) {
    const int w = image.width, h = image.height, bands = image.bands;
    const std::size_t row = static_cast<std::size_t>(w);
    scratch.resize(3 * row + 1);
    float* const hk = scratch.data();             // hk[x]: key of (x - 1, x), x in 1..w-1; hk[0] = hk[w] = ∞
    float* up = scratch.data() + row + 1;         // keys of (x, y - 1) for row y
    float* down = scratch.data() + 2 * row + 1;   // keys of (x, y + 1)
    auto key = [](float d) { return d < INFINITY ? d : INFINITY; };  // minps
    auto vertical = [&](int y, float* out) {  // keys between rows y and y + 1
        std::fill(out, out + w, 0.0f);
        for (int b = 0; b < bands; ++b) {
            const float* a = image.band_data(b) + static_cast<std::size_t>(y) * row;
            const float* c = a + row;
            for (int x = 0; x < w; ++x) {
                const float diff = a[x] - c[x];
                out[x] += diff * diff;
            }
        }
        for (int x = 0; x < w; ++x) out[x] = key(out[x]);
    };
    if (y0 > 0) vertical(y0 - 1, up);
    else std::fill(up, up + w, INFINITY);
    for (int y = y0; y < y1; ++y) {
        const std::size_t at = static_cast<std::size_t>(y) * row;
        if (y + 1 < h) vertical(y, down);
        else std::fill(down, down + w, INFINITY);
        std::fill(hk, hk + w + 1, 0.0f);
        for (int b = 0; b < bands; ++b) {
            const float* a = image.band_data(b) + at;
            for (int x = 1; x < w; ++x) {
                const float diff = a[x] - a[x - 1];
                hk[x] += diff * diff;
            }
        }
        for (int x = 1; x < w; ++x) hk[x] = key(hk[x]);
        hk[0] = hk[w] = INFINITY;
        const uint16_t* l = level_row(y);
        const uint16_t* lu = y > 0 ? level_row(y - 1) : l;  // the row itself: never lower
        const uint16_t* ld = y + 1 < h ? level_row(y + 1) : l;
        const uint32_t up_bit = y > 0 ? 1u : 0u, down_bit = y + 1 < h ? 8u : 0u;
        uint32_t* out = parent + at;
        auto state = [&](int x, uint32_t lower) {
            const float ku = up[x], kl = hk[x], kr = hk[x + 1], kd = down[x];
            const uint32_t a = kl < ku, b = kr < ku, c = kd < ku, d = kr < kl, e = kd < kl, f = kd < kr;
            const uint32_t ranks = (a + b + c) | (1 - a + d + e) << 2 | (2 - b - d + f) << 4 | (3 - c - e - f) << 6;
            return kUnflooded | ranks << 4 | lower;
        };
        auto lower_of = [&](int x) {
            uint32_t m = (lu[x] <= l[x] ? up_bit : 0u) | (ld[x] < l[x] ? down_bit : 0u);
            if (x > 0 && l[x - 1] <= l[x]) m |= 2u;
            if (x + 1 < w && l[x + 1] < l[x]) m |= 4u;
            return m;
        };
        out[0] = state(0, lower_of(0));
        for (int x = 1; x + 1 < w; ++x)
            out[x] = state(x, (lu[x] <= l[x] ? up_bit : 0u) | (l[x - 1] <= l[x] ? 2u : 0u) | (l[x + 1] < l[x] ? 4u : 0u) |
                                  (ld[x] < l[x] ? down_bit : 0u));
        if (w > 1) out[w - 1] = state(w - 1, lower_of(w - 1));
        if (valid) {
            const uint8_t* v = valid + at;
            const uint8_t* vu = y > 0 ? v - row : v;
            const uint8_t* vd = y + 1 < h ? v + row : v;
            for (int x = 0; x < w; ++x) {
                const uint32_t keep = (vu[x] ? 1u : 0u) | (vd[x] ? 8u : 0u) | (x > 0 && v[x - 1] ? 2u : 0u) | (x + 1 < w && v[x + 1] ? 4u : 0u);
                out[x] = v[x] ? out[x] & (~15u | keep) : kNoData;
            }
        }
        std::swap(up, down);
    }
}

// The starting states of all pixels (parent[], n entries), by blocks of rows
// in parallel. `level` (may be null) is the level raster; without it the
// levels of each block and its one-row halo are quantised here from the
// bands (no smoothing), the same as unsmoothed_gradient_levels.
void descent_states(const Image<float>& image, const WatershedOptions& options, const uint16_t* level, const uint8_t* valid,
                    uint32_t* parent) {
    const int w = image.width, h = image.height;
    const std::size_t row = static_cast<std::size_t>(w);
    const float norm = gradient_norm(image, options);
    constexpr int kBlockRows = 32;
    const int blocks = (h + kBlockRows - 1) / kBlockRows;
    tbb::parallel_for(tbb::blocked_range<int>(0, blocks), [&](const tbb::blocked_range<int>& range) {
        std::vector<float> scratch, g(row);
        std::vector<uint16_t> levels;  // rows ly0 .. ly1 - 1
        for (int blk = range.begin(); blk != range.end(); ++blk) {
            const int y0 = blk * kBlockRows, y1 = std::min(h, y0 + kBlockRows);
            if (level) {
                descent_states_rows(image, valid, y0, y1, [&](int y) { return level + static_cast<std::size_t>(y) * row; }, scratch, parent);
                continue;
            }
            const int ly0 = std::max(0, y0 - 1), ly1 = std::min(h, y1 + 1);
            levels.resize(static_cast<std::size_t>(ly1 - ly0) * row);
            for (int y = ly0; y < ly1; ++y) unsmoothed_level_row(image, options, norm, y, g.data(), levels.data() + static_cast<std::size_t>(y - ly0) * row);
            descent_states_rows(image, valid, y0, y1, [&](int y) { return levels.data() + static_cast<std::size_t>(y - ly0) * row; },
                                scratch, parent);
        }
    });
}

// The walk over pixels [first, last) (see above); parent[] holds the states.
void descend_rows(uint32_t w, uint32_t* parent, std::size_t first, std::size_t last, std::vector<uint32_t>& stack) {
    auto state_of = [parent](uint32_t q) { return std::atomic_ref<uint32_t>(parent[q]).load(std::memory_order_relaxed); };
    const uint32_t offset[4] = {0u - w, 0u - 1u, 1u, w};  // up, left, right, down (modulo 2^32)
    std::size_t top = 0;  // stack[0, top): pixels waiting on their lower neighbours
    for (std::size_t i = first; i < last; ++i) {
        uint32_t v = state_of(static_cast<uint32_t>(i));
        if (!(v & kUnflooded) || v == kNoData) continue;
        uint32_t p = static_cast<uint32_t>(i);
        for (;;) {  // v: the state of p, not flooded yet
            const unsigned lower = v & 15u;
            uint32_t s[4];
            unsigned wait = 0;
            for (unsigned m = lower; m; m &= m - 1) {
                const int j = __builtin_ctz(m);
                s[j] = state_of(p + offset[j]);
                wait |= (s[j] >> 31) << j;
            }
            if (wait) {  // p waits under its lower neighbours; walk on to the last of them
                if (top + 5 > stack.size()) stack.resize(2 * stack.size() + 8);
                stack[top++] = p;
                for (unsigned m = wait; m; m &= m - 1) stack[top++] = p + offset[__builtin_ctz(m)];
            } else {
                uint32_t seed = p;
                if (lower) {
                    seed = s[__builtin_ctz(lower)];
                    unsigned other = 0;  // lower neighbours of another seed than the first one's
                    for (unsigned m = lower & (lower - 1); m; m &= m - 1) {
                        const int j = __builtin_ctz(m);
                        other |= unsigned(s[j] != seed) << j;
                    }
                    if (other) {  // several seeds: the first neighbour of each, the closest in colour wins
                        unsigned firsts = lower;
                        for (unsigned m = lower & (lower - 1); m; m &= m - 1) {
                            const int j = __builtin_ctz(m);
                            for (unsigned e = lower & ((1u << j) - 1); e; e &= e - 1)
                                if (s[__builtin_ctz(e)] == s[j]) firsts &= ~(1u << j);
                        }
                        seed = s[kPick[firsts][(v >> 4) & 0xFFu]];
                    }
                }
                std::atomic_ref<uint32_t>(parent[p]).store(seed, std::memory_order_relaxed);
            }
            bool more = false;  // on with the latest stacked pixel not flooded yet (reached twice, or by another thread)
            while (top > 0) {
                p = stack[--top];
                v = state_of(p);
                if (v & kUnflooded) {
                    more = true;
                    break;
                }
            }
            if (!more) break;
        }
    }
}

// The walk over all rows: blocks of rows in parallel, in stages so that
// progress is reported from the calling thread.
void flood_descent(uint32_t w, uint32_t h, uint32_t* parent, const Progress& progress) {
    constexpr uint32_t kBlockRows = 32;
    const uint32_t blocks = (h + kBlockRows - 1) / kBlockRows;
    const std::size_t n = std::size_t(w) * h;
    const uint32_t per_stage = std::max<uint32_t>(8, (blocks + 7) / 8);
    for (uint32_t stage = 0; stage < blocks; stage += per_stage) {
        tbb::parallel_for(tbb::blocked_range<uint32_t>(stage, std::min(blocks, stage + per_stage), 1),
                          [&](const tbb::blocked_range<uint32_t>& range) {
                              std::vector<uint32_t> stack(1024);
                              for (uint32_t blk = range.begin(); blk != range.end(); ++blk) {
                                  const std::size_t first = std::size_t(blk) * kBlockRows * w;
                                  descend_rows(w, parent, first, std::min(n, first + std::size_t(kBlockRows) * w), stack);
                              }
                          });
        progress(0.5 + 0.4 * std::min(blocks, stage + per_stage) / blocks, "flooding");
    }
}

// The labels (1..count, 0 = nodata) as an Oversegmentation; progress done.
Oversegmentation finish_oversegmentation(LargeVector<uint32_t>&& labels, int w, int h, uint32_t count, const Progress& progress) {
    Oversegmentation out;
    out.labels.width = w, out.labels.height = h, out.labels.bands = 1;
    out.labels.data = std::move(labels);
    out.region_count = count;
    progress(1.0, "watershed");
    return out;
}

// label_basins without the seed -> label table (4 bytes a pixel, fresh
// memory), for fewer than 2^31 - 1 pixels whose basin seeds are pixels of
// their basins: a seed's label is kept in its own entry, tagged by the top
// bit, from the first pixel of its basin in raster order; the tags are
// cleared at the end. The same labels as label_basins. (Measured: cheaper
// than clearing each seed's tag on its own turn in the same pass, whose
// three-way branch on the seed's position mispredicts.)
Oversegmentation label_seeds_in_place(LargeVector<uint32_t>&& parent, int w, int h, const Progress& progress) {
    constexpr uint32_t kTag = 0x80000000u;
    const std::size_t n = parent.size();
    uint32_t* label = parent.data();
    uint32_t next = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const uint32_t r = label[i];
        if (r == kNoData) {
            label[i] = 0;
        } else if (!(r & kTag)) {  // else: a seed labelled before its own turn
            // r's entry is tagged once r is passed or labelled ahead of it.
            if (!(label[r] & kTag)) label[r] = kTag | ++next;
            label[i] = label[r];
        }
    }
    parallel_for_each_index(n, [&](std::size_t i) { label[i] &= ~kTag; });
    return finish_oversegmentation(std::move(parent), w, h, next, progress);
}

// Labels of the basins: parent[i] (a basin's seed pixel, or kNone for
// nodata) becomes the basin's label, numbered in raster order of first
// appearance; root_label (n zeros) is the seed -> label table.
Oversegmentation label_basins(LargeVector<uint32_t>&& parent, LargeVector<uint32_t>& root_label, int w, int h, const Progress& progress) {
    constexpr uint32_t kNone = 0xFFFFFFFFu;
    const std::size_t n = parent.size();
    uint32_t next = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const uint32_t r = parent[i];
        if (r == kNone) {
            parent[i] = 0;
            continue;
        }
        if (!root_label[r]) root_label[r] = ++next;
        parent[i] = root_label[r];
    }
    return finish_oversegmentation(std::move(parent), w, h, next, progress);
}

}  // namespace

Image<float> multiband_gradient(const Image<float>& image, const WatershedOptions& options) {
    const int w = image.width, h = image.height;
    // Small pages: these buffers are read row by row, and fresh huge pages
    // cost far more to touch first on a virtual machine (small_page_vector).
    Image<float> grad;
    grad.width = w, grad.height = h, grad.bands = 1;
    grad.data = small_page_vector<float>(image.pixel_count());
    grad.data.resize(image.pixel_count(), 0.0f);
    LargeVector<float> smooth, tmp;
    if (options.smoothing_sigma_px > 0.0) {
        smooth = small_page_vector<float>(image.pixel_count()), tmp = small_page_vector<float>(image.pixel_count());
        smooth.resize(image.pixel_count()), tmp.resize(image.pixel_count());
    }
    for (int b = 0; b < image.bands; ++b) {
        const double wb = options.band_weights.empty() ? 1.0 : options.band_weights[b];
        if (wb == 0.0) continue;
        const float* src = image.band_data(b);
        if (options.smoothing_sigma_px > 0.0) {
            gaussian_blur(src, smooth.data(), tmp.data(), w, h, options.smoothing_sigma_px);
            src = smooth.data();
        }
        const auto fw = static_cast<float>(wb);
        tbb::parallel_for(0, h, [&](int y) {
            const int y0 = std::max(0, y - 1), y1 = std::min(h - 1, y + 1);
            add_sobel_row(src + static_cast<std::size_t>(y0) * w, src + static_cast<std::size_t>(y) * w,
                          src + static_cast<std::size_t>(y1) * w, w, fw, grad.band_data(0) + static_cast<std::size_t>(y) * w);
        });
    }
    const float norm = gradient_norm(image, options);
    float* g = grad.band_data(0);
    parallel_for_each_index(grad.pixel_count(), [&](std::size_t i) { g[i] = std::sqrt(g[i]) * norm; });
    return grad;
}

Oversegmentation watershed_oversegment(const Image<float>& image, const std::vector<uint8_t>& valid,
                                       const WatershedOptions& options, const Progress& progress) {
    options.validate(image.bands);
    const int w = image.width, h = image.height;
    const std::size_t n = image.pixel_count();
    if (n == 0) throw Error("watershed", "empty image");
    if (!valid.empty() && valid.size() != n) throw Error("watershed", "valid mask size does not match the image");
    const auto h_levels = static_cast<uint32_t>(std::lround(options.h_minima * kLevelsPerUnit));
    if (h_levels == 0 && n < 0x7FFFFFFFu) {
        // Without dynamics: no sort, a parallel walk (flood_descent) gives the
        // same seeds. Without smoothing no level raster either: the states
        // are made from the bands by blocks of rows.
        LargeVector<uint32_t> parent = small_page_vector<uint32_t>(n);
        parent.resize(n);
        LargeVector<uint16_t> level;
        if (options.smoothing_sigma_px > 0.0) level = smoothed_gradient_levels(image, options);
        descent_states(image, options, level.empty() ? nullptr : level.data(), valid.empty() ? nullptr : valid.data(), parent.data());
        LargeVector<uint16_t>().swap(level);
        progress(0.3, "gradient");
        flood_descent(static_cast<uint32_t>(w), static_cast<uint32_t>(h), parent.data(), progress);
        return label_seeds_in_place(std::move(parent), w, h, progress);
    }
    // Integer levels (1/4 grey level) for a bucket (hierarchical) queue.
    // Without smoothing, straight from the bands (no float gradient raster).
    LargeVector<uint16_t> level;
    if (options.smoothing_sigma_px > 0.0) level = smoothed_gradient_levels(image, options);
    else level = unsmoothed_gradient_levels(image, options);
    progress(0.3, "gradient");
    constexpr uint32_t kNone = 0xFFFFFFFFu;
    // Band pointers in locals: stores to parent[] could otherwise alias the image's fields.
    const int bands = image.bands;
    std::vector<const float*> band_ptrs(bands);
    for (int b = 0; b < bands; ++b) band_ptrs[b] = image.band_data(b);
    const float* const* band = band_ptrs.data();

    // Counting sort of valid pixels by level; ties stay in raster order
    // (deterministic). Counted and scattered in parallel by row chunks:
    // chunk c's pixels of a level go after those of chunks < c, so the order
    // is the sequential one whatever the chunk count.
    const int chunk_rows = std::max(1, (h + 15) / 16);
    const int chunks = (h + chunk_rows - 1) / chunk_rows;
    auto chunk_range = [&](int c) {
        return std::pair<std::size_t, std::size_t>(static_cast<std::size_t>(c) * chunk_rows * w,
                                                   std::min<std::size_t>(n, static_cast<std::size_t>(c + 1) * chunk_rows * w));
    };
    std::vector<uint16_t> chunk_max(chunks, 0);
    tbb::parallel_for(0, chunks, [&](int c) {
        const auto [lo, hi] = chunk_range(c);
        uint16_t m = 0;
        for (std::size_t i = lo; i < hi; ++i) m = std::max(m, level[i]);
        chunk_max[c] = m;
    });
    const uint32_t max_level = *std::max_element(chunk_max.begin(), chunk_max.end());
    const std::size_t n_levels = std::size_t(max_level) + 1;
    std::vector<uint32_t> chunk_count(static_cast<std::size_t>(chunks) * n_levels, 0);  // [chunk][level]
    tbb::parallel_for(0, chunks, [&](int c) {
        const auto [lo, hi] = chunk_range(c);
        uint32_t* cc = chunk_count.data() + static_cast<std::size_t>(c) * n_levels;
        for (std::size_t i = lo; i < hi; ++i)
            if (valid.empty() || valid[i]) ++cc[level[i]];
    });
    // count[l] = start of level l in `order`; chunk_count becomes each chunk's write position.
    std::vector<uint32_t> count(n_levels + 1, 0);
    uint32_t n_valid = 0;
    for (std::size_t l = 0; l < n_levels; ++l) {
        count[l] = n_valid;
        for (int c = 0; c < chunks; ++c) {
            uint32_t& cc = chunk_count[static_cast<std::size_t>(c) * n_levels + l];
            const uint32_t k = cc;
            cc = n_valid;
            n_valid += k;
        }
    }
    count[n_levels] = n_valid;
    if (n_valid == 0) throw Error("watershed", "image has no valid (non-nodata) pixels");
    LargeVector<uint32_t> order = small_page_vector<uint32_t>(n);  // reused as the root -> label table at the end
    order.resize(n_valid);
    tbb::parallel_for(0, chunks, [&](int c) {
        const auto [lo, hi] = chunk_range(c);
        uint32_t* pos = chunk_count.data() + static_cast<std::size_t>(c) * n_levels;
        for (std::size_t i = lo; i < hi; ++i)
            if (valid.empty() || valid[i]) order[pos[level[i]]++] = static_cast<uint32_t>(i);
    });
    // count[l] is now made the end of level l's run (the start of l + 1's), as the flooding reads it.
    for (std::size_t l = 0; l < n_levels; ++l) count[l] = count[l + 1];
    progress(0.5, "sorting");

    // Union-find flooding (h > 0). parent == kNone: not yet flooded. Each root keeps the
    // level of its basin's minimum; basins meeting at level L merge when the
    // shallower one's depth (L - its minimum) is below h.
    LargeVector<uint32_t> parent = small_page_vector<uint32_t>(n);
    parent.resize(n, kNone);
    // The flooding reads levels from `count`; the level buffer holds the
    // basins' minima instead (written when a basin starts, read only for roots).
    LargeVector<uint16_t> min_level = std::move(level);
    // absorbed[r] (one bit per pixel, small enough to stay in cache) is set
    // when root r is merged into another basin. A flooded pixel points at a
    // root that usually still is one: one bit test then replaces the load of
    // the root's parent entry, a cache miss far away in the image.
    LargeVector<uint64_t> absorbed((n + 63) / 64, 0);
    auto is_absorbed = [&](uint32_t r) { return (absorbed[r >> 6] >> (r & 63)) & 1u; };
    auto find = [&](uint32_t x) {
        uint32_t r = parent[x];
        if (!is_absorbed(r)) return r;
        while (parent[r] != r) r = parent[r];
        while (parent[x] != r) {
            const uint32_t next = parent[x];
            parent[x] = r;
            x = next;
        }
        return r;
    };
    // count[l] is now the end of level l's run in `order` (the start of l + 1's).
    uint32_t lp = 0;
    // Pixels come in level order, scattered over the image: each one's
    // neighbourhood is a cache miss. The pixels a few steps ahead are known,
    // so their parent entries and colours are loaded while this one is done.
    constexpr uint32_t kAhead = 16;
    const std::size_t row = static_cast<std::size_t>(w);
    auto prefetch_pixel = [&](uint32_t q) {
        const uint32_t* pq = parent.data() + q;
        prefetch_line(pq);
        if (q >= row) prefetch_line(pq - row);
        if (q + row < n) prefetch_line(pq + row);
        for (int b = 0; b < bands; ++b) {
            prefetch_line(band[b] + q);
            if (q >= row) prefetch_line(band[b] + q - row);
            if (q + row < n) prefetch_line(band[b] + q + row);
        }
    };
    for (uint32_t k = 0; k < n_valid; ++k) {
        if ((k & 0xFFFFF) == 0) progress(0.5 + 0.4 * k / n_valid, "flooding");
        while (k >= count[lp]) ++lp;  // the level of order[k], without reading level[]
        if (k + kAhead < n_valid) prefetch_pixel(order[k + kAhead]);
        const uint32_t p = order[k];
        const int x = static_cast<int>(p % static_cast<uint32_t>(w)), y = static_cast<int>(p / static_cast<uint32_t>(w));
        uint32_t roots[4], via[4];
        int nr = 0;
        auto visit = [&](uint32_t q) {
            if (parent[q] == kNone) return;
            const uint32_t r = find(q);
            for (int i = 0; i < nr; ++i)
                if (roots[i] == r) return;
            via[nr] = q;
            roots[nr++] = r;
        };
        if (y > 0) visit(p - static_cast<uint32_t>(w));
        if (x > 0) visit(p - 1);
        if (x < w - 1) visit(p + 1);
        if (y < h - 1) visit(p + static_cast<uint32_t>(w));
        if (nr == 1) {
            parent[p] = roots[0];
            continue;
        }
        if (nr == 0) {
            parent[p] = p;
            if (h_levels > 0) min_level[p] = static_cast<uint16_t>(lp);
            continue;
        }
        // The flooded neighbour most similar in colour decides where p goes, so
        // region borders follow the colour edge rather than the flooding order.
        uint32_t closest_root = roots[0];
        float closest = INFINITY;
        for (int i = 0; i < nr; ++i) {
            float d = 0.0f;
            for (int b = 0; b < bands; ++b) {
                const float diff = band[b][p] - band[b][via[i]];
                d += diff * diff;
            }
            if (d < closest) closest = d, closest_root = roots[i];
        }
        // Deepest basin first (lowest minimum, then lowest root index).
        auto deeper = [&](uint32_t a, uint32_t b) {
            return min_level[a] != min_level[b] ? min_level[a] < min_level[b] : a < b;
        };
        for (int i = 1; i < nr; ++i)  // insertion sort of at most 4 roots
            for (int j = i; j > 0 && deeper(roots[j], roots[j - 1]); --j) std::swap(roots[j], roots[j - 1]);
        const uint32_t deepest = roots[0];
        bool closest_merged = false;
        for (int i = 1; i < nr; ++i)
            if (lp - min_level[roots[i]] < h_levels) {
                parent[roots[i]] = deepest;
                absorbed[roots[i] >> 6] |= uint64_t(1) << (roots[i] & 63);
                closest_merged = closest_merged || roots[i] == closest_root;
            }
        parent[p] = closest_merged ? deepest : closest_root;
    }

    // Label in place: parent[i] becomes the basin's label, numbered in raster
    // order of first appearance; `order` is reused as the root -> label table.
    for (std::size_t i = 0; i < n; ++i)
        if (parent[i] != kNone) parent[i] = find(static_cast<uint32_t>(i));
    LargeVector<uint32_t>& root_label = order;
    root_label.assign(n, 0);
    return label_basins(std::move(parent), root_label, w, h, progress);
}

}  // namespace cityforge
