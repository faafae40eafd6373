#pragma once
// `cityforge synth`: renders a generated Scene to the files a real survey
// gives (ortho GeoTIFF, LAS point cloud) plus exact truth (GeoJSON footprints,
// building label raster) in a real projected CRS.
#include <cstdint>
#include <string>

#include "core/progress.hpp"
#include "synth/scene.hpp"
#include "synth/views.hpp"

namespace cityforge {

enum class CloudMode { lidar, photo };
std::string to_string(CloudMode m);
CloudMode cloud_mode_from_string(const std::string& s);

struct SynthOptions {
    double size_m = 500.0;          ///< scene edge length, metres (square scene)
    double gsd_m = 0.5;             ///< ortho ground sample distance, metres
    uint64_t seed = 1;              ///< same seed -> same bytes
    int epsg = 32650;               ///< projected CRS with metre units
    double origin_x = 500000.0;     ///< lower-left corner easting, CRS units
    double origin_y = 4400000.0;    ///< lower-left corner northing, CRS units
    double cloud_density_m2 = 8.0;  ///< points per square metre; 0 = no cloud
    CloudMode cloud_mode = CloudMode::lidar;
    /// Perspective photos and the exact surface (views/, surface.las); views.views = 0 (default) = none.
    synth::ViewsOptions views;
    double lidar_sigma_m = 0.03;    ///< vertical noise of LiDAR points, metres (photo mode: 0.12)
    double sun_azimuth_deg = 135.0; ///< sun bearing, clockwise from north (shading and cast shadows)
    double sun_elevation_deg = 48.0;///< sun elevation above the horizon, degrees (5..90)
    synth::SceneVariation variation;///< terrain, roof colours, terraces, oblique corners, roof mix (defaults: the default town)
    /// Throws Error on out-of-range values (size 20..20000 m, GSD 0.05..10 m, ...).
    void validate() const;
};

struct SynthResult {
    std::string ortho_path;        ///< ortho.tif (RGB Byte)
    std::string cloud_path;        ///< cloud.las (empty when no cloud)
    std::string truth_path;        ///< truth.geojson
    std::string truth_raster_path; ///< truth_buildings.tif (UInt32 building id per pixel, 0 = none)
    std::string scene_path;        ///< scene.json
    std::string views_dir;         ///< views/ (photos, cameras_truth.json, gps.txt); empty when none
    std::string surface_path;      ///< surface.las (exact surface); empty when no views
    int views = 0;
    uint64_t surface_points = 0;
    int width = 0, height = 0;     ///< ortho size in pixels
    int buildings = 0;
    int trees = 0;
    uint64_t points = 0;
    double seconds = 0.0;
};

/// Generates the scene and writes all files into `out_dir` (created if needed).
SynthResult write_synthetic_town(const std::string& out_dir, const SynthOptions& options, const Progress& progress = {});

}  // namespace cityforge
