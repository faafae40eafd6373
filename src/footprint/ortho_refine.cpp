#include "footprint/ortho_refine.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <optional>

#include "core/error.hpp"
#include "core/statistics.hpp"
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
    if (cloud_peel_rings < 0 || cloud_peel_rings > 100) throw Error("cloud_peel_rings", "must be between 0 and 100");
    if (!(max_crown_plane_sigma_m >= 0)) throw Error("crown_plane_sigma_m", "must be >= 0 (0 = off)");
    if (!(min_crown_local_roughness_m >= 0)) throw Error("crown_local_roughness_m", "must be >= 0");
    if (!(crown_local_radius_m > 0 && gsd_m > 0)) throw Error("ortho refinement", "the crown's local radius and the pixel size must be > 0");
    if (!(max_vegetation_share > 0 && max_vegetation_share <= 1)) throw Error("max_vegetation_share", "must be in (0, 1]");
    if (!(min_crown_building_colour_share > 0)) throw Error("min_crown_building_colour_share", "must be > 0 (above 1 = off)");
}

namespace {
// Robust scatter of heights about their plane: the trimmed least-squares
// plane (fit_trimmed_plane, 2.5 sigma), so a few pixels of wall or ground
// along a segment's edge do not count; then sigma = 1.4826 x the median
// absolute residual of all the points (the unit of z). 0 below 6 points or
// for a line-like set.
double robust_plane_sigma(const std::vector<std::array<double, 3>>& p) {
    TrimmedPlaneOptions o;
    o.trim_sigmas = 2.5;
    const std::optional<TrimmedPlane> plane = fit_trimmed_plane(p, o);
    if (!plane) return 0.0;
    std::vector<double> r(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) r[i] = std::abs(p[i][2] - plane->z(p[i][0], p[i][1]));
    return 1.4826 * *percentile(r, 50.0);
}

// Scatter of a segment's heights about its roof: the least of one robust
// plane and two, split through the centroid along either principal axis of
// the segment's pixels (a gable's ridge, or a valley, in one segment).
double roof_plane_sigma(const std::vector<std::array<double, 3>>& p) {
    double best = robust_plane_sigma(p);
    if (p.size() < 12) return best;
    double mx = 0, my = 0;
    for (const auto& q : p) mx += q[0], my += q[1];
    mx /= static_cast<double>(p.size()), my /= static_cast<double>(p.size());
    double xx = 0, xy = 0, yy = 0;
    for (const auto& q : p) xx += (q[0] - mx) * (q[0] - mx), xy += (q[0] - mx) * (q[1] - my), yy += (q[1] - my) * (q[1] - my);
    const double angle = 0.5 * std::atan2(2.0 * xy, xx - yy);  // the major axis
    const double axes[2][2] = {{std::cos(angle), std::sin(angle)}, {-std::sin(angle), std::cos(angle)}};
    for (const auto& d : axes) {
        std::vector<std::array<double, 3>> side[2];
        for (const auto& q : p) side[(q[0] - mx) * d[0] + (q[1] - my) * d[1] < 0.0 ? 0 : 1].push_back(q);
        if (side[0].size() < 6 || side[1].size() < 6) continue;
        const double s0 = robust_plane_sigma(side[0]), s1 = robust_plane_sigma(side[1]);
        const double n0 = static_cast<double>(side[0].size()), n1 = static_cast<double>(side[1].size());
        best = std::min(best, std::sqrt((n0 * s0 * s0 + n1 * s1 * s1) / (n0 + n1)));
    }
    return best;
}

// Local roughness of a segment's heights: at each sample, the RMS residual
// of the samples within `radius` pixels (of the same segment, at least 9)
// about their least-squares plane; the median over the samples. Roof facets
// are locally planar (ridges and hips touch few samples), crowns are not.
double local_roughness(const std::vector<std::array<double, 3>>& p, int radius) {
    if (p.size() < 9) return 0.0;
    double x0 = p[0][0], y0 = p[0][1], x1 = x0, y1 = y0;
    for (const auto& q : p) x0 = std::min(x0, q[0]), y0 = std::min(y0, q[1]), x1 = std::max(x1, q[0]), y1 = std::max(y1, q[1]);
    const int gw = static_cast<int>(x1 - x0) + 1, gh = static_cast<int>(y1 - y0) + 1;
    std::vector<double> z(static_cast<std::size_t>(gw) * gh, std::numeric_limits<double>::quiet_NaN());
    for (const auto& q : p) z[static_cast<std::size_t>(q[1] - y0) * gw + static_cast<std::size_t>(q[0] - x0)] = q[2];
    std::vector<double> rough;
    rough.reserve(p.size());
    for (const auto& q : p) {
        const int cx = static_cast<int>(q[0] - x0), cy = static_cast<int>(q[1] - y0);
        double n = 0, sx = 0, sy = 0, sz = 0, xx = 0, xy = 0, yy = 0, xz = 0, yz = 0, zz = 0;
        for (int dy = -radius; dy <= radius; ++dy)
            for (int dx = -radius; dx <= radius; ++dx) {
                const int x = cx + dx, y = cy + dy;
                if (x < 0 || y < 0 || x >= gw || y >= gh) continue;
                const double v = z[static_cast<std::size_t>(y) * gw + x];
                if (std::isnan(v)) continue;
                n += 1, sx += dx, sy += dy, sz += v, xx += dx * dx, xy += dx * dy, yy += dy * dy, xz += dx * v, yz += dy * v, zz += v * v;
            }
        if (n < 9) continue;
        const double mx = sx / n, my = sy / n, mz = sz / n;
        const double cxx = xx - n * mx * mx, cxy = xy - n * mx * my, cyy = yy - n * my * my;
        const double cxz = xz - n * mx * mz, cyz = yz - n * my * mz, czz = zz - n * mz * mz;
        const double det = cxx * cyy - cxy * cxy;
        if (!(det > 1e-9)) continue;
        const double a = (cxz * cyy - cyz * cxy) / det, b = (cyz * cxx - cxz * cxy) / det;
        rough.push_back(std::sqrt(std::max(0.0, czz - a * cxz - b * cyz) / n));
    }
    if (rough.empty()) return 0.0;
    std::nth_element(rough.begin(), rough.begin() + static_cast<std::ptrdiff_t>(rough.size() / 2), rough.end());
    return rough[rough.size() / 2];
}

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

std::size_t refine_buildings_with_ortho(BuildingMask& mask, const BuildingCells& cells, const Image<float>& colours,
                                 const std::vector<uint8_t>& valid, const Image<float>& ndsm, double full_scale,
                                 const Image<uint32_t>& segments, const std::vector<uint8_t>& vegetation,
                                 const OrthoRefineOptions& o) {
    o.validate();
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = mask.labels.pixel_count();
    if (colours.pixel_count() != n || valid.size() != n || ndsm.pixel_count() != n || cells.cells.size() != n ||
        (!segments.data.empty() && segments.pixel_count() != n) || (!vegetation.empty() && vegetation.size() != n))
        throw Error("ortho refinement", "rasters differ in size");
    if (mask.count == 0) return 0;
    std::size_t crowns = 0;
    const int local_radius_px = std::max(1, static_cast<int>(std::lround(o.crown_local_radius_m / o.gsd_m)));
    const std::vector<uint32_t> old(mask.labels.data.begin(), mask.labels.data.end());
    std::vector<Box> box(mask.count + 1, Box{w, h, -1, -1});
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            if (const uint32_t l = old[static_cast<std::size_t>(y) * w + x]) {
                Box& b = box[l];
                b.x0 = std::min(b.x0, x), b.y0 = std::min(b.y0, y), b.x1 = std::max(b.x1, x), b.y1 = std::max(b.y1, y);
            }
    // Heights (crop pixel coordinates, nDSM) that scatter like a crown: no
    // plane (nor two along an axis) fits them, and they are rough locally.
    auto crown_heights = [&](const std::vector<std::array<double, 3>>& p) {
        return !p.empty() && roof_plane_sigma(p) > o.max_crown_plane_sigma_m &&
               local_roughness(p, local_radius_px) > o.min_crown_local_roughness_m;
    };
    // The whole-building crown test (min_crown_building_colour_share): the
    // share of its seen cells with vegetation colours, then its heights.
    auto crown_as_a_whole = [&](uint32_t l) {
        if (vegetation.empty() || !(o.max_crown_plane_sigma_m > 0) || o.min_crown_building_colour_share > 1.0) return false;
        const Box& b = box[l];
        long seen = 0, coloured = 0;
        std::vector<std::array<double, 3>> heights;
        for (int y = b.y0; y <= b.y1; ++y)
            for (int x = b.x0; x <= b.x1; ++x) {
                const std::size_t k = static_cast<std::size_t>(y) * w + x;
                if (old[k] != l) continue;
                if (valid[k]) ++seen, coloured += vegetation[k] >= 1;
                if (std::isfinite(ndsm.data[k])) heights.push_back({double(x - b.x0), double(y - b.y0), double(ndsm.data[k])});
            }
        if (seen == 0 || static_cast<double>(coloured) < o.min_crown_building_colour_share * static_cast<double>(seen)) return false;
        return crown_heights(heights);
    };
    std::vector<uint32_t> out(n, 0);
    for (uint32_t l = 1; l <= mask.count; ++l) {
        Box b = box[l];
        if (b.x1 < b.x0) continue;
        if (crown_as_a_whole(l)) {
            ++crowns;
            continue;
        }
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
        std::vector<uint32_t> seen(count + 1, 0), votes(count + 1, 0), yes(count + 1, 0), size(count + 1, 0), green(count + 1, 0),
            weak(count + 1, 0);
        std::vector<uint8_t> vetoed(count + 1, 0), crown(count + 1, 0);
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const uint32_t s = seg.at(0, x, y);
                if (!s) continue;
                const std::size_t k = global(x, y);
                ++size[s];
                if (!vegetation.empty()) green[s] += vegetation[k] >= 2, weak[s] += vegetation[k] >= 1;
                seen[s] += cells.evidence[k];
                ++votes[s], yes[s] += cells.cells[k];
                // A segment reaching the crop's edge (inside the grid) runs on
                // beyond the building: ground, or roof merged with ground.
                if ((x == 0 && b.x0 > 0) || (y == 0 && b.y0 > 0) || (x == cw - 1 && b.x1 < w - 1) || (y == ch - 1 && b.y1 < h - 1)) vetoed[s] = 1;
            }
        // Vegetation colours: never building (the ortho cannot draw it; a
        // grass-coloured roof keeps its heights' outline). Vegetation colours,
        // even weak ones, on a surface that is no plane: a crown. The nDSM
        // samples (crop pixel coordinates) are gathered for those segments only.
        std::vector<std::vector<std::array<double, 3>>> samples(!vegetation.empty() && o.max_crown_plane_sigma_m > 0 ? count + 1 : 0);
        if (!samples.empty())
            for (int y = 0; y < ch; ++y)
                for (int x = 0; x < cw; ++x) {
                    const uint32_t s = seg.at(0, x, y);
                    const float z = ndsm.data[global(x, y)];
                    if (s && 2 * weak[s] > size[s] && std::isfinite(z)) samples[s].push_back({double(x), double(y), double(z)});
                }
        for (uint32_t s = 1; s <= count; ++s) {
            crown[s] = !samples.empty() && crown_heights(samples[s]);
            vetoed[s] |= 2 * green[s] > size[s] || crown[s];
        }
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
            // A cell with no roof point whose ground points are too few
            // against the ortho's prior: the ortho keeps its vote there.
            auto weak_ground = [&](std::size_t k) {
                return edge_lr_base > 0 && cells.roof_points[k] == 0 && edge_lr_base >= cells.ground_points[k] * kLn3;
            };
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
                    if (!(voted[c] && !cells.cells[k] && weak_ground(k))) edged[c] = cells.cells[k];
                }
            voted.swap(edged);
            // A segment of the ortho may run on beyond the roof (a dark crown
            // against a dark roof): its pixels the cloud measured as not
            // building are peeled off from the outline inward, ring by ring
            // (only removed, never added; weak ground evidence as above).
            for (int pass = 0; pass < o.cloud_peel_rings; ++pass) {
                std::vector<std::size_t> peel;
                for (int y = 0; y < ch; ++y)
                    for (int x = 0; x < cw; ++x) {
                        const std::size_t c = static_cast<std::size_t>(y) * cw + x, k = global(x, y);
                        if (!voted[c] || !cells.evidence[k] || cells.cells[k] || (old[k] && old[k] != l)) continue;
                        const bool outline = x == 0 || y == 0 || x == cw - 1 || y == ch - 1 || !voted[c - 1] || !voted[c + 1] ||
                                             !voted[c - static_cast<std::size_t>(cw)] || !voted[c + static_cast<std::size_t>(cw)];
                        if (outline && !weak_ground(k)) peel.push_back(c);
                    }
                if (peel.empty()) break;
                for (const std::size_t c : peel) voted[c] = 0;
            }
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
        // Its cells in crown segments do not count against the redrawing; a
        // building mostly in crowns is one (photo clouds: no point classes).
        // (The share is of its cells the ortho sees: a true ortho made from a
        // photo cloud has gaps.)
        long inter = 0, kept = 0, own = 0, own_seen = 0, own_crown = 0;
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                const bool k1 = keep[static_cast<std::size_t>(y) * cw + x], k0 = old[global(x, y)] == l;
                const uint32_t s = seg.at(0, x, y);
                inter += k1 && k0, kept += k1, own += k0, own_seen += k0 && valid[global(x, y)], own_crown += k0 && s && crown[s];
            }
        if (own_crown > 0 && static_cast<double>(own_crown) >= o.max_vegetation_share * static_cast<double>(own_seen)) {
            ++crowns;
            continue;
        }
        const bool redrawn = static_cast<double>(inter) >= o.min_iou_with_heights * static_cast<double>(kept + own - own_crown - inter);
        // First come, first served in label (raster) order.
        for (int y = 0; y < ch; ++y)
            for (int x = 0; x < cw; ++x) {
                // Not redrawn: the heights' outline without its crown segments.
                const uint32_t s = seg.at(0, x, y);
                const bool take = redrawn ? keep[static_cast<std::size_t>(y) * cw + x] != 0 : old[global(x, y)] == l && !(s && crown[s]);
                if (take && !out[global(x, y)]) out[global(x, y)] = l;
            }
    }
    std::copy(out.begin(), out.end(), mask.labels.data.begin());
    // A redrawing can leave pixels cut off from their building (an earlier
    // building took the pixels between, an outline pixel went back to the
    // cloud's decision): each building stays one part.
    keep_largest_parts(mask);
    return crowns;
}

}  // namespace cityforge
