// cityforge heights: per-building heights from a dense point cloud (LOD1 attributes).
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/heights_run.hpp"

namespace cityforge::cli {

void add_heights_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string footprints, cloud, out;
        HeightsRunOptions options;
        bool recompute_ground = false, no_outliers = false;
        std::string ground_method = "plane";
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("heights", "Per-building heights from a dense point cloud (LOD1 attributes)");
    cmd->add_option("--footprints", s->footprints, "Footprint polygons (GeoPackage, Shapefile, GeoJSON, ...)")->required();
    cmd->add_option("--cloud", s->cloud, "Point cloud (LAS 1.0-1.4, LAZ, COPC, PLY, XYZ/CSV)")->required();
    cmd->add_option("--out", s->out, "Output .gpkg (layer buildings), .geojson, .fgb or .shp")->required();
    cmd->add_option("--cloud-crs", o.cloud_crs, "CRS of the cloud, e.g. EPSG:7415 (overrides the file's)");
    cmd->add_option("--layer", o.footprint_layer, "Footprint layer name (default: the only polygon layer; several are an error)");
    cmd->add_option("--roof-percentile", o.heights.roof_percentile, "Roof percentile used for height_m")->capture_default_str();
    cmd->add_option("--ground-method", s->ground_method,
                    "Ground under a footprint: plane (robust plane through the ground ring at the footprint's centroid) or percentile")
        ->check(CLI::IsMember({"plane", "percentile"}))
        ->capture_default_str();
    cmd->add_option("--ground-percentile", o.heights.ground_percentile, "Percentile of ground z around the footprint (--ground-method percentile)")
        ->capture_default_str();
    cmd->add_option("--ground-outlier-m", o.heights.ground_outlier_m, "Plane method: ring points farther from the plane are left out, metres")
        ->capture_default_str();
    cmd->add_option("--ground-buffer-m", o.heights.ground_buffer_m, "Width of the ring searched for ground points, metres")->capture_default_str();
    cmd->add_option("--min-height-m", o.heights.min_height_above_ground_m, "Roof points must be this far above the ground, metres")->capture_default_str();
    cmd->add_option("--min-roof-points", o.heights.min_roof_points, "Fewer roof points -> null percentiles")->capture_default_str();
    cmd->add_option("--max-points-in-memory", o.max_points_in_memory, "Larger clouds are read window by window (tiles of --tile-m)")
        ->capture_default_str();
    cmd->add_option("--tile-m", o.tile_m, "Tile edge of windowed reading, metres")->capture_default_str();
    cmd->add_flag("--recompute-ground", s->recompute_ground, "Ignore class 2 and classify ground with SMRF");
    cmd->add_flag("--no-outlier-filter", s->no_outliers, "Skip statistical outlier removal");
    cmd->add_option("--sor-k", o.outliers.k_neighbours, "Outlier removal: neighbours")->capture_default_str();
    cmd->add_option("--sor-std", o.outliers.std_multiplier, "Outlier removal: sigma multiplier")->capture_default_str();
    cmd->add_option("--smrf-slope", o.ground.slope, "SMRF slope (rise/run)")->capture_default_str();
    cmd->add_option("--smrf-window-m", o.ground.window, "SMRF largest window, metres")->capture_default_str();
    cmd->add_option("--smrf-threshold-m", o.ground.elevation_threshold, "SMRF elevation threshold, metres")->capture_default_str();
    out.push_back({cmd, [s, &g]() {
                       HeightsRunOptions opt = s->options;
                       opt.ground.trust_classification = !s->recompute_ground;
                       opt.outliers.enabled = !s->no_outliers;
                       opt.heights.ground_method = ground_method_from_string(s->ground_method);
                       refuse_existing_output(g, s->out);
                       const HeightsRunReport r = run_heights(s->footprints, s->cloud, s->out, opt, make_progress(g));
                       warn_without_vertical_crs(s->cloud, opt.cloud_crs, "ground_z and the roof heights", "give --cloud-crs");
                       if (!g.quiet) {
                           std::string q;
                           for (const auto& [k, v] : r.quality_counts) q += " " + k + "=" + std::to_string(v);
                           std::fprintf(stderr,
                                        "cityforge: heights for %zu buildings in %.1f s, %zu cloud window(s) (%s; %llu points, %zu outliers + %zu isolated removed, %zu on sparse surfaces kept, %zu ground points %s%s); quality:%s\n",
                                        r.buildings, r.seconds, r.tiles, r.crs.c_str(), static_cast<unsigned long long>(r.points_read),
                                        r.removed_statistical, r.removed_isolated, r.restored_surface, r.ground_points,
                                        r.ground_from_classification ? "from class 2" : "from SMRF", r.reprojected ? ", cloud reprojected" : "",
                                        q.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
