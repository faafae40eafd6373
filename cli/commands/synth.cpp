// cityforge synth: a synthetic town with exact ground truth.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "synth/synth.hpp"

namespace cityforge::cli {

void add_synth_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string out;
        SynthOptions options;
        std::string cloud_mode = "lidar";
        std::vector<double> origin;
        std::vector<int> view_size;
    };
    auto s = std::make_shared<State>();
    auto* cmd = parent.add_subcommand("synth", "Generate a synthetic town with exact ground truth");
    cmd->add_option("--out", s->out, "Output folder")->required();
    cmd->add_option("--size-m", s->options.size_m, "Scene edge length in metres")->capture_default_str();
    cmd->add_option("--gsd", s->options.gsd_m, "Ortho ground sample distance in metres")->capture_default_str();
    cmd->add_option("--seed", s->options.seed, "Random seed (same seed, same bytes)")->capture_default_str();
    cmd->add_option("--epsg", s->options.epsg, "Projected CRS (metres) of the outputs")->capture_default_str();
    cmd->add_option("--origin", s->origin, "Lower-left corner X Y in the CRS")->expected(2);
    cmd->add_option("--cloud-density", s->options.cloud_density_m2, "Points per m2 (0 = no cloud)")->capture_default_str();
    cmd->add_option("--cloud-mode", s->cloud_mode, "lidar or photo (dense image matching: noisier, gaps)")
        ->check(CLI::IsMember({"lidar", "photo"}))
        ->capture_default_str();
    auto& views = s->options.views;
    cmd->add_option("--views", views.views, "Perspective aerial photos to render into OUT/views (0 = none), with OUT/surface.las")
        ->capture_default_str();
    cmd->add_option("--view-gsd", views.gsd_m, "Photo ground sample distance at mean terrain height, metres")->capture_default_str();
    cmd->add_option("--view-size", s->view_size, "Photo width and height in pixels (default 640 480)")->expected(2);
    cmd->add_option("--forward-overlap", views.forward_overlap, "Along-strip overlap of neighbouring photos")->capture_default_str();
    cmd->add_option("--side-overlap", views.side_overlap, "Overlap of neighbouring strips")->capture_default_str();
    cmd->add_option("--oblique-deg", views.oblique_deg,
                    "Oblique camera: 5 photos per station (nadir + 4 tilted N/E/S/W by this angle); 0 = nadir only")
        ->capture_default_str();
    cmd->add_option("--surface-spacing", views.surface_spacing_m, "Sample spacing of OUT/surface.las, metres")->capture_default_str();
    // Variations of the town (defaults: the default town, byte for byte).
    synth::SceneVariation& v = s->options.variation;
    cmd->add_option("--lidar-sigma-m", s->options.lidar_sigma_m, "Vertical noise of LiDAR points, metres")->capture_default_str();
    cmd->add_option("--sun-azimuth-deg", s->options.sun_azimuth_deg, "Sun bearing, clockwise from north")->capture_default_str();
    cmd->add_option("--sun-elevation-deg", s->options.sun_elevation_deg, "Sun elevation, degrees")->capture_default_str();
    cmd->add_option("--terrain-slope", v.terrain_slope_max, "Largest terrain gradient per axis (0.1 = 10 %)")->capture_default_str();
    cmd->add_option("--terrain-undulation-m", v.terrain_undulation_m, "Amplitude of the terrain undulation, metres")->capture_default_str();
    cmd->add_option("--dark-roof-share", v.dark_roof_share, "Share of roofs absorbing most LiDAR pulses")->capture_default_str();
    cmd->add_option("--tree-touch-share", v.tree_touch_share, "Share of buildings with a crown touching them")->capture_default_str();
    cmd->add_option("--ground-like-roof-share", v.ground_like_roof_share, "Share of roofs coloured like grass, soil or road")->capture_default_str();
    cmd->add_option("--terraced-share", v.terraced_block_share, "Share of blocks built as terraces of equal height")->capture_default_str();
    cmd->add_option("--oblique-share", v.oblique_share, "Share of rectangles with a corner cut at an oblique angle")->capture_default_str();
    cmd->add_option("--round-share", v.round_share, "Share of rectangles drawn round or many-sided instead (circles, ellipses, octagons, hexagons; flat roofs)")
        ->capture_default_str();
    cmd->add_flag("--all-roof-families", v.all_roof_families, "Flat, shed, gable and hip roofs in equal shares");
    cmd->add_flag("--base-at-area-centroid", v.base_at_area_centroid, "Building base at the terrain height of the footprint's area centroid");
    out.push_back({cmd, [s, &g]() {
                       SynthOptions o = s->options;
                       if (s->origin.size() == 2) o.origin_x = s->origin[0], o.origin_y = s->origin[1];
                       o.cloud_mode = cloud_mode_from_string(s->cloud_mode);
                       if (s->view_size.size() == 2) o.views.width_px = s->view_size[0], o.views.height_px = s->view_size[1];
                       refuse_existing_output(g, s->out);
                       const SynthResult r = write_synthetic_town(s->out, o, make_progress(g));
                       if (!g.quiet)
                           std::fprintf(stderr, "cityforge: synth wrote %s (%d x %d px, %d buildings, %d trees, %llu points) in %.1f s\n",
                                        s->out.c_str(), r.width, r.height, r.buildings, r.trees,
                                        static_cast<unsigned long long>(r.points), r.seconds);
                       if (!g.quiet && r.views > 0)
                           std::fprintf(stderr, "cityforge: synth rendered %d photos into %s and %llu exact surface points\n", r.views,
                                        r.views_dir.c_str(), static_cast<unsigned long long>(r.surface_points));
                       return 0;
                   }});
}

}  // namespace cityforge::cli
