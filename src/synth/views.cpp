#include "synth/views.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>
#include <sstream>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/random.hpp"
#include "crs/crs.hpp"
#include "synth/render.hpp"

namespace cityforge::synth {

void ViewsOptions::validate() const {
    if (views < 2 || views > 400) throw Error("--views", "must be between 2 and 400 photos");
    if (!(gsd_m >= 0.02 && gsd_m <= 2.0)) throw Error("--view-gsd", "must be between 0.02 and 2 metres");
    if (width_px < 64 || height_px < 64 || width_px > 8000 || height_px > 8000)
        throw Error("--view-size", "must be between 64 and 8000 pixels per side");
    if (!(forward_overlap >= 0.0 && forward_overlap <= 0.95)) throw Error("--forward-overlap", "must be in 0..0.95");
    if (!(side_overlap >= 0.0 && side_overlap <= 0.95)) throw Error("--side-overlap", "must be in 0..0.95");
    if (!(focal_px >= 0.0)) throw Error("--focal-px", "must be >= 0");
    if (!(oblique_deg >= 0.0 && oblique_deg <= 50.0)) throw Error("--oblique-deg", "must be in 0..50 degrees");
    if (oblique_deg > 0 && views % 5 != 0)
        throw Error("--views", "with --oblique-deg every station takes 5 photos: give a multiple of 5 (got " + std::to_string(views) + ")");
    if (!(surface_spacing_m >= 0.02 && surface_spacing_m <= 5.0)) throw Error("--surface-spacing", "must be in 0.02..5 m");
}

namespace {

constexpr double kPi = std::numbers::pi;

// Bilinear height field over the fine DSM with a coarse max grid so rays skip
// empty space quickly.
struct HeightField {
    const Image<float>& dsm;
    double texel, size;
    int n;
    static constexpr int kBlock = 16;
    int nb = 0;
    std::vector<float> block_max;
    float zmin = 1e30f, zmax = -1e30f;

    HeightField(const Image<float>& d, double tg, double size_m) : dsm(d), texel(tg), size(size_m), n(d.width) {
        nb = (n + kBlock - 1) / kBlock;
        block_max.assign(static_cast<std::size_t>(nb) * nb, -1e30f);
        for (int r = 0; r < n; ++r)
            for (int c = 0; c < n; ++c) {
                const float z = dsm.at(0, c, r);
                zmin = std::min(zmin, z), zmax = std::max(zmax, z);
                // Texels feed the bilinear height of the neighbouring blocks too.
                for (int br = std::max(0, (r - 1) / kBlock); br <= std::min(nb - 1, (r + 1) / kBlock); ++br)
                    for (int bc = std::max(0, (c - 1) / kBlock); bc <= std::min(nb - 1, (c + 1) / kBlock); ++bc) {
                        float& m = block_max[static_cast<std::size_t>(br) * nb + bc];
                        m = std::max(m, z);
                    }
            }
    }
    double col_of(double x) const { return x / texel - 0.5; }
    double row_of(double y) const { return (size - y) / texel - 0.5; }
    double height(double x, double y) const {
        const double fc = std::clamp(col_of(x), 0.0, n - 1.0), fr = std::clamp(row_of(y), 0.0, n - 1.0);
        const int c0 = std::min(n - 2, static_cast<int>(fc)), r0 = std::min(n - 2, static_cast<int>(fr));
        const double tc = fc - c0, tr = fr - r0;
        const double a = dsm.at(0, c0, r0), b = dsm.at(0, c0 + 1, r0), c = dsm.at(0, c0, r0 + 1), d = dsm.at(0, c0 + 1, r0 + 1);
        return (a * (1 - tc) + b * tc) * (1 - tr) + (c * (1 - tc) + d * tc) * tr;
    }
    bool inside(double x, double y) const { return x >= 0 && y >= 0 && x <= size && y <= size; }

    // First intersection of the ray C + t d (d unit, pointing down) with the surface.
    bool trace(const Eigen::Vector3d& C, const Eigen::Vector3d& d, Eigen::Vector3d& hit) const {
        if (d.z() >= -1e-6) return false;
        const double top = zmax + 0.01, bottom = zmin - 0.01;
        double t = C.z() > top ? (C.z() - top) / -d.z() : 0.0;
        const double t_end = (C.z() - bottom) / -d.z();
        const double fine = texel * 0.5;
        double prev = t;
        while (t <= t_end) {
            const Eigen::Vector3d p = C + t * d;
            if (!inside(p.x(), p.y())) return false;
            const int bc = std::clamp(static_cast<int>(col_of(p.x()) / kBlock), 0, nb - 1);
            const int br = std::clamp(static_cast<int>(row_of(p.y()) / kBlock), 0, nb - 1);
            const double m = block_max[static_cast<std::size_t>(br) * nb + bc];
            if (p.z() > m + 1e-3) {
                // Skip to where the ray reaches the block maximum or leaves the block.
                const double t_z = (p.z() - m) / -d.z();
                const double bx0 = (bc * kBlock + 0.5) * texel, bx1 = ((bc + 1) * kBlock + 0.5) * texel;
                const double by1 = size - (br * kBlock + 0.5) * texel, by0 = size - ((br + 1) * kBlock + 0.5) * texel;
                double t_exit = 1e30;
                if (d.x() > 1e-12) t_exit = std::min(t_exit, (bx1 - p.x()) / d.x());
                if (d.x() < -1e-12) t_exit = std::min(t_exit, (bx0 - p.x()) / d.x());
                if (d.y() > 1e-12) t_exit = std::min(t_exit, (by1 - p.y()) / d.y());
                if (d.y() < -1e-12) t_exit = std::min(t_exit, (by0 - p.y()) / d.y());
                prev = t;
                t += std::max(std::min(t_z, t_exit), 0.0) + 1e-4;
                continue;
            }
            if (p.z() <= height(p.x(), p.y())) {
                double lo = prev, hi = t;
                for (int k = 0; k < 24; ++k) {
                    const double mid = 0.5 * (lo + hi);
                    const Eigen::Vector3d q = C + mid * d;
                    (q.z() <= height(q.x(), q.y()) ? hi : lo) = mid;
                }
                hit = C + hi * d;
                return true;
            }
            prev = t;
            t += fine;
        }
        return false;
    }
};

struct Sampler {
    const Scene& scene;
    const Rendered& r;
    const HeightField& hf;
    uint64_t seed;
    double sun[3];

    // Colour of the surface at a hit point (RGB 0..255, before sensor noise).
    std::array<double, 3> colour(const Eigen::Vector3d& p) const {
        const double e = hf.texel;
        const double gx = (hf.height(p.x() + e, p.y()) - hf.height(p.x() - e, p.y())) / (2 * e);
        const double gy = (hf.height(p.x(), p.y() + e) - hf.height(p.x(), p.y() - e)) / (2 * e);
        const double g = std::hypot(gx, gy);
        const int n = hf.n;
        const int col = std::clamp(static_cast<int>(std::lround(hf.col_of(p.x()))), 0, n - 1);
        const int row = std::clamp(static_cast<int>(std::lround(hf.row_of(p.y()))), 0, n - 1);
        std::array<double, 3> c{};
        if (g > 3.0) {
            // Facade: outward normal -grad h, storeys of 3 m with windows.
            const double nx = -gx / g, ny = -gy / g;
            uint32_t id = 0;
            for (int dr = -2; dr <= 2 && !id; ++dr)
                for (int dc = -2; dc <= 2 && !id; ++dc) {
                    const int rr = std::clamp(row + dr, 0, n - 1), cc = std::clamp(col + dc, 0, n - 1);
                    id = r.building.at(0, cc, rr);
                }
            const uint64_t h = hash64(seed, id, 5, 5);
            const double base = 150 + 60 * unit_from_hash(h);
            std::array<double, 3> wall{base, base * (0.92 + 0.06 * unit_from_hash(h ^ 1)), base * (0.82 + 0.1 * unit_from_hash(h ^ 2))};
            const double along = p.x() * -ny + p.y() * nx;
            const double ground = scene.terrain_z(p.x(), p.y());
            const double fz = std::fmod(p.z() - ground, 3.0), fa = std::fmod(std::abs(along), 2.6);
            const bool window = p.z() - ground > 1.0 && fz > 1.0 && fz < 2.3 && fa > 0.6 && fa < 1.9;
            const double lit = 0.45 + 0.55 * std::max(0.0, nx * sun[0] + ny * sun[1]) / std::hypot(sun[0], sun[1]);
            const double tex = 0.85 + 0.3 * value_noise(seed + 211, along, p.z(), 0.4);
            for (int k = 0; k < 3; ++k) c[k] = (window ? 55.0 + 10 * k : wall[k]) * lit * tex;
            return c;
        }
        // Top surfaces: the ortho colour (sun shading, cast shadows) bilinear,
        // times a ground-fixed texture at a few scales.
        const double fc = std::clamp(hf.col_of(p.x()), 0.0, n - 1.0), fr = std::clamp(hf.row_of(p.y()), 0.0, n - 1.0);
        const int c0 = std::min(n - 2, static_cast<int>(fc)), r0 = std::min(n - 2, static_cast<int>(fr));
        const double tc = fc - c0, tr = fr - r0;
        const double tex = 1.0 + 0.22 * (value_noise(seed + 101, p.x(), p.y(), 0.3) - 0.5) +
                           0.16 * (value_noise(seed + 103, p.x(), p.y(), 0.9) - 0.5) +
                           0.10 * (value_noise(seed + 107, p.x(), p.y(), 2.7) - 0.5);
        for (int k = 0; k < 3; ++k) {
            const double a = r.rgb.at(k, c0, r0), b = r.rgb.at(k, c0 + 1, r0), cc = r.rgb.at(k, c0, r0 + 1), d = r.rgb.at(k, c0 + 1, r0 + 1);
            c[k] = ((a * (1 - tc) + b * tc) * (1 - tr) + (cc * (1 - tc) + d * tc) * tr) * tex;
        }
        return c;
    }
};

Eigen::Matrix3d attitude(double yaw, double pitch, double roll) {
    // Nadir camera flying east: image x east, image y south, optical axis down.
    Eigen::Matrix3d nadir;
    nadir << 1, 0, 0, 0, -1, 0, 0, 0, -1;
    const Eigen::Matrix3d heading = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    const Eigen::Matrix3d small =
        (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY())).toRotationMatrix();
    return small * nadir * heading.transpose();
}

}  // namespace

ViewsResult write_views(const std::string& out_dir, const Scene& scene, const ViewsOptions& o, int epsg, double origin_x,
                        double origin_y, uint64_t seed, const Progress& progress) {
    o.validate();
    namespace fs = std::filesystem;
    const double texel = std::max(0.025, o.gsd_m * 0.5);
    if (scene.size_m / texel > 6000.0)
        throw Error("--views", "scene too large for views at this GSD (" + std::to_string(int(scene.size_m / texel)) +
                                   " texels per side, at most 6000): lower --size-m or raise --view-gsd");
    const double focal = o.focal_px > 0 ? o.focal_px : o.width_px;
    // Mean terrain height and flight altitude.
    double zsum = 0;
    for (int i = 0; i < 16; ++i)
        for (int j = 0; j < 16; ++j) zsum += scene.terrain_z((i + 0.5) * scene.size_m / 16, (j + 0.5) * scene.size_m / 16);
    const double zmean = zsum / 256.0;
    const double altitude = focal * o.gsd_m;
    const double wg = o.width_px * o.gsd_m, hg = o.height_px * o.gsd_m;
    const double fs_m = (1.0 - o.forward_overlap) * wg, ss_m = (1.0 - o.side_overlap) * hg;
    const int heads = o.oblique_deg > 0 ? 5 : 1;  // photos per station
    const int stations = o.views / heads;
    const int strips = std::max(1, static_cast<int>(std::lround(std::sqrt(stations * fs_m / ss_m))));
    const int per_strip = (stations + strips - 1) / strips;
    const double block_w = (per_strip - 1) * fs_m + wg, block_h = (strips - 1) * ss_m + hg;
    // Oblique heads see beyond the nadir block: the far edge of a tilted photo
    // lies altitude * tan(tilt + half field) from its station.
    const double tilt = o.oblique_deg * kPi / 180.0;
    const double reach = heads > 1 ? altitude * std::tan(tilt + std::atan(0.5 * std::max(o.width_px, o.height_px) / focal)) : 0.0;
    const double need_w = heads > 1 ? std::max(block_w, block_w - wg + 2 * reach) : block_w;
    const double need_h = heads > 1 ? std::max(block_h, block_h - hg + 2 * reach) : block_h;
    if (need_w > scene.size_m - 4.0 || need_h > scene.size_m - 4.0 || !std::isfinite(reach)) {
        char buf[240];
        std::snprintf(buf, sizeof buf, "flight block of %.0f x %.0f m%s does not fit the %.0f m scene: raise --size-m or lower --views/--view-gsd",
                      need_w, need_h, heads > 1 ? " (with the oblique photos' reach)" : "", scene.size_m);
        throw Error("--views", buf);
    }
    const fs::path views_dir = fs::path(out_dir) / "views";
    ensure_directory(views_dir);

    Rendered r = render(scene, texel, kSunAzimuthDeg, kSunElevationDeg, progress.sub(0.0, 0.2));
    colourise(scene, texel, kSunAzimuthDeg, kSunElevationDeg, r);
    const HeightField hf(r.dsm, texel, scene.size_m);
    const double az = kSunAzimuthDeg * kPi / 180.0, el = kSunElevationDeg * kPi / 180.0;
    const Sampler sampler{scene, r, hf, seed, {std::sin(az) * std::cos(el), std::cos(az) * std::cos(el), std::sin(el)}};

    const CrsInfo crs = crs_from_user_input("EPSG:" + std::to_string(epsg), "--epsg");
    ViewsResult res;
    res.cameras.crs = crs.label();
    res.cameras.crs_wkt = crs.wkt;
    res.cameras.scene_z_range_m = {hf.zmin, hf.zmax};
    const double x0 = 0.5 * (scene.size_m - block_w) + 0.5 * wg, y0 = 0.5 * (scene.size_m + block_h) - 0.5 * hg;
    for (int i = 0; i < o.views; ++i) {
        const int station = i / heads, head = i % heads;  // head 0 = nadir, 1..4 = tilted N, E, S, W
        const int strip = station / per_strip, k = station % per_strip;
        const bool back = strip % 2 == 1;  // serpentine: every other strip flown west
        Rng rng(seed, 7000 + static_cast<uint64_t>(heads > 1 ? 100000 + i : i));
        const double x = x0 + (back ? per_strip - 1 - k : k) * fs_m + rng.uniform(-0.5, 0.5);
        const double y = y0 - strip * ss_m + rng.uniform(-0.5, 0.5);
        const double z = zmean + altitude + rng.uniform(-0.5, 0.5);
        const double yaw = (back ? kPi : 0.0) + rng.uniform(-2.0, 2.0) * kPi / 180.0;
        double pitch = rng.uniform(-1.5, 1.5) * kPi / 180.0, roll = rng.uniform(-1.5, 1.5) * kPi / 180.0;
        photo::PhotoCamera probe;
        probe.rotation = attitude(yaw, pitch, roll);
        if (head > 0) {
            // Tilt the optical axis towards the head's compass direction (in
            // the map frame, whatever the strip's heading).
            const double bearing = (head - 1) * 0.5 * kPi;  // N, E, S, W
            const Eigen::Vector3d towards(std::sin(bearing), std::cos(bearing), 0.0);
            const Eigen::Vector3d axis = Eigen::Vector3d::UnitZ().cross(towards);  // rotating -z towards `towards`
            const Eigen::Matrix3d tilt_world = Eigen::AngleAxisd(-tilt, axis).toRotationMatrix();
            probe.rotation = probe.rotation * tilt_world.transpose();
        }
        photo::PhotoCamera cam;
        char name[32];
        std::snprintf(name, sizeof name, "view_%03d.png", i);
        cam.image = name;
        cam.width = o.width_px, cam.height = o.height_px;
        cam.fx = cam.fy = focal;
        cam.cx = 0.5 * (o.width_px - 1), cam.cy = 0.5 * (o.height_px - 1);
        cam.rotation = probe.rotation;
        cam.centre = {x, y, z};  // scene-local for rendering; shifted to map coordinates below
        res.cameras.cameras.push_back(cam);
    }

    // Render each photo: 2 x 2 rays per pixel, plus sensor noise.
    for (std::size_t vi = 0; vi < res.cameras.cameras.size(); ++vi) {
        const photo::PhotoCamera& cam = res.cameras.cameras[vi];
        cv::Mat img(cam.height, cam.width, CV_8UC3);
        tbb::parallel_for(0, cam.height, [&](int row) {
            for (int col = 0; col < cam.width; ++col) {
                double acc[3] = {0, 0, 0};
                for (int s = 0; s < 4; ++s) {
                    const double u = col - 0.25 + 0.5 * (s % 2), v = row - 0.25 + 0.5 * (s / 2);
                    Eigen::Vector3d hit;
                    std::array<double, 3> c{40, 40, 40};
                    if (hf.trace(cam.centre, cam.ray(u, v), hit)) c = sampler.colour(hit);
                    for (int k = 0; k < 3; ++k) acc[k] += 0.25 * c[k];
                }
                const double noise = 1.5 * normal_from_hash(hash64(seed, vi + 100, static_cast<uint64_t>(row), static_cast<uint64_t>(col)));
                auto* px = img.ptr<uint8_t>(row) + 3 * col;
                for (int k = 0; k < 3; ++k)  // OpenCV order: B, G, R
                    px[2 - k] = static_cast<uint8_t>(std::clamp(std::lround(acc[k] + noise), 0L, 255L));
            }
        });
        const fs::path final_path = views_dir / cam.image;
        const fs::path tmp = temporary_path_for(final_path).replace_extension(".png");
        if (!cv::imwrite(tmp.string(), img)) {
            discard_file(tmp);
            throw Error(final_path.string(), "cannot write PNG");
        }
        commit_file(tmp, final_path);
        progress(0.2 + 0.6 * double(vi + 1) / double(res.cameras.cameras.size()), "views");
    }

    // Map coordinates, GPS positions (WGS 84 longitude/latitude, heights as in the scene).
    std::vector<double> lon, lat, h;
    for (photo::PhotoCamera& cam : res.cameras.cameras) {
        cam.centre += Eigen::Vector3d(origin_x, origin_y, 0.0);
        lon.push_back(cam.centre.x()), lat.push_back(cam.centre.y()), h.push_back(cam.centre.z());
    }
    transform_points(crs, crs_from_user_input("EPSG:4326", "gps"), lon, lat, h, "gps.txt");
    std::ostringstream gps;
    gps << "# image latitude_deg longitude_deg height_m (WGS 84; heights in the scene's vertical frame)\n";
    for (std::size_t i = 0; i < lon.size(); ++i) {
        char line[160];
        std::snprintf(line, sizeof line, "%s %.9f %.9f %.3f\n", res.cameras.cameras[i].image.c_str(), lat[i], lon[i], h[i]);
        gps << line;
    }
    write_text_file(views_dir / "gps.txt", gps.str());
    {
        const photo::PhotoCamera& c = res.cameras.cameras.front();
        char k[200];
        std::snprintf(k, sizeof k, "%.6f 0 %.6f\n0 %.6f %.6f\n0 0 1\n", c.fx, c.cx, c.fy, c.cy);
        write_text_file(views_dir / "K.txt", k);
    }
    photo::write_cameras_json((views_dir / "cameras_truth.json").string(), res.cameras);

    // Exact surface: top surface on a grid over the flight block, and walls.
    const double margin = 0.0;  // the union of the photo footprints at ground level
    const double bx0 = std::max(0.0, x0 - 0.5 * wg - margin), bx1 = std::min(scene.size_m, x0 - 0.5 * wg + block_w + margin);
    const double by1 = std::min(scene.size_m, y0 + 0.5 * hg + margin), by0 = std::max(0.0, y0 + 0.5 * hg - block_h - margin);
    const double sp = o.surface_spacing_m;
    LasWriter writer((fs::path(out_dir) / "surface.las").string(), {0.001, 0.001, 0.001},
                     {std::floor(origin_x / 1000) * 1000, std::floor(origin_y / 1000) * 1000, 0.0}, crs.wkt,
                     "cityforge synth (exact surface)");
    auto push = [&](PointCloud& pc, double x, double y, double z, uint8_t cls, int col, int row) {
        pc.x.push_back(origin_x + x), pc.y.push_back(origin_y + y), pc.z.push_back(z);
        pc.classification.push_back(cls);
        pc.return_number.push_back(1), pc.number_of_returns.push_back(1);
        pc.intensity.push_back(0);
        pc.gps_time.push_back(0.0);
        col = std::clamp(col, 0, hf.n - 1), row = std::clamp(row, 0, hf.n - 1);
        pc.red.push_back(static_cast<uint16_t>(r.rgb.at(0, col, row) * 257));
        pc.green.push_back(static_cast<uint16_t>(r.rgb.at(1, col, row) * 257));
        pc.blue.push_back(static_cast<uint16_t>(r.rgb.at(2, col, row) * 257));
    };
    {
        PointCloud pc;
        for (double y = by1 - 0.5 * sp; y > by0; y -= sp) {
            pc.clear();
            for (double x = bx0 + 0.5 * sp; x < bx1; x += sp) {
                const int col = static_cast<int>(std::lround(hf.col_of(x))), row = static_cast<int>(std::lround(hf.row_of(y)));
                double z = scene.terrain_z(x, y);
                uint8_t cls = las_class::ground;
                for (int dr = -1; dr <= 1 && cls == las_class::ground; ++dr)
                    for (int dc = -1; dc <= 1; ++dc) {
                        const uint32_t id = r.building.at(0, std::clamp(col + dc, 0, hf.n - 1), std::clamp(row + dr, 0, hf.n - 1));
                        if (!id || !scene.buildings[id - 1].contains(x, y)) continue;
                        const SceneBuilding& b = scene.buildings[id - 1];
                        z = b.ground_z + b.roof_height(x, y), cls = las_class::building;
                        break;
                    }
                const uint32_t t = r.tree.at(0, std::clamp(col, 0, hf.n - 1), std::clamp(row, 0, hf.n - 1));
                if (t) {
                    const double cz = scene.trees[t - 1].crown_z(x, y);
                    if (cz > z) z = cz, cls = las_class::vegetation_high;
                }
                push(pc, x, y, z, cls, col, row);
            }
            writer.write(pc);
        }
        // Walls: every footprint edge from the terrain up to the roof.
        pc.clear();
        for (const SceneBuilding& b : scene.buildings) {
            std::vector<std::vector<LocalPoint>> rings{b.outline};
            for (const auto& hole : b.holes) rings.push_back(hole);
            for (const auto& ring : rings)
                for (std::size_t i = 0; i < ring.size(); ++i) {
                    const auto a = b.to_scene(ring[i]), c = b.to_scene(ring[(i + 1) % ring.size()]);
                    const double len = std::hypot(c[0] - a[0], c[1] - a[1]);
                    for (double s = 0.5 * sp; s < len; s += sp) {
                        const double x = a[0] + (c[0] - a[0]) * s / len, y = a[1] + (c[1] - a[1]) * s / len;
                        if (x < bx0 || x > bx1 || y < by0 || y > by1) continue;
                        const double top = b.ground_z + b.roof_height(x, y), ground = scene.terrain_z(x, y);
                        for (double z = ground + 0.5 * sp; z < top; z += sp)
                            push(pc, x, y, z, kSurfaceWallClass, static_cast<int>(hf.col_of(x)), static_cast<int>(hf.row_of(y)));
                    }
                }
        }
        writer.write(pc);
    }
    writer.close();
    res.surface_points = writer.points_written();
    progress(1.0, "surface");
    return res;
}

}  // namespace cityforge::synth
