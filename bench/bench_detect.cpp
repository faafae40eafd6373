// Learned building detection benchmark: applies a detector model (default:
// the shipped RGB model) to a 4000 x 4000 px RGB tile (a synthetic town at
// 0.5 m, 2000 m a side) and prints the time of each step: reading and
// normalising, the pixel stage (models that have one), segmentation (watershed + merging at the model's scales),
// features, classification and outlines (components, necks split when the
// model has a neck split).
//
//   build/bin/bench_detect [model.cfdet] [size_px]
#include "bench_main.hpp"
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "core/error.hpp"
#include "detect/detector.hpp"
#include "detect/segment_merge.hpp"
#include "pipeline/train_run.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

namespace {
using cityforge::bench::now;
}  // namespace

static int run_bench(int argc, char** argv) {
    const int size_px = argc > 2 ? static_cast<int>(cityforge::bench::parse_number(argv[2], "SIZE_PX")) : 4000;
    const detect::BandLayout rgb{3, -1};
    const std::string model_path = argc > 1 ? argv[1] : default_model_path(rgb, 0.5);  // the tile is 0.5 m
    const detect::DetectorModel model = detect::read_model_file(model_path);
    SynthOptions so;
    so.gsd_m = 0.5;
    so.size_m = size_px * so.gsd_m;
    so.cloud_density_m2 = 0;
    const auto dir = std::filesystem::temp_directory_path() / ("cityforge_bench_detect_" + std::to_string(size_px));
    std::filesystem::path ortho = dir / "ortho.tif";
    if (!std::filesystem::exists(ortho)) ortho = write_synthetic_town(dir.string(), so).ortho_path;
    double t = now();
    const DetectionImage img = read_detection_image(ortho.string());
    const double t_read = now() - t;
    t = now();
    std::vector<float> pix;
    if (model.options.pixel.enabled)
        pix = detect::pixel_probability(model.pixel_model, img.normalised, img.valid, img.layout, img.gsd_m, model.options.pixel, 0,
                                         detect::kCnnDetectionTiling);
    const double t_pix = now() - t;
    t = now();
    const detect::SceneSegments seg = detect::segment_scene(img.normalised, img.valid, model.options.segmentation, {}, img.gsd_m);
    const double t_seg = now() - t;
    t = now();
    const detect::FeatureMatrix f =
        detect::segment_features(img.normalised, img.valid, seg, img.layout, img.gsd_m, model.options.pixel.enabled ? &pix : nullptr);
    const double t_feat = now() - t;
    t = now();
    const std::vector<float> p = detect::segment_probabilities(model, f);
    const double t_pred = now() - t;
    t = now();
    std::size_t n_pairs = 0;
    if (model.options.merge_threshold > 0.0) {
        const detect::SegmentPairs pairs = detect::segment_pairs(img.normalised, seg, img.gsd_m, model.options.pixel.enabled ? &pix : nullptr);
        n_pairs = detect::predict_booster(model.merge_model, pairs.values, pairs.size(), pairs.cols).size();
    }
    const double t_pairs = now() - t;
    t = now();
    const BuildingMask mask = detect_building_mask(model, img);  // the whole chain once more, for the total
    const double t_all = now() - t;
    std::printf("bench_detect: %d x %d px RGB (%s), model %s\n", img.grid.width, img.grid.height, ortho.string().c_str(), model_path.c_str());
    std::printf("  read + normalise      %7.2f s\n", t_read);
    if (model.options.pixel.enabled)
        std::printf("  pixel stage           %7.2f s  (%s on %g m cells)\n", t_pix,
                    model.options.pixel.kind == detect::PixelStageKind::cnn    ? "U-Net"
                    : model.options.pixel.kind == detect::PixelStageKind::both ? "filter bank + boosted trees, and U-Net"
                                                                                : "filter bank + boosted trees",
                    model.options.pixel.cell_m);
    std::printf("  segmentation          %7.2f s  (%u segments, scales", t_seg, seg.count);
    for (double s : model.options.segmentation.scales_at(img.gsd_m)) std::printf(" %.4g", s);
    if (model.options.segmentation.reference_gsd_m > 0.0)
        std::printf(" at %g m: the model's scales hold at %g m", img.gsd_m, model.options.segmentation.reference_gsd_m);
    std::printf(")\n  features              %7.2f s  (%zu per segment)\n", t_feat, f.cols);
    std::printf("  classification        %7.2f s\n", t_pred);
    if (model.options.merge_threshold > 0.0) std::printf("  pair classifier       %7.2f s  (%zu adjacent segment pairs)\n", t_pairs, n_pairs);
    std::printf("  detect_building_mask  %7.2f s  (segmentation .. components; %u buildings", t_all, mask.count);
    if (model.options.neck_split_m > 0.0) std::printf("; necks split at %g m", model.options.neck_split_m);
    std::printf(")\n");
    std::printf("  total incl. reading   %7.2f s   (target < 30 s on 2 cores)\n", t_read + t_all);
    (void)p;
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_detect", "bench_detect [MODEL] [SIZE_PX]", run_bench);
}
