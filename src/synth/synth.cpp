#include "synth/synth.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <numbers>
#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>

#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/image.hpp"
#include "core/random.hpp"
#include "crs/crs.hpp"
#include "io/vector.hpp"
#include "raster/raster.hpp"
#include "synth/render.hpp"

namespace cityforge {

std::string to_string(CloudMode m) { return m == CloudMode::lidar ? "lidar" : "photo"; }

CloudMode cloud_mode_from_string(const std::string& s) {
    if (s == "lidar") return CloudMode::lidar;
    if (s == "photo") return CloudMode::photo;
    throw Error("--cloud-mode", "must be 'lidar' or 'photo', not '" + s + "'");
}

void SynthOptions::validate() const {
    if (!(size_m >= 20.0 && size_m <= 20000.0)) throw Error("--size-m", "must be between 20 and 20000 metres");
    if (!(gsd_m >= 0.05 && gsd_m <= 10.0)) throw Error("--gsd", "must be between 0.05 and 10 metres");
    if (size_m / gsd_m > 100000.0) throw Error("--size-m", "scene would exceed 100000 pixels per side");
    if (!(cloud_density_m2 >= 0.0 && cloud_density_m2 <= 200.0)) throw Error("--cloud-density", "must be between 0 and 200 points/m2");
    if (!std::isfinite(origin_x) || !std::isfinite(origin_y)) throw Error("--origin", "must be finite");
    if (views.views != 0) views.validate();
    if (!(lidar_sigma_m >= 0.0 && lidar_sigma_m <= 1.0)) throw Error("--lidar-sigma-m", "must be between 0 and 1 m");
    if (!(sun_azimuth_deg >= 0.0 && sun_azimuth_deg < 360.0)) throw Error("--sun-azimuth-deg", "must be in [0, 360)");
    if (!(sun_elevation_deg >= 5.0 && sun_elevation_deg <= 90.0)) throw Error("--sun-elevation-deg", "must be between 5 and 90");
    variation.validate();
}

namespace synth {


// Pixel-centre rasterisation of buildings and trees plus the DSM.
Rendered render(const Scene& scene, double gsd, double sun_az_deg, double sun_el_deg, const Progress& progress) {
    const int n = static_cast<int>(std::lround(scene.size_m / gsd));
    Rendered r;
    r.building = Image<uint32_t>(n, n, 1, 0u);
    r.tree = Image<uint32_t>(n, n, 1, 0u);
    r.dsm = Image<float>(n, n, 1, 0.0f);
    auto centre_x = [&](int col) { return (col + 0.5) * gsd; };
    auto centre_y = [&](int row) { return scene.size_m - (row + 0.5) * gsd; };

    tbb::parallel_for(0, n, [&](int row) {
        const double y = centre_y(row);
        for (int col = 0; col < n; ++col) r.dsm.at(0, col, row) = static_cast<float>(scene.terrain_z(centre_x(col), y));
    });
    progress(0.2, "terrain");
    // Buildings never overlap, so rasterising them in any order gives the same result.
    tbb::parallel_for(std::size_t(0), scene.buildings.size(), [&](std::size_t i) {
        const SceneBuilding& b = scene.buildings[i];
        double minx = 1e300, maxx = -1e300, miny = 1e300, maxy = -1e300;
        for (const auto& p : b.outline) {
            const auto xy = b.to_scene(p);
            minx = std::min(minx, xy[0]), maxx = std::max(maxx, xy[0]);
            miny = std::min(miny, xy[1]), maxy = std::max(maxy, xy[1]);
        }
        const int c0 = std::max(0, int(std::floor(minx / gsd))), c1 = std::min(n - 1, int(std::ceil(maxx / gsd)));
        const int r0 = std::max(0, int(std::floor((scene.size_m - maxy) / gsd))), r1 = std::min(n - 1, int(std::ceil((scene.size_m - miny) / gsd)));
        for (int row = r0; row <= r1; ++row)
            for (int col = c0; col <= c1; ++col) {
                const double x = centre_x(col), y = centre_y(row);
                if (!b.contains(x, y)) continue;
                r.building.at(0, col, row) = static_cast<uint32_t>(b.id);
                r.dsm.at(0, col, row) = static_cast<float>(b.ground_z + b.roof_height(x, y));
            }
    });
    progress(0.5, "buildings");
    // Trees overlap each other: apply them in id order so the result is deterministic.
    for (std::size_t i = 0; i < scene.trees.size(); ++i) {
        const auto& t = scene.trees[i];
        const int c0 = std::max(0, int(std::floor((t.cx - t.radius) / gsd))), c1 = std::min(n - 1, int(std::ceil((t.cx + t.radius) / gsd)));
        const int r0 = std::max(0, int(std::floor((scene.size_m - t.cy - t.radius) / gsd)));
        const int r1 = std::min(n - 1, int(std::ceil((scene.size_m - t.cy + t.radius) / gsd)));
        for (int row = r0; row <= r1; ++row)
            for (int col = c0; col <= c1; ++col) {
                const double z = t.crown_z(centre_x(col), centre_y(row));
                if (z > r.dsm.at(0, col, row)) {
                    r.dsm.at(0, col, row) = static_cast<float>(z);
                    r.tree.at(0, col, row) = static_cast<uint32_t>(i + 1);
                }
            }
    }
    progress(0.6, "trees");
    // Cast shadows: one sweep along the sun direction (towards the south-east =
    // +col, +row). H is the height of the sun ray grazing the highest obstacle.
    r.shadow = Image<uint8_t>(n, n, 1, 0);
    if (sun_az_deg != kSunAzimuthDeg || sun_el_deg != kSunElevationDeg) {
        // Any other sun: march from every pixel towards the sun until the ray
        // clears the highest surface of the scene.
        const double az = sun_az_deg * std::numbers::pi / 180.0;
        const double rise = std::tan(sun_el_deg * std::numbers::pi / 180.0);  // ray height gained per metre
        const double dx = std::sin(az), dy = std::cos(az);                      // towards the sun, scene axes
        float zmax = -1e30f;
        for (float v : r.dsm.data) zmax = std::max(zmax, v);
        tbb::parallel_for(0, n, [&](int row) {
            for (int col = 0; col < n; ++col) {
                const float z0 = r.dsm.at(0, col, row);
                const double reach = (zmax - z0) / rise;
                for (double d = gsd; d <= reach; d += gsd) {
                    const int cc = static_cast<int>(std::floor(col + 0.5 + dx * d / gsd));
                    const int rr = static_cast<int>(std::floor(row + 0.5 - dy * d / gsd));
                    if (cc < 0 || rr < 0 || cc >= n || rr >= n) break;
                    if (r.dsm.at(0, cc, rr) > z0 + d * rise + 0.05) {
                        r.shadow.at(0, col, row) = 1;
                        break;
                    }
                }
            }
        });
    } else {
        const double drop = gsd * std::sqrt(2.0) * std::tan(kSunElevationDeg * std::numbers::pi / 180.0);
        std::vector<float> below(n + 1, -1e30f), cur(n + 1, -1e30f);
        for (int row = n - 1; row >= 0; --row) {
            for (int col = n - 1; col >= 0; --col) {
                // Horizon from the pixel diagonally towards the sun (row + 1, col + 1).
                const float h = below[col + 1] - static_cast<float>(drop);
                const float z = r.dsm.at(0, col, row);
                if (h > z + 0.05f) r.shadow.at(0, col, row) = 1;
                cur[col] = std::max(h, z);
            }
            std::swap(below, cur);
        }
    }
    progress(0.7, "shadows");
    return r;
}

void colourise(const Scene& scene, double gsd, double sun_az_deg, double sun_el_deg, Rendered& r) {
    const int n = r.building.width;
    r.rgb = Image<uint8_t>(n, n, 3, 0);
    const double az = sun_az_deg * std::numbers::pi / 180.0, el = sun_el_deg * std::numbers::pi / 180.0;
    const double sun[3] = {std::sin(az) * std::cos(el), std::cos(az) * std::cos(el), std::sin(el)};
    const uint64_t seed = scene.seed;
    tbb::parallel_for(0, n, [&](int row) {
        const double y = scene.size_m - (row + 0.5) * gsd;
        for (int col = 0; col < n; ++col) {
            const double x = (col + 0.5) * gsd;
            double c[3];
            double texture = 4.0;
            if (const uint32_t t = r.tree.at(0, col, row)) {
                const auto& tree = scene.trees[t - 1];
                const double dx = (x - tree.cx) / tree.radius, dy = (y - tree.cy) / tree.radius;
                const double lit = 0.75 + 0.35 * (dx * sun[0] + dy * sun[1]);
                for (int k = 0; k < 3; ++k) c[k] = tree.color[k] * lit;
                texture = 14.0;
            } else if (const uint32_t id = r.building.at(0, col, row)) {
                const SceneBuilding& b = scene.buildings[id - 1];
                double gx = 0, gy = 0;
                b.roof_height(x, y, &gx, &gy);
                const double nn = std::sqrt(gx * gx + gy * gy + 1.0);
                const double cos_i = (-gx * sun[0] - gy * sun[1] + sun[2]) / nn;
                const double shade = 0.35 + 0.65 * std::max(0.0, cos_i) / sun[2];
                for (int k = 0; k < 3; ++k) c[k] = b.color[k] * std::min(shade, 1.25);
                texture = 3.0;
            } else if (scene.on_road(x, y)) {
                const double v = 92 + 10 * value_noise(seed + 7, x, y, 25.0);
                c[0] = v, c[1] = v, c[2] = v + 4;
            } else {
                const double g = value_noise(seed + 3, x, y, 18.0);
                const double soil = value_noise(seed + 5, x, y, 40.0);
                if (soil > 0.8) {  // bare soil / gravel patches
                    c[0] = 150, c[1] = 130, c[2] = 100;
                } else {
                    c[0] = 78 + 30 * g, c[1] = 118 + 30 * g, c[2] = 55 + 15 * g;
                }
                texture = 8.0;
            }
            const double shadow = r.shadow.at(0, col, row) ? 0.42 : 1.0;
            const uint64_t h = hash64(seed, static_cast<uint64_t>(row), static_cast<uint64_t>(col), 11);
            const double common = texture * normal_from_hash(h);
            for (int k = 0; k < 3; ++k) {
                const double noise = common + 2.0 * normal_from_hash(hash64(seed, row, col, 20 + k));
                r.rgb.at(k, col, row) = static_cast<uint8_t>(std::clamp(std::lround(c[k] * shadow + noise), 0L, 255L));
            }
        }
    });
}

}  // namespace synth

namespace {

using synth::Rendered;
using synth::Scene;
using synth::SceneBuilding;
using synth::kSunAzimuthDeg;
using synth::kSunElevationDeg;

// Points of one raster row: surface z at exact positions, with mode-dependent
// noise, gaps and outliers. A pure function of (seed, row), so rows can be made
// in parallel and concatenated in order.
void cloud_row(const Scene& scene, const Rendered& r, double gsd, const SynthOptions& o, int row, PointCloud& out) {
    const int n = r.building.width;
    const double per_pixel = o.cloud_density_m2 * gsd * gsd;
    const bool photo = o.cloud_mode == CloudMode::photo;
    const uint64_t seed = o.seed * 7919 + 17;
    for (int col = 0; col < n; ++col) {
        uint64_t h = hash64(seed, static_cast<uint64_t>(row), static_cast<uint64_t>(col), 1);
        int count = static_cast<int>(per_pixel);
        if (unit_from_hash(h) < per_pixel - count) ++count;
        // Candidate buildings for exact containment: those in the 3x3 neighbourhood.
        uint32_t cand[9];
        int nc = 0;
        bool edge = false;
        const uint32_t own = r.building.at(0, col, row);
        for (int dr = -1; dr <= 1; ++dr)
            for (int dc = -1; dc <= 1; ++dc) {
                const int rr = row + dr, cc = col + dc;
                if (rr < 0 || cc < 0 || rr >= n || cc >= n) continue;
                const uint32_t id = r.building.at(0, cc, rr);
                if (id != own) edge = true;
                if (id && std::find(cand, cand + nc, id) == cand + nc) cand[nc++] = id;
            }
        const uint32_t tree_id = r.tree.at(0, col, row);
        const bool in_shadow = r.shadow.at(0, col, row);
        for (int k = 0; k < count; ++k) {
            h = splitmix64(h + static_cast<uint64_t>(k) * 0x9e37ULL);
            const double x = (col + unit_from_hash(splitmix64(h ^ 1))) * gsd;
            const double y = o.size_m - (row + unit_from_hash(splitmix64(h ^ 2))) * gsd;
            const double ground = scene.terrain_z(x, y);
            double z = ground;
            uint8_t cls = las_class::ground;
            uint8_t ret = 1, nret = 1;
            uint16_t intensity = 9000;
            const SceneBuilding* hit = nullptr;
            for (int i = 0; i < nc; ++i) {
                const SceneBuilding& b = scene.buildings[cand[i] - 1];
                if (b.contains(x, y)) {
                    hit = &b;
                    break;
                }
            }
            if (hit) {
                z = hit->ground_z + hit->roof_height(x, y);
                cls = las_class::building;
                intensity = 20000;
            }
            // Tree crowns: this pixel's visible tree, if its crown covers the point.
            if (tree_id) {
                const auto& t = scene.trees[tree_id - 1];
                const double cz = t.crown_z(x, y);
                if (cz > z) {
                    const double u = unit_from_hash(splitmix64(h ^ 3));
                    if (!photo && u < 0.3) {  // pulse through a gap in the canopy: last return
                        ret = 2, nret = 2;
                    } else {
                        z = cz - (photo ? 0.0 : (t.height - t.crown_base) * 0.3 * unit_from_hash(splitmix64(h ^ 4)));
                        cls = las_class::vegetation_high;
                        intensity = 12000;
                        nret = photo ? 1 : 2;
                    }
                }
            }
            // Gaps: dark roofs absorb most LiDAR pulses; image matching fails in
            // shadows and in poorly textured patches.
            const double g = unit_from_hash(splitmix64(h ^ 5));
            if (!photo && hit && hit->dark_roof && g < 0.8) continue;
            if (photo && in_shadow && g < 0.5) continue;
            if (photo && value_noise(seed + 9, x, y, 30.0) > 0.85 && g < 0.9) continue;
            double sigma = photo ? 0.12 : o.lidar_sigma_m;
            if (photo && in_shadow) sigma *= 2.0;
            if (photo && edge && cls == las_class::building) {
                // Dense matching smears roof edges towards the ground.
                z = ground + (z - ground) * (0.5 + 0.5 * unit_from_hash(splitmix64(h ^ 6)));
                sigma = 0.3;
            }
            z += sigma * normal_from_hash(splitmix64(h ^ 7));
            const double outlier_rate = photo ? 2e-3 : 1e-4;
            if (unit_from_hash(splitmix64(h ^ 8)) < outlier_rate) {
                const double mag = 5.0 + 40.0 * unit_from_hash(splitmix64(h ^ 9));
                z += (unit_from_hash(splitmix64(h ^ 10)) < 0.5 ? -mag : mag);
            }
            out.x.push_back(o.origin_x + x);
            out.y.push_back(o.origin_y + y);
            out.z.push_back(z);
            out.classification.push_back(cls);
            out.return_number.push_back(ret);
            out.number_of_returns.push_back(nret);
            out.intensity.push_back(intensity);
            out.gps_time.push_back(row * 0.01 + col * 1e-6);
            out.red.push_back(static_cast<uint16_t>(r.rgb.at(0, col, row) * 257));
            out.green.push_back(static_cast<uint16_t>(r.rgb.at(1, col, row) * 257));
            out.blue.push_back(static_cast<uint16_t>(r.rgb.at(2, col, row) * 257));
        }
    }
}

uint64_t write_cloud(const std::string& path, const Scene& scene, const Rendered& r, double gsd, const SynthOptions& o,
                     const std::string& wkt, const Progress& progress) {
    LasWriter writer(path, {0.001, 0.001, 0.001},
                     {std::floor(o.origin_x / 1000) * 1000, std::floor(o.origin_y / 1000) * 1000, 0.0}, wkt,
                     "cityforge synth");
    const int n = r.building.width;
    const int band = 64;
    std::vector<PointCloud> rows(band);
    for (int r0 = 0; r0 < n; r0 += band) {
        const int r1 = std::min(n, r0 + band);
        tbb::parallel_for(r0, r1, [&](int row) {
            PointCloud& pc = rows[row - r0];
            pc.clear();
            cloud_row(scene, r, gsd, o, row, pc);
        });
        for (int row = r0; row < r1; ++row) writer.write(rows[row - r0]);
        progress(double(r1) / n, "cloud");
    }
    writer.close();
    return writer.points_written();
}

}  // namespace

SynthResult write_synthetic_town(const std::string& out_dir, const SynthOptions& o, const Progress& progress) {
    o.validate();
    const auto t0 = std::chrono::steady_clock::now();
    const CrsInfo crs = crs_from_user_input("EPSG:" + std::to_string(o.epsg), "--epsg");
    if (crs.geographic || std::abs(crs.linear_unit_m - 1.0) > 1e-9)
        throw Error("--epsg", "must be a projected CRS in metres (EPSG:" + std::to_string(o.epsg) + " is not)");
    ensure_directory(out_dir);
    namespace fs = std::filesystem;
    SynthResult res;
    res.ortho_path = (fs::path(out_dir) / "ortho.tif").string();
    res.truth_path = (fs::path(out_dir) / "truth.geojson").string();
    res.truth_raster_path = (fs::path(out_dir) / "truth_buildings.tif").string();
    res.scene_path = (fs::path(out_dir) / "scene.json").string();

    const Scene scene = synth::generate_scene({o.size_m, o.seed, o.variation});
    progress(0.05, "scene");
    Rendered r = synth::render(scene, o.gsd_m, o.sun_azimuth_deg, o.sun_elevation_deg, progress.sub(0.05, 0.35));
    synth::colourise(scene, o.gsd_m, o.sun_azimuth_deg, o.sun_elevation_deg, r);
    res.width = res.height = r.building.width;
    const GeoTransform gt{o.origin_x, o.gsd_m, o.origin_y + res.height * o.gsd_m, -o.gsd_m};
    GeoTiffWriteOptions rgb_options;
    rgb_options.rgb = true;
    write_geotiff(res.ortho_path, r.rgb, gt, crs.wkt, rgb_options);
    GeoTiffWriteOptions label_options;
    label_options.band_descriptions = {"building id (truth.geojson id), 0 = none"};
    write_geotiff(res.truth_raster_path, r.building, gt, crs.wkt, label_options);
    progress(0.45, "ortho");

    // Truth footprints in map coordinates.
    std::vector<FieldDefinition> fields{{"id", FieldType::integer},          {"shape", FieldType::string},
                                        {"roof_type", FieldType::string},    {"eave_height_m", FieldType::real},
                                        {"ridge_height_m", FieldType::real}, {"ground_z_m", FieldType::real},
                                        {"orientation_deg", FieldType::real}, {"area_m2", FieldType::real},
                                        {"n_holes", FieldType::integer}};
    std::vector<Feature> features;
    std::map<std::string, int> shape_counts, roof_counts;
    for (const SceneBuilding& b : scene.buildings) {
        Feature f;
        f.geometry = {b.footprint(o.origin_x, o.origin_y)};
        double orientation = std::fmod(b.angle_rad * 180.0 / std::numbers::pi + 180.0, 180.0);
        f.values = {int64_t(b.id), synth::to_string(b.shape), synth::to_string(b.roof), b.eave_height_m,
                    b.ridge_height_m, b.ground_z, orientation, b.area_m2(), int64_t(b.holes.size())};
        features.push_back(std::move(f));
        ++shape_counts[synth::to_string(b.shape)];
        ++roof_counts[synth::to_string(b.roof)];
    }
    VectorWriteOptions vo;
    vo.layer = "truth";
    write_polygon_features(res.truth_path, crs, fields, features, vo);
    res.buildings = static_cast<int>(scene.buildings.size());
    res.trees = static_cast<int>(scene.trees.size());

    if (o.cloud_density_m2 > 0.0) {
        res.cloud_path = (fs::path(out_dir) / "cloud.las").string();
        res.points = write_cloud(res.cloud_path, scene, r, o.gsd_m, o, crs.wkt, progress.sub(0.5, 0.98));
    }

    if (o.views.views > 0) {
        const synth::ViewsResult v = synth::write_views(out_dir, scene, o.views, o.epsg, o.origin_x, o.origin_y, o.seed, progress.sub(0.98, 0.995));
        res.views_dir = (fs::path(out_dir) / "views").string();
        res.surface_path = (fs::path(out_dir) / "surface.las").string();
        res.views = static_cast<int>(v.cameras.cameras.size());
        res.surface_points = v.surface_points;
    }

    nlohmann::json j;
    j["generator"] = "cityforge synth";
    j["parameters"] = {{"size_m", o.size_m},       {"gsd_m", o.gsd_m},
                       {"seed", o.seed},           {"epsg", o.epsg},
                       {"origin_x", o.origin_x},   {"origin_y", o.origin_y},
                       {"cloud_density_m2", o.cloud_density_m2}, {"cloud_mode", to_string(o.cloud_mode)}};
    j["crs"] = crs.label();
    j["origin_is"] = "lower-left corner of the scene";
    j["ortho"] = {{"file", "ortho.tif"}, {"width", res.width}, {"height", res.height}};
    j["sun"] = {{"azimuth_deg", o.sun_azimuth_deg}, {"elevation_deg", o.sun_elevation_deg}};
    j["terrain"] = {{"z0_m", scene.terrain[0]}, {"dz_dx", scene.terrain[1]}, {"dz_dy", scene.terrain[2]},
                    {"undulation_amplitude_m", scene.undulation_m}};
    const synth::SceneVariation& v = o.variation;
    const synth::SceneVariation d;
    if (o.lidar_sigma_m != 0.03) j["parameters"]["lidar_sigma_m"] = o.lidar_sigma_m;
    if (v.terrain_slope_max != d.terrain_slope_max || v.terrain_undulation_m != d.terrain_undulation_m ||
        v.dark_roof_share != d.dark_roof_share || v.tree_touch_share != d.tree_touch_share || v.ground_like_roof_share != d.ground_like_roof_share ||
        v.terraced_block_share != d.terraced_block_share || v.oblique_share != d.oblique_share || v.round_share != d.round_share || v.all_roof_families != d.all_roof_families ||
        v.base_at_area_centroid != d.base_at_area_centroid)
        j["variation"] = {{"terrain_slope_max", v.terrain_slope_max}, {"terrain_undulation_m", v.terrain_undulation_m},
                          {"dark_roof_share", v.dark_roof_share},      {"tree_touch_share", v.tree_touch_share},
                          {"ground_like_roof_share", v.ground_like_roof_share}, {"terraced_block_share", v.terraced_block_share},
                          {"oblique_share", v.oblique_share},          {"round_share", v.round_share}, {"all_roof_families", v.all_roof_families},
                          {"base_at_area_centroid", v.base_at_area_centroid}};
    j["counts"] = {{"buildings", res.buildings}, {"trees", res.trees}, {"points", res.points},
                   {"roads_ns", scene.roads_x.size()}, {"roads_ew", scene.roads_y.size()},
                   {"shapes", shape_counts}, {"roof_types", roof_counts}};
    j["files"] = {{"ortho", "ortho.tif"}, {"truth", "truth.geojson"}, {"truth_raster", "truth_buildings.tif"},
                  {"cloud", o.cloud_density_m2 > 0 ? nlohmann::json("cloud.las") : nlohmann::json(nullptr)}};
    if (o.views.views > 0)
        j["views"] = {{"folder", "views"}, {"count", res.views}, {"gsd_m", o.views.gsd_m},
                      {"width_px", o.views.width_px}, {"height_px", o.views.height_px},
                      {"forward_overlap", o.views.forward_overlap}, {"side_overlap", o.views.side_overlap},
                      {"oblique_deg", o.views.oblique_deg},
                      {"cameras", "views/cameras_truth.json"}, {"gps", "views/gps.txt"}, {"camera_matrix", "views/K.txt"},
                      {"surface", "surface.las"}, {"surface_points", res.surface_points}};
    write_text_file(res.scene_path, j.dump(2) + "\n");
    progress(1.0, "done");
    res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return res;
}

}  // namespace cityforge
