// cityforge cloud ...: point cloud tools (rasterize; more subcommands register on the same parent).
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/rasterize_run.hpp"

namespace cityforge::cli {

namespace {

void add_rasterize_command(CLI::App& cloud, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string cloud, out;
        RasterizeOptions options;
        bool recompute_ground = false;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = cloud.add_subcommand("rasterize", "DSM, DTM, nDSM and point density GeoTIFFs from a cloud");
    cmd->add_option("--cloud", s->cloud, "Point cloud (LAS, LAZ, COPC, PLY, XYZ/CSV)")->required();
    cmd->add_option("--out", s->out, "Output folder")->required();
    cmd->add_option("--grid", o.grid_raster, "Use this raster's grid exactly (origin, size, GSD, CRS), e.g. the ortho");
    cmd->add_option("--gsd", o.gsd_m, "Cell size in metres when no --grid is given")->capture_default_str();
    cmd->add_option("--cloud-crs", o.cloud_crs, "CRS of the cloud, e.g. EPSG:7415");
    cmd->add_flag("--recompute-ground", s->recompute_ground, "Ignore class 2 and classify ground with SMRF");
    cmd->add_option("--max-points-in-memory", o.max_points_in_memory, "Larger clouds are read window by window")
        ->capture_default_str();
    cmd->add_option("--tile-m", o.tile_m, "Largest tile edge of windowed reading, metres")->capture_default_str();
    cmd->add_option("--overlap-m", o.overlap_m, "Context read around each tile, metres")->capture_default_str();
    out.push_back({cmd, [s, &g]() {
                       RasterizeOptions opt = s->options;
                       opt.ground.trust_classification = !s->recompute_ground;
                       refuse_existing_output(g, s->out);
                       const RasterizeReport r = rasterize_run(s->cloud, s->out, opt, make_progress(g));
                       warn_without_vertical_crs(s->cloud, opt.cloud_crs, "the DSM and DTM", "give --cloud-crs");
                       if (!g.quiet)
                           std::fprintf(stderr, "cityforge: rasters %d x %d (%s) from %llu points, %zu ground (%s) in %.1f s -> %s\n",
                                        r.width, r.height, r.crs.c_str(), static_cast<unsigned long long>(r.points), r.ground_points,
                                        r.ground_from_classification ? "class 2" : "SMRF", r.seconds, s->out.c_str());
                       return 0;
                   }});
}

}  // namespace

void add_cloud_commands(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    auto* cloud = parent.add_subcommand("cloud", "Point cloud tools");
    cloud->require_subcommand(1);
    add_rasterize_command(*cloud, g, out);
    add_cloud_translate_command(*cloud, g, out);
}

}  // namespace cityforge::cli
