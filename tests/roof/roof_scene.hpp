#pragma once
// Roof points sampled from synthetic scene buildings with exact roofs, for
// the LOD2 tests: a jittered grid at `density` points per m², z noise sigma.
#include <array>
#include <vector>

#include "core/geometry.hpp"
#include "synth/scene.hpp"

namespace cityforge::test {

struct RoofSample {
    std::vector<Polygon> footprint;               ///< scene-local metres
    std::vector<std::array<double, 3>> points;    ///< on the roof, z absolute
    double ground_z = 0.0;
};

inline RoofSample sample_roof(const synth::SceneBuilding& b, double density, double sigma, uint64_t seed) {
    RoofSample s;
    Polygon p = b.footprint();
    orient_polygon(p);
    s.footprint = {p};
    s.ground_z = b.ground_z;
    s.points = synth::sample_roof_points(b, density, sigma, seed);
    return s;
}

}  // namespace cityforge::test
