#pragma once
// `cityforge export`: buildings with heights (any OGR polygon layer, e.g. the
// output of `cityforge heights`) -> GeoJSON (RFC 7946 or native CRS),
// GeoPackage, CityGML 2.0 (LOD0+1, LOD0+2), CityJSON 2.0 and CityJSONSeq, all
// from one building model, each solid validated and its errors reported.
#include <map>
#include <set>
#include <string>
#include <vector>

#include "core/progress.hpp"
#include "io/tiles3d_writer.hpp"
#include "model/building_model.hpp"
#include "model/roof_texture.hpp"

namespace cityforge {

struct PolygonLayer;
struct CrsInfo;

struct ExportOptions {
    /// Any of geojson, gpkg, citygml, cityjson, cityjsonseq, 3dtiles (DIR/3dtiles/tileset.json), gltf (DIR/buildings.glb).
    std::vector<std::string> formats{"geojson", "gpkg", "citygml", "cityjson", "cityjsonseq", "3dtiles", "gltf"};
    std::vector<int> lods{0, 1, 2};          ///< levels of detail written where the format has them
    std::string geojson_crs = "rfc7946";     ///< "rfc7946" (WGS84 lon/lat, 7 decimals) or "native" (non-standard `crs` member)
    std::string vertical_crs;                ///< supplies the vertical CRS when the input has none ("EPSG:5709")
    std::string layer;                       ///< input layer (empty = first)
    std::string id_field = "id";             ///< building id attribute; absent -> the feature id
    std::string ground_field = "ground_z";   ///< ground height attribute, vertical CRS units
    std::string height_field = "height_m";   ///< LOD1 height above ground attribute, metres
    /// Warn when the layer lacks the ground or height field. Off where no heights are
    /// expected (a run without a cloud, which says so itself).
    bool warn_missing_heights = true;
    SolidValidityOptions validity;
    /// Also write the building table (the GeoPackage's rows) to a database: "PG:dbname=... [tables=NAME]"
    /// (default table `buildings`, replaced in one transaction); empty = none.
    std::string database;
    Tiles3dWriteOptions tiles;               ///< 3D Tiles quadtree (prefer_lod2 follows `lods`)
    /// Ortho (north-up, the buildings' horizontal CRS) whose pixels texture the LOD2 roofs in
    /// CityJSON and buildings.glb (atlas DIR/textures/roofs.png) and 3D Tiles (an atlas per tile
    /// in its glb); empty = untextured.
    std::string texture_ortho;
    RoofTextureOptions texture;
    void validate() const;
};

struct ExportReport {
    std::string crs;                         ///< label of the model CRS (horizontal + vertical)
    bool vertical_known = false;             ///< false: heights have no named vertical datum
    std::size_t buildings = 0, with_lod1 = 0, valid_lod1 = 0, with_lod2 = 0, valid_lod2 = 0;
    std::map<std::string, std::size_t> status_counts;
    std::map<std::string, std::string> files;     ///< format -> path written
    std::map<std::string, double> seconds;        ///< format -> seconds spent writing
};

/// The fields build_city_model computes itself ("cityforge_id", "status",
/// "reason", "roof_z", validity, volumes, roof type, refined-LOD flags): input
/// fields of these names are replaced ("status"/"reason" carry a source's
/// failure over when they say more than "ok").
const std::set<std::string>& model_output_fields();

/// The exporters' view of a CRS: EPSG codes of the parts and of the compound, units,
/// and the ground scale at the centre of `buildings` (map units of `crs`; an empty
/// extent gives the nominal scale 1).
ModelCrs model_crs_of(const CrsInfo& crs, const Extent& buildings);

/// Builds the city model of a polygon layer: ids (unique), heights from the
/// named fields, attributes, status carried over from a source `status` /
/// `reason`, LOD1 prisms and their validity. `crs` is the layer's, with a
/// vertical part when known.
CityModel build_city_model(const PolygonLayer& layer, const CrsInfo& crs, const ExportOptions& options, const std::string& path);

/// Reads `in_path`, builds the model and writes `out_dir`/buildings.geojson,
/// buildings.gpkg, buildings_lod1.gml, buildings_lod2.gml (when LOD 2 is
/// asked for), buildings.city.json and buildings.city.jsonl. Lon/lat input
/// is worked on the UTM zone of its centre (working_crs_for_layer); the
/// report's `crs` names the CRS written. Throws Error naming the file for
/// unreadable input, a missing CRS, or a height field of the wrong type.
ExportReport run_export(const std::string& in_path, const std::string& out_dir, const ExportOptions& options,
                        const Progress& progress = {});

/// Writes the chosen formats of an already built model into `out_dir`.
ExportReport write_city_model(const CityModel& model, const CrsInfo& crs, const std::string& out_dir, const ExportOptions& options,
                              const Progress& progress = {});

}  // namespace cityforge
