#pragma once
// CityGML 2.0 export of a CityModel: one bldg:Building per building with its
// attributes as generic attributes, bldg:measuredHeight, lod0FootPrint and
// lod1Solid, or lod2Solid with boundedBy Roof/Wall/GroundSurface. srsName
// names the compound horizontal + vertical CRS; srsDimension 3. Written as a
// stream (no document in memory) to a temporary file renamed when complete.
#include <string>

#include "model/building_model.hpp"

namespace cityforge {

struct CityGmlWriteOptions {
    int lod = 1;                 ///< 1: lod0FootPrint + lod1Solid; 2: lod0FootPrint + lod2Solid + boundedBy surfaces
    int decimals = 3;            ///< coordinate decimals (3 = millimetres in a metric CRS)
};

struct CityGmlWriteReport {
    std::size_t buildings = 0;          ///< bldg:Building elements written (every building, with or without geometry)
    std::size_t with_geometry = 0;      ///< of them with a solid of the requested LOD
};

/// The envelope's srsName names the model's EPSG codes; without any code it is
/// left out (the header comment names the CRS). Throws Error naming `path`
/// when the file cannot be written.
CityGmlWriteReport write_citygml(const std::string& path, const CityModel& model, const CityGmlWriteOptions& options = {});

/// "bldg_" + the id with every character outside [A-Za-z0-9_-] replaced by '_':
/// an XML NCName usable as gml:id.
std::string gml_id_for(const std::string& building_id);

}  // namespace cityforge
