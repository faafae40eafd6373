#include "footprint/building_mask.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "core/error.hpp"
#include "core/morphology.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/vectorize.hpp"

namespace cityforge {

void BuildingMaskOptions::validate() const {
    if (!(gsd_m > 0.0)) throw Error("--gsd", "must be > 0");
    if (!(min_height_m > 0.0)) throw Error("--min-height-m", "must be > 0");
    if (!(min_area_m2 >= 0.0)) throw Error("--min-area-m2", "must be >= 0");
    if (!(min_hole_m2 >= 0.0)) throw Error("--min-hole-m2", "must be >= 0");
    if (!(split_step_m >= 0.0)) throw Error("--split-step-m", "must be >= 0");
    if (!(min_split_part_m2 >= 0.0)) throw Error("--min-split-part-m2", "must be >= 0");
    if (!(split_gap_step_m >= 0.0)) throw Error("split_gap_step_m", "must be >= 0");
    if (fill_passes < 0 || fill_passes > 50) throw Error("fill passes", "must be between 0 and 50");
    if (!(hidden_completion_max_share >= 0.0 && hidden_completion_max_share <= 1.0)) throw Error("hidden_completion_max_share", "must be in [0, 1]");
    if (opening_radius_px < 0 || opening_radius_px > 10) throw Error("--opening-px", "must be between 0 and 10");
    if (use_classes < -1 || use_classes > 1) throw Error("use_point_classes", "must be auto, yes or no");
}


namespace {
// 4-connected runs of equal values among the cells `member` accepts,
// numbered 1.. in raster order of their first cell (0 elsewhere);
// sizes[run] = its cells.
template <typename Values, typename Member>
uint32_t label_runs(const Values& values, int w, int h, Member member, std::vector<uint32_t>& label, std::vector<uint32_t>& sizes) {
    label.assign(values.size(), 0);
    sizes.assign(1, 0);
    uint32_t next = 0;
    std::vector<std::size_t> stack;
    for (std::size_t s = 0; s < values.size(); ++s) {
        if (label[s] || !member(s)) continue;
        label[s] = ++next;
        sizes.push_back(0);
        stack.push_back(s);
        while (!stack.empty()) {
            const std::size_t p = stack.back();
            stack.pop_back();
            ++sizes[next];
            const int x = static_cast<int>(p % static_cast<std::size_t>(w)), y = static_cast<int>(p / static_cast<std::size_t>(w));
            const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
            for (int k = 0; k < 4; ++k) {
                if (nx[k] < 0 || ny[k] < 0 || nx[k] >= w || ny[k] >= h) continue;
                const std::size_t q = static_cast<std::size_t>(ny[k]) * w + nx[k];
                if (!label[q] && values[q] == values[s] && member(q)) label[q] = next, stack.push_back(q);
            }
        }
    }
    return next;
}
}  // namespace

uint32_t label_components(const std::vector<uint8_t>& mask, uint8_t value, int w, int h, std::vector<uint32_t>& label,
                    std::vector<uint32_t>& sizes) {
    return label_runs(mask, w, h, [&](std::size_t k) { return mask[k] == value; }, label, sizes);
}


BuildingMask buildings_from_cells(const BuildingCells& cells, int w, int h, const BuildingMaskOptions& o) {
    BuildingMask mask = label_buildings(cells.cells, w, h, o);
    mask.used_classes = cells.used_classes;
    split_at_height_steps(mask, cells.step_dsm, o);
    return mask;
}

namespace {
// Minimum-area rectangle of the corners of cells (indices into a w-wide
// grid; pixel units); none for a single line of cells.
std::optional<OrientedRectangle> cells_rectangle(const std::vector<std::size_t>& cells, int w) {
    Polygon corners;
    corners.outer.reserve(cells.size() * 4);
    for (const std::size_t k : cells) {
        const double x = static_cast<double>(k % static_cast<std::size_t>(w)), y = static_cast<double>(k / static_cast<std::size_t>(w));
        for (const auto& [dx, dy] : {std::pair{0, 0}, std::pair{1, 0}, std::pair{0, 1}, std::pair{1, 1}}) corners.outer.push_back({x + dx, y + dy});
    }
    try {
        return minimum_area_rectangle(corners);
    } catch (const Error&) {
        return std::nullopt;
    }
}

// Crown-only cells that the fill made building (mask 1, no evidence) and
// that lie outside the minimum-area rectangle of the measured building cells
// of their component, grown by `tolerance` cells, go back to not building.
// Each component is judged on its own cells alone.
void trim_crown_fill(std::vector<uint8_t>& mask, const std::vector<uint8_t>& crown_only, const std::vector<uint8_t>& evidence, int w, int h,
                     int tolerance) {
    std::vector<uint32_t> labels, sizes;
    const uint32_t count = label_components(mask, 1, w, h, labels, sizes);
    // Per component: its measured cells and its crown-fill cells (each list
    // in raster order), so each component visits only its own cells.
    std::vector<std::vector<std::size_t>> measured(count + 1), crown_fill(count + 1);
    for (std::size_t k = 0; k < mask.size(); ++k)
        if (const uint32_t l = labels[k]) {
            if (evidence[k]) measured[l].push_back(k);
            else if (crown_only[k]) crown_fill[l].push_back(k);
        }
    for (uint32_t l = 1; l <= count; ++l) {
        if (crown_fill[l].empty() || measured[l].empty()) continue;
        std::optional<OrientedRectangle> rect = cells_rectangle(measured[l], w);
        if (!rect) continue;
        rect->length += 2.0 * tolerance, rect->width += 2.0 * tolerance;
        for (const std::size_t k : crown_fill[l])
            if (!rect->contains({static_cast<double>(k % static_cast<std::size_t>(w)) + 0.5, static_cast<double>(k / static_cast<std::size_t>(w)) + 0.5}))
                mask[k] = 0;
    }
}
}  // namespace

bool point_classes_present(const Image<float>& building_share, const Image<float>& vegetation_share) {
    std::size_t classified = 0, with_points = 0;
    const std::size_t n = std::min(building_share.pixel_count(), vegetation_share.pixel_count());
    for (std::size_t k = 0; k < n; ++k)
        if (!std::isnan(building_share.data[k])) {
            ++with_points;
            classified += building_share.data[k] > 0.0f || vegetation_share.data[k] > 0.0f;
        }
    return with_points > 0 && classified * 10 > with_points;
}

BuildingCells building_cells(const Image<float>& ndsm, const Image<float>& dsm, const Image<float>& building_share,
                             const Image<float>& vegetation_share, const BuildingMaskOptions& o) {
    o.validate();
    const int w = ndsm.width, h = ndsm.height;
    const std::size_t n = ndsm.pixel_count();
    if (dsm.pixel_count() != n || building_share.pixel_count() != n || vegetation_share.pixel_count() != n)
        throw Error("building detection", "rasters differ in size");
    BuildingCells out;
    out.used_classes = o.use_classes < 0 ? point_classes_present(building_share, vegetation_share) : o.use_classes == 1;
    // Cell states: 0 = decided not building, 1 = building, 2 = unknown (no
    // point, or only crown points over something high). Unknown cells are
    // decided by their neighbours below.
    constexpr uint8_t kUnknown = 2;
    std::vector<uint8_t> mask(n, 0), crown_only(n, 0);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * w + x;
            const float z = ndsm.data[k];
            if (std::isnan(z)) {
                mask[k] = kUnknown;
                continue;
            }
            if (z < o.min_height_m) continue;
            if (out.used_classes) {
                const float b = building_share.data[k], v = vegetation_share.data[k];
                if (std::isnan(b)) {
                    // Crown points only: a roof may lie under the crown.
                    if (!std::isnan(v)) mask[k] = kUnknown, crown_only[k] = 1;
                    continue;
                }
                // Exact ties (a cell with as many building as other points, common
                // at 1-2 points per cell) alternate in a checkerboard so that
                // edge cells are neither all in nor all out: no outward bias.
                if (b < o.min_building_share || (b == o.min_building_share && ((static_cast<long>(x) + y + o.grid_col0 + o.grid_row0) & 1))) continue;
            } else {
                // Roughness: residual of the 3x3 DSM neighbourhood around its best plane,
                // approximated by the mean absolute second difference over the
                // directions whose both neighbours have a height. Crowns are
                // rough and dense; a cell whose neighbours are all gaps (dark
                // roofs lose most pulses) is a roof candidate.
                if (x == 0 || y == 0 || x == w - 1 || y == h - 1) continue;
                auto d = [&](int dx, int dy) { return dsm.data[static_cast<std::size_t>(y + dy) * w + x + dx]; };
                const float c = d(0, 0);
                float sum = 0.0f;
                int pairs = 0;
                for (const auto& [dx, dy] : {std::pair{1, 0}, std::pair{0, 1}, std::pair{1, 1}, std::pair{1, -1}}) {
                    const float second = d(-dx, -dy) + d(dx, dy) - 2 * c;
                    if (!std::isnan(second)) sum += std::abs(second), ++pairs;
                }
                const float r = pairs ? sum / static_cast<float>(pairs) : 0.0f;
                if (r > o.max_roughness_m) continue;
            }
            mask[k] = 1;
        }
    // Unknown cells (dark roofs absorb most LiDAR pulses, matching fails in
    // shadows, crowns hide roofs) take the building label when at least as
    // many of their decided neighbours are building as not; the front moves
    // one cell per pass, and what is still unknown afterwards is not building.
    out.evidence.resize(n);
    for (std::size_t k = 0; k < n; ++k) out.evidence[k] = mask[k] != kUnknown;
    for (int iter = 0; iter < o.fill_passes; ++iter) {
        std::vector<uint8_t> next = mask;
        bool changed = false;
        for (int y = 1; y < h - 1; ++y)
            for (int x = 1; x < w - 1; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                if (mask[k] != kUnknown) continue;
                int votes = 0, against = 0;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const uint8_t m = mask[static_cast<std::size_t>(y + dy) * w + x + dx];
                        votes += m == 1;
                        against += m == 0;
                    }
                if (votes >= 2 && votes >= against) next[k] = 1, changed = true;
            }
        mask.swap(next);
        if (!changed) break;
    }
    if (out.used_classes && o.crown_fill_rectangle_cells >= 0) trim_crown_fill(mask, crown_only, out.evidence, w, h, o.crown_fill_rectangle_cells);
    // Heights for the step split: only cells with their own evidence (a crown
    // over a roof would otherwise look like a taller building).
    out.step_dsm = dsm;
    for (std::size_t k = 0; k < n; ++k)
        if (mask[k] != 1 || !out.evidence[k]) out.step_dsm.data[k] = NAN;
    for (uint8_t& m : mask) m = m == 1;
    out.cells = std::move(mask);
    return out;
}

namespace {
// Union-find over roof parts: a merged part points to the part it joined.
struct PartSets {
    std::vector<uint32_t> parent;
    explicit PartSets(uint32_t n) : parent(n + 1) {
        for (uint32_t i = 0; i <= n; ++i) parent[i] = i;
    }
    uint32_t find(uint32_t a) {
        while (parent[a] != a) a = parent[a] = parent[parent[a]];
        return a;
    }
};
}  // namespace

void split_at_height_steps(BuildingMask& mask, const Image<float>& dsm, const BuildingMaskOptions& o) {
    if (!(o.split_step_m > 0) || mask.count == 0) return;
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = mask.labels.pixel_count();
    if (dsm.pixel_count() != n) throw Error("building detection", "DSM size differs from the mask");
    const auto& building = mask.labels.data;
    const float step = static_cast<float>(o.split_step_m);
    auto neighbours = [w, h](std::size_t k, std::size_t* out) {
        const int x = static_cast<int>(k % static_cast<std::size_t>(w)), y = static_cast<int>(k / static_cast<std::size_t>(w));
        int c = 0;
        if (x > 0) out[c++] = k - 1;
        if (x + 1 < w) out[c++] = k + 1;
        if (y > 0) out[c++] = k - static_cast<std::size_t>(w);
        if (y + 1 < h) out[c++] = k + static_cast<std::size_t>(w);
        return c;
    };
    // 1. Parts: cells of one building joined when their heights differ by at
    // most the step (slopes of pitched roofs stay joined).
    std::vector<uint32_t> part(n, 0);
    uint32_t parts = 0;
    std::vector<std::size_t> stack;
    std::size_t nb[4];
    for (std::size_t s = 0; s < n; ++s) {
        if (!building[s] || part[s] || std::isnan(dsm.data[s])) continue;
        part[s] = ++parts;
        stack.push_back(s);
        while (!stack.empty()) {
            const std::size_t p = stack.back();
            stack.pop_back();
            for (int i = 0, c = neighbours(p, nb); i < c; ++i) {
                const std::size_t q = nb[i];
                if (building[q] != building[p] || part[q] || std::isnan(dsm.data[q])) continue;
                if (std::abs(dsm.data[q] - dsm.data[p]) > step) continue;
                part[q] = parts;
                stack.push_back(q);
            }
        }
    }
    // Cells without a height join the neighbouring part with the smallest id,
    // one ring per pass, and carry that neighbour's height on (`carried`: the
    // height each part reaches a gap with); a building without any height
    // keeps one part.
    std::vector<float> carried(dsm.data.begin(), dsm.data.end());
    struct Grown {
        std::size_t cell;
        uint32_t part;
        float z;
    };
    for (std::vector<Grown> ring;; ring.clear()) {
        // One ring: decided from the parts before it, then applied.
        for (std::size_t k = 0; k < n; ++k) {
            if (!building[k] || part[k]) continue;
            uint32_t best = 0;
            float z = std::numeric_limits<float>::quiet_NaN();
            for (int i = 0, c = neighbours(k, nb); i < c; ++i)
                if (building[nb[i]] == building[k] && part[nb[i]] && (!best || part[nb[i]] < best)) best = part[nb[i]], z = carried[nb[i]];
            if (best) ring.push_back({k, best, z});
        }
        if (ring.empty()) break;
        for (const Grown& g : ring) part[g.cell] = g.part, carried[g.cell] = g.z;
    }
    for (std::size_t k = 0; k < n; ++k)
        if (building[k] && !part[k]) {
            // Whole building without heights: one part.
            part[k] = ++parts;
            stack.push_back(k);
            while (!stack.empty()) {
                const std::size_t p = stack.back();
                stack.pop_back();
                for (int i = 0, c = neighbours(p, nb); i < c; ++i)
                    if (building[nb[i]] == building[p] && !part[nb[i]]) part[nb[i]] = parts, stack.push_back(nb[i]);
            }
        }
    // 2. Sizes, contact with the outline, shared borders between parts, and
    // how much of each border is a measured step (both cells with a height;
    // such pairs differ by more than the step, or the flood had joined them).
    std::vector<long> size(parts + 1, 0), measured_size(parts + 1, 0);
    std::vector<uint8_t> outline(parts + 1, 0);
    struct Border {
        long length = 0;    // cell pairs across the border
        long measured = 0;  // of which both cells have a height
        double gap_dz = 0;  // sum over the other pairs of |difference of the carried heights|
    };
    std::vector<std::map<uint32_t, Border>> border(parts + 1);
    for (std::size_t k = 0; k < n; ++k) {
        if (!part[k]) continue;
        ++size[part[k]];
        measured_size[part[k]] += !std::isnan(dsm.data[k]);
        const int c = neighbours(k, nb);
        if (c < 4) outline[part[k]] = 1;
        for (int i = 0; i < c; ++i) {
            if (building[nb[i]] != building[k]) {
                outline[part[k]] = 1;
            } else if (part[nb[i]] != part[k]) {
                Border& b = border[part[k]][part[nb[i]]];
                ++b.length;
                const bool measured = !std::isnan(dsm.data[k]) && !std::isnan(dsm.data[nb[i]]);
                b.measured += measured;
                if (!measured && !std::isnan(carried[k]) && !std::isnan(carried[nb[i]])) b.gap_dz += std::abs(carried[k] - carried[nb[i]]);
            }
        }
    }
    PartSets sets(parts);
    auto merge = [&](uint32_t p, uint32_t into) {
        size[into] += size[p];
        measured_size[into] += measured_size[p];
        outline[into] |= outline[p];
        for (const auto& [q, b] : border[p]) {
            if (q == into) continue;
            Border& bi = border[into][q];
            bi.length += b.length, bi.measured += b.measured, bi.gap_dz += b.gap_dz;
            Border& bq = border[q][into];
            bq.length += b.length, bq.measured += b.measured, bq.gap_dz += b.gap_dz;
            border[q].erase(p);
        }
        border[into].erase(p);
        border[p].clear();
        sets.parent[p] = into;
    };
    // 3. Parts that meet mostly across cells without heights (gaps, dark
    // roofs) are one roof: a step must be measured along most of the border
    // -- unless the heights the two parts carry into the gap differ by more
    // than split_gap_step_m on average and both parts have heights over a
    // quarter of min_split_part_m2 at least (a roof beside a tree crown
    // across a gap of a photogrammetric cloud; one roof's sides across a gap
    // differ by its slope times the gap; a few stray returns in a gap are no
    // part of their own).
    const double gap_step = o.split_gap_step_m, cell_area_m2 = o.gsd_m * o.gsd_m;
    auto is_step = [&](uint32_t p, uint32_t q, const Border& b) {
        if (b.measured >= 4 && 2 * b.measured >= b.length) return true;
        const long gap = b.length - b.measured;
        auto measured = [&](uint32_t r) { return 4.0 * static_cast<double>(measured_size[r]) * cell_area_m2 >= o.min_split_part_m2; };
        return gap_step > 0 && gap > 0 && b.gap_dz > gap_step * static_cast<double>(gap) && measured(p) && measured(q);
    };
    for (bool changed = true; changed;) {
        changed = false;
        for (uint32_t p = 1; p <= parts; ++p) {
            if (sets.parent[p] != p) continue;
            for (auto it = border[p].begin(); it != border[p].end();) {
                const uint32_t q = it->first;
                if (is_step(p, q, it->second)) {
                    ++it;
                    continue;
                }
                merge(q, p);
                changed = true;
                it = border[p].begin();
            }
        }
    }
    // 4. Small parts and parts inside the roof merge into the neighbour with
    // the longest shared border (smallest id on ties), smallest parts first.
    const double cell_m2 = o.gsd_m * o.gsd_m;
    auto weak = [&](uint32_t p) { return static_cast<double>(size[p]) * cell_m2 < o.min_split_part_m2 || !outline[p]; };
    std::set<std::pair<long, uint32_t>> queue;
    for (uint32_t p = 1; p <= parts; ++p)
        if (sets.parent[p] == p && weak(p) && !border[p].empty()) queue.insert({size[p], p});
    while (!queue.empty()) {
        const uint32_t p = queue.begin()->second;
        queue.erase(queue.begin());
        uint32_t into = 0;
        long longest = -1;
        for (const auto& [q, b] : border[p])
            if (b.length > longest) longest = b.length, into = q;  // map order: smallest id wins ties
        if (!into) continue;
        if (weak(into)) queue.erase({size[into], into});
        merge(p, into);
        if (weak(into) && !border[into].empty()) queue.insert({size[into], into});
    }
    // 5. Relabel: one label per surviving part, in raster order.
    std::vector<uint32_t> relabel(parts + 1, 0);
    uint32_t count = 0;
    for (std::size_t k = 0; k < n; ++k) {
        if (!part[k]) continue;
        const uint32_t root = sets.find(part[k]);
        if (!relabel[root]) relabel[root] = ++count;
        mask.labels.data[k] = relabel[root];
    }
    mask.count = count;
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
    std::vector<uint8_t> at_border(parts + 1, 0);
    for (int x = 0; x < w; ++x) {
        if (o.keep_border_sides & 2) at_border[label[x]] = 1;
        if (o.keep_border_sides & 8) at_border[label[static_cast<std::size_t>(h - 1) * w + x]] = 1;
    }
    for (int y = 0; y < h; ++y) {
        if (o.keep_border_sides & 1) at_border[label[static_cast<std::size_t>(y) * w]] = 1;
        if (o.keep_border_sides & 4) at_border[label[static_cast<std::size_t>(y) * w + w - 1]] = 1;
    }
    std::vector<uint32_t> keep(parts + 1, 0);
    for (uint32_t p = 1; p <= parts; ++p)
        if (sizes[p] * cell_m2 >= o.min_area_m2 || at_border[p]) keep[p] = ++out.count;
    out.labels = Image<uint32_t>(w, h, 1, 0u);
    for (std::size_t k = 0; k < n; ++k) out.labels.data[k] = keep[label[k]];
    return out;
}

namespace {
// Whether the cells `own` and `add` (indices on a grid `w` wide) still trace
// one valid polygon: an addition must not pinch the outline (rings touching
// at a vertex) nor split it.
bool stays_one_valid_polygon(const std::vector<std::size_t>& own, const std::vector<std::size_t>& add, int w) {
    int x0 = w, y0 = std::numeric_limits<int>::max(), x1 = -1, y1 = -1;
    for (const auto* v : {&own, &add})
        for (const std::size_t k : *v) {
            const int x = static_cast<int>(k % static_cast<std::size_t>(w)), y = static_cast<int>(k / static_cast<std::size_t>(w));
            x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
        }
    Image<uint32_t> crop(x1 - x0 + 3, y1 - y0 + 3, 1, 0u);
    for (const auto* v : {&own, &add})
        for (const std::size_t k : *v)
            crop.at(0, static_cast<int>(k % static_cast<std::size_t>(w)) - x0 + 1, static_cast<int>(k / static_cast<std::size_t>(w)) - y0 + 1) = 1;
    const std::vector<Polygon> parts = vectorize_region(crop, 1, GeoTransform{0.0, 1.0, 0.0, -1.0});
    return parts.size() == 1 && polygon_is_valid(parts[0]);
}
}  // namespace

std::size_t complete_hidden_roofs(BuildingMask& mask, const BuildingCells& cells, double max_growth_share) {
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = mask.labels.pixel_count();
    if (mask.count == 0) return 0;
    if (cells.evidence.size() != n || cells.cells.size() != n) throw Error("building completion", "cells differ in size from the mask");

    auto& labels = mask.labels.data;
    std::vector<std::vector<std::size_t>> pixels(mask.count + 1);
    for (std::size_t k = 0; k < n; ++k)
        if (labels[k]) pixels[labels[k]].push_back(k);
    // Cells that may hold a roof: not measured as something else.
    auto hidden = [&](std::size_t k) { return !cells.evidence[k] || cells.cells[k]; };
    // Each building's claim against the labels as they are (no building sees
    // another's claim).
    std::vector<std::vector<std::size_t>> claims(mask.count + 1);
    std::vector<uint8_t> claimed(n, 0);  // 0, 1, 2 = more than one
    std::vector<uint8_t> seen(n, 0);
    std::vector<std::size_t> stack;
    for (uint32_t l = 1; l <= mask.count; ++l) {
        const std::vector<std::size_t>& own = pixels[l];
        // Touches a free cell that may hold a roof at all?
        bool near = false;
        for (const std::size_t k : own) {
            const int x = static_cast<int>(k % static_cast<std::size_t>(w)), y = static_cast<int>(k / static_cast<std::size_t>(w));
            auto free_hidden = [&](std::size_t q) { return !labels[q] && hidden(q); };
            if ((x > 0 && free_hidden(k - 1)) || (x + 1 < w && free_hidden(k + 1)) || (y > 0 && free_hidden(k - w)) || (y + 1 < h && free_hidden(k + w))) {
                near = true;
                break;
            }
        }
        if (!near) continue;
        // Its minimum-area rectangle (pixel units; a corner cut off at an
        // oblique angle, by the data or by the building, does not turn it).
        const std::optional<OrientedRectangle> rect = cells_rectangle(own, w);
        if (!rect) continue;  // a single line of cells: no area to complete
        auto inside = [&](int x, int y) { return rect->contains({x + 0.5, y + 0.5}); };  // the cell's centre
        std::vector<std::size_t>& add = claims[l];
        stack.assign(own.begin(), own.end());
        while (!stack.empty()) {
            const std::size_t p = stack.back();
            stack.pop_back();
            const int x = static_cast<int>(p % static_cast<std::size_t>(w)), y = static_cast<int>(p / static_cast<std::size_t>(w));
            const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
            for (int i = 0; i < 4; ++i) {
                if (nx[i] < 0 || ny[i] < 0 || nx[i] >= w || ny[i] >= h) continue;
                const std::size_t q = static_cast<std::size_t>(ny[i]) * w + nx[i];
                if (labels[q] || seen[q] || !hidden(q) || !inside(nx[i], ny[i])) continue;
                seen[q] = 1;
                add.push_back(q);
                stack.push_back(q);
            }
        }
        for (const std::size_t q : add) seen[q] = 0;
        if (static_cast<double>(add.size()) > max_growth_share * static_cast<double>(own.size())) add.clear();
        if (!add.empty() && !stays_one_valid_polygon(own, add, w)) add.clear();
        for (const std::size_t q : add) claimed[q] = static_cast<uint8_t>(std::min(2, claimed[q] + 1));
    }
    // A claim that meets another building's is dropped whole (what is added
    // stays connected to its building).
    std::size_t added = 0;
    for (uint32_t l = 1; l <= mask.count; ++l) {
        if (std::any_of(claims[l].begin(), claims[l].end(), [&](std::size_t q) { return claimed[q] > 1; })) continue;
        for (const std::size_t q : claims[l]) labels[q] = l, ++added;
    }
    return added;
}

std::size_t keep_largest_parts(BuildingMask& mask) {
    auto& labels = mask.labels.data;
    std::vector<uint32_t> part, part_size;
    label_runs(labels, mask.labels.width, mask.labels.height, [&](std::size_t k) { return labels[k] != 0; }, part, part_size);
    std::vector<uint32_t> best(mask.count + 1, 0);  // per building: its largest part (the first met of equal ones)
    for (std::size_t k = 0; k < labels.size(); ++k)
        if (const uint32_t l = labels[k]; l && l <= mask.count && (!best[l] || part_size[part[k]] > part_size[best[l]])) best[l] = part[k];
    std::size_t removed = 0;
    for (std::size_t k = 0; k < labels.size(); ++k)
        if (labels[k] && labels[k] <= mask.count && part[k] != best[labels[k]]) labels[k] = 0, ++removed;
    return removed;
}

BuildingMask label_cut_buildings(const std::vector<uint8_t>& whole, std::vector<uint8_t> cut, int w, int h, BuildingMaskOptions options) {
    if (whole.size() != cut.size()) throw Error("building detection", "internal: cut and whole masks differ in size");
    // Nothing cut (no object rule split a building; the usual case in the
    // cross-validation's sweeps): label_buildings fills, opens and drops in
    // that order, so one call gives the same buildings as the two below.
    if (cut == whole) return label_buildings(std::move(cut), w, h, options);
    BuildingMaskOptions fill = options;
    fill.min_area_m2 = 0.0, fill.opening_radius_px = 0;  // only the holes: every part stays as it is
    const BuildingMask filled = label_buildings(whole, w, h, fill);
    // Building where the filled mask is, except the cut pixels (building in `whole`, not in `cut`).
    for (std::size_t i = 0; i < cut.size(); ++i) cut[i] = filled.labels.data[i] != 0 && (cut[i] || !whole[i]) ? 1 : 0;
    options.min_hole_m2 = 0.0;  // filled above
    return label_buildings(std::move(cut), w, h, options);
}

}  // namespace cityforge
