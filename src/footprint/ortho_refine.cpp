#include "footprint/ortho_refine.hpp"

#include <algorithm>
#include <cmath>
#include <map>

#include "core/error.hpp"
#include "core/grid_fill.hpp"
#include "segment/boundary_refine.hpp"
#include "segment/region_merging.hpp"

namespace cityforge {

void OrthoRefineOptions::validate() const {
    if (!(segment_scale > 0)) throw Error("--segment-scale", "must be > 0");
    if (refine_passes < 0 || refine_passes > 20) throw Error("--refine-passes", "must be between 0 and 20");
    if (!(ndsm_band_weight >= 0)) throw Error("--ndsm-weight", "must be >= 0");
    if (!(min_segment_building_share > 0 && min_segment_building_share <= 1)) throw Error("--min-segment-building-share", "must be in (0, 1]");
    if (!(min_iou_with_heights >= 0 && min_iou_with_heights <= 1)) throw Error("ortho refinement", "IoU limit must be in [0, 1]");
    if (!(ortho_edge_odds >= 0)) throw Error("--ortho-edge-odds", "must be >= 0");
    if (margin_px < 1 || margin_px > 200) throw Error("ortho margin", "must be between 1 and 200 pixels");
}

namespace {
struct Box {
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // inclusive
};

// Segments of one crop: given labels relabelled 1..count, or watershed +
// merging of the crop's colours (normalised on the crop) and nDSM band.
Image<uint32_t> crop_segments(const Box& b, const Image<float>& colours, const std::vector<uint8_t>& valid, const Image<float>& ndsm,
                              double full_scale, const Image<uint32_t>& given, const OrthoRefineOptions& o, uint32_t& count,
                              Image<float>& crop_colours) {
    const int cw = b.x1 - b.x0 + 1, ch = b.y1 - b.y0 + 1;
    const int w = colours.width;
    crop_colours = Image<float>(cw, ch, colours.bands, 0.0f);
    std::vector<uint8_t> crop_valid(static_cast<std::size_t>(cw) * ch);
    std::vector<double> heights(static_cast<std::size_t>(cw) * ch);
    for (int y = 0; y < ch; ++y)
        for (int x = 0; x < cw; ++x) {
            const std::size_t k = static_cast<std::size_t>(b.y0 + y) * w + b.x0 + x, c = static_cast<std::size_t>(y) * cw + x;
            for (int band = 0; band < colours.bands; ++band) crop_colours.band_data(band)[c] = colours.band_data(band)[k];
            crop_valid[c] = valid[k];
            heights[c] = ndsm.data[k];
        }
    normalize_bands(crop_colours, crop_valid);
    if (!given.data.empty()) {
        // Given segments, renumbered in the crop's raster order.
        Image<uint32_t> out(cw, ch, 1, 0u);
        std::map<uint32_t, uint32_t> number;
        count = 0;
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const uint32_t g = given.at(0, b.x0 + x, b.y0 + y);
                if (!g) continue;
                auto [it, fresh] = number.try_emplace(g, count + 1);
                if (fresh) ++count;
                out.at(0, x, y) = it->second;
            }
        return out;
    }
    fill_gaps(heights, cw, ch);  // a gap (dark roof) read as 0 m would look like ground
    Image<float> bands(cw, ch, colours.bands + 1, 0.0f);
    std::copy(crop_colours.data.begin(), crop_colours.data.end(), bands.data.begin());
    float* hb = bands.band_data(colours.bands);
    for (std::size_t i = 0; i < heights.size(); ++i)
        hb[i] = std::isnan(heights[i]) ? 0.0f : static_cast<float>(std::clamp(heights[i] / full_scale, 0.0, 1.0) * 255.0);
    WatershedOptions wo = o.watershed;
    wo.band_weights.resize(static_cast<std::size_t>(colours.bands), 1.0);
    wo.band_weights.push_back(o.ndsm_band_weight);
    return segment_at_scale(bands, crop_valid, wo, o.segment_scale, count);
}
}  // namespace

void refine_buildings_with_ortho(BuildingMask& mask, const BuildingCells& cells, const Image<float>& colours,
                                 const std::vector<uint8_t>& valid, const Image<float>& ndsm, double full_scale,
                                 const Image<uint32_t>& segments, const std::vector<uint8_t>& vegetation,
                                 const OrthoRefineOptions& o) {
    o.validate();
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = mask.labels.pixel_count();
    if (colours.pixel_count() != n || valid.size() != n || ndsm.pixel_count() != n || cells.cells.size() != n ||
        (!segments.data.empty() && segments.pixel_count() != n) || (!vegetation.empty() && vegetation.size() != n))
        throw Error("ortho refinement", "rasters differ in size");
    if (mask.count == 0) return;
    const std::vector<uint32_t> old(mask.labels.data.begin(), mask.labels.data.end());
    std::vector<Box> box(mask.count + 1, Box{w, h, -1, -1});
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            if (const uint32_t l = old[static_cast<std::size_t>(y) * w + x]) {
                Box& b = box[l];
                b.x0 = std::min(b.x0, x), b.y0 = std::min(b.y0, y), b.x1 = std::max(b.x1, x), b.y1 = std::max(b.y1, y);
            }
    std::vector<uint32_t> out(n, 0);
    for (uint32_t l = 1; l <= mask.count; ++l) {
        Box b = box[l];
        if (b.x1 < b.x0) continue;
        b.x0 = std::max(0, b.x0 - o.margin_px), b.y0 = std::max(0, b.y0 - o.margin_px);
        b.x1 = std::min(w - 1, b.x1 + o.margin_px), b.y1 = std::min(h - 1, b.y1 + o.margin_px);
        const int cw = b.x1 - b.x0 + 1, ch = b.y1 - b.y0 + 1;
        uint32_t count = 0;
        Image<float> crop_colours;
        Image<uint32_t> seg = crop_segments(b, colours, valid, ndsm, full_scale, segments, o, count, crop_colours);
        if (o.refine_passes > 0 && count > 0) refine_segment_boundaries(crop_colours, crop_colours.bands, seg, count, o.refine_passes);
        auto global = [&](int x, int y) { return static_cast<std::size_t>(b.y0 + y) * w + b.x0 + x; };
        // Votes of the cells: a segment with cells of their own evidence is
        // decided by all its cells, measured or inferred from their neighbours
        // (a sparse roof -- dark, or at a few points per m2 -- has most cells
        // inferred, and its measured cells may lie all along its edge).
        std::vector<uint32_t> seen(count + 1, 0), votes(count + 1, 0), yes(count + 1, 0), size(count + 1, 0), green(count + 1, 0);
        std::vector<uint8_t> vetoed(count + 1, 0);
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const uint32_t s = seg.at(0, x, y);
                if (!s) continue;
                const std::size_t k = global(x, y);
                ++size[s];
                if (!vegetation.empty()) green[s] += vegetation[k];
                seen[s] += cells.evidence[k];
                ++votes[s], yes[s] += cells.cells[k];
                // A segment reaching the crop's edge (inside the grid) runs on
                // beyond the building: ground, or roof merged with ground.
                if ((x == 0 && b.x0 > 0) || (y == 0 && b.y0 > 0) || (x == cw - 1 && b.x1 < w - 1) || (y == ch - 1 && b.y1 < h - 1)) vetoed[s] = 1;
            }
        for (uint32_t s = 1; s <= count; ++s)
            if (2 * green[s] > size[s]) vetoed[s] = 1;  // vegetation colours: a crown
        std::vector<uint8_t> voted(static_cast<std::size_t>(cw) * ch, 0);
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const uint32_t s = seg.at(0, x, y);
                const std::size_t k = global(x, y);
                if (!s || (old[k] && old[k] != l)) continue;  // never another building's cells
                voted[static_cast<std::size_t>(y) * cw + x] =
                    !vetoed[s] && (seen[s] ? static_cast<double>(yes[s]) >= o.min_segment_building_share * votes[s] : old[k] == l);
            }
        if (cells.used_classes && o.cloud_edges) {
            // Outline pixels with evidence keep the classified cloud's decision
            // -- unless its evidence is too weak against the ortho's. A pixel of
            // a sparse roof (dark: a fifth of the pulses) with no roof point and
            // one ground point is as likely three-quarters roof as a quarter:
            // with Poisson returns at the ground's rate g and the roof's rate r
            // (points per cell, measured around and on this building), n ground
            // and no roof points, the likelihood ratio of roof cover 3/4 against
            // 1/4 is exp((g - r) / 2) / 3^n; the ortho's vote for building stays
            // when that ratio times `ortho_edge_odds` is at least 1. On a roof
            // as bright as the ground (r = g) one ground point always wins.
            constexpr double kLn3 = 1.0986122886681098;  // ln 3: one ground point's weight
            double edge_lr_base = 0.0;  // (g - r) / 2 + ln(odds); 0 = the cloud decides alone
            if (o.ortho_edge_odds > 0 && !cells.roof_points.empty()) {
                double roof_pts = 0, ground_pts = 0;
                long roof_cells = 0, ground_cells = 0;
                for (int y = 0; y < ch; ++y)
                    for (int x = 0; x < cw; ++x) {
                        const std::size_t k = global(x, y);
                        if (old[k] == l) roof_pts += cells.roof_points[k], ++roof_cells;
                        // Every ground cell, with points or none: the cells with
                        // points alone would overstate a sparse ground's rate.
                        else if (!old[k] && !cells.cells[k]) ground_pts += cells.ground_points[k], ++ground_cells;
                    }
                if (roof_cells > 0 && ground_cells > 0) {
                    const double g = ground_pts / static_cast<double>(ground_cells), r = roof_pts / static_cast<double>(roof_cells);
                    edge_lr_base = 0.5 * (g - r) + std::log(o.ortho_edge_odds);
                }
            }
            std::vector<uint8_t> edged = voted;
            for (int y = 0; y < ch; ++y)
                for (int x = 0; x < cw; ++x) {
                    const std::size_t k = global(x, y);
                    if (!cells.evidence[k] || (old[k] && old[k] != l)) continue;
                    bool edge = false;
                    for (int dy = -1; dy <= 1 && !edge; ++dy)
                        for (int dx = -1; dx <= 1 && !edge; ++dx) {
                            const int xx = x + dx, yy = y + dy;
                            if (xx < 0 || yy < 0 || xx >= cw || yy >= ch) continue;
                            edge = voted[static_cast<std::size_t>(yy) * cw + xx] != voted[static_cast<std::size_t>(y) * cw + x];
                        }
                    if (!edge) continue;
                    const std::size_t c = static_cast<std::size_t>(y) * cw + x;
                    const bool weak_ground = voted[c] && !cells.cells[k] && edge_lr_base > 0 && cells.roof_points[k] == 0 &&
                                             edge_lr_base >= cells.ground_points[k] * kLn3;
                    if (!weak_ground) edged[c] = cells.cells[k];
                }
            voted.swap(edged);
        }
        // The building: voted pixels connected to its own cells.
        std::vector<uint8_t> keep(voted.size(), 0);
        std::vector<std::size_t> stack;
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const std::size_t c = static_cast<std::size_t>(y) * cw + x;
                if (voted[c] && old[global(x, y)] == l && !keep[c]) keep[c] = 1, stack.push_back(c);
            }
        while (!stack.empty()) {
            const std::size_t c = stack.back();
            stack.pop_back();
            const int x = static_cast<int>(c % static_cast<std::size_t>(cw)), y = static_cast<int>(c / static_cast<std::size_t>(cw));
            const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
            for (int i = 0; i < 4; ++i) {
                if (nx[i] < 0 || ny[i] < 0 || nx[i] >= cw || ny[i] >= ch) continue;
                const std::size_t q = static_cast<std::size_t>(ny[i]) * cw + nx[i];
                if (voted[q] && !keep[q]) keep[q] = 1, stack.push_back(q);
            }
        }
        // A redrawing that strays far from the heights' outline (a roof
        // merged with its surroundings, or lost) keeps the heights' outline.
        long inter = 0, kept = 0, own = 0;
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const bool k1 = keep[static_cast<std::size_t>(y) * cw + x], k0 = old[global(x, y)] == l;
                inter += k1 && k0, kept += k1, own += k0;
            }
        const bool redrawn = static_cast<double>(inter) >= o.min_iou_with_heights * static_cast<double>(kept + own - inter);
        // First come, first served in label (raster) order.
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const bool take = redrawn ? keep[static_cast<std::size_t>(y) * cw + x] != 0 : old[global(x, y)] == l;
                if (take && !out[global(x, y)]) out[global(x, y)] = l;
            }
    }
    std::copy(out.begin(), out.end(), mask.labels.data.begin());
    // A redrawing can leave pixels cut off from their building (an earlier
    // building took the pixels between, an outline pixel went back to the
    // cloud's decision): each building stays one part.
    keep_largest_parts(mask);
}

}  // namespace cityforge
