// cityforge roofs: LOD2 buildings (roof planes, walls, ground) from footprints and a dense cloud.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "core/log.hpp"
#include "pipeline/roofs_run.hpp"

namespace cityforge::cli {

void add_roofs_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string footprints, cloud, out, formats = "geojson,gpkg,citygml,cityjson,cityjsonseq,3dtiles,gltf", lods = "0,1,2";
        RoofsRunOptions options;
        bool recompute_ground = false, no_outliers = false, no_retry = false;
        std::string detector = "region_growing";
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("roofs", "LOD2 buildings (roof planes, walls, ground) from footprints and a dense cloud, written as city models");
    cmd->add_option("--footprints", s->footprints, "Footprint polygons (any OGR layer)")->required();
    cmd->add_option("--cloud", s->cloud, "Point cloud (LAS 1.0-1.4, LAZ, COPC, PLY, XYZ/CSV)")->required();
    cmd->add_option("--out", s->out, "Output folder (buildings.gpkg, .geojson, _lod1.gml, _lod2.gml, .city.json, .city.jsonl)")->required();
    cmd->add_option("--cloud-crs", o.heights.cloud_crs, "CRS of the cloud, e.g. EPSG:7415 (overrides the file's)");
    cmd->add_option("--layer", o.heights.footprint_layer, "Footprint layer name (default: the only polygon layer; several are an error)");
    cmd->add_option("--formats", s->formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq, 3dtiles (3dtiles/tileset.json), gltf (buildings.glb)")->capture_default_str();
    cmd->add_option("--lod", s->lods, "Comma-separated levels of detail: 0, 1, 2")->capture_default_str();
    cmd->add_option("--texture-ortho", o.model.texture_ortho, "Texture the LOD2 roofs with this ortho's pixels (CityJSON, buildings.glb, 3D Tiles)");
    cmd->add_option("--db", o.model.database, "Also write the building table to PostGIS: \"PG:dbname=... [tables=NAME]\" (table replaced)");
    cmd->add_option("--id-field", o.model.id_field, "Building id attribute (absent: the feature id)")->capture_default_str();
    cmd->add_option("--vertical-crs", o.model.vertical_crs, "Vertical CRS of the heights when the cloud names none, e.g. EPSG:5709");
    cmd->add_option("--roof-percentile", o.heights.heights.roof_percentile, "Roof percentile of the LOD1 height and the flat fallback")
        ->capture_default_str();
    cmd->add_option("--plane-distance-m", o.lod2.planes.distance_tolerance_m, "Roof planes: max point-to-plane distance, metres")->capture_default_str();
    cmd->add_option("--plane-normal-deg", o.lod2.planes.normal_tolerance_deg, "Roof planes: max normal deviation, degrees")->capture_default_str();
    cmd->add_option("--plane-min-points", o.lod2.planes.min_points, "Roof planes: minimum support")->capture_default_str();
    cmd->add_option("--lod2-min-points", o.lod2.min_points, "Fewer roof points -> flat roof (LOD1.2)")->capture_default_str();
    cmd->add_option("--max-median-residual-m", o.lod2.max_median_residual_m, "A roof model missing its points by more (median) -> flat roof")
        ->capture_default_str();
    cmd->add_option("--plane-detector", s->detector, "Roof planes: region_growing (ours), cgal_region_growing or cgal_ransac (CGAL Shape_detection)")
        ->capture_default_str();
    cmd->add_option("--lod2-retry-rmse-m", o.lod2.retry_rmse_m,
                    "A roof model with a larger RMSE (or a fallback) is rebuilt with alternative plane settings, the best kept")
        ->capture_default_str();
    cmd->add_flag("--no-lod2-retry", s->no_retry, "Keep the first roof model (no alternative plane settings)");
    cmd->add_flag("--recompute-ground", s->recompute_ground, "Ignore class 2 and classify ground with SMRF");
    cmd->add_flag("--no-outlier-filter", s->no_outliers, "Skip statistical outlier removal");
    out.push_back({cmd, [s, &g]() {
                       RoofsRunOptions opt = s->options;
                       opt.heights.ground.trust_classification = !s->recompute_ground;
                       opt.heights.outliers.enabled = !s->no_outliers;
                       opt.lod2.retry_alternatives = !s->no_retry;
                       opt.lod2.planes.detector = plane_detector_from_string(s->detector, "--plane-detector");
                       opt.model.formats = split_list(s->formats);
                       opt.model.lods = parse_lods(s->lods);
                       refuse_existing_output(g, s->out);
                       if (!opt.model.vertical_crs.empty()) vertical_crs_option(opt.model.vertical_crs);
                       require_readable_raster(opt.model.texture_ortho);
                       const RoofsRunReport r = run_roofs(s->footprints, s->cloud, s->out, opt, make_progress(g));
                       if (!r.model.vertical_known)
                           log::warning(s->cloud + ": no vertical CRS: the city models' heights are written without a named height datum; give --vertical-crs (e.g. EPSG:5703 NAVD88, 5709 NAP, 5720 NGF-IGN69 height)");
                       if (!g.quiet) {
                           std::string types;
                           for (const auto& [k, v] : r.roof_types) types += " " + k + "=" + std::to_string(v);
                           std::fprintf(stderr,
                                        "cityforge: %zu buildings (%s): LOD2 roof planes %zu, flat fallback %zu, valid LOD2 %zu of %zu; roofs:%s; mean RMSE %.3f m; roofs %.1f s, total %.1f s -> %s\n",
                                        r.model.buildings, r.model.crs.c_str(), r.lod2, r.fallbacks, r.model.valid_lod2, r.model.with_lod2,
                                        types.c_str(), r.mean_rmse_m, r.lod2_seconds, r.seconds, s->out.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
