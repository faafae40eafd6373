#pragma once
// Internal to synth: the top-down rendering of a Scene on a pixel grid (labels,
// DSM, cast shadows, colours) shared by the ortho/cloud writer (synth.cpp) and
// the perspective views (views.cpp).
#include <cstdint>

#include "core/image.hpp"
#include "core/progress.hpp"
#include "synth/scene.hpp"

namespace cityforge::synth {

inline constexpr double kSunAzimuthDeg = 135.0;   ///< sun in the south-east: shadows fall north-west
inline constexpr double kSunElevationDeg = 48.0;

/// A scene on a north-up grid of `gsd` metres; row 0 is the scene's north edge.
struct Rendered {
    Image<uint32_t> building;   ///< building id per pixel (0 = none), pixel-centre sampling
    Image<uint32_t> tree;       ///< visible tree id + 1 per pixel (0 = none)
    Image<float> dsm;           ///< top surface, absolute metres
    Image<uint8_t> shadow;      ///< 1 = in cast shadow
    Image<uint8_t> rgb;         ///< filled by colourise()
};

/// Pixel-centre rasterisation of buildings and trees, the DSM and cast shadows
/// for a sun at bearing `sun_az_deg` (clockwise from north) and elevation `sun_el_deg`.
Rendered render(const Scene& scene, double gsd, double sun_az_deg, double sun_el_deg, const Progress& progress);
/// Sun-shaded, textured colours of `r` (r.rgb), same sun as render().
void colourise(const Scene& scene, double gsd, double sun_az_deg, double sun_el_deg, Rendered& r);

}  // namespace cityforge::synth
