// cityforge train: a building detector learned from labelled footprints.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/train_run.hpp"

namespace cityforge::cli {

namespace {
void print_scores(const char* what, const DetectionScores& s) {
    std::fprintf(stderr, "%s P %.3f R %.3f F1 %.3f (%zu of %zu predicted, %zu reference)", what, s.precision, s.recall, s.f1, s.tp, s.predicted,
                 s.reference);
}
}  // namespace

void add_train_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string out;
        bool overwrite = false;
        bool no_pairs = false;
        TrainOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto& d = o.detector;
    auto* cmd = parent.add_subcommand("train", "Learn a building detector (segment features + gradient-boosted trees) from labelled footprints, "
                                               "with a spatial k-fold cross-validation");
    cmd->add_option("--ortho", o.orthos, "Training image(s), any CRS GDAL reads (repeat for several); an alpha band is a mask")->required();
    cmd->add_option("--labels", o.labels,
                    "Building labels: one for all images or one per image; any OGR polygon layer in any CRS, or a mask raster on the image's grid (> 0 = building)")
        ->required();
    cmd->add_option("--label-layer", o.label_layer, "Layer of the label files (default: the first)");
    cmd->add_option("--ndsm", o.ndsms, "nDSM raster per ortho (heights above ground, aligned with it): one more band; the model then needs heights");
    cmd->add_option("--cloud", o.clouds, "Point cloud per ortho (LAS, LAZ, COPC, PLY, XYZ), rasterised to an nDSM band on the ortho's grid");
    cmd->add_option("--cloud-crs", o.cloud_crs, "CRS of the clouds, e.g. EPSG:7415");
    cmd->add_option("--nir-band", o.nir_band, "1-based band of near infrared in every image (NDVI features)");
    cmd->add_option("--out", s->out, "Model file to write (.cfdet)")->required();
    cmd->add_flag("--overwrite", s->overwrite, "Replace an existing model file");
    cmd->add_option("--folds", o.folds, "Spatial k-fold cross-validation (0 = none)")->capture_default_str();
    cmd->add_option("--fold-block-m", o.fold_block_m, "Fold blocks, metres a side (folds never share a block)")->capture_default_str();
    cmd->add_option("--thresholds", o.thresholds, "Candidate probability thresholds; the best pooled CV F1 is kept")->delimiter(',');
    cmd->add_option("--split-levels", o.split_levels,
                    "Candidate object split levels (0 = components of building segments; l = kept apart where context scale l's regions meet); "
                    "the best pooled CV F1 is kept")
        ->delimiter(',');
    cmd->add_option("--merge-thresholds", o.merge_thresholds,
                    "Candidate thresholds of the pair classifier grouping adjacent building segments into buildings (tried against the split "
                    "levels; the best pooled CV F1 is kept)")
        ->delimiter(',');
    cmd->add_option("--neck-splits-m", o.neck_split_candidates_m,
                    "Candidate neck splits, metres: touching buildings joined by a neck narrower than about twice this are cut apart "
                    "(tried after the grouping; the best pooled CV F1 is kept; none = never)")
        ->delimiter(',');
    cmd->add_option("--cv-out", o.cv_out_dir,
                    "Directory for the cross-validation's out-of-fold footprints (pixel space, JSON), pixel map, classified segments and folds per image "
                    "(error analysis)");
    cmd->add_option("--neck-split-m", d.neck_split_m, "Neck split, metres, when there is no cross-validation (0 = off)")->capture_default_str();
    cmd->add_flag("--no-pair-classifier", s->no_pairs, "Buildings from the split levels only (no pair classifier is trained)");
    cmd->add_option("--split-level", d.object_split_level, "Object split level when there is no cross-validation")->capture_default_str();
    cmd->add_option("--threshold", d.threshold, "Probability threshold when there is no cross-validation")->capture_default_str();
    cmd->add_option("--scales", d.segmentation.scales, "Merging scales: classified segments first, then context levels")->delimiter(',');
    cmd->add_option("--reference-gsd-m", d.segmentation.reference_gsd_m,
                    "The merging scales hold at this GSD and are scaled by it / the image's GSD (segments of the same ground size at any "
                    "resolution); 0 = the scales as given")
        ->capture_default_str();
    cmd->add_option("--h-minima", d.segmentation.watershed.h_minima, "Watershed dynamics threshold (normalised gradient units)")->capture_default_str();
    cmd->add_option("--rounds", d.booster.rounds, "Boosting rounds (trees)")->capture_default_str();
    cmd->add_option("--max-depth", d.booster.max_depth, "Depth of each tree")->capture_default_str();
    cmd->add_option("--learning-rate", d.booster.learning_rate, "Shrinkage (eta)")->capture_default_str();
    cmd->add_option("--seed", d.booster.seed, "Seed of row/column sampling and of the folds (same data and seed, same model bytes)")
        ->capture_default_str();
    cmd->add_option("--map-split", d.map_split_threshold,
                    "Map-guided first segments: each connected piece of a first-scale segment where the pixel stage's map reaches this "
                    "becomes a segment of its own (0 = off; needs the pixel stage)")
        ->capture_default_str();
    cmd->add_option("--map-split-min-m2", d.map_split_min_m2, "Map-guided first segments: smallest piece split off (and smallest rest), square metres")
        ->capture_default_str();
    cmd->add_option("--min-label-share", d.min_label_share, "A segment is building when this share of its pixels is labelled")->capture_default_str();
    cmd->add_option("--min-area-m2", d.min_area_m2, "Smallest building kept when applied, square metres")->capture_default_str();
    cmd->add_flag("!--no-pixel-stage", d.pixel.enabled,
                  "Segment features only, without the pixel stage (a per-pixel filter bank + boosted trees whose building-probability map "
                  "adds segment features)");
    cmd->add_option("--pixel-cell-m", d.pixel.cell_m, "Pixel stage: working cell, metres (the image is box-averaged to about this)")
        ->capture_default_str();
    cmd->add_option("--pixel-sigmas-m", d.pixel.sigmas_m, "Pixel stage: filter scales, metres (increasing)")->delimiter(',');
    cmd->add_option("--pixel-samples", d.pixel.samples_per_image, "Pixel stage: training cells per image")->capture_default_str();
    cmd->add_option("--pixel-rounds", d.pixel.booster.rounds, "Pixel stage: boosting rounds")->capture_default_str();
    cmd->add_option_function<std::string>(
           "--pixel-stage", [s](const std::string& k) { s->options.detector.pixel.kind = detect::parse_pixel_stage_kind(k); },
           "Pixel stage: 'boosted' (filter bank + boosted trees), 'cnn' (a small U-Net on the cell bands, libtorch CPU) or 'both' (the mean of the two maps)")
        ->check(CLI::IsMember({"boosted", "cnn", "both"}))
        ->default_str("boosted");
    cmd->add_option("--pixel-cnn-steps", d.pixel.cnn.steps, "Pixel CNN: training steps (Adam)")->capture_default_str();
    cmd->add_option("--pixel-cnn-channels", d.pixel.cnn.base_channels, "Pixel CNN: channels at full resolution")->capture_default_str();
    cmd->add_option("--pixel-cnn-crop", d.pixel.cnn.crop_cells, "Pixel CNN: training crop side, cells")->capture_default_str();
    cmd->add_option("--pixel-cnn-tta", d.pixel.cnn.tta,
                    "Pixel CNN: test-time augmentation, the map averaged over 1 (none), 4 (flips, rot180) or 8 (also transposes) transforms, "
                    "in the cross-validation's maps and when applied")
        ->check(CLI::IsMember({1, 4, 8}))
        ->capture_default_str();
    cmd->add_option("--core-thresholds", o.core_threshold_candidates,
                    "Instance separation: candidate thresholds of the core CNN's map (building cores grown back over the building mask, "
                    "buildings cut where two cores meet; tried after the neck split, the best pooled CV F1 is kept; none = no core CNN)")
        ->delimiter(',');
    cmd->add_option("--core-depth-m", d.instance.core_depth_m, "Core CNN target: labelled pixels at least this far (m) from an unlabelled one")
        ->capture_default_str();
    cmd->add_option("--core-cell-m", d.instance.cell_m, "Core CNN: working cell, metres")->capture_default_str();
    cmd->add_option("--core-cnn-steps", d.instance.cnn.steps, "Core CNN: training steps (Adam)")->capture_default_str();
    cmd->add_option("--core-cnn-channels", d.instance.cnn.base_channels, "Core CNN: channels at full resolution")->capture_default_str();
    cmd->add_option("--min-core-m2", d.instance.min_core_m2, "Smallest core that makes a building of its own, square metres")->capture_default_str();
    out.push_back({cmd, [s, &g]() {
                       remove_stale_temporaries_beside(s->out);
                       if (s->no_pairs) s->options.merge_thresholds.clear();
                       const TrainReport r = run_train(s->out, s->options, s->overwrite, make_progress(g));
                       if (!g.quiet) {
                           std::fprintf(stderr, "cityforge: trained on %zu image(s), %s, %zu segments (%zu building), %zu reference buildings, %zu features\n",
                                        r.images, r.bands.c_str(), r.segments, r.building_segments, r.reference_buildings, r.features);
                           for (const FoldReport& f : r.folds) {
                               std::fprintf(stderr, "  fold %d (%zu test segments): ", f.fold, f.test_segments);
                               print_scores("objects@IoU0.5", f.objects);
                               std::fprintf(stderr, "; ");
                               print_scores("segment pixels", f.segments);
                               std::fprintf(stderr, "\n");
                           }
                           for (const auto& [name, sc] : r.per_image) {
                               std::fprintf(stderr, "  %s: ", name.c_str());
                               print_scores("objects@IoU0.5", sc);
                               std::fprintf(stderr, "\n");
                           }
                           if (!r.folds.empty()) {
                               std::fprintf(stderr, "  pooled: ");
                               print_scores("objects@IoU0.5", r.pooled_objects);
                               std::fprintf(stderr, "; ");
                               print_scores("segment pixels", r.pooled_segments);
                               std::fprintf(stderr, "\n");
                           }
                           std::fprintf(stderr, "cityforge: threshold %.2f, split level %d, merge threshold %.2f, fingerprint %s, %zu bytes in %.1f s -> %s\n", r.threshold, r.object_split_level, r.merge_threshold, r.fingerprint.c_str(),
                                        r.model_bytes, r.seconds, s->out.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
