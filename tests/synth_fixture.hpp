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

/// A small town photographed by `views` cameras in strips (120 m, seed 3,
/// 320 x 240 px photos at 0.15 m, exact surface every 0.15 m), no cloud.
inline SynthResult make_views(const ScratchDir& dir, int views = 4) {
    SynthOptions o;
    o.size_m = 120;
    o.seed = 3;
    o.cloud_density_m2 = 0;
    o.views.views = views;
    o.views.gsd_m = 0.15;
    o.views.width_px = 320;
    o.views.height_px = 240;
    o.views.surface_spacing_m = 0.15;
    return write_synthetic_town(dir.path.string(), o);
}

}  // namespace cityforge::test
