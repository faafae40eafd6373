#include "footprint/building_mask.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.hpp"
#include "core/morphology.hpp"

namespace cityforge {

void BuildingMaskOptions::validate() const {
    if (!(gsd_m > 0.0)) throw Error("--gsd", "must be > 0");
    if (!(min_height_m > 0.0)) throw Error("--min-height-m", "must be > 0");
    if (!(min_area_m2 >= 0.0)) throw Error("--min-area-m2", "must be >= 0");
    if (!(min_hole_m2 >= 0.0)) throw Error("--min-hole-m2", "must be >= 0");
    if (opening_radius_px < 0 || opening_radius_px > 10) throw Error("--opening-px", "must be between 0 and 10");
}


uint32_t label_components(const std::vector<uint8_t>& mask, uint8_t value, int w, int h, std::vector<uint32_t>& label,
                    std::vector<uint32_t>& sizes) {
    label.assign(mask.size(), 0);
    sizes.assign(1, 0);
    uint32_t next = 0;
    std::vector<uint32_t> stack;
    for (std::size_t s = 0; s < mask.size(); ++s) {
        if (mask[s] != value || label[s]) continue;
        label[s] = ++next;
        sizes.push_back(0);
        stack.push_back(static_cast<uint32_t>(s));
        while (!stack.empty()) {
            const uint32_t p = stack.back();
            stack.pop_back();
            ++sizes[next];
            const int x = static_cast<int>(p % static_cast<uint32_t>(w)), y = static_cast<int>(p / static_cast<uint32_t>(w));
            const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
            for (int k = 0; k < 4; ++k) {
                if (nx[k] < 0 || ny[k] < 0 || nx[k] >= w || ny[k] >= h) continue;
                const std::size_t q = static_cast<std::size_t>(ny[k]) * w + nx[k];
                if (mask[q] == value && !label[q]) label[q] = next, stack.push_back(static_cast<uint32_t>(q));
            }
        }
    }
    return next;
}


BuildingMask detect_buildings(const Image<float>& ndsm, const Image<float>& dsm, const Image<float>& building_share,
                              const Image<float>& vegetation_share, const BuildingMaskOptions& o) {
    o.validate();
    const int w = ndsm.width, h = ndsm.height;
    const std::size_t n = ndsm.pixel_count();
    if (dsm.pixel_count() != n || building_share.pixel_count() != n || vegetation_share.pixel_count() != n)
        throw Error("building detection", "rasters differ in size");
    BuildingMask out;
    std::size_t classified = 0, with_points = 0;
    for (std::size_t k = 0; k < n; ++k)
        if (!std::isnan(building_share.data[k])) {
            ++with_points;
            classified += building_share.data[k] > 0.0f || vegetation_share.data[k] > 0.0f;
        }
    out.used_classes = with_points > 0 && classified * 10 > with_points;  // classes present in > 10 % of cells
    std::vector<uint8_t> mask(n, 0);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const float z = ndsm.data[k];
            if (std::isnan(z) || z < o.min_height_m) continue;
            if (out.used_classes) {
                const float b = building_share.data[k], v = vegetation_share.data[k];
                // Exact ties (a cell with as many building as other points, common
                // at 1-2 points per cell) alternate in a checkerboard so that
                // edge cells are neither all in nor all out: no outward bias.
                if (std::isnan(b) || v > o.max_vegetation_share) continue;
                if (b < o.min_building_share || (b == o.min_building_share && ((x + y) & 1))) continue;
            } else {
                // Roughness: residual of the 3x3 DSM neighbourhood around its best plane,
                // approximated by the mean absolute second difference.
                if (x == 0 || y == 0 || x == w - 1 || y == h - 1) continue;
                auto d = [&](int dx, int dy) { return dsm.data[static_cast<std::size_t>(y + dy) * w + x + dx]; };
                const float c = d(0, 0);
                const float r = (std::abs(d(-1, 0) + d(1, 0) - 2 * c) + std::abs(d(0, -1) + d(0, 1) - 2 * c) +
                                 std::abs(d(-1, -1) + d(1, 1) - 2 * c) + std::abs(d(-1, 1) + d(1, -1) - 2 * c)) / 4.0f;
                if (std::isnan(r) || r > o.max_roughness_m) continue;
            }
            mask[k] = 1;
        }
    // Cells without points (dark roofs absorb most LiDAR pulses, matching fails
    // in shadows) take the building label when most of their neighbours have it.
    for (int iter = 0; iter < 3; ++iter) {
        std::vector<uint8_t> next = mask;
        for (int y = 1; y < h - 1; ++y)
            for (int x = 1; x < w - 1; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                if (mask[k] || !std::isnan(ndsm.data[k])) continue;
                int votes = 0, known = 0;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const std::size_t q = static_cast<std::size_t>(y + dy) * w + x + dx;
                        if (q == k) continue;
                        votes += mask[q];
                        known += mask[q] || !std::isnan(ndsm.data[q]);
                    }
                if (votes >= 2 && 2 * votes >= known) next[k] = 1;
            }
        mask.swap(next);
    }
    BuildingMask labelled = label_buildings(std::move(mask), w, h, o);
    labelled.used_classes = out.used_classes;
    return labelled;
}

BuildingMask label_buildings(std::vector<uint8_t> mask, int w, int h, const BuildingMaskOptions& o) {
    o.validate();
    const std::size_t n = static_cast<std::size_t>(w) * h;
    if (mask.size() != n) throw Error("building detection", "mask size differs from the grid");
    BuildingMask out;
    // Fill small holes (data gaps, dark roofs) before opening, keep courtyards.
    std::vector<uint32_t> label, sizes;
    const double cell_m2 = o.gsd_m * o.gsd_m;
    const uint32_t holes = label_components(mask, 0, w, h, label, sizes);
    std::vector<uint8_t> touches_border(holes + 1, 0);
    for (int x = 0; x < w; ++x) touches_border[label[x]] = 1, touches_border[label[static_cast<std::size_t>(h - 1) * w + x]] = 1;
    for (int y = 0; y < h; ++y) touches_border[label[static_cast<std::size_t>(y) * w]] = 1, touches_border[label[static_cast<std::size_t>(y) * w + w - 1]] = 1;
    for (std::size_t k = 0; k < n; ++k)
        if (!mask[k] && !touches_border[label[k]] && sizes[label[k]] * cell_m2 < o.min_hole_m2) mask[k] = 1;
    if (o.opening_radius_px > 0) mask = morphology_square(morphology_square(mask, w, h, o.opening_radius_px, true), w, h, o.opening_radius_px, false);
    const uint32_t parts = label_components(mask, 1, w, h, label, sizes);
    std::vector<uint32_t> keep(parts + 1, 0);
    for (uint32_t p = 1; p <= parts; ++p)
        if (sizes[p] * cell_m2 >= o.min_area_m2) keep[p] = ++out.count;
    out.labels = Image<uint32_t>(w, h, 1, 0u);
    for (std::size_t k = 0; k < n; ++k) out.labels.data[k] = keep[label[k]];
    return out;
}

}  // namespace cityforge
