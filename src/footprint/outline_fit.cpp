#include "footprint/outline_fit.hpp"

#include <cmath>

#include "core/error.hpp"
#include "footprint/vectorize.hpp"

namespace cityforge {

FootprintFit footprint_fit_from_string(const std::string& s) {
    if (s == "raw") return FootprintFit::raw;
    if (s == "rectangle") return FootprintFit::rectangle;
    if (s == "recursive") return FootprintFit::recursive;
    if (s == "regularised" || s == "regularized") return FootprintFit::regularised;
    throw Error("--fit", "must be raw, rectangle, recursive or regularised, not '" + s + "'");
}

std::string to_string(FootprintFit f) {
    switch (f) {
        case FootprintFit::raw: return "raw";
        case FootprintFit::rectangle: return "rectangle";
        case FootprintFit::recursive: return "recursive";
        case FootprintFit::regularised: return "regularised";
    }
    return "raw";
}

void OutlineFitOptions::validate() const {
    if (!(simplify_m >= 0.0)) throw Error("simplify_m", "must be >= 0 metres");
    curved.validate();
}

namespace {
// The fit asked for, and a smooth outline for round buildings; throws where a fit fails.
void fit_outline(const Polygon& pixels, const OutlineFitOptions& o, double pixel_size, double unit, FittedOutline& r) {
    const OrientedRectangle rect = minimum_area_rectangle(r.raw);
    r.orientation_deg = rect.orientation_deg;
    auto measured = [&r](Polygon fitted) {
        const FitAccuracy acc = fit_accuracy(r.raw, fitted);
        r.outline = std::move(fitted), r.area_error_pct = acc.area_error_pct, r.iou = acc.iou;
    };
    if (o.fit == FootprintFit::rectangle) {
        measured(rect.polygon());
    } else if (o.fit == FootprintFit::regularised) {
        RegularizeOptions go = o.regularize;
        go.merge_offset /= unit, go.min_edge /= unit, go.match_area_max_offset /= unit;
        measured(regularised_fit(pixels, rect.orientation_deg, pixel_size, o.simplify_m / unit, polygon_area(r.raw), go));
    } else if (o.fit == FootprintFit::recursive) {
        RecursiveFitOptions ro = o.recursive;
        ro.min_rectangle_area /= unit * unit;
        ro.match_area_max_offset /= unit;
        const RecursiveFit rf = recursive_rectangle_fit(r.raw, ro);
        r.outline = rf.polygon, r.area_error_pct = rf.accuracy.area_error_pct, r.iou = rf.accuracy.iou;
    }
    if (o.fit == FootprintFit::recursive || o.fit == FootprintFit::regularised) {
        // Round and many-sided buildings: the smoothed pixel outline, not a staircase of rectangles.
        if (const std::optional<Polygon> curved = curved_outline(pixels, std::abs(pixel_size), o.curved)) {
            measured(*curved);
            r.fit = "curved";
        }
    }
}
}  // namespace

FittedOutline fit_building_outline(const Polygon& pixels, const OutlineFitOptions& o, double pixel_size, double unit) {
    if (!(std::abs(pixel_size) > 0.0)) throw Error("fit_building_outline", "the pixel size must not be zero");
    if (!(unit > 0.0)) throw Error("fit_building_outline", "metres per CRS unit must be positive");
    o.validate();
    FittedOutline r;
    // Douglas–Peucker may fold a ring onto itself: then the exact pixel outline.
    r.raw = simplify_polygon(pixels, o.simplify_m / unit);
    if (!polygon_is_valid(r.raw)) r.raw = pixels;
    r.outline = r.raw, r.fit = to_string(o.fit);
    try {
        fit_outline(pixels, o, pixel_size, unit, r);
    } catch (const Error& e) {
        // Whatever the fit had set (a recursive fit before a failed curved
        // outline, say) is dropped: a failed fit leaves the raw outline.
        r.status = "fit_failed", r.reason = e.what();
        r.outline = r.raw, r.fit = to_string(o.fit), r.area_error_pct = 0.0, r.iou = 1.0;
    }
    orient_polygon(r.outline);
    if (r.status == "ok" && !polygon_is_valid(r.outline)) {
        // A fit that kept an outline passing one vertex twice (a pocket
        // open to the outside only diagonally, e.g. on sparse LiDAR): the
        // pocket filled (fill_pinched_pockets) gives a simple ring.
        const Polygon filled = fill_pinched_pockets(r.outline);
        if (polygon_is_valid(filled)) {
            r.reason = "a pocket open only diagonally was filled";
            const FitAccuracy acc = fit_accuracy(r.raw, filled);
            r.outline = filled, r.area_error_pct = acc.area_error_pct, r.iou = acc.iou;
        } else {
            r.status = "fit_failed", r.reason = "the fit is not a valid polygon", r.outline = r.raw, r.area_error_pct = 0.0, r.iou = 1.0;
        }
    }
    return r;
}

}  // namespace cityforge
