#pragma once
// Roof points sampled from synthetic scene buildings with exact roofs, for
// the LOD2 tests: a jittered grid at `density` points per m², z noise sigma.
#include <array>
#include <vector>

#include "core/geometry.hpp"
#include "core/random.hpp"
#include "synth/scene.hpp"

namespace cityforge::test {

struct RoofSample {
    std::vector<Polygon> footprint;               ///< scene-local metres
    std::vector<std::array<double, 3>> points;    ///< on the roof, z absolute
    double ground_z = 0.0;
};

inline RoofSample sample_roof(const synth::SceneBuilding& b, double density, double sigma, uint64_t seed) {
    RoofSample s;
    Polygon p;
    for (const auto& q : b.outline) {
        const auto xy = b.to_scene(q);
        p.outer.push_back({xy[0], xy[1]});
    }
    for (const auto& h : b.holes) {
        p.holes.emplace_back();
        for (const auto& q : h) {
            const auto xy = b.to_scene(q);
            p.holes.back().push_back({xy[0], xy[1]});
        }
    }
    orient_polygon(p);
    s.footprint = {p};
    s.ground_z = b.ground_z;
    const Extent e = polygon_extent(p);
    const double step = 1.0 / std::sqrt(density);
    Rng rng(seed, static_cast<uint64_t>(b.id));
    for (double y = e.min_y; y < e.max_y; y += step)
        for (double x = e.min_x; x < e.max_x; x += step) {
            const double px = x + rng.uniform(0, step), py = y + rng.uniform(0, step);
            if (!point_in_polygon(p, px, py)) continue;
            s.points.push_back({px, py, b.ground_z + b.roof_height(px, py) + sigma * rng.normal()});
        }
    return s;
}

}  // namespace cityforge::test
