// Footprint benchmark: vectorisation and fits on the exact building raster of
// a synthetic city (default 4000 m, 8000 x 8000 px, ~9,700 buildings).
// Prints buildings per second for each step and the fits' area error and IoU
// against the raw (pixel-exact) polygons.
//
//   build/bin/bench_footprints [size_m]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"
#include "raster/raster.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
}  // namespace

int main(int argc, char** argv) {
    SynthOptions so;
    so.size_m = argc > 1 ? std::atof(argv[1]) : 4000.0;
    so.cloud_density_m2 = 0;
    const auto dir = std::filesystem::temp_directory_path() / "cityforge_bench_footprints";
    const SynthResult s = write_synthetic_town(dir.string(), so);
    RasterReader reader(s.truth_raster_path);
    const Image<uint32_t> labels = reader.read_all<uint32_t>();
    double t = now();
    const auto polys = vectorize_all(labels, reader.info().transform);
    const double t_vec = now() - t;
    std::vector<Polygon> raw;
    for (const auto& p : polys)
        if (!p.empty()) raw.push_back(p[0]);
    std::printf("%.0f m city: %zu buildings; vectorisation %.2f s = %.0f buildings/s\n", so.size_m, raw.size(), t_vec,
                double(raw.size()) / t_vec);
    t = now();
    std::vector<Polygon> simplified;
    for (const Polygon& p : raw) simplified.push_back(simplify_polygon(p, 0.25));
    std::printf("simplification (0.25 m): %.0f buildings/s\n", double(raw.size()) / (now() - t));
    t = now();
    double err = 0.0, iou = 0.0;
    for (const Polygon& p : simplified) {
        const FitAccuracy a = fit_accuracy(p, minimum_area_rectangle(p).polygon());
        err += std::abs(a.area_error_pct), iou += a.iou;
    }
    const double t_rect = now() - t;
    std::printf("minimum-area rectangle + accuracy: %.0f buildings/s; mean |area error| %.2f %%, mean IoU %.3f\n",
                double(raw.size()) / t_rect, err / double(raw.size()), iou / double(raw.size()));
    t = now();
    err = iou = 0.0;
    for (const Polygon& p : simplified) {
        const RecursiveFit f = recursive_rectangle_fit(p);
        err += std::abs(f.accuracy.area_error_pct), iou += f.accuracy.iou;
    }
    const double t_rec = now() - t;
    std::printf("recursive rectangle fit: %.0f buildings/s; mean |area error| %.2f %%, mean IoU %.3f\n", double(raw.size()) / t_rec,
                err / double(raw.size()), iou / double(raw.size()));
    std::filesystem::remove_all(dir);
    return 0;
}
