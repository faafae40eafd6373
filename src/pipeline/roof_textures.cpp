#include "pipeline/roof_textures.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"
#include "raster/quicklook.hpp"
#include "raster/raster.hpp"

namespace cityforge {

RoofTextureAtlas build_roof_texture_atlas(const CityModel& model, const std::string& ortho_path, const RoofTextureOptions& options) {
    const RasterReader reader(ortho_path);
    const RasterInfo& info = reader.info();
    if (!info.crs.horizontal_epsg || !model.crs.horizontal_epsg || *info.crs.horizontal_epsg != *model.crs.horizontal_epsg)
        throw Error(ortho_path, "the ortho is in " + info.crs.label() + ", the buildings in " + model.crs.label +
                                    "; roof textures need the ortho in the buildings' CRS (gdalwarp -t_srs)");
    RoofTextureAtlas atlas;
    atlas.layout = layout_roof_textures(model, info.transform, info.width, info.height, options);
    const RoofTextureLayout& l = atlas.layout;
    if (l.windows.empty()) return atlas;
    const std::vector<int> bands = info.band_count() >= 3 ? std::vector<int>{1, 2, 3} : std::vector<int>{1, 1, 1};
    const bool byte = std::all_of(bands.begin(), bands.end(), [&](int b) { return info.bands[b - 1].type == SampleType::byte; });
    std::vector<float> rgb(std::size_t(l.atlas_width) * l.atlas_height * 3, 0.0f);
    for (const RoofTextureWindow& w : l.windows) {
        const Image<float> img = reader.read<float>({w.col, w.row, w.width, w.height}, bands);
        for (int b = 0; b < 3; ++b)
            for (int r = 0; r < w.height; ++r)
                for (int c = 0; c < w.width; ++c)
                    rgb[(std::size_t(w.atlas_row + r) * l.atlas_width + (w.atlas_col + c)) * 3 + b] = img.at(b, c, r);
    }
    std::vector<uint8_t> bytes(rgb.size());
    if (byte) {
        for (std::size_t i = 0; i < rgb.size(); ++i) bytes[i] = static_cast<uint8_t>(rgb[i]);
    } else {
        for (int b = 0; b < 3; ++b) {
            std::vector<float> v;
            for (const RoofTextureWindow& w : l.windows)
                for (int r = 0; r < w.height; ++r)
                    for (int c = 0; c < w.width; ++c) v.push_back(rgb[(std::size_t(w.atlas_row + r) * l.atlas_width + (w.atlas_col + c)) * 3 + b]);
            std::nth_element(v.begin(), v.begin() + v.size() * 2 / 100, v.end());
            const float lo = v[v.size() * 2 / 100];
            std::nth_element(v.begin(), v.begin() + v.size() * 98 / 100, v.end());
            const float hi = v[v.size() * 98 / 100], span = hi > lo ? hi - lo : 1.0f;
            for (std::size_t i = std::size_t(b); i < rgb.size(); i += 3)
                bytes[i] = static_cast<uint8_t>(std::clamp((rgb[i] - lo) / span * 255.0f + 0.5f, 0.0f, 255.0f));
        }
    }
    atlas.png = encode_png(bytes, l.atlas_width, l.atlas_height, 3, ortho_path);
    atlas.rgb = std::move(bytes);  // 3D Tiles cut one atlas per tile from these
    return atlas;
}

}  // namespace cityforge
