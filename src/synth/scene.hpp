#pragma once
// A synthetic town with exact ground truth: street grid, blocks, buildings of
// several shapes and roof types, trees, gently sloping terrain. Pure geometry
// (no GDAL): coordinates are scene-local metres, x east and y north from the
// scene's lower-left corner; writers add the CRS origin.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/geometry.hpp"

namespace cityforge::synth {

enum class RoofType { flat, shed, gable, hip };
enum class BuildingShape { rectangle, l_shape, t_shape, u_shape, courtyard };
std::string to_string(RoofType t);
std::string to_string(BuildingShape s);

/// A rectangle in a building's local frame (u along the building axis, v across), metres.
struct Wing {
    double u0 = 0, v0 = 0, u1 = 0, v1 = 0;
    bool contains(double u, double v) const { return u >= u0 && u <= u1 && v >= v0 && v <= v1; }
};

struct LocalPoint {
    double u = 0, v = 0;
};

struct SceneBuilding {
    int id = 0;                      ///< 1-based, unique in the scene
    BuildingShape shape = BuildingShape::rectangle;
    RoofType roof = RoofType::flat;
    double cx = 0, cy = 0;           ///< centre, scene-local metres
    double angle_rad = 0;            ///< rotation of the local u axis from east, counter-clockwise
    std::vector<Wing> wings;         ///< union = footprint; each wing carries its own roof
    std::vector<LocalPoint> outline;            ///< exterior ring, counter-clockwise, local frame
    std::vector<std::vector<LocalPoint>> holes; ///< courtyards, clockwise, local frame
    double ground_z = 0;             ///< terrain height at the centre (building base), m
    double eave_height_m = 0;        ///< above ground_z
    double ridge_height_m = 0;       ///< above ground_z (= eave for flat roofs)
    double pitch_tan = 0;            ///< roof slope as tan(pitch); 0 for flat
    std::array<uint8_t, 3> color{};  ///< roof base colour
    bool dark_roof = false;          ///< low LiDAR reflectance: most returns missing
    /// The outline is not the union of the wings (a corner cut off at an
    /// oblique angle): containment tests the outline, roofs still come from the wings.
    bool oblique = false;

    /// Local frame coordinates of a scene point.
    LocalPoint to_local(double x, double y) const;
    /// Scene coordinates of a local point.
    std::array<double, 2> to_scene(LocalPoint p) const;
    bool contains(double x, double y) const;
    /// Roof height above ground_z at a scene point inside the footprint, with
    /// its gradient in scene axes (dz/dx, dz/dy).
    double roof_height(double x, double y, double* dzdx = nullptr, double* dzdy = nullptr) const;
    double area_m2() const;
    /// The footprint in map coordinates: scene-local metres shifted by (ox, oy);
    /// exterior counter-clockwise, courtyards clockwise.
    Polygon footprint(double ox = 0.0, double oy = 0.0) const;
};

struct SceneTree {
    double cx = 0, cy = 0;  ///< scene-local metres
    double radius = 3;      ///< crown radius, m
    double height = 10;     ///< tree top above ground, m
    double crown_base = 3;  ///< crown base above ground, m
    double ground_z = 0;
    std::array<uint8_t, 3> color{};
    /// Crown surface height (absolute) at a point, or -inf outside the crown.
    double crown_z(double x, double y) const;
};

/// How far a town departs from the default generator. The defaults give the
/// default town (same seed, same scene, byte for byte); every share is a
/// probability in [0, 1] drawn from its own random stream.
struct SceneVariation {
    double terrain_slope_max = 0.008;    ///< |dz/dx| and |dz/dy| of the planar terrain drawn up to this (0.1 = 10 %)
    double terrain_undulation_m = 1.2;   ///< amplitude of the terrain's long-wave undulation, metres
    double dark_roof_share = 0.05;       ///< roofs that absorb most LiDAR pulses
    double tree_touch_share = 0.25;      ///< buildings with a tree crown touching their side
    double ground_like_roof_share = 0.0; ///< roofs coloured like grass, soil or road
    double terraced_block_share = 0.0;   ///< blocks built as terraces: touching buildings of equal height
    double oblique_share = 0.0;          ///< rectangular buildings with a corner cut off at an oblique angle
    /// Rectangular buildings drawn instead as round or many-sided flat-roofed
    /// buildings inscribed in their rectangle: circles and ellipses (48
    /// vertices), octagons and hexagons, at any rotation.
    double round_share = 0.0;
    bool all_roof_families = false;      ///< roof types drawn with equal shares (flat, shed, gable, hip) instead of the default mix
    /// Building base at the terrain height of the footprint's area centroid
    /// (the mean terrain under it) instead of at its bounding-box centre.
    bool base_at_area_centroid = false;
    void validate() const;               ///< throws Error naming the option
};

struct SceneLayout {
    double size_m = 500;
    uint64_t seed = 1;
    SceneVariation variation;
};

struct Scene {
    double size_m = 500;
    uint64_t seed = 1;
    std::array<double, 3> terrain{};    ///< z0, dz/dx, dz/dy of the planar part
    double undulation_m = 1.2;          ///< amplitude of the long-wave part
    std::vector<std::array<double, 2>> roads_x;  ///< [x0, x1] intervals of north–south roads
    std::vector<std::array<double, 2>> roads_y;  ///< [y0, y1] intervals of east–west roads
    std::vector<SceneBuilding> buildings;
    std::vector<SceneTree> trees;

    /// Terrain height (absolute, m) at a scene point: a gentle plane plus a
    /// low-amplitude undulation, so heights above ground differ from z.
    double terrain_z(double x, double y) const;
    bool on_road(double x, double y) const;
};

/// Generates the scene for `layout` deterministically (same seed, same scene).
Scene generate_scene(const SceneLayout& layout);

/// Points on a building's exact roof: a jittered grid of `density` points per
/// m² inside its footprint, z noise of `sigma` metres, scene-local x, y and
/// absolute z. Deterministic in (seed, building id). For LOD2 tests and benchmarks.
std::vector<std::array<double, 3>> sample_roof_points(const SceneBuilding& building, double density, double sigma, uint64_t seed);

}  // namespace cityforge::synth
