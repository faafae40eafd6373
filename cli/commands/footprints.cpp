// cityforge footprints: building footprints with rectangle fits.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/footprints_run.hpp"

namespace cityforge::cli {

void add_footprints_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string out, fit = "recursive", mode = "auto", regularize = "lines", detector = "auto", self_training = "on";
        bool roof_seams = RoofSeamOptions{}.enabled;
        FootprintsRunOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("footprints", "Building footprints with rectangle fits (ortho + cloud, ortho-only or cloud-only detection)");
    cmd->add_option("--cloud", o.cloud, "Point cloud (LAS, LAZ, COPC, PLY, XYZ/CSV)");
    cmd->add_option("--ortho", o.ortho, "Ortho (any GDAL raster): its grid and CRS are used");
    cmd->add_option("--ndsm", o.ndsm, "Heights without a cloud: nDSM raster (height above ground), aligned with the ortho's grid");
    cmd->add_option("--ndsm-band", o.ndsm_band, "Heights without a cloud: 1-based band of the ortho holding the nDSM");
    cmd->add_option("--cloud-cell-px", o.cloud_cell_factor, "Cloud rasters on cells of N x N ortho pixels (0 = from the cloud's density)")
        ->capture_default_str();
    cmd->add_option("--max-points-in-memory", o.max_points_in_memory, "Larger clouds are read window by window (tiles of --tile-m)")
        ->capture_default_str();
    cmd->add_option("--tile-m", o.cloud_tile_m, "Largest tile edge of windowed cloud reading, metres")->capture_default_str();
    cmd->add_option("--nir-band", o.nir_band, "1-based band of the ortho holding near infrared: NDVI marks vegetation");
    cmd->add_option("--mode", s->mode, "Detection: ortho_cloud (segments voted by the cloud), ortho_only, cloud_only; auto = from the inputs")
        ->check(CLI::IsMember({"auto", "ortho_cloud", "ortho_only", "cloud_only"}))
        ->capture_default_str();
    cmd->add_option("--detector", s->detector,
                    "ortho_only: model (learned: --model, or the shipped default for the image's bands), rules (hand-set segment rules); "
                    "auto = model, or rules with --segments")
        ->check(CLI::IsMember({"auto", "model", "rules"}))
        ->capture_default_str();
    cmd->add_option("--model", o.model, "ortho_only: detector model from `cityforge train` (default: the shipped model for the image's bands trained nearest its GSD, models/default_<pan|rgb>*.cfdet); given, --mode auto applies it, with --ndsm/--cloud as its nDSM band when trained with one");
    cmd->add_option("--self-training", s->self_training,
                    "ortho_cloud: where the heights cover only part of the ortho, train an image model on the buildings under them "
                    "and detect the others with it (field source = image_model)")
        ->check(CLI::IsMember({"on", "off"}))
        ->capture_default_str();
    cmd->add_option("--segments", o.segments, "Ortho modes: labels from `cityforge segment` (GeoTIFF, or its folder: the --segment-scale level)");
    cmd->add_option("--segment-scale", o.segmentation.segment_scale, "Ortho modes: merging scale of the segmentation")->capture_default_str();
    cmd->add_option("--refine-passes", o.segmentation.refine_passes, "Ortho modes: passes moving boundary pixels to the closest-colour segment")
        ->capture_default_str();
    cmd->add_option("--ndsm-weight", o.segmentation.ndsm_band_weight, "ortho_cloud: weight of the nDSM band in the segmentation")->capture_default_str();
    cmd->add_option("--ortho-edge-odds", o.segmentation.ortho_edge_odds,
                    "ortho_cloud with a classified cloud: prior odds of the ortho's edge where an outline pixel has only ground points, weighed by "
                    "the roof's and the ground's return rates (sparse, dark roofs); 0 = the cloud's points decide the edge")
        ->capture_default_str();
    cmd->add_option("--crown-plane-sigma-m", o.segmentation.max_crown_plane_sigma_m,
                    "ortho_cloud without point classes: segments of vegetation colours (weak ones included) whose heights scatter about "
                    "their roof planes by more than this (metres) are tree crowns, cut from buildings; 0 = off")
        ->capture_default_str();
    cmd->add_option("--min-segment-building-share", o.segmentation.min_segment_building_share,
                    "ortho_cloud: share of a segment's pixels that must be cloud building cells")
        ->capture_default_str();
    cmd->add_option("--out", s->out, "Output .gpkg (layer buildings), .geojson, .fgb or .shp")->required();
    cmd->add_option("--cloud-crs", o.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
    cmd->add_option("--working-crs", o.working_crs,
                    "CRS to work in (metres): default the ortho's, or the UTM zone of its centre for a lon/lat ortho (read warped onto it)");
    cmd->add_option("--out-crs", o.out_crs, "CRS of the written footprints (default: the input's)");
    cmd->add_option("--fit", s->fit,
                    "Geometry written: recursive (rectangles cut/added until the area error < tolerance), regularised (edges snapped to the dominant directions), rectangle (minimum-area) or raw (simplified outline)")
        ->check(CLI::IsMember({"recursive", "regularised", "rectangle", "raw"}))
        ->capture_default_str();
    cmd->add_option("--gsd", o.mask.gsd_m, "Raster cell in metres when no --ortho is given")->capture_default_str();
    cmd->add_option("--min-height-m", o.mask.min_height_m, "nDSM threshold for buildings, metres")->capture_default_str();
    cmd->add_option("--min-area-m2", o.mask.min_area_m2, "Smallest building kept, square metres")->capture_default_str();
    cmd->add_option("--min-hole-m2", o.mask.min_hole_m2, "Smaller holes are filled, larger ones (courtyards) kept")->capture_default_str();
    cmd->add_option("--opening-px", o.mask.opening_radius_px, "Morphological opening radius removing slivers, pixels")->capture_default_str();
    cmd->add_option("--hidden-completion-max-share", o.mask.hidden_completion_max_share,
                    "Roofs the data hides (no point: dark roofs, crowns) completed inside each building's rectangle when that grows it by at most this share; 0 = never")
        ->capture_default_str();
    cmd->add_option("--split-step-m", o.mask.split_step_m, "Split buildings along roof height steps larger than this, metres (0 = never)")
        ->capture_default_str();
    cmd->add_option("--min-split-part-m2", o.mask.min_split_part_m2, "Smallest part split off at a height step, square metres")
        ->capture_default_str();
    cmd->add_flag("--roof-seams,!--no-roof-seams", s->roof_seams,
                  "ortho_cloud: split touching roofs of one height (terraces) where the colour steps on one surface, at valleys, or where a ridge turns (on by default)")
        ->capture_default_str();
    cmd->add_option("--fit-tolerance-pct", o.recursive.tolerance_pct, "Recursive fit: stop below this area error, percent")->capture_default_str();
    cmd->add_option("--regularize-method", s->regularize,
                    "Regularised fit: lines (edge lines snapped to the dominant directions) or cgal (CGAL Shape_regularization contours)")
        ->check(CLI::IsMember({"lines", "cgal"}))
        ->capture_default_str();
    cmd->add_option("--simplify-m", o.simplify_m, "Douglas-Peucker tolerance of the outline, metres")->capture_default_str();
    out.push_back({cmd, [s, &g]() {
                       FootprintsRunOptions opt = s->options;
                       opt.fit = footprint_fit_from_string(s->fit);
                       opt.seams.enabled = s->roof_seams;
                       opt.mode = detection_mode_from_string(s->mode);
                       opt.detector = ortho_detector_from_string(s->detector);
                       opt.self_training.enabled = s->self_training == "on";
                       opt.regularize.method = s->regularize == "cgal" ? RegularizeMethod::cgal_contours : RegularizeMethod::lines;
                       refuse_existing_output(g, s->out);
                       const FootprintsReport r = run_footprints(s->out, opt, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr,
                                        "cityforge: %zu footprints (%s%s%s%s%s, %s, classes %s) on %d x %d cells in %.1f s; mean |fit area error| %.2f %% -> %s\n",
                                        r.buildings, r.mode.c_str(), r.detector.empty() ? "" : ", detector ", r.detector.c_str(),
                                        r.height_source.empty() ? "" : ", heights from ", r.height_source.c_str(),
                                        r.crs.c_str(), r.used_classes ? "used" : "absent", r.width, r.height, r.seconds,
                                        r.mean_abs_fit_area_error_pct, s->out.c_str());
                       if (!g.quiet && r.hidden_completed_cells > 0)
                           std::fprintf(stderr, "cityforge: %zu unmeasured roof cells completed (dark roofs, crowns over roofs)\n", r.hidden_completed_cells);
                       if (!g.quiet && r.crowns_dropped > 0)
                           std::fprintf(stderr, "cityforge: %d tree crowns dropped (vegetation colours on a surface that is no plane; no point classes)\n",
                                        r.crowns_dropped);
                       if (!g.quiet && !r.self_training.empty())
                           std::fprintf(stderr, "cityforge: %zu from the heights, %zu from the image; %.0f %% of the ortho outside the heights; %s\n",
                                        r.from_heights, r.from_image, r.uncovered_share * 100.0, r.self_training.c_str());
                       return 0;
                   }});
}

}  // namespace cityforge::cli
