// cityforge stereo / orient / densify / photo: from overlapping photos to a
// dense georeferenced cloud (library: pipeline/photo_run.hpp).
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/photo_run.hpp"

namespace cityforge::cli {

namespace {

void add_stereo(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        StereoRunOptions options;
        std::vector<double> z_range;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("stereo", "Dense cloud of one oriented image pair (rectification, SGBM, left-right check)");
    cmd->add_option("--left", o.left_path, "Left image")->required();
    cmd->add_option("--right", o.right_path, "Right image")->required();
    cmd->add_option("--cameras", o.cameras_path, "Cameras JSON (synth's cameras_truth.json, orient's cameras.json)")->required();
    cmd->add_option("--out", o.out_path, "Output LAS 1.4 cloud (RGB, cameras' CRS)")->required();
    cmd->add_option("--z-range", s->z_range, "Lowest and highest surface height, metres (default: from the cameras file)")->expected(2);
    cmd->add_option("--block-size", o.stereo.block_size_px, "SGBM window, pixels (odd)")->capture_default_str();
    cmd->add_option("--uniqueness", o.stereo.uniqueness_ratio, "SGBM uniqueness ratio, percent")->capture_default_str();
    cmd->add_option("--lr-max-diff", o.stereo.lr_max_diff_px, "Left-right consistency tolerance, pixels")->capture_default_str();
    cmd->add_option("--subsample", o.stereo.subsample, "Keep every n-th pixel in rows and columns")->capture_default_str();
    cmd->add_flag("--overwrite", o.overwrite, "Replace an existing output");
    out.push_back({cmd, [s, &g]() {
                       StereoRunOptions opt = s->options;
                       remove_stale_temporaries_beside(opt.out_path);
                       if (s->z_range.size() == 2) opt.stereo.z_min_m = s->z_range[0], opt.stereo.z_max_m = s->z_range[1];
                       const StereoRunResult r = run_stereo(opt, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr,
                                        "cityforge: stereo wrote %s: %llu points (%s), baseline %.2f m, disparities %d..%d, "
                                        "%zu matched, %zu failed the left-right check, %.1f s\n",
                                        opt.out_path.c_str(), static_cast<unsigned long long>(r.points), r.crs.c_str(),
                                        r.baseline_m, r.min_disparity_px, r.min_disparity_px + r.num_disparities_px,
                                        r.matched_pixels, r.lr_rejected, r.seconds);
                       return 0;
                   }});
}

void add_orient_options(CLI::App* cmd, OrientRunOptions& o) {
    cmd->add_option("--images", o.images_dir, "Folder of overlapping photos (JPEG, PNG, TIFF)")->required();
    cmd->add_option("--camera", o.camera_path, "Camera matrix K.txt (3 x 3, pixels of the photos); default: self-calibration");
    cmd->add_option("--gps", o.gps, "GPS positions: 'exif' or a file of lines 'image lat lon height'")->capture_default_str();
    cmd->add_option("--crs", o.crs, "Output CRS (projected, metres; with a vertical part, heights go to it); default: the UTM zone of the site");
    cmd->add_option("--gps-height-crs", o.gps_height_crs,
                    "Vertical CRS of the GPS heights (EXIF's altitude is above sea level: EGM96), or 'ellipsoid' (WGS 84 ellipsoidal heights)")
        ->capture_default_str();
    cmd->add_option("--max-image-px", o.max_image_px, "Downscale photos to this longest side")->capture_default_str();
    cmd->add_option("--threads", o.threads, "Threads of feature extraction and matching (results do not depend on it)")->capture_default_str();
    cmd->add_option("--colmap", o.colmap, "COLMAP executable")->capture_default_str();
    cmd->add_option("--max-features", o.max_features, "SIFT features per image")->capture_default_str();
    cmd->add_option("--matcher", o.matcher, "exhaustive (every pair) or sequential (file-name = flight order)")->capture_default_str();
    cmd->add_option("--sequential-overlap", o.sequential_overlap, "Sequential matcher: photos after each one to match")->capture_default_str();
}

void add_densify_options(CLI::App* cmd, photo::DensifyOptions& d) {
    cmd->add_option("--cell-px", d.cell_px, "Image cell size beta (one patch per cell), pixels")->capture_default_str();
    cmd->add_option("--cell-m", d.cell_m, "Cells are also at least this many metres on the surface (0 = pixels only)")->capture_default_str();
    cmd->add_option("--patch-grid", d.patch_grid, "Patch samples mu per side")->capture_default_str();
    cmd->add_option("--min-ncc", d.min_ncc, "NCC for an image to count as seeing a patch")->capture_default_str();
    cmd->add_option("--min-views", d.min_views, "Images per patch, reference included")->capture_default_str();
    cmd->add_option("--min-view-share", d.min_view_share, "Images per patch: also this share of the images that should see it (0 = off)")
        ->capture_default_str();
    cmd->add_option("--neighbour-images", d.neighbour_images, "Candidate images per reference image")->capture_default_str();
    cmd->add_option("--iterations", d.iterations, "Expansion + filtering rounds")->capture_default_str();
    cmd->add_option("--points-per-patch", d.points_per_patch_side, "Output points per patch side (1 = centres)")->capture_default_str();
    cmd->add_option("--max-view-angle", d.max_view_angle_deg, "Largest angle between a patch's normal and a ray of an image seeing it, degrees")
        ->capture_default_str();
    cmd->add_option("--max-tilt", d.max_tilt_deg, "Largest tilt of a patch's normal during its refinement, degrees")->capture_default_str();
    cmd->add_option("--wall-hypotheses", d.wall_hypotheses, "Expansion also tries a wall and a level plane where the parent's plane fails (0/1)")
        ->capture_default_str();
    cmd->add_option("--min-support", d.min_support, "Share of adjacent patches among the neighbouring ones to survive filtering")
        ->capture_default_str();
}

void add_orient(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    auto o = std::make_shared<OrientRunOptions>();
    auto* cmd = parent.add_subcommand("orient", "Orient and georeference photos (COLMAP on the CPU + GPS similarity)");
    add_orient_options(cmd, *o);
    cmd->add_option("--out", o->out_dir, "Output folder (images/, cameras.json, sparse.las, orient_report.json)")->required();
    cmd->add_flag("--overwrite", o->overwrite, "Replace an existing output folder");
    out.push_back({cmd, [o, &g]() {
                       remove_stale_temporaries_beside(o->out_dir);
                       const OrientRunResult r = run_orient(*o, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr,
                                        "cityforge: orient wrote %s: %d of %d photos oriented, %llu sparse points, "
                                        "%.2f px mean reprojection error, GPS RMSE %.2f m (%s), %.0f s\n",
                                        o->out_dir.c_str(), r.oriented, r.images, static_cast<unsigned long long>(r.sparse_points),
                                        r.mean_reprojection_error_px, r.gps_rmse_m, r.crs.c_str(), r.seconds);
                       return 0;
                   }});
}

void add_densify(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    auto o = std::make_shared<DensifyRunOptions>();
    auto* cmd = parent.add_subcommand("densify", "Patch-based multi-view stereo (PMVS-style) of an oriented folder");
    cmd->add_option("--model", o->model_dir, "Oriented folder (orient's output, or synth's views/)")->required();
    cmd->add_option("--out", o->out_path, "Output LAS 1.4 cloud")->required();
    add_densify_options(cmd, o->densify);
    cmd->add_flag("--overwrite", o->overwrite, "Replace an existing output");
    out.push_back({cmd, [o, &g]() {
                       remove_stale_temporaries_beside(o->out_path);
                       const DensifyRunResult r = run_densify(*o, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr,
                                        "cityforge: densify wrote %s: %llu points (%s) from %d images, %zu seeds, %zu expanded, "
                                        "%zu filtered, %.1f s\n",
                                        o->out_path.c_str(), static_cast<unsigned long long>(r.points), r.crs.c_str(), r.images,
                                        r.seeds, r.expanded, r.filtered, r.seconds);
                       return 0;
                   }});
}

void add_photo(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    auto o = std::make_shared<PhotoRunOptions>();
    auto* cmd = parent.add_subcommand("photo", "Photos to a dense georeferenced cloud: orient + densify [+ true ortho + run]");
    add_orient_options(cmd, o->orient);
    cmd->add_option("--oriented", o->oriented_dir, "Start from this oriented folder (of `orient`, or an earlier OUT/orient): no re-orientation");
    add_densify_options(cmd, o->densify);
    cmd->add_option("--out", o->out_dir, "Output folder (cloud.las, sparse.las, cameras.json, photo_report.json)")->required();
    cmd->add_flag("--overwrite", o->overwrite, "Replace an existing output folder");
    cmd->add_flag("--run", o->run,
                  "Then the building chain on the dense cloud: OUT/ortho.tif (the cloud's colours), OUT/orthophoto.tif (the photos' "
                  "colours on the cloud's surface) and OUT/run/ (as `run`)");
    cmd->add_option("--ortho-gsd", o->ortho_gsd_m, "Cell of both orthos (the run's grid), metres")->capture_default_str();
    cmd->add_option("--run-ortho", o->run_ortho, "The run's ortho: photos (orthophoto.tif) or cloud (ortho.tif)")->capture_default_str();
    auto run_config = std::make_shared<std::string>();
    cmd->add_option("--run-config", *run_config, "JSON config of the run (schemas/run_config.schema.json; ortho and cloud are set)");
    out.push_back({cmd, [o, run_config, &g]() {
                       if (!run_config->empty()) o->city = run_options_from_json(read_json_file(*run_config), *run_config);
                       remove_stale_temporaries_beside(o->out_dir);
                       const PhotoRunResult r = run_photo(*o, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr, "cityforge: photo wrote %s: %llu dense points, %llu sparse (%s)%s%s, %.0f s\n",
                                        o->out_dir.c_str(), static_cast<unsigned long long>(r.densify.points),
                                        static_cast<unsigned long long>(r.orient.sparse_points), r.orient.crs.c_str(),
                                        o->run ? "; buildings: " : "",
                                        o->run ? std::to_string(r.city.buildings).c_str() : "", r.seconds);
                       return 0;
                   }});
}

}  // namespace

void add_photo_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    add_stereo(parent, g, out);
    add_orient(parent, g, out);
    add_densify(parent, g, out);
    add_photo(parent, g, out);
}

}  // namespace cityforge::cli
