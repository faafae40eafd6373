#pragma once
// A synthetic town with exact truth for tests: one call instead of filling
// SynthOptions by hand in every test.
#include <cstdint>

#include "synth/synth.hpp"
#include "test_support.hpp"

namespace cityforge::test {

/// Writes a town of `size_m` x `size_m` metres (UTM 50N, default origin) into
/// `dir`; `cloud_density_m2` = 0 writes no cloud.
inline SynthResult make_town(const ScratchDir& dir, double size_m, uint64_t seed, double cloud_density_m2,
                             CloudMode mode = CloudMode::lidar) {
    SynthOptions o;
    o.size_m = size_m;
    o.seed = seed;
    o.cloud_density_m2 = cloud_density_m2;
    o.cloud_mode = mode;
    return write_synthetic_town(dir.path.string(), o);
}

}  // namespace cityforge::test
