// Developer driver of the training library (the same call as `cityforge
// train`), used by scripts/train_default_models.sh before the CLI split:
//   detect_train OUT.cfdet ORTHO LABELS [ORTHO LABELS ...]
#include <cstdio>
#include <cstdlib>
#include <string>

#include "core/error.hpp"
#include "pipeline/train_run.hpp"

using namespace cityforge;

int main(int argc, char** argv) try {
    if (argc < 4 || (argc - 2) % 2) {
        std::fprintf(stderr, "usage: detect_train OUT ORTHO LABELS [ORTHO LABELS ...]\n");
        return 2;
    }
    TrainOptions o;
    for (int i = 2; i + 1 < argc; i += 2) o.orthos.push_back(argv[i]), o.labels.push_back(argv[i + 1]);
    // Developer overrides (experiments): FOLDS, SCALES=a,b,c, HMIN, SIGMA, ROUNDS, DEPTH, SHARE.
    if (const char* f = std::getenv("FOLDS")) o.folds = std::atoi(f);
    if (const char* f = std::getenv("SCALES")) {
        o.detector.segmentation.scales.clear();
        for (std::string t = f; !t.empty();) {
            const auto c = t.find(',');
            o.detector.segmentation.scales.push_back(std::atof(t.substr(0, c).c_str()));
            t = c == std::string::npos ? "" : t.substr(c + 1);
        }
    }
    if (const char* f = std::getenv("HMIN")) o.detector.segmentation.watershed.h_minima = std::atof(f);
    if (const char* f = std::getenv("SIGMA")) o.detector.segmentation.watershed.smoothing_sigma_px = std::atof(f);
    if (const char* f = std::getenv("ROUNDS")) o.detector.booster.rounds = std::atoi(f);
    if (const char* f = std::getenv("DEPTH")) o.detector.booster.max_depth = std::atoi(f);
    if (const char* f = std::getenv("SHARE")) o.detector.min_label_share = std::atof(f);
    const TrainReport r = run_train(argv[1], o, true);
    for (const FoldReport& f : r.folds)
        std::printf("fold %d: objects P %.3f R %.3f F1 %.3f (%zu/%zu/%zu)  segment px P %.3f R %.3f F1 %.3f\n", f.fold, f.objects.precision,
                    f.objects.recall, f.objects.f1, f.objects.tp, f.objects.predicted, f.objects.reference, f.segments.precision,
                    f.segments.recall, f.segments.f1);
    for (const auto& [name, s] : r.per_image) std::printf("  %s: P %.3f R %.3f F1 %.3f (%zu/%zu/%zu)\n", name.c_str(), s.precision, s.recall, s.f1, s.tp, s.predicted, s.reference);
    std::printf("pooled: objects P %.3f R %.3f F1 %.3f; segment px F1 %.3f; threshold %.2f; %zu segments, %zu features, %zu bytes, %.1f s\n",
                r.pooled_objects.precision, r.pooled_objects.recall, r.pooled_objects.f1, r.pooled_segments.f1, r.threshold, r.segments,
                r.features, r.model_bytes, r.seconds);
    return 0;
} catch (const cityforge::Error& e) {
    std::fprintf(stderr, "detect_train: %s\n", e.what());
    return 1;
}
