// Accuracy of the photogrammetric clouds on a synthetic town with exact truth
// (`cityforge synth --views`): F-score at tau = 0.1, 0.25, 0.5 m and chamfer
// distance of each cloud against OUT/surface.las, the predicted points taken
// within the exact surface's xy extent (the photographed block: oblique heads
// see beyond it), and the pose error of oriented cameras against
// views/cameras_truth.json. Figures are printed; nothing is asserted.
//
//   build/bin/bench_photo SYNTH_DIR [cameras=EST.json] NAME=CLOUD.las ...
#include <algorithm>
#include <cstdio>
#include <string>

#include "audit/cloud_compare.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "photo/camera.hpp"

using namespace cityforge;

int main(int argc, char** argv) try {
    if (argc < 3) {
        std::fprintf(stderr, "usage: bench_photo SYNTH_DIR [cameras=EST.json] NAME=CLOUD.las ...\n");
        return 2;
    }
    const std::string dir = argv[1];
    const PointCloud surface = read_las(dir + "/surface.las");
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (std::size_t i = 0; i < surface.size(); ++i)
        x0 = std::min(x0, surface.x[i]), x1 = std::max(x1, surface.x[i]), y0 = std::min(y0, surface.y[i]), y1 = std::max(y1, surface.y[i]);
    std::printf("reference %s: %zu points, %.0f x %.0f m\n\n", (dir + "/surface.las").c_str(), surface.size(), x1 - x0, y1 - y0);
    std::printf("| cloud | points in block | F@0.1 | F@0.25 | F@0.5 | P@0.25 | R@0.25 | chamfer m |\n|---|---|---|---|---|---|---|---|\n");
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        const auto eq = arg.find('=');
        if (eq == std::string::npos) throw Error(arg, "expected NAME=FILE");
        const std::string name = arg.substr(0, eq), path = arg.substr(eq + 1);
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
        std::printf("| %s | %zu of %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f |\n", name.c_str(), pred.size(), all.size(), c.scores[0].f_score,
                    c.scores[1].f_score, c.scores[2].f_score, c.scores[1].precision, c.scores[1].recall, c.chamfer);
    }
    return 0;
} catch (const std::exception& e) {
    std::fprintf(stderr, "bench_photo: %s\n", e.what());
    return 1;
}
