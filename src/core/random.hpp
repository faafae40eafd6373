#pragma once
// Counter-based pseudo-random numbers (SplitMix64). Every value is a pure
// function of (seed, counters), so results do not depend on thread order or
// on the standard library's distribution implementations.
#include <cmath>
#include <cstdint>

namespace cityforge {

constexpr uint64_t splitmix64(uint64_t z) {
    z += 0x9e3779b97f4a7c15ULL;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/// Hash of a seed and up to three counters.
constexpr uint64_t hash64(uint64_t seed, uint64_t a, uint64_t b = 0, uint64_t c = 0) {
    return splitmix64(seed ^ splitmix64(a ^ splitmix64(b ^ splitmix64(c + 0x632be59bd9b4e019ULL))));
}

/// Uniform in [0, 1) from a hash.
constexpr double unit_from_hash(uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

/// Approximately standard normal (Irwin–Hall of 4 uniforms, scaled to unit variance).
constexpr double normal_from_hash(uint64_t h) {
    double s = 0.0;
    for (int i = 0; i < 4; ++i) {
        h = splitmix64(h);
        s += unit_from_hash(h);
    }
    return (s - 2.0) * 1.7320508075688772;
}

/// Sequential generator for code that draws many numbers in a fixed order.
class Rng {
public:
    explicit Rng(uint64_t seed, uint64_t stream = 0) : state_(hash64(seed, stream, 0x5eed)) {}
    uint64_t next() { return splitmix64(state_++); }
    double uniform() { return unit_from_hash(next()); }
    double uniform(double a, double b) { return a + (b - a) * uniform(); }
    /// Integer in [a, b] inclusive.
    int integer(int a, int b) { return a + static_cast<int>(uniform() * (b - a + 1)); }
    bool chance(double p) { return uniform() < p; }
    double normal() { return normal_from_hash(next()); }

private:
    uint64_t state_;
};

/// Smooth value noise in [0, 1): bilinear interpolation of hashed lattice
/// values with cell size `cell` (same units as x, y).
inline double value_noise(uint64_t seed, double x, double y, double cell) {
    const double fx = x / cell, fy = y / cell;
    const double x0 = std::floor(fx), y0 = std::floor(fy);
    const double tx = fx - x0, ty = fy - y0;
    const auto ix = static_cast<int64_t>(x0), iy = static_cast<int64_t>(y0);
    auto v = [&](int64_t a, int64_t b) {
        return unit_from_hash(hash64(seed, static_cast<uint64_t>(a), static_cast<uint64_t>(b), 77));
    };
    const double sx = tx * tx * (3 - 2 * tx), sy = ty * ty * (3 - 2 * ty);
    const double top = v(ix, iy) * (1 - sx) + v(ix + 1, iy) * sx;
    const double bottom = v(ix, iy + 1) * (1 - sx) + v(ix + 1, iy + 1) * sx;
    return top * (1 - sy) + bottom * sy;
}

}  // namespace cityforge
