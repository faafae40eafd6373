#pragma once
// Roof textures from an ortho (the texture-mapping step): each building's LOD2
// roofs get the ortho's pixel window under them, copied unchanged at the
// ortho's GSD into one atlas image, and texture coordinates from their map
// x, y. Layout only (pure geometry, no GDAL); the pixels are cut by the
// pipeline. The ortho must be north-up and in the model's horizontal CRS.
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "core/geo_transform.hpp"
#include "model/building_model.hpp"

namespace cityforge {

/// One building's ortho window and where it sits in the atlas.
struct RoofTextureWindow {
    std::size_t building = 0;               ///< index in CityModel::buildings
    int col = 0, row = 0, width = 0, height = 0;  ///< ortho pixel window (roofs' plan bounding box + margin, clipped)
    int atlas_col = 0, atlas_row = 0;       ///< its top-left pixel in the atlas
};

struct RoofTextureLayout {
    GeoTransform ortho;                     ///< the ortho's georeferencing (model CRS units)
    int atlas_width = 0, atlas_height = 0;  ///< pixels; 0 x 0 when nothing is textured
    std::vector<RoofTextureWindow> windows; ///< by building index
    std::vector<std::size_t> outside;       ///< buildings with roofs not on the ortho
    std::vector<std::size_t> no_room;       ///< buildings whose window did not fit in the atlas

    /// The window of building `b`, or nullptr when its roofs are not textured.
    const RoofTextureWindow* window_of(std::size_t b) const;
    /// Texture coordinates of map point (x, y) in window `w`, in glTF's convention:
    /// u to the right, v down from the atlas' top edge, both 0..1.
    std::array<double, 2> uv(const RoofTextureWindow& w, double x, double y) const;
};

/// The layout with its image.
struct RoofTextureAtlas {
    RoofTextureLayout layout;  ///< windows and texture coordinates
    std::string png;           ///< the atlas image (RGB PNG bytes); empty when no roof is textured
    /// The same image's pixels: row-major, 3 bytes (R, G, B) per pixel, atlas_width x atlas_height;
    /// empty when no roof is textured. Lets writers cut smaller atlases (one per 3D Tiles tile).
    std::vector<uint8_t> rgb;
};

struct RoofTextureOptions {
    int max_atlas_px = 8192;   ///< longest atlas side, pixels; windows that do not fit are left untextured
    int margin_px = 1;         ///< extra ortho pixels around each roof window (no bleeding at the edges)
    void validate() const;     ///< throws Error naming the option
};

/// Windows for every building with LOD2 roof faces, shelf-packed (tallest
/// first, then by building index: deterministic) into one atlas.
RoofTextureLayout layout_roof_textures(const CityModel& model, const GeoTransform& ortho, int ortho_width, int ortho_height,
                                       const RoofTextureOptions& options = {});

/// The windows of `buildings` (indices into CityModel::buildings; those without a
/// window in `layout` are skipped) packed the same way into an atlas of their own:
/// the same ortho pixels, new atlas positions. Windows that do not fit in
/// `max_atlas_px` go to `no_room`. Deterministic: depends only on the windows.
RoofTextureLayout repack_roof_textures(const RoofTextureLayout& layout, const std::vector<std::size_t>& buildings, int max_atlas_px = 16384);

/// The pixels of atlas `to` (row-major RGB, to.atlas_width x to.atlas_height,
/// black outside the windows) copied from atlas `from` (pixels `from_rgb`, the
/// same windows placed elsewhere; every window of `to` must be in `from`).
std::vector<uint8_t> copy_roof_texture_pixels(const RoofTextureLayout& from, const std::vector<uint8_t>& from_rgb, const RoofTextureLayout& to);

/// Texture coordinates (glTF convention, as RoofTextureLayout::uv) of building
/// `building`'s faces, given in map x, y (model CRS): per face, one (u, v) per
/// face_vertices(face) for roof faces, empty for walls and ground; all empty when
/// the building has no window in `layout`.
std::vector<std::vector<std::array<float, 2>>> roof_face_uvs(const std::vector<Face>& faces, const RoofTextureLayout& layout,
                                                             std::size_t building);

}  // namespace cityforge
