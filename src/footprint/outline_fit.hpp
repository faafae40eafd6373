#pragma once
// One building's footprint from its pixel outline: the simplified outline,
// then the fit asked for (minimum-area rectangle, recursive rectangles or
// edge regularisation), a smooth outline for round buildings, and a valid
// polygon or the reason there is none. Planar, in the outline's CRS units
// (a projected CRS; `metres_per_unit` converts the options' metres); no GDAL.
#include <string>

#include "core/geometry.hpp"
#include "footprint/curved_outline.hpp"
#include "footprint/rectangle_fit.hpp"
#include "footprint/regularize.hpp"

namespace cityforge {

/// The footprint geometry written for a building.
enum class FootprintFit { raw, rectangle, recursive, regularised };
/// "raw", "rectangle", "recursive", "regularised" (or "regularized"); throws Error naming --fit otherwise.
FootprintFit footprint_fit_from_string(const std::string& s);
/// The fit's name as footprint_fit_from_string reads it ("regularised", not "regularized").
std::string to_string(FootprintFit f);

/// What fit_building_outline does. Here the nested fits' lengths and areas
/// are in metres and m² (their own headers say CRS units: the lengths and
/// areas are converted with `metres_per_unit` before they are applied).
struct OutlineFitOptions {
    FootprintFit fit = FootprintFit::recursive;
    double simplify_m = 0.25;          ///< Douglas–Peucker tolerance of the raw outline, metres (>= 0)
    RecursiveFitOptions recursive;     ///< the recursive fit: min_rectangle_area in m², match_area_max_offset in metres
    RegularizeOptions regularize;      ///< the regularised fit: merge_offset, min_edge, match_area_max_offset in metres
    CurvedOutlineOptions curved;       ///< round buildings (recursive and regularised fits only; in pixels)
    void validate() const;             ///< throws Error naming the option
};

/// One building's outline and how it was fitted. Polygons in the pixel
/// outline's CRS units; `outline` is oriented (orient_polygon).
struct FittedOutline {
    Polygon raw;                  ///< the simplified pixel outline (the pixel outline itself where simplifying folds it)
    Polygon outline;              ///< the footprint: the fit, or `raw` when the fit failed
    std::string fit;              ///< the fit used: to_string(options.fit), or "curved"
    std::string status = "ok";    ///< "ok" or "fit_failed"
    std::string reason;           ///< why the fit failed, or what was mended (a pocket filled); empty otherwise
    double orientation_deg = 0.0; ///< the minimum-area rectangle's orientation
    double area_error_pct = 0.0;  ///< the fit's area against `raw`'s, percent (0 for raw and failed fits)
    double iou = 1.0;             ///< the fit's intersection over union with `raw`
};

/// Fits one building's pixel outline `pixels` (rings along pixel edges of
/// `pixel_size` CRS units, non-zero; its largest part, holes allowed;
/// `metres_per_unit` > 0). A fit that throws, or gives an invalid polygon
/// that filling diagonal-only pockets does not mend, leaves `raw` (fit: the
/// fit asked for, area error 0, IoU 1) with status "fit_failed" and the
/// reason. Throws Error for a zero pixel size, a unit that is not positive
/// or options that fail validate().
FittedOutline fit_building_outline(const Polygon& pixels, const OutlineFitOptions& options, double pixel_size, double metres_per_unit);

}  // namespace cityforge
