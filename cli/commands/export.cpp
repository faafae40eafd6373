// cityforge export: city models in GeoJSON, GeoPackage, CityGML 2.0, CityJSON 2.0 / CityJSONSeq.
#include <cstdio>
#include <memory>

#include "commands/commands.hpp"
#include "pipeline/export_run.hpp"

namespace cityforge::cli {

void add_export_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string in, out, formats = "geojson,gpkg,citygml,cityjson,cityjsonseq,3dtiles,gltf", lods = "0,1,2";
        ExportOptions options;
    };
    auto s = std::make_shared<State>();
    auto& o = s->options;
    auto* cmd = parent.add_subcommand("export", "City models: GeoJSON, GeoPackage, CityGML 2.0, CityJSON 2.0 / CityJSONSeq, 3D Tiles 1.1, glTF 2.0");
    cmd->add_option("--in", s->in, "Buildings with heights (e.g. from `cityforge heights`), any OGR polygon layer")->required();
    cmd->add_option("--out", s->out, "Output folder")->required();
    cmd->add_option("--formats", s->formats, "Comma-separated: geojson, gpkg, citygml, cityjson, cityjsonseq, 3dtiles (3dtiles/tileset.json), gltf (buildings.glb)")->capture_default_str();
    cmd->add_option("--lod", s->lods, "Comma-separated levels of detail: 0 (footprint), 1 (block), 2 (roofs)")->capture_default_str();
    cmd->add_option("--geojson-crs", o.geojson_crs, "rfc7946 (WGS84 lon/lat) or native (real CRS, non-standard crs member)")
        ->check(CLI::IsMember({"rfc7946", "native"}))
        ->capture_default_str();
    cmd->add_option("--vertical-crs", o.vertical_crs, "Vertical CRS of the heights when the input names none, e.g. EPSG:5709");
    cmd->add_option("--layer", o.layer, "Input layer (default: the only polygon layer; several are an error)");
    cmd->add_option("--id-field", o.id_field, "Building id attribute (absent: the feature id)")->capture_default_str();
    cmd->add_option("--ground-field", o.ground_field, "Ground height attribute (vertical CRS units)")->capture_default_str();
    cmd->add_option("--height-field", o.height_field, "LOD1 height above ground attribute (metres)")->capture_default_str();
    cmd->add_option("--texture-ortho", o.texture_ortho, "Texture the LOD2 roofs with this ortho's pixels (CityJSON, buildings.glb, 3D Tiles)");
    cmd->add_option("--db", o.database, "Also write the building table to PostGIS: \"PG:dbname=... [tables=NAME]\" (table replaced)");
    cmd->add_option("--tile-buildings", o.tiles.max_buildings_per_tile, "3D Tiles: most buildings in one tile before the quadtree splits it")
        ->capture_default_str();
    cmd->add_option("--planarity-tolerance", o.validity.planarity_tolerance, "Validity: max vertex distance to its face plane (CRS units)")
        ->capture_default_str();
    out.push_back({cmd, [s, &g]() {
                       ExportOptions opt = s->options;
                       opt.formats = split_list(s->formats);
                       opt.lods = parse_lods(s->lods);
                       refuse_existing_output(g, s->out);
                       if (!opt.vertical_crs.empty()) vertical_crs_option(opt.vertical_crs);
                       require_readable_raster(opt.texture_ortho);
                       const ExportReport r = run_export(s->in, s->out, opt, make_progress(g));
                       if (!g.quiet) {
                           std::string files, statuses;
                           for (const auto& [format, path] : r.files)
                               files += " " + format + " (" + std::to_string(r.seconds.at(format)).substr(0, 5) + " s)";
                           for (const auto& [k, v] : r.status_counts) statuses += " " + k + "=" + std::to_string(v);
                           std::fprintf(stderr, "cityforge: %zu buildings (%s%s); LOD1 %zu (%zu valid), LOD2 %zu (%zu valid); status:%s; wrote%s -> %s\n",
                                        r.buildings, r.crs.c_str(), r.vertical_known ? "" : ", no vertical datum", r.with_lod1, r.valid_lod1,
                                        r.with_lod2, r.valid_lod2, statuses.c_str(), files.c_str(), s->out.c_str());
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
