#pragma once
// Vector data through OGR: describing a dataset and writing polygon features
// (with holes) and attributes in a given CRS. Used for truth files, footprints
// and reports; algorithm modules hand us plain geometry.
#include <cstdint>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "core/attribute.hpp"
#include "core/geo_transform.hpp"
#include "core/geometry.hpp"
#include "crs/crs.hpp"

namespace cityforge {

struct VectorLayerInfo {
    std::string name;
    std::string geometry_type;  ///< OGR name, e.g. "Polygon", "Multi Polygon"
    int64_t feature_count = 0;
    CrsInfo crs;
    std::optional<Extent> extent;  ///< in the layer's CRS
    std::vector<std::string> fields;
};

struct VectorInfo {
    std::string path;
    std::string driver;
    std::vector<VectorLayerInfo> layers;
};

/// Opens `path` with OGR and describes its layers. Throws Error naming the
/// file when it is missing or not a vector dataset.
VectorInfo read_vector_info(const std::string& path);


/// A (multi)polygon feature: one Polygon per part.
struct Feature {
    std::vector<Polygon> geometry;
    std::vector<AttributeValue> values;  ///< one per field, in schema order
};

struct FieldDefinition {
    std::string name;
    FieldType type = FieldType::real;
};

struct VectorWriteOptions {
    std::string driver = "GeoJSON";  ///< any OGR driver name, e.g. "GPKG"
    std::string layer = "buildings";
    /// GeoJSON only: write RFC 7946 (WGS84 lon/lat, no crs member) instead of the native CRS.
    /// A feature that cannot be moved to lon/lat (coordinates far outside the CRS's area)
    /// keeps its row with a null geometry, and a warning names it (source, id_field).
    bool rfc7946 = false;
    std::string source;    ///< the input named in messages about single features; empty = the output path
    std::string id_field;  ///< field whose value names a feature in messages; empty or absent = its number (from 1)
    int coordinate_precision = 0;  ///< 0 = driver default
};

/// Polygon features read from a vector file, with their CRS and attributes
/// (every field as text, in the layer's order).
struct PolygonLayer {
    CrsInfo crs;
    std::vector<std::string> field_names;
    std::vector<FieldType> field_types;  ///< one per field: OGR integers -> integer, reals -> real, anything else -> string
    std::vector<Feature> features;  ///< values typed by field_types (int64_t, double, std::string) or null
    std::vector<int64_t> fids;      ///< OGR feature ids, same order
};

/// Reads the polygon/multipolygon features (z dropped) of layer `layer`;
/// when empty, of the dataset's only polygon layer (tables without geometry
/// aside). Throws Error naming the file for a missing file, a missing layer
/// (listing the layers), several polygon layers and no name (listing them),
/// a layer without polygons, or an invalid (self-intersecting or empty)
/// polygon (with its feature id).
PolygonLayer read_polygon_layer(const std::string& path, const std::string& layer = {});

/// Writes polygon features in `crs` (temporary file + rename). Rings are
/// written as given; the exterior counter-clockwise, holes clockwise is the
/// caller's job (see orient_polygon).
void write_polygon_features(const std::string& path, const CrsInfo& crs, const std::vector<FieldDefinition>& fields,
                            const std::vector<Feature>& features, const VectorWriteOptions& options = {});

/// True for a database connection GDAL opens by name ("PG:dbname=... [tables=NAME]"), which is
/// never a file: readers do not look for it on disk, and write_polygon_features writes a PostGIS table
/// (NAME from `tables=`, else VectorWriteOptions::layer) replaced in one transaction, SRID = the
/// horizontal EPSG code, the vertical CRS in a `crs_vertical` text column.
bool is_database_name(const std::string& path);
/// Leaves out of `layer` the fields whose names equal one of `ours` (the
/// fields the command writes itself; compared case-insensitively, as
/// GeoPackage, SQLite and Shapefile compare them), with one warning naming
/// them and `subject`: our values replace theirs, the other fields pass
/// through. Re-running a command on its own output therefore works and gives
/// the same fields. Returns the names left out. `warn` false: no warning (a
/// caller that has said it once already, e.g. per tile).
std::vector<std::string> drop_colliding_fields(PolygonLayer& layer, const std::vector<std::string>& ours, const std::string& subject,
                                               bool warn = true);

/// Moves every vertex of `features` from `from` to `to` (one PROJ
/// transformation for all). Throws Error naming `subject` when PROJ fails.
void reproject_features(std::vector<Feature>& features, const CrsInfo& from, const CrsInfo& to, const std::string& subject);

/// The projected CRS a layer is worked on: `working_crs` when given (it must
/// be projected), else the layer's own CRS when projected, else (a lon/lat
/// layer, as OpenStreetMap extracts and most deliveries are) the UTM zone of
/// the centre of its features, on its datum (utm_crs_for). Error naming
/// `subject` for a layer without a CRS or a geographic working CRS.
CrsInfo working_crs_for_layer(const PolygonLayer& layer, const std::string& working_crs, const std::string& subject);

/// Moves `layer` onto `target` (reproject_features) when its horizontal CRS
/// differs, with an info line naming `subject` and both CRSs; `layer.crs`
/// becomes `target`. Nothing happens when they are the same.
void put_layer_on(PolygonLayer& layer, const CrsInfo& target, const std::string& subject);

/// Output driver for a path: ".gpkg" -> GPKG, ".geojson"/".json" -> GeoJSON,
/// ".fgb" -> FlatGeobuf, ".shp" -> ESRI Shapefile; Error otherwise.
std::string vector_driver_for(const std::string& path);

}  // namespace cityforge
