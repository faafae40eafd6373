#include "model/roof_texture.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"
#include "model/face_mesh.hpp"

namespace cityforge {

namespace {

// Shelf packing of `wanted` into `layout` (windows, atlas size, no_room): tallest
// first, then by building index; atlas width about the square root of the total area.
void pack_windows(std::vector<RoofTextureWindow> wanted, int max_px, RoofTextureLayout& layout) {
    layout.windows.clear();
    layout.atlas_width = layout.atlas_height = 0;
    if (wanted.empty()) return;
    std::vector<std::size_t> order(wanted.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return wanted[a].height != wanted[b].height ? wanted[a].height > wanted[b].height : wanted[a].building < wanted[b].building;
    });
    double area = 0;
    int widest = 0;
    for (const RoofTextureWindow& w : wanted) area += double(w.width) * w.height, widest = std::max(widest, w.width);
    const int width = std::min(max_px, std::max(widest, int(std::ceil(std::sqrt(area) * 1.15))));
    int x = 0, y = 0, shelf = 0, used_w = 0;
    for (std::size_t i : order) {
        RoofTextureWindow& w = wanted[i];
        if (w.width > width) {
            layout.no_room.push_back(w.building);
            continue;
        }
        if (x + w.width > width) y += shelf, x = 0, shelf = 0;
        if (y + w.height > max_px) {
            layout.no_room.push_back(w.building);
            continue;
        }
        w.atlas_col = x, w.atlas_row = y;
        x += w.width, shelf = std::max(shelf, w.height), used_w = std::max(used_w, x);
        layout.windows.push_back(w);
    }
    layout.atlas_width = used_w;
    layout.atlas_height = y + shelf;
    std::sort(layout.windows.begin(), layout.windows.end(), [](const RoofTextureWindow& a, const RoofTextureWindow& b) { return a.building < b.building; });
    std::sort(layout.no_room.begin(), layout.no_room.end());
}

}  // namespace

void RoofTextureOptions::validate() const {
    if (max_atlas_px < 16 || max_atlas_px > 16384) throw Error("--texture-max-px", "must be between 16 and 16384");
    if (margin_px < 0 || margin_px > 64) throw Error("--texture-margin-px", "must be between 0 and 64");
}

const RoofTextureWindow* RoofTextureLayout::window_of(std::size_t b) const {
    const auto it = std::lower_bound(windows.begin(), windows.end(), b, [](const RoofTextureWindow& w, std::size_t i) { return w.building < i; });
    return it != windows.end() && it->building == b ? &*it : nullptr;
}

std::array<double, 2> RoofTextureLayout::uv(const RoofTextureWindow& w, double x, double y) const {
    const PixelPoint p = ortho.map_to_pixel({x, y});
    return {(w.atlas_col + (p.col - w.col)) / double(atlas_width), (w.atlas_row + (p.row - w.row)) / double(atlas_height)};
}

RoofTextureLayout layout_roof_textures(const CityModel& model, const GeoTransform& ortho, int ortho_width, int ortho_height,
                                       const RoofTextureOptions& o) {
    o.validate();
    RoofTextureLayout layout;
    layout.ortho = ortho;
    std::vector<RoofTextureWindow> wanted;
    for (std::size_t b = 0; b < model.buildings.size(); ++b) {
        double c0 = INFINITY, c1 = -INFINITY, r0 = INFINITY, r1 = -INFINITY;
        for (const Solid& s : model.buildings[b].lod2)
            for (const Face& f : s.faces)
                if (f.type == SurfaceType::roof)
                    for (const Point3& p : f.outer) {
                        const PixelPoint q = ortho.map_to_pixel({p.x, p.y});
                        c0 = std::min(c0, q.col), c1 = std::max(c1, q.col), r0 = std::min(r0, q.row), r1 = std::max(r1, q.row);
                    }
        if (!std::isfinite(c0)) continue;
        const int col0 = std::max(0, int(std::floor(c0)) - o.margin_px), col1 = std::min(ortho_width, int(std::ceil(c1)) + o.margin_px);
        const int row0 = std::max(0, int(std::floor(r0)) - o.margin_px), row1 = std::min(ortho_height, int(std::ceil(r1)) + o.margin_px);
        // Every roof vertex must be on the ortho (a partly covered roof would be textured with what is not there).
        if (c0 < 0 || r0 < 0 || c1 > ortho_width || r1 > ortho_height || col1 <= col0 || row1 <= row0) {
            layout.outside.push_back(b);
            continue;
        }
        wanted.push_back({b, col0, row0, col1 - col0, row1 - row0, 0, 0});
    }
    pack_windows(std::move(wanted), o.max_atlas_px, layout);
    return layout;
}

RoofTextureLayout repack_roof_textures(const RoofTextureLayout& layout, const std::vector<std::size_t>& buildings, int max_atlas_px) {
    RoofTextureLayout out;
    out.ortho = layout.ortho;
    std::vector<RoofTextureWindow> wanted;
    for (std::size_t b : buildings)
        if (const RoofTextureWindow* w = layout.window_of(b)) wanted.push_back(*w);
    std::sort(wanted.begin(), wanted.end(), [](const RoofTextureWindow& a, const RoofTextureWindow& b) { return a.building < b.building; });
    wanted.erase(std::unique(wanted.begin(), wanted.end(), [](const RoofTextureWindow& a, const RoofTextureWindow& b) { return a.building == b.building; }),
                 wanted.end());
    pack_windows(std::move(wanted), max_atlas_px, out);
    return out;
}

std::vector<uint8_t> copy_roof_texture_pixels(const RoofTextureLayout& from, const std::vector<uint8_t>& from_rgb, const RoofTextureLayout& to) {
    if (from_rgb.size() != std::size_t(from.atlas_width) * from.atlas_height * 3)
        throw Error("roof textures", "internal: the atlas pixels do not match its size");
    std::vector<uint8_t> rgb(std::size_t(to.atlas_width) * to.atlas_height * 3, 0);
    for (const RoofTextureWindow& w : to.windows) {
        const RoofTextureWindow* src = from.window_of(w.building);
        if (!src || src->width != w.width || src->height != w.height) throw Error("roof textures", "internal: a window is not in the source atlas");
        for (int r = 0; r < w.height; ++r)
            std::copy_n(from_rgb.begin() + std::ptrdiff_t((std::size_t(src->atlas_row + r) * from.atlas_width + src->atlas_col) * 3), std::size_t(w.width) * 3,
                        rgb.begin() + std::ptrdiff_t((std::size_t(w.atlas_row + r) * to.atlas_width + w.atlas_col) * 3));
    }
    return rgb;
}

std::vector<std::vector<std::array<float, 2>>> roof_face_uvs(const std::vector<Face>& faces, const RoofTextureLayout& layout, std::size_t building) {
    std::vector<std::vector<std::array<float, 2>>> uv(faces.size());
    const RoofTextureWindow* w = layout.window_of(building);
    for (std::size_t k = 0; w && k < faces.size(); ++k)
        if (faces[k].type == SurfaceType::roof)
            for (const Point3& p : face_vertices(faces[k])) {
                const auto t = layout.uv(*w, p.x, p.y);
                uv[k].push_back({float(t[0]), float(t[1])});
            }
    return uv;
}

}  // namespace cityforge
