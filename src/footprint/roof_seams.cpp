#include "footprint/roof_seams.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include "core/error.hpp"

namespace cityforge {

void RoofSeamOptions::validate() const {
    if (!(gsd_m > 0)) throw Error("roof seams", "gsd_m must be > 0");
    if (!(window_m >= gsd_m)) throw Error("--seam-window-m", "must be at least one cell");
    if (!(min_part_length_m > 0)) throw Error("--seam-min-part-length-m", "must be > 0");
    if (!(min_part_area_m2 >= 0)) throw Error("--seam-min-part-area-m2", "must be >= 0");
    if (!(min_colour_contrast > 0) || !(min_colour_step_share >= 0)) throw Error("--seam-min-contrast", "must be > 0");
    if (!(ridge_rise_m > 0) || !(valley_depth_m > 0)) throw Error("roof seams", "ridge / valley heights must be > 0");
    if (!(min_width_share > 0 && min_width_share <= 1)) throw Error("roof seams", "min_width_share must be in (0, 1]");
}

namespace {

constexpr double kPi = 3.14159265358979323846;
// A valley must be this many times deeper than the scatter of the slices'
// heights about each side's line (sparse points on facets that vary along the
// slice make noisy slices, and noise dips look like valleys).
constexpr double kValleyToScatter = 4.0;
// Where a ridge turns, the level side's cross-section and both sides' scatter
// stay within this share of the ridge side's rise.
constexpr double kLevelShare = 0.25;
// Steepest roof facet, as its rise per unit run (tan 65 deg): steeper slopes
// between slices are walls.
constexpr double kSteepestRoof = 2.14;
// A colour step where one side is the other times one factor below this in
// every band (within kShadowRatioSpread) is a cast shadow's edge (in the
// shade, direct sun is lost and every band dims alike; synthetic towns: 0.42).
constexpr double kShadowRatio = 0.55;
constexpr double kShadowRatioSpread = 0.1;
// Where the roof also steps in height (see height_step), a colour step of
// this share of min_colour_contrast is a seam.
constexpr double kSteppedContrastShare = 0.5;
// At a seam the slices either side of the seam slice differ by at least
// this share of the step between the windows.
constexpr double kAbruptShare = 0.6;
// Colours are read this many cells inside a building's outline.
constexpr int kInnerCells = 2;
// and this many cells from the extremes of its width across a seam's axis.
constexpr double kSideCells = 4.0;

struct Slice {
    double count = 0;               // cells
    double colour_count = 0;        // cells with valid colours
    std::vector<double> colour;     // per band sums
    double height = 0, height_count = 0;
    double strip_count[3] = {0, 0, 0};  // the same across three strips of the building's width
    std::vector<double> strip_colour[3];
    double strip_height[3] = {0, 0, 0}, strip_height_count[3] = {0, 0, 0};  // heights per strip
};

struct Axis {
    double cx, cy;  // unit direction, in cell units
};

// A building's own origin (its bounding box's first column and row): cell
// coordinates are taken from it, so that the same building on two windows of
// a grid gives the same sums to the last bit (tile-size independence).
struct CellOrigin {
    std::size_t col = 0, row = 0;
};

// Cells of one building (linear indices) split into pieces by seams across
// `axis`; returns a piece index per cell (0 = no split).
std::vector<int> seams_along(const std::vector<std::size_t>& cells, int w, CellOrigin origin, Axis axis, const Image<float>& colours,
                             const std::vector<uint8_t>& valid, const std::vector<uint8_t>& inner, const Image<float>& ndsm,
                             const std::vector<double>& pixel_sd, const RoofSeamOptions& o, int& cuts) {
    const int bands = colours.bands;
    std::vector<double> u(cells.size()), vv(cells.size());
    double umin = INFINITY, umax = -INFINITY, vmin = INFINITY, vmax = -INFINITY;
    for (std::size_t i = 0; i < cells.size(); ++i) {
        const double x = double(cells[i] % std::size_t(w) - origin.col), y = double(cells[i] / std::size_t(w) - origin.row);
        u[i] = x * axis.cx + y * axis.cy;
        vv[i] = -x * axis.cy + y * axis.cx;
        umin = std::min(umin, u[i]), umax = std::max(umax, u[i]);
        vmin = std::min(vmin, vv[i]), vmax = std::max(vmax, vv[i]);
    }
    std::vector<int> piece(cells.size(), 0);
    const int nbins = static_cast<int>(std::floor(umax - umin)) + 1;
    const int W = std::max(1, static_cast<int>(std::lround(o.window_m / o.gsd_m)));
    const int min_len = static_cast<int>(std::ceil(o.min_part_length_m / o.gsd_m));
    if (nbins < 2 * min_len + 1) return piece;
    std::vector<Slice> s(static_cast<std::size_t>(nbins));
    for (auto& sl : s) {
        sl.colour.assign(static_cast<std::size_t>(bands), 0.0);
        for (auto& sc : sl.strip_colour) sc.assign(static_cast<std::size_t>(bands), 0.0);
    }
    std::vector<int> bin(cells.size());
    for (std::size_t i = 0; i < cells.size(); ++i) {
        const int b = std::min(nbins - 1, static_cast<int>(std::floor(u[i] - umin)));
        bin[i] = b;
        Slice& sl = s[static_cast<std::size_t>(b)];
        sl.count += 1;
        const std::size_t k = cells[i];
        // Colours from the same band across the width in every slice (a
        // ragged outline would make slices sample a gable's two facets in
        // changing proportions): cells inside the outline and this far from
        // the building's sides.
        if ((valid.empty() || valid[k]) && inner[k] && vv[i] >= vmin + kSideCells && vv[i] <= vmax - kSideCells) {
            sl.colour_count += 1;
            const int strip = std::clamp(static_cast<int>(3.0 * (vv[i] - vmin) / std::max(vmax - vmin, 1e-9)), 0, 2);
            sl.strip_count[strip] += 1;
            for (int c = 0; c < bands; ++c) {
                sl.colour[static_cast<std::size_t>(c)] += colours.band_data(c)[k];
                sl.strip_colour[strip][static_cast<std::size_t>(c)] += colours.band_data(c)[k];
            }
        }
        const float z = ndsm.data[k];
        if (!std::isnan(z)) {
            sl.height += z, sl.height_count += 1;
            const int strip = std::clamp(static_cast<int>(3.0 * (vv[i] - vmin) / std::max(vmax - vmin, 1e-9)), 0, 2);
            sl.strip_height[strip] += z, sl.strip_height_count[strip] += 1;
        }
    }
    // Window statistics on [a, b): count-weighted mean colour, the spread of
    // the slices' means around it, mean height, mean width.
    struct Win {
        bool ok = false;
        std::vector<double> mean;
        double noise2 = 0, height = NAN, width = 0;
        double slope = NAN;  // height change per cell along the axis (least squares over the slices)
        double intercept = NAN;  // height of that line at slice 0, metres
        double height_scatter = NAN;  // residual standard deviation of the slices' heights about that line, metres
    };
    auto window = [&](int a, int b) {
        Win r;
        if (a < 0 || b > nbins) return r;
        r.mean.assign(static_cast<std::size_t>(bands), 0.0);
        double cc = 0, hs = 0, hc = 0;
        for (int j = a; j < b; ++j) {
            const Slice& sl = s[static_cast<std::size_t>(j)];
            if (sl.colour_count < 2) return r;
            for (int c = 0; c < bands; ++c) r.mean[static_cast<std::size_t>(c)] += sl.colour[static_cast<std::size_t>(c)];
            cc += sl.colour_count, hs += sl.height, hc += sl.height_count, r.width += sl.count;
        }
        for (double& m : r.mean) m /= cc;
        double v = 0;
        for (int j = a; j < b; ++j) {
            const Slice& sl = s[static_cast<std::size_t>(j)];
            for (int c = 0; c < bands; ++c) {
                const double d = sl.colour[static_cast<std::size_t>(c)] / sl.colour_count - r.mean[static_cast<std::size_t>(c)];
                v += d * d;
            }
        }
        r.noise2 = v / double(std::max(1, (b - a) * bands));
        r.height = hc > 0 ? hs / hc : NAN;
        r.width /= double(b - a);
        double st = 0, sh = 0, stt = 0, sth = 0, sn = 0;
        for (int j = a; j < b; ++j) {
            const Slice& sl = s[static_cast<std::size_t>(j)];
            if (sl.height_count < 1) continue;
            const double t = j, z = sl.height / sl.height_count;
            st += t, sh += z, stt += t * t, sth += t * z, sn += 1;
        }
        if (sn >= 3 && sn * stt - st * st > 0) {
            r.slope = (sn * sth - st * sh) / (sn * stt - st * st);
            // Scatter of the slices' heights about that line: a slice along a
            // ridge or across facets sampled by a few points is noisy, a slice
            // of one level (along a valley or a flat roof) is not.
            const double c0 = (sh - r.slope * st) / sn;
            r.intercept = c0;
            double rr = 0;
            for (int j = a; j < b; ++j) {
                const Slice& sl = s[static_cast<std::size_t>(j)];
                if (sl.height_count < 1) continue;
                const double d = sl.height / sl.height_count - (c0 + r.slope * j);
                rr += d * d;
            }
            r.height_scatter = std::sqrt(rr / std::max(1.0, sn - 2));
        }
        r.ok = true;
        return r;
    };
    double scale = 0;
    for (double sd : pixel_sd) scale += sd;
    scale /= double(std::max(1, bands));
    struct Candidate {
        int seam;
        double strength;
    };
    // A colour seam between houses of a terrace lies where the roof surface
    // runs on unchanged (same height trend on both sides, no ridge, hip or
    // valley in between): there, a change of colour is a change of roof,
    // not of shading between two facets.
    const double min_slope = o.ridge_rise_m / o.window_m * o.gsd_m;  // per cell
    auto slice_height = [&](int j) {
        const Slice& sl = s[static_cast<std::size_t>(j)];
        return sl.height_count > 0 ? sl.height / sl.height_count : NAN;
    };
    auto same_surface = [&](const Win& L, const Win& R, int m) {
        if (std::isnan(L.slope) || std::isnan(R.slope)) return true;  // no heights: colours alone
        if (std::abs(L.slope - R.slope) > min_slope) return false;
        // Slices too noisy to see a ridge or a fold (sparse points on facets
        // that vary along the slice): not known to be one surface.
        if (!(std::max(L.height_scatter, R.height_scatter) <= 0.5 * o.ridge_rise_m)) return false;
        double peak = -INFINITY;
        for (int j = std::max(0, m - W); j <= std::min(nbins - 1, m + W); ++j) {
            const double z = slice_height(j);
            if (!std::isnan(z)) peak = std::max(peak, z);
        }
        // The windows' ends read off each side's line (an end slice may hold
        // no point on a sparse roof).
        const double ends = std::max(L.intercept + L.slope * (m - W), R.intercept + R.slope * (m + W));
        return !(peak > -INFINITY) || peak - ends <= o.ridge_rise_m;
    };
    // The step runs straight across the whole width: each third of the width
    // changes colour the same way (a shadow edge or a crown does not).
    auto straight = [&](int m, const std::vector<double>& step_vec, double step) {
        for (int t = 0; t < 3; ++t) {
            std::vector<double> l(static_cast<std::size_t>(bands), 0.0), r(static_cast<std::size_t>(bands), 0.0);
            double lc = 0, rc = 0;
            for (int j = m - W; j < m; ++j)
                for (int c = 0; c < bands; ++c) l[static_cast<std::size_t>(c)] += s[static_cast<std::size_t>(j)].strip_colour[t][static_cast<std::size_t>(c)];
            for (int j = m - W; j < m; ++j) lc += s[static_cast<std::size_t>(j)].strip_count[t];
            for (int j = m + 1; j <= m + W; ++j)
                for (int c = 0; c < bands; ++c) r[static_cast<std::size_t>(c)] += s[static_cast<std::size_t>(j)].strip_colour[t][static_cast<std::size_t>(c)];
            for (int j = m + 1; j <= m + W; ++j) rc += s[static_cast<std::size_t>(j)].strip_count[t];
            if (lc < 2 || rc < 2) return false;
            double along = 0;  // this strip's step projected on the whole step
            for (int c = 0; c < bands; ++c) along += (l[static_cast<std::size_t>(c)] / lc - r[static_cast<std::size_t>(c)] / rc) * step_vec[static_cast<std::size_t>(c)];
            along /= std::max(step, 1e-9) * double(std::max(1, bands));
            if (along < 0.6 * step) return false;
        }
        return true;
    };
    // Cross-section of the roof over the slices [a, b): how far the middle
    // third of the width stands above the outer thirds (a ridge along the
    // axis: a gable's or hip's peak), as a mean over the window and the
    // scatter of the slices around it; NaN without heights in every strip.
    struct Profile {
        double rise = NAN, scatter = NAN;
        double tilt = NAN;  // mean height of the first outer third minus the last, metres
    };
    // Per slice, once: the middle third's height above the outer thirds'
    // mean and the first outer third's above the last (NaN without heights
    // in every strip).
    std::vector<double> slice_rise(static_cast<std::size_t>(nbins), NAN), slice_tilt(static_cast<std::size_t>(nbins), NAN);
    for (int j = 0; j < nbins; ++j) {
        const Slice& sl = s[static_cast<std::size_t>(j)];
        if (sl.strip_height_count[0] < 1 || sl.strip_height_count[1] < 1 || sl.strip_height_count[2] < 1) continue;
        const double h0 = sl.strip_height[0] / sl.strip_height_count[0], h2 = sl.strip_height[2] / sl.strip_height_count[2];
        slice_rise[static_cast<std::size_t>(j)] = sl.strip_height[1] / sl.strip_height_count[1] - 0.5 * (h0 + h2);
        slice_tilt[static_cast<std::size_t>(j)] = h0 - h2;
    }
    auto cross_profile = [&](int a, int b) {
        Profile p;
        if (a < 0 || b > nbins) return p;
        double n = 0, rise = 0, tilt = 0;
        for (int j = a; j < b; ++j)
            if (!std::isnan(slice_rise[static_cast<std::size_t>(j)])) n += 1, rise += slice_rise[static_cast<std::size_t>(j)], tilt += slice_tilt[static_cast<std::size_t>(j)];
        if (2 * n < double(b - a)) return p;
        p.rise = rise / n, p.tilt = tilt / n;
        double v = 0;
        for (int j = a; j < b; ++j)
            if (const double r = slice_rise[static_cast<std::size_t>(j)]; !std::isnan(r)) v += (r - p.rise) * (r - p.rise);
        p.scatter = std::sqrt(v / n);
        return p;
    };
    // Both sides' lines run down into the valley's floor (two facets meeting
    // there), rather than one low slice between two level stretches.
    auto valley_on_lines = [&](const Win& L, const Win& R, int m, double floor_z) {
        const double depth = std::min(L.height, R.height) - floor_z;
        const double at_l = L.intercept + L.slope * m, at_r = R.intercept + R.slope * m;
        // Across the width both sides are level (the ridges run across the
        // row); a ridge along the row sampled by a few points is not a valley.
        // Both sides are measured across the whole width, level and not
        // tilted (a hole in a roof or a lower wing is not a valley), and
        // their facets are roofs, not walls.
        const Profile pl = cross_profile(m - W, m), pr = cross_profile(m + 1, m + 1 + W);
        if (!(std::abs(pl.rise) <= 0.5 * depth && std::abs(pr.rise) <= 0.5 * depth && std::abs(pl.tilt) <= 0.5 * depth &&
              std::abs(pr.tilt) <= 0.5 * depth))
            return false;
        if (std::max(-L.slope, R.slope) > kSteepestRoof * o.gsd_m) return false;
        // (the floor may lie between two slices: half a slice's rise of slack)
        return std::abs(at_l - floor_z) < 0.5 * depth + std::abs(L.slope) && std::abs(at_r - floor_z) < 0.5 * depth + std::abs(R.slope);
    };
    // A terrace's roofs run level along the row (flat, or a ridge along it)
    // with one cross-section on both sides of the seam; a facet rising along
    // the axis, or a cross-section that changes (slices cutting a hip's
    // facets at an angle), shades differently along the axis by itself.
    auto level_along_row = [&](const Win& L, const Win& R, int m) {
        if (std::isnan(L.slope) || std::isnan(R.slope)) return true;  // no heights: colours alone
        if (std::max(std::abs(L.slope), std::abs(R.slope)) > min_slope) return false;
        const Profile pl = cross_profile(m - W, m), pr = cross_profile(m + 1, m + 1 + W);
        if (std::isnan(pl.rise) || std::isnan(pr.rise)) return true;
        return std::abs(pl.rise - pr.rise) <= o.ridge_rise_m && std::abs(pl.tilt - pr.tilt) <= o.ridge_rise_m;
    };
    // The ridge turns: on one side a ridge runs along the axis (the middle
    // stands above the outer thirds all along the window), on the other the
    // cross-section is level all along (ridge across the axis, or none), and
    // the change happens at one straight line across the whole width. A hip
    // fades its ridge out gradually, so it does not pass.
    auto ridge_turns = [&](int m, const Win& left, const Win& right) {
        const Profile L = cross_profile(m - W, m), R = cross_profile(m + 1, m + 1 + W);
        if (std::isnan(L.rise) || std::isnan(R.rise) || std::isnan(left.slope) || std::isnan(right.slope)) return 0.0;
        const Profile& ridge = L.rise > R.rise ? L : R;
        const Profile& level = L.rise > R.rise ? R : L;
        if (ridge.rise < o.valley_depth_m) return 0.0;
        const double tol = kLevelShare * ridge.rise;
        if (std::abs(level.rise) > tol || level.scatter > tol || ridge.scatter > tol) return 0.0;
        // The ridge side is a symmetric peak (a gable or hip, not a shed or a
        // cut corner), and the level side's facet rises away from the seam (a
        // roof whose ridge runs across: the seam is at its eave).
        if (std::abs(ridge.tilt) > tol) return 0.0;
        const double rising_away = L.rise > R.rise ? right.slope : -left.slope;
        if (rising_away < 2 * min_slope) return 0.0;
        // Abrupt: the slices on either side of the seam already hold each side's cross-section.
        const Profile next_ridge = L.rise > R.rise ? cross_profile(m - 1, m) : cross_profile(m + 1, m + 2);
        const Profile next_level = L.rise > R.rise ? cross_profile(m + 1, m + 2) : cross_profile(m - 1, m);
        if (std::isnan(next_ridge.rise) || std::isnan(next_level.rise) || next_ridge.rise < ridge.rise - tol || std::abs(next_level.rise) > tol)
            return 0.0;
        return ridge.rise - std::abs(level.rise);
    };
    // The colour changes at once: the slices either side of the seam slice
    // already differ by most of the windows' step (a shadow edge crossing
    // the roof at a slant builds its step up over many slices).
    auto abrupt = [&](int m, const std::vector<double>& step_vec, double step) {
        const Slice& a = s[static_cast<std::size_t>(m - 1)];
        const Slice& b = s[static_cast<std::size_t>(m + 1)];
        if (a.colour_count < 1 || b.colour_count < 1) return false;
        double along = 0;
        for (int c = 0; c < bands; ++c)
            along += (a.colour[static_cast<std::size_t>(c)] / a.colour_count - b.colour[static_cast<std::size_t>(c)] / b.colour_count) *
                     step_vec[static_cast<std::size_t>(c)];
        return along / (std::max(step, 1e-9) * double(std::max(1, bands))) >= kAbruptShare * step;
    };
    // A cast shadow's edge: one side is the other darkened by one factor in
    // every band, well below 1 (a neighbour's shadow across a low sun). Two
    // houses' roofs differ by their own colours, not by one dimming.
    auto cast_shadow = [&](const Win& L, const Win& R) {
        double lo = INFINITY, hi = -INFINITY;
        for (int c = 0; c < bands; ++c) {
            const double a = L.mean[static_cast<std::size_t>(c)], b = R.mean[static_cast<std::size_t>(c)];
            if (!(a > 0 && b > 0)) return false;
            const double ratio = a / b;  // left over right, the same way in every band
            lo = std::min(lo, ratio), hi = std::max(hi, ratio);
        }
        const bool dimmed = hi <= kShadowRatio || lo >= 1.0 / kShadowRatio;
        return dimmed && (hi <= 1.0 ? hi - lo : 1.0 / lo - 1.0 / hi) <= kShadowRatioSpread;
    };
    // The roof steps in height at m between two level sides: windows a guard
    // of two slices away (the cloud blurs the step), both level along the
    // row and barely scattered, their lines apart by at least valley_depth_m
    // (and kValleyToScatter times their scatter) at the seam, every third of
    // the width stepping the same way by at least half of it.
    auto height_step = [&](int m) {
        const int a = m - W - 2, b = m + 3 + W;
        const Win Lg = window(a, m - 2), Rg = window(m + 3, b);
        if (!Lg.ok || !Rg.ok || std::isnan(Lg.slope) || std::isnan(Rg.slope)) return false;
        if (std::max(std::abs(Lg.slope), std::abs(Rg.slope)) > min_slope) return false;
        const double scatter = std::max(Lg.height_scatter, Rg.height_scatter);
        const double dh = (Lg.intercept + Lg.slope * m) - (Rg.intercept + Rg.slope * m);
        if (!(std::abs(dh) >= o.valley_depth_m && std::abs(dh) >= kValleyToScatter * scatter)) return false;
        for (int t = 0; t < 3; ++t) {
            double ls = 0, lc = 0, rs = 0, rc = 0;
            for (int j = a; j < m - 2; ++j) ls += s[static_cast<std::size_t>(j)].strip_height[t], lc += s[static_cast<std::size_t>(j)].strip_height_count[t];
            for (int j = m + 3; j < b; ++j) rs += s[static_cast<std::size_t>(j)].strip_height[t], rc += s[static_cast<std::size_t>(j)].strip_height_count[t];
            if (lc < 1 || rc < 1 || !((ls / lc - rs / rc) * (dh > 0 ? 1 : -1) >= 0.5 * std::abs(dh))) return false;
        }
        return true;
    };
    // The slices' colour noise over the whole building (median of every
    // window pair's): four slices a side estimate it poorly, and a window that
    // happens to be quiet would make noise look like a step.
    double typical_noise = 0.0;
    {
        std::vector<double> nz;
        for (int m = min_len; m + min_len < nbins; ++m) {
            const Win L = window(m - W, m), R = window(m + 1, m + 1 + W);
            if (L.ok && R.ok) nz.push_back(std::sqrt(0.5 * (L.noise2 + R.noise2)));
        }
        if (!nz.empty()) {
            std::nth_element(nz.begin(), nz.begin() + static_cast<std::ptrdiff_t>(nz.size() / 2), nz.end());
            typical_noise = nz[nz.size() / 2];
        }
    }
    std::vector<Candidate> cand;
    for (int m = min_len; m + min_len < nbins; ++m) {
        // Seam slice m (mixed pixels) left out; windows on both sides.
        const Win L = window(m - W, m), R = window(m + 1, m + 1 + W);
        if (!L.ok || !R.ok) continue;
        const Slice& at = s[static_cast<std::size_t>(m)];
        // A straight stretch of a row: the seam slice and both sides about equally wide.
        if (at.count < o.min_width_share * std::max(L.width, R.width) || std::min(L.width, R.width) < o.min_width_share * std::max(L.width, R.width))
            continue;
        const double hm = at.height_count > 0 ? at.height / at.height_count : NAN;
        bool seam = false;
        double strength = 0;
        // A valley: both sides slope down into the seam, alike (two pitched roofs of one pitch).
        const bool valley = !std::isnan(hm) && !std::isnan(L.height) && !std::isnan(R.height) && !std::isnan(L.slope) && !std::isnan(R.slope) &&
                            std::min(L.height, R.height) - hm > o.valley_depth_m && L.slope < -2 * min_slope && R.slope > 2 * min_slope &&
                            std::abs(L.slope + R.slope) < 0.5 * std::max(-L.slope, R.slope) &&
                            std::min(L.height, R.height) - hm > kValleyToScatter * std::max(L.height_scatter, R.height_scatter) &&
                            valley_on_lines(L, R, m, hm);
        const double turn = valley ? 0.0 : ridge_turns(m, L, R);
        if (valley) {
            seam = true;  // a valley across the row
            strength = 1e6 + std::min(L.height, R.height) - hm;
        } else if (turn > 0) {
            seam = true;  // a ridge along the row meets a roof with its ridge across
            strength = 1e6 + turn;
        } else if ((same_surface(L, R, m) && level_along_row(L, R, m)) || [&] {
                       // The cloud's heights blur a step between two houses over a
                       // slice or two, not always the one the colours step at: the
                       // surface read off windows a guard of two slices away.
                       const Win Lg = window(m - W - 2, m - 2), Rg = window(m + 3, m + 3 + W);
                       return Lg.ok && Rg.ok && same_surface(Lg, Rg, m) && level_along_row(Lg, Rg, m);
                   }()) {
            double d2 = 0;
            std::vector<double> step_vec(static_cast<std::size_t>(bands));
            for (int c = 0; c < bands; ++c) {
                const double d = L.mean[static_cast<std::size_t>(c)] - R.mean[static_cast<std::size_t>(c)];
                step_vec[static_cast<std::size_t>(c)] = d;
                d2 += d * d;
            }
            const double step = std::sqrt(d2 / double(std::max(1, bands)));
            const double noise = std::max(std::sqrt(0.5 * (L.noise2 + R.noise2)), typical_noise);
            const double contrast = step / std::max(noise, 1e-6 * std::max(scale, 1e-6));
            // (d) a weaker colour step where the roof also steps in height
            // between two level sides (houses of one eave on sloping ground).
            const bool stepped = contrast >= kSteppedContrastShare * o.min_colour_contrast && contrast < o.min_colour_contrast && height_step(m);
            if ((contrast >= o.min_colour_contrast || stepped) && step >= o.min_colour_step_share * scale && straight(m, step_vec, step) &&
                abrupt(m, step_vec, step) && !cast_shadow(L, R))
                seam = true, strength = contrast;
        }
        if (seam) cand.push_back({m, strength});
    }
    if (cand.empty()) return piece;
    // Strongest first; a seam too close to a kept one or to the ends, or
    // leaving a small part, is dropped.
    std::sort(cand.begin(), cand.end(), [](const Candidate& a, const Candidate& b) { return a.strength != b.strength ? a.strength > b.strength : a.seam < b.seam; });
    std::vector<double> cum(static_cast<std::size_t>(nbins) + 1, 0.0);
    for (int j = 0; j < nbins; ++j) cum[static_cast<std::size_t>(j) + 1] = cum[static_cast<std::size_t>(j)] + s[static_cast<std::size_t>(j)].count;
    const double min_cells = o.min_part_area_m2 / (o.gsd_m * o.gsd_m);
    std::vector<int> kept;
    for (const Candidate& c : cand) {
        std::vector<int> trial = kept;
        trial.push_back(c.seam);
        std::sort(trial.begin(), trial.end());
        bool ok = true;
        int prev = 0;
        for (std::size_t t = 0; t <= trial.size() && ok; ++t) {
            const int next = t < trial.size() ? trial[t] : nbins;
            if (next - prev < min_len || cum[static_cast<std::size_t>(next)] - cum[static_cast<std::size_t>(prev)] < min_cells) ok = false;
            prev = next;
        }
        if (ok) kept = std::move(trial);
    }
    if (kept.empty()) return piece;
    cuts += static_cast<int>(kept.size());
    // Pieces: slices before the first seam are 0, and so on; the seam slice's
    // own cells go to the side whose colour they are closer to.
    for (std::size_t i = 0; i < cells.size(); ++i) {
        int p = 0;
        while (p < static_cast<int>(kept.size()) && bin[i] > kept[static_cast<std::size_t>(p)]) ++p;
        if (p < static_cast<int>(kept.size()) && bin[i] == kept[static_cast<std::size_t>(p)]) {
            const int m = kept[static_cast<std::size_t>(p)];
            const Win L = window(m - W, m), R = window(m + 1, m + 1 + W);
            double dl = 0, dr = 0;
            const std::size_t k = cells[i];
            if (L.ok && R.ok && (valid.empty() || valid[k]))
                for (int c = 0; c < bands; ++c) {
                    const double v = colours.band_data(c)[k];
                    dl += (v - L.mean[static_cast<std::size_t>(c)]) * (v - L.mean[static_cast<std::size_t>(c)]);
                    dr += (v - R.mean[static_cast<std::size_t>(c)]) * (v - R.mean[static_cast<std::size_t>(c)]);
                }
            if (dr < dl) ++p;
        }
        piece[i] = p;
    }
    return piece;
}

}  // namespace

int split_at_roof_seams(BuildingMask& mask, const Image<float>& colours, const std::vector<uint8_t>& valid, const Image<float>& ndsm,
                        const RoofSeamOptions& o) {
    o.validate();
    if (!o.enabled || mask.count == 0 || colours.bands == 0) return 0;
    const int w = mask.labels.width, h = mask.labels.height;
    const std::size_t n = mask.labels.pixel_count();
    if (colours.pixel_count() != n || ndsm.pixel_count() != n || (!valid.empty() && valid.size() != n))
        throw Error("roof seams", "ortho, heights and building grid differ in size");
    std::vector<std::vector<std::size_t>> cells(mask.count + 1);
    for (std::size_t k = 0; k < n; ++k)
        if (mask.labels.data[k]) cells[mask.labels.data[k]].push_back(k);
    // Colours are read inside each building, two cells from its outline: the
    // outline's cells mix roof with wall, shadow and ground, and a slice
    // holding one or two of them more than its neighbours would shift its
    // mean by more than a step between two houses' roofs.
    std::vector<uint8_t> inner(n, 0);
    for (std::size_t k = 0; k < n; ++k) {
        const uint32_t l = mask.labels.data[k];
        if (!l) continue;
        const int x = static_cast<int>(k % std::size_t(w)), y = static_cast<int>(k / std::size_t(w));
        bool in = x >= kInnerCells && y >= kInnerCells && x + kInnerCells < w && y + kInnerCells < h;
        for (int d = 1; d <= kInnerCells && in; ++d)
            in = mask.labels.data[k - std::size_t(d)] == l && mask.labels.data[k + std::size_t(d)] == l &&
                 mask.labels.data[k - std::size_t(d) * std::size_t(w)] == l && mask.labels.data[k + std::size_t(d) * std::size_t(w)] == l;
        inner[k] = in;
    }
    // part id per cell: (building, piece) numbered across the whole grid.
    std::vector<uint32_t> part(n, 0);
    uint32_t next_part = 0;
    int cuts = 0;
    for (uint32_t l = 1; l <= mask.count; ++l) {
        const auto& cl = cells[l];
        if (cl.empty()) continue;
        const uint32_t base = next_part + 1;
        if (double(cl.size()) * o.gsd_m * o.gsd_m < 2.0 * o.min_part_area_m2) {
            for (std::size_t k : cl) part[k] = base;
            ++next_part;
            continue;
        }
        // Principal axes from the second moments; seams across each.
        CellOrigin origin{std::size_t(w), cl.front() / std::size_t(w)};  // cells are in raster order
        for (std::size_t k : cl) origin.col = std::min(origin.col, k % std::size_t(w));
        double mx = 0, my = 0;
        for (std::size_t k : cl) mx += double(k % std::size_t(w) - origin.col), my += double(k / std::size_t(w) - origin.row);
        mx /= double(cl.size()), my /= double(cl.size());
        double sxx = 0, sxy = 0, syy = 0;
        for (std::size_t k : cl) {
            const double dx = double(k % std::size_t(w) - origin.col) - mx, dy = double(k / std::size_t(w) - origin.row) - my;
            sxx += dx * dx, sxy += dx * dy, syy += dy * dy;
        }
        const double ang = 0.5 * std::atan2(2 * sxy, sxx - syy);
        // Snap to the grid when within 3 degrees (axis-aligned rows: slices follow the pixel rows).
        double a0 = ang;
        for (double q : {-kPi / 2, 0.0, kPi / 2})
            if (std::abs(ang - q) < 3.0 * kPi / 180.0) a0 = q;
        std::vector<double> sd(static_cast<std::size_t>(colours.bands), 0.0);
        for (int c = 0; c < colours.bands; ++c) {
            double sum = 0, sum2 = 0, cnt = 0;
            for (std::size_t k : cl)
                if (valid.empty() || valid[k]) {
                    const double v = colours.band_data(c)[k];
                    sum += v, sum2 += v * v, cnt += 1;
                }
            sd[static_cast<std::size_t>(c)] = cnt > 1 ? std::sqrt(std::max(0.0, sum2 / cnt - (sum / cnt) * (sum / cnt))) : 0.0;
        }
        const Axis along{std::cos(a0), std::sin(a0)}, across{-std::sin(a0), std::cos(a0)};
        const std::vector<int> p1 = seams_along(cl, w, origin, along, colours, valid, inner, ndsm, sd, o, cuts);
        const int n1 = p1.empty() ? 1 : *std::max_element(p1.begin(), p1.end()) + 1;
        uint32_t used = 0;
        for (int a = 0; a < n1; ++a) {
            std::vector<std::size_t> sub;
            for (std::size_t i = 0; i < cl.size(); ++i)
                if (p1[i] == a) sub.push_back(cl[i]);
            if (sub.empty()) continue;
            const std::vector<int> p2 = seams_along(sub, w, origin, across, colours, valid, inner, ndsm, sd, o, cuts);
            const int n2 = p2.empty() ? 1 : *std::max_element(p2.begin(), p2.end()) + 1;
            for (std::size_t i = 0; i < sub.size(); ++i) part[sub[i]] = base + used + static_cast<uint32_t>(p2[i]);
            used += static_cast<uint32_t>(n2);
        }
        next_part += used;
    }
    if (cuts == 0) return 0;
    // New labels: 4-connected components of equal part ids, in raster order.
    Image<uint32_t> out(w, h, 1, 0);
    uint32_t count = 0;
    std::vector<std::size_t> stack;
    for (std::size_t s0 = 0; s0 < n; ++s0) {
        if (!part[s0] || out.data[s0]) continue;
        out.data[s0] = ++count;
        stack.push_back(s0);
        while (!stack.empty()) {
            const std::size_t p = stack.back();
            stack.pop_back();
            const int x = static_cast<int>(p % std::size_t(w)), y = static_cast<int>(p / std::size_t(w));
            const std::size_t nb[4] = {x > 0 ? p - 1 : p, x + 1 < w ? p + 1 : p, y > 0 ? p - std::size_t(w) : p, y + 1 < h ? p + std::size_t(w) : p};
            for (std::size_t q : nb)
                if (q != p && part[q] == part[p] && !out.data[q]) out.data[q] = count, stack.push_back(q);
        }
    }
    // Fragments: a seam slice's cells go to the side whose colour they are
    // closer to, which can leave a few cells cut off from their side. A
    // piece smaller than a part joins the neighbouring piece of the same
    // building it shares most edges with (ties: the lower label).
    const double min_cells = o.min_part_area_m2 / (o.gsd_m * o.gsd_m);
    std::vector<std::size_t> size(count + 1, 0);
    for (std::size_t k = 0; k < n; ++k) ++size[out.data[k]];
    std::vector<std::map<uint32_t, int>> shared(count + 1);
    for (std::size_t k = 0; k < n; ++k) {
        const uint32_t c = out.data[k];
        if (!c || double(size[c]) >= min_cells) continue;
        const int x = static_cast<int>(k % std::size_t(w)), y = static_cast<int>(k / std::size_t(w));
        const std::size_t nb[4] = {x > 0 ? k - 1 : k, x + 1 < w ? k + 1 : k, y > 0 ? k - std::size_t(w) : k, y + 1 < h ? k + std::size_t(w) : k};
        for (std::size_t q : nb) {
            const uint32_t d = out.data[q];
            if (q != k && d && d != c && mask.labels.data[q] == mask.labels.data[k] && double(size[d]) >= min_cells) ++shared[c][d];
        }
    }
    std::vector<uint32_t> into(count + 1);
    for (uint32_t c = 0; c <= count; ++c) {
        into[c] = c;
        int best = 0;
        for (const auto& [d, edges] : shared[c])
            if (edges > best) best = edges, into[c] = d;
    }
    // Labels 1..count again, in raster order of first appearance.
    std::vector<uint32_t> renumber(count + 1, 0);
    uint32_t next = 0;
    for (std::size_t k = 0; k < n; ++k) {
        uint32_t& v = out.data[k];
        if (!v) continue;
        v = into[v];
        if (!renumber[v]) renumber[v] = ++next;
        v = renumber[v];
    }
    mask.labels = std::move(out);
    mask.count = next;
    return cuts;
}

}  // namespace cityforge
