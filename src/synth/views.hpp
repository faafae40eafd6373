#pragma once
// Perspective aerial photos of a synthetic scene with exact truth: a flight
// plan of strips with forward and side overlap, pinhole cameras looking down
// (small attitude jitter) or an oblique camera of 5 heads per station, images ray-cast against the scene's fine DSM with
// sun shading, cast shadows, facades and ground texture; plus the exact
// surface (terrain, roofs, walls, tree crowns) as a reference cloud.
#include <cstdint>
#include <string>

#include "core/progress.hpp"
#include "photo/camera.hpp"
#include "synth/scene.hpp"

namespace cityforge::synth {

/// Class of wall samples in surface.las (LAS 1.4 user-definable range):
/// terrain is 2, roofs 6, tree crowns 5, walls this.
inline constexpr uint8_t kSurfaceWallClass = 64;

struct ViewsOptions {
    int views = 0;                   ///< number of photos (>= 2 when asked for)
    double gsd_m = 0.1;              ///< ground sample distance at mean terrain height, metres/pixel
    int width_px = 640, height_px = 480;
    double forward_overlap = 0.8;    ///< along-strip overlap of neighbouring photos, 0..0.95
    double side_overlap = 0.6;       ///< overlap of neighbouring strips, 0..0.95
    double focal_px = 0.0;           ///< 0 = image width (about 53 degrees across)
    /// 0 = nadir photos only. > 0: an oblique ("Maltese cross") camera: each
    /// station takes 5 photos, nadir and 4 tilted by this angle towards north,
    /// east, south and west, so walls facing every way are seen in several
    /// photos; `views` must then be a multiple of 5. Degrees, 0..50.
    double oblique_deg = 0.0;
    double surface_spacing_m = 0.1;  ///< sample spacing of surface.las
    /// Throws Error on out-of-range values.
    void validate() const;
};

struct ViewsResult {
    photo::CameraSet cameras;  ///< the exact cameras (map coordinates)
    uint64_t surface_points = 0;
};

/// Renders `options.views` photos of `scene` into `out_dir`/views (view_NNN.png,
/// cameras_truth.json, gps.txt with WGS 84 positions) and writes
/// `out_dir`/surface.las (classes 2 terrain, 5 crowns, 6 roofs,
/// kSurfaceWallClass walls). Map coordinates = scene-local + (origin_x, origin_y)
/// in EPSG:`epsg`. Deterministic in (scene, options, seed).
ViewsResult write_views(const std::string& out_dir, const Scene& scene, const ViewsOptions& options, int epsg,
                        double origin_x, double origin_y, uint64_t seed, const Progress& progress = {});

}  // namespace cityforge::synth
