// Accuracy of the photogrammetric clouds on a synthetic town with exact truth
// (`cityforge synth --views`): F-score at tau = 0.1, 0.25, 0.5 m and chamfer
// distance of each cloud against OUT/surface.las, the predicted points taken
// within the exact surface's xy extent (the photographed block: oblique heads
// see beyond it), and the pose error of oriented cameras against
// views/cameras_truth.json. Figures are printed; nothing is asserted.
//
// Where recall is lost: recall@0.25 per surface kind (terrain 2, crowns 5,
// roofs 6, walls synth::kSurfaceWallClass) and over the truth points that at
// least two of the photos see ("visible": ray cast against the truth's own top
// surface, see photos_seeing) among the photos of `views=` (default: all of
// views/cameras_truth.json; give the cameras the cloud was made from, e.g. a
// subset).
//
//   build/bin/bench_photo SYNTH_DIR [views=CAMERAS.json] [cameras=EST.json] [seen=OUT.u16] NAME=CLOUD.las ...
// (seen= writes the number of photos seeing each truth point, uint16 in surface.las order.)
#include "bench_main.hpp"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <tbb/parallel_for.h>

#include "audit/cloud_compare.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "photo/camera.hpp"
#include "synth/views.hpp"

using namespace cityforge;

namespace {

// Number of photos of `set` that see each point of `surface`: the point
// projects inside the photo and the segment from it to the camera centre
// passes above the top surface. The top surface is the DSM of the truth's
// own grid samples (every class but walls, spacing `sp`, nearest cell): a wall
// sample looking into its building crosses the roof and is hidden, looking
// out it is not. The segment leaves the point's own cell unchecked.
std::vector<uint16_t> photos_seeing(const PointCloud& surface, const photo::CameraSet& set) {
    const std::size_t n = surface.size();
    double sp = 1e300, x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
    for (std::size_t i = 0; i < n; ++i) {
        if (surface.classification[i] == synth::kSurfaceWallClass) continue;
        x0 = std::min(x0, surface.x[i]), x1 = std::max(x1, surface.x[i]), y0 = std::min(y0, surface.y[i]), y1 = std::max(y1, surface.y[i]);
        if (i > 0 && surface.classification[i - 1] != synth::kSurfaceWallClass && surface.y[i] == surface.y[i - 1] && surface.x[i] > surface.x[i - 1])
            sp = std::min(sp, surface.x[i] - surface.x[i - 1]);
    }
    if (!(sp < 1e299)) throw Error("surface.las", "no grid of top-surface samples");
    const int cols = static_cast<int>(std::lround((x1 - x0) / sp)) + 1, rows = static_cast<int>(std::lround((y1 - y0) / sp)) + 1;
    std::vector<float> dsm(static_cast<std::size_t>(cols) * rows, -1e30f);
    float zmax = -1e30f;
    for (std::size_t i = 0; i < n; ++i) {
        if (surface.classification[i] == synth::kSurfaceWallClass) continue;
        const int c = static_cast<int>(std::lround((surface.x[i] - x0) / sp)), r = static_cast<int>(std::lround((surface.y[i] - y0) / sp));
        float& z = dsm[static_cast<std::size_t>(r) * cols + c];
        z = std::max(z, static_cast<float>(surface.z[i]));
        zmax = std::max(zmax, z);
    }
    std::vector<uint16_t> seen(n, 0);
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        const Eigen::Vector3d p(surface.x[i], surface.y[i], surface.z[i]);
        for (const photo::PhotoCamera& cam : set.cameras) {
            const auto px = cam.project(p);
            if (!px || !cam.inside(*px)) continue;
            const Eigen::Vector3d d = cam.centre - p;
            const double horiz = std::hypot(d.x(), d.y());
            bool hidden = false;
            if (horiz > 1e-9) {
                const double step = 0.5 * sp / horiz;  // along d, half a cell horizontally
                for (double t = 0.75 * sp / horiz; t < 1.0; t += step) {
                    const Eigen::Vector3d q = p + t * d;
                    if (q.z() > zmax) break;
                    const int c = static_cast<int>(std::lround((q.x() - x0) / sp)), r = static_cast<int>(std::lround((q.y() - y0) / sp));
                    if (c < 0 || r < 0 || c >= cols || r >= rows) break;
                    if (q.z() < dsm[static_cast<std::size_t>(r) * cols + c] - 0.05) {
                        hidden = true;
                        break;
                    }
                }
            }
            if (!hidden) ++seen[i];
        }
    });
    return seen;
}

PointCloud subset(const PointCloud& c, const std::vector<uint8_t>& keep) {
    PointCloud out;
    for (std::size_t i = 0; i < c.size(); ++i)
        if (keep[i]) out.append(c, i);
    return out;
}

}  // namespace

static int run_bench(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: bench_photo SYNTH_DIR [views=CAMERAS.json] [cameras=EST.json] NAME=CLOUD.las ...\n");
        return 2;
    }
    const std::string dir = argv[1];
    const PointCloud surface = read_las(dir + "/surface.las");
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (std::size_t i = 0; i < surface.size(); ++i)
        x0 = std::min(x0, surface.x[i]), x1 = std::max(x1, surface.x[i]), y0 = std::min(y0, surface.y[i]), y1 = std::max(y1, surface.y[i]);
    std::printf("reference %s: %zu points, %.0f x %.0f m\n", (dir + "/surface.las").c_str(), surface.size(), x1 - x0, y1 - y0);

    std::string views_path = dir + "/views/cameras_truth.json", seen_path;
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg.rfind("views=", 0) == 0) views_path = arg.substr(6);
        if (arg.rfind("seen=", 0) == 0) seen_path = arg.substr(5);
    }
    const photo::CameraSet views = photo::read_cameras_json(views_path);
    const std::vector<uint16_t> seen = photos_seeing(surface, views);
    if (!seen_path.empty()) {  // for pictures: photos seeing each truth point, uint16 in surface.las order
        std::FILE* f = std::fopen(seen_path.c_str(), "wb");
        if (!f || std::fwrite(seen.data(), sizeof(uint16_t), seen.size(), f) != seen.size()) throw Error(seen_path, "cannot write");
        std::fclose(f);
    }
    // Truth subsets: kinds, and the points at least two photos see.
    struct Part {
        std::string name;
        PointCloud points;
    };
    std::vector<Part> parts;
    const std::pair<const char*, uint8_t> kinds[] = {
        {"terrain", las_class::ground}, {"roof", las_class::building}, {"wall", synth::kSurfaceWallClass}, {"crown", las_class::vegetation_high}};
    std::vector<uint8_t> visible(surface.size());
    for (std::size_t i = 0; i < surface.size(); ++i) visible[i] = seen[i] >= 2;
    std::size_t n_visible = std::count(visible.begin(), visible.end(), 1);
    std::printf("photos for visibility: %s (%zu); truth points seen by >= 2 of them: %zu (%.1f %%)\n", views_path.c_str(), views.cameras.size(),
                n_visible, 100.0 * double(n_visible) / double(surface.size()));
    for (const auto& [name, cls] : kinds) {
        std::vector<uint8_t> k(surface.size()), kv(surface.size());
        std::size_t cnt = 0, cv = 0;
        for (std::size_t i = 0; i < surface.size(); ++i) {
            k[i] = surface.classification[i] == cls, kv[i] = k[i] && visible[i];
            cnt += k[i], cv += kv[i];
        }
        if (!cnt) continue;
        std::printf("  %-8s %9zu truth points, %5.1f %% seen by >= 2 photos\n", name, cnt, 100.0 * double(cv) / double(cnt));
        parts.push_back({name, subset(surface, k)});
        if (cv) parts.push_back({std::string(name) + " (visible)", subset(surface, kv)});
    }
    if (n_visible) parts.push_back({"all (visible)", subset(surface, visible)});
    std::printf("\n| cloud | points in block | F@0.1 | F@0.25 | F@0.5 | P@0.25 | R@0.25 | chamfer m | F@0.25 visible | R@0.25 visible |\n"
                "|---|---|---|---|---|---|---|---|---|---|\n");
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        const auto eq = arg.find('=');
        if (eq == std::string::npos) throw Error(arg, "expected NAME=FILE");
        const std::string name = arg.substr(0, eq), path = arg.substr(eq + 1);
        if (name == "views" || name == "seen") continue;
        if (name == "cameras") {
            const photo::PoseError e = photo::compare_poses(photo::read_cameras_json(path), photo::read_cameras_json(dir + "/views/cameras_truth.json"));
            std::printf("\npose error of %s: %d cameras, position mean %.3f m (max %.3f), angle mean %.3f deg (max %.3f)\n", path.c_str(),
                        e.matched, e.mean_position_m, e.max_position_m, e.mean_angle_deg, e.max_angle_deg);
            continue;
        }
        const PointCloud all = read_las(path);
        PointCloud pred;
        for (std::size_t i = 0; i < all.size(); ++i)
            if (all.x[i] >= x0 && all.x[i] <= x1 && all.y[i] >= y0 && all.y[i] <= y1) pred.append(all, i);
        const CloudComparison c = compare_clouds(pred, surface, {0.1, 0.25, 0.5});
        // Recall over the visible truth; precision stays that of the whole
        // truth (a point near an unseen surface is still right).
        double rv = 0;
        std::string per_part;
        for (const Part& p : parts) {
            const double r = compare_clouds(pred, p.points, {0.25}).scores[0].recall;
            if (p.name == "all (visible)") rv = r;
            char buf[96];
            std::snprintf(buf, sizeof buf, "%s%s %.3f", per_part.empty() ? "" : ", ", p.name.c_str(), r);
            per_part += buf;
        }
        const double pr = c.scores[1].precision;
        const double fv = pr + rv > 0 ? 2 * pr * rv / (pr + rv) : 0.0;
        std::printf("| %s | %zu of %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f |\n", name.c_str(), pred.size(), all.size(),
                    c.scores[0].f_score, c.scores[1].f_score, c.scores[2].f_score, pr, c.scores[1].recall, c.chamfer, fv, rv);
        std::printf("    R@0.25 by kind: %s\n", per_part.c_str());
    }
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_photo", "bench_photo SYNTH_DIR [views=CAMERAS.json] [cameras=EST.json] NAME=CLOUD.las ...", run_bench);
}
