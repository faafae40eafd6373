#pragma once
// Refined levels of detail (Biljecki et al.'s framework as 3DBAG uses it)
// derived from a building's LOD2 solids: the roof parts of each solid (roof
// faces that meet without a height step) as LOD1.3 blocks, each at its own
// height, and as LOD2.2 solids, each written as a BuildingPart. LOD1.2 (one
// height per footprint) is the LOD1 prism. Map CRS, z in the vertical datum
// units; pure geometry, no GDAL.
#include <string>
#include <vector>

#include "model/solid.hpp"

namespace cityforge {

/// One roof part of a LOD2 solid.
struct RoofPart {
    std::size_t solid = 0;   ///< index of the LOD2 solid (footprint part) it comes from
    Solid lod13;             ///< LOD1.3 block: the part's outline extruded from the ground to `lod13_roof_z`
    Solid lod22;             ///< LOD2.2 solid: the part's roof faces, walls down to the ground along its outline, its ground face
    double ground_z = 0.0;   ///< z of the part's ground face
    /// Flat roof of the block: the 70th percentile, by roof area, of the part's roof
    /// surface height (3DBAG takes the 70th percentile of the part's points).
    double lod13_roof_z = 0.0;
    std::vector<std::string> lod13_errors, lod22_errors;  ///< validate_solid() messages; empty = valid
    double lod13_volume = 0.0, lod22_volume = 0.0;        ///< CRS units³
};

struct RoofPartsResult {
    std::vector<RoofPart> parts;  ///< in solid order, then by first roof face; empty without a solid with roof faces
    /// Solids that could not be split at their steps (a step inside a part, or an
    /// outline that touches itself at a vertex): each stays one part. Empty = all split.
    std::vector<std::string> unsplit;
};

/// Splits every LOD2 solid of a building into its roof parts: roof faces are
/// joined when they share an edge at the same heights (a ridge, a hip, a valley
/// or a flat join), not across a step wall. Each part gets its own walls down to
/// the ground and its own ground face, so that parts touch along their step walls
/// and do not overlap. A solid with one roof part keeps its solid as LOD2.2.
/// Each part's solids are validated with `validity`.
RoofPartsResult roof_parts(const std::vector<Solid>& lod2, const SolidValidityOptions& validity = {});

}  // namespace cityforge
