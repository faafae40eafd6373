// Footprint benchmark: vectorisation and every fit on the exact building
// raster of a synthetic city (default 4000 m, 8000 x 8000 px, ~9,700
// buildings). Prints buildings per second for each step, each fit's area error
// and IoU against the raw (simplified pixel-exact) polygons and its mean
// absolute area error against the exact truth polygons.
//
//   build/bin/bench_footprints [size_m]
#include "bench_main.hpp"
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "core/error.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/regularize.hpp"
#include "io/vector.hpp"
#include "footprint/vectorize.hpp"
#include "raster/raster.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
}  // namespace

static int run_bench(int argc, char** argv) {
    SynthOptions so;
    so.size_m = argc > 1 ? cityforge::bench::parse_number(argv[1], "SIZE_M") : 4000.0;
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
    // Exact truth polygons by building id (the raster's labels are the ids).
    const PolygonLayer truth_layer = read_polygon_layer(s.truth_path);
    std::vector<const Polygon*> truth(polys.size(), nullptr);
    for (std::size_t i = 0; i < truth_layer.features.size(); ++i) {
        const auto id = static_cast<std::size_t>(truth_layer.fids[i]);
        if (id < truth.size() && !truth_layer.features[i].geometry.empty()) truth[id] = &truth_layer.features[i].geometry[0];
    }
    std::vector<std::size_t> ids;
    for (std::size_t id = 0; id < polys.size(); ++id)
        if (!polys[id].empty()) ids.push_back(id);
    const double pixel = reader.info().transform.pixel_width;
    auto run = [&](const char* name, auto&& fit) {
        double err = 0.0, iou = 0.0, truth_err = 0.0;
        std::size_t failed = 0, with_truth = 0;
        std::vector<Polygon> out(simplified.size());
        const double t0 = now();
        for (std::size_t i = 0; i < simplified.size(); ++i) {
            try {
                out[i] = fit(i);
            } catch (const Error&) {
                out[i] = simplified[i], ++failed;  // the raw outline is kept, as the footprints command does
            }
        }
        const double dt = now() - t0;
        for (std::size_t i = 0; i < simplified.size(); ++i) {
            const FitAccuracy a = fit_accuracy(simplified[i], out[i]);
            err += std::abs(a.area_error_pct), iou += a.iou;
            if (const Polygon* tp = truth[ids[i]]) {
                truth_err += std::abs(polygon_area(out[i]) - polygon_area(*tp)) / polygon_area(*tp) * 100.0;
                ++with_truth;
            }
        }
        const double n = double(simplified.size());
        std::printf("%-28s %8.0f buildings/s; vs raw: mean |area error| %.3f %%, mean IoU %.3f; vs truth: mean |area error| %.3f %%; failed %zu\n",
                    name, n / dt, err / n, iou / n, truth_err / double(std::max<std::size_t>(1, with_truth)), failed);
    };
    std::vector<double> orientation(simplified.size());
    for (std::size_t i = 0; i < simplified.size(); ++i) orientation[i] = minimum_area_rectangle(simplified[i]).orientation_deg;
    run("raw (simplified outline)", [&](std::size_t i) { return simplified[i]; });
    run("minimum-area rectangle", [&](std::size_t i) { return minimum_area_rectangle(simplified[i]).polygon(); });
    run("recursive rectangles", [&](std::size_t i) { return recursive_rectangle_fit(simplified[i]).polygon; });
    RegularizeOptions lines, cgal;
    cgal.method = RegularizeMethod::cgal_contours;
    run("regularised (lines)", [&](std::size_t i) {
        return regularised_fit(raw[i], orientation[i], pixel, 0.25, polygon_area(simplified[i]), lines);
    });
    run("regularised (CGAL contours)", [&](std::size_t i) {
        return regularised_fit(raw[i], orientation[i], pixel, 0.25, polygon_area(simplified[i]), cgal);
    });
    std::filesystem::remove_all(dir);
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_footprints", "bench_footprints [SIZE_M]", run_bench);
}
