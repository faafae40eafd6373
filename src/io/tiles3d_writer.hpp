#pragma once
// 3D Tiles 1.1 (tileset.json + glb content) and standalone glTF 2.0 export of
// a CityModel. Tiles: an explicit quadtree over the buildings' footprint
// centres; content only in the leaves (refine ADD), bounding volumes as
// oriented boxes in ECEF (EPSG:4978, every vertex transformed by PROJ from
// the model's CRS, vertical datum included where PROJ relates it to the
// ellipsoid), geometric errors that halve with depth (0 at the leaves).
// Each glb carries per-building feature ids (EXT_mesh_features) and the
// buildings' attributes (EXT_structural_metadata).
#include <string>

#include "model/building_model.hpp"
#include "model/roof_texture.hpp"

namespace cityforge {

struct CrsInfo;

struct Tiles3dWriteOptions {
    int max_buildings_per_tile = 300;  ///< a quadtree node with more buildings is split
    int max_depth = 12;                ///< leaves at this depth keep all their buildings
    bool prefer_lod2 = true;           ///< LOD2 solids where a building has them, else LOD1
    void validate() const;
};

struct Tiles3dWriteReport {
    std::size_t buildings = 0;  ///< buildings with a mesh (valid or not; those without solids are left out)
    std::size_t tiles = 0, content_tiles = 0, triangles = 0;
    int depth = 0;              ///< deepest level (root = 0)
};

/// Writes `dir`/tileset.json and `dir`/content/L_X_Y.glb (a temporary sibling
/// directory renamed when complete; an existing `dir` is replaced). With
/// `textures` (an atlas of `model`, its `rgb` pixels filled), the LOD2 roofs of
/// the buildings it covers are textured: each tile's glb embeds its own atlas
/// (PNG) holding only its buildings' windows, the ortho's pixels unchanged, and
/// texture coordinates into it (baseColorTexture). Throws Error naming `dir`
/// when the CRS cannot be transformed to ECEF or no building has a solid.
Tiles3dWriteReport write_3dtiles(const std::string& dir, const CityModel& model, const CrsInfo& crs, const Tiles3dWriteOptions& options = {},
                                 const RoofTextureAtlas* textures = nullptr);

/// Writes one .glb of the whole model in a local frame: x east, y north,
/// z up in the model CRS units minus `origin` (the extent's centre, rounded
/// to whole units; glTF itself is y-up), the CRS and origin in asset.extras.
/// With `textures` (an atlas of `model`), LOD2 roofs of the buildings it covers
/// carry texture coordinates into the embedded atlas image (baseColorTexture).
/// Returns the number of triangles.
std::size_t write_glb(const std::string& path, const CityModel& model, bool prefer_lod2 = true, const RoofTextureAtlas* textures = nullptr);

}  // namespace cityforge
