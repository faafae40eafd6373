#pragma once
// The building model every exporter reads: footprints with holes, heights and
// their quality, fit information and all source attributes, LOD1 and LOD2
// solids with semantic surfaces, and per-building status. Map coordinates in
// `CityModel::crs`; z in its vertical datum. No GDAL.
#include <array>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/attribute.hpp"
#include "core/geometry.hpp"
#include "model/refined_lod.hpp"
#include "model/solid.hpp"

namespace cityforge {

/// The reference system of a model, as exporters need to name it.
struct ModelCrs {
    std::string label;                    ///< "EPSG:28992+5709", for humans
    std::optional<int> horizontal_epsg;   ///< EPSG code of the horizontal CRS
    std::optional<int> vertical_epsg;     ///< EPSG code of the vertical CRS (datum), if known
    std::optional<int> compound_epsg;     ///< EPSG code of the whole compound CRS (e.g. 7415), if one exists
    double linear_unit_m = 1.0;           ///< metres per x/y unit
    double z_unit_m = 1.0;                ///< metres per z unit
    /// Ground metres per metre of the CRS's grid at the model (ground_scale_factor at
    /// the centre of its footprints): cos(latitude) in Web Mercator, exactly 1 for UTM
    /// and national grids. Areas and volumes in ground units multiply by its square.
    double ground_scale = 1.0;
    /// Ground m^3 per CRS unit^3 of a solid (x, y in map units, z in vertical units).
    double volume_unit_m3() const { return linear_unit_m * linear_unit_m * ground_scale * ground_scale * z_unit_m; }
    /// GML srsName: "urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709" when both parts are
    /// known, else the single code ("urn:ogc:def:crs:EPSG::32650"). Empty without any code.
    std::string gml_srs_name() const;
    /// CityJSON referenceSystem: "https://www.opengis.net/def/crs/EPSG/0/7415" (the compound
    /// code), else the horizontal code (the vertical datum is then only in the metadata title
    /// and the log). Empty without any code.
    std::string cityjson_reference_system() const;
};

struct Building {
    std::string id;                 ///< unique in the model; letters, digits, '_', '-', '.' (a valid XML id after a prefix)
    std::vector<Polygon> footprint; ///< parts, outer counter-clockwise, holes clockwise; map CRS
    std::optional<double> ground_z; ///< ground height, vertical datum units
    std::optional<double> height_m; ///< LOD1 height above ground_z, metres
    std::optional<double> roof_z;   ///< absolute LOD1 roof height, vertical datum units (ground_z + height)
    /// Every source attribute, in source order (exporters write them all).
    std::vector<std::pair<std::string, AttributeValue>> attributes;
    std::vector<Solid> lod1;        ///< one prism per footprint part; empty without heights
    std::vector<Solid> lod2;        ///< roof-shaped solids (from `cityforge roofs`); empty when none
    std::string roof_type;          ///< LOD2 roof type (flat, shed, gable, hip, complex) or empty
    std::string status = "ok";      ///< "ok", or why a LOD is missing ("no_height", "invalid_lod1", ...)
    std::string reason;             ///< human-readable detail of a non-ok status
    std::vector<std::string> lod1_errors, lod2_errors;  ///< validate_solid() messages; empty = valid
    double lod1_volume = 0.0;       ///< CRS units³ (sum over parts)
    double lod2_volume = 0.0;
    /// Roof parts of the LOD2 solids (LOD1.3 blocks and LOD2.2 BuildingParts), derived from
    /// `lod2` by complete_building(); empty without LOD2. Not stored in the building lines.
    std::vector<RoofPart> roof_parts;
    std::vector<std::string> roof_parts_unsplit;  ///< why a LOD2 solid stayed one part although its roof steps
};

struct CityModel {
    ModelCrs crs;
    std::vector<Building> buildings;
    std::string title = "cityforge buildings";
    /// The input the buildings were read from (e.g. the footprints file), named in
    /// writers' messages about single buildings; may be empty.
    std::string source;
    /// Declared type of the buildings' attributes, by name (from the source
    /// layer and the stages that add them); writers use it so that a field
    /// whose values are all null keeps its type. Missing: from the values.
    std::vector<std::pair<std::string, FieldType>> attribute_types;
};

/// Builds the LOD1 prisms of `b` from ground_z and height_m (converted to z
/// units with crs.z_unit_m), validates them and LOD2 solids if any, and sets
/// status, reason, errors and volumes. A building without heights keeps no
/// LOD1 and gets status "no_height". Derives the roof parts (LOD1.3, LOD2.2)
/// from the LOD2 solids; an invalid LOD1.3 block sets status "invalid_lod13".
void complete_building(Building& b, const ModelCrs& crs, const SolidValidityOptions& validity = {});

/// z of the LOD0 footprint of a building without ground_z (no_height: no
/// point near it), so that it keeps its footprint in every format: the
/// median ground_z of the model's other buildings, 0 when none has one.
/// Writers mark such footprints with the attribute footprint_z_estimated.
double fallback_footprint_z(const CityModel& model);

/// Extent of one building: min x, y, z, max x, y, z (z from its solids or ground_z; 0 when unknown).
std::array<double, 6> building_extent(const Building& building);

/// Model extent over footprints (z from the solids, or ground_z): min x, y, z, max x, y, z.
std::array<double, 6> model_extent(const CityModel& model);

}  // namespace cityforge
