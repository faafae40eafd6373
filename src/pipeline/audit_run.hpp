#pragma once
// `cityforge audit footprints|rectangles|heights|clouds`: accuracy audits of
// our results or anyone's. Each reads its inputs (any OGR polygon layer, or
// LAS/PLY/XYZ clouds), reprojects the prediction into the reference's CRS
// when they differ (and says so), and writes DIR/report.json (schema:
// schemas/audit_report.schema.json), DIR/report.md and DIR/report.html
// (self-contained, SVG charts). Gates (`--fail-below`, `--fail-above`) turn a
// report into pass/fail for CI.
#include <cmath>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "audit/cloud_compare.hpp"
#include "audit/footprint_match.hpp"
#include "audit/gates.hpp"

namespace cityforge {

/// Files written by an audit, and the verdict of its gates.
struct AuditOutput {
    std::string json_path, markdown_path, html_path;
    std::map<std::string, double> measures;  ///< every gateable measure, by name
    GateOutcome gates;                       ///< passed unless a gate failed
};

struct FootprintAuditOptions {
    double iou_threshold = 0.5;
    std::vector<AuditGate> gates;  ///< on footprint_audit_measures()
    std::string pred_layer, ref_layer;  ///< empty = first layer
    /// Raster drawn under the footprint map of report.html (same CRS as the
    /// reference); empty = no picture.
    std::string ortho_path;
    void validate() const;
};
/// precision, recall, f1, object_quality (ISPRS per-object), iou (mean),
/// completeness, correctness, quality (ISPRS per-area), area_error_pct (mean
/// absolute), polis (mean, CRS units).
std::vector<std::string> footprint_audit_measures();

struct FootprintAuditReport {
    FootprintScores scores;
    std::string crs;            ///< CRS the scores were computed in (the reference's)
    bool reprojected = false;   ///< the prediction was reprojected to it
    AuditOutput output;
};

/// Throws Error naming the file for unreadable inputs, missing CRSs, a
/// geographic reference CRS, or projections PROJ cannot relate.
FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& options);

struct RectangleAuditOptions {
    /// Attribute of the fitted layer holding the original (unfitted) area in
    /// square metres; used when no original layer is given.
    std::string original_area_field = "raw_area_m2";
    /// Optional layer of original polygons: each fitted footprint is matched
    /// one to one at `iou_threshold` and the areas compared directly.
    std::string original_path;
    double iou_threshold = 0.5;
    std::vector<AuditGate> gates;  ///< on rectangle_audit_measures()
    std::string ortho_path;        ///< raster under the report map (same CRS); empty = none
    void validate() const;
};
/// mean_abs_error_pct, max_abs_error_pct, mean_error_pct.
std::vector<std::string> rectangle_audit_measures();

struct RectangleError {
    int64_t fid = 0;                  ///< of the fitted footprint
    double original_m2 = 0.0, fitted_m2 = 0.0;
    double error_m2 = 0.0;            ///< fitted - original
    double error_pct = 0.0;           ///< (fitted - original) / original * 100
    double iou = -1.0;                ///< fitted vs original polygon; -1 when only areas are known
};

struct RectangleAuditReport {
    std::size_t fitted = 0;           ///< footprints in the fitted layer
    std::vector<RectangleError> rows;  ///< those with an original area
    /// Over the rows with a defined error; NaN (null in JSON, n/a in the
    /// tables) when there is none: a mean over nothing is not 0.
    double mean_abs_error_pct = NAN, max_abs_error_pct = NAN, mean_error_pct = NAN;
    double mean_abs_error_m2 = NAN;
    AuditOutput output;
};

/// The reference study's Table 5 for any fitted footprints: original vs
/// fitted area per building. Areas are planar in the layer's projected CRS.
RectangleAuditReport audit_rectangles(const std::string& fitted_path, const std::string& out_dir, const RectangleAuditOptions& options);

struct HeightAuditOptions {
    std::string pred_field = "height_m";  ///< numeric attribute of the prediction
    std::string ref_field;                ///< numeric attribute of the reference (required)
    double iou_threshold = 0.5;           ///< footprints are matched one to one at this IoU
    std::vector<AuditGate> gates;         ///< on height_audit_measures()
    std::string ortho_path;               ///< raster under the report map (reference CRS); empty = none
    void validate() const;
};
/// mae, rmse, bias, abs_bias, max_abs (metres), coverage (share of the
/// reference buildings with both heights).
std::vector<std::string> height_audit_measures();

struct HeightError {
    int64_t reference_fid = 0, predicted_fid = 0;
    double predicted = 0.0, reference = 0.0, error = 0.0;  ///< metres (predicted - reference)
    std::string ground_method;              ///< the prediction's ground_method attribute, empty when it has none
    std::optional<double> ground_rmse_m;    ///< the prediction's ground_rmse_m attribute (ground fit residual), metres
};

/// Errors of the buildings whose ground came from one method.
struct HeightErrorGroup {
    std::size_t count = 0;
    double mae = 0.0, bias = 0.0, mean_ground_rmse_m = 0.0;  ///< metres
};

struct HeightAuditReport {
    std::size_t matched = 0, with_values = 0, reference = 0;
    /// Metres, over `rows`; NaN (null in JSON, n/a in the tables) when no
    /// matched footprint has both heights.
    double mae = NAN, rmse = NAN, bias = NAN, max_abs = NAN;
    std::vector<HeightError> rows;
    std::map<std::string, HeightErrorGroup> by_ground_method;  ///< only when the prediction has ground_method
    AuditOutput output;
};

/// Matches footprints (reprojecting the prediction if needed) and compares the
/// two height attributes of the matches. Throws Error naming the file when a
/// field is missing.
HeightAuditReport audit_heights(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                const HeightAuditOptions& options);

struct CloudAuditOptions {
    std::vector<double> taus_m{1.0, 2.0};  ///< distance thresholds, metres
    std::string pred_crs, ref_crs;         ///< CRS overrides for clouds that carry none
    std::vector<AuditGate> gates;          ///< on cloud_audit_measures(taus_m)
    void validate() const;
};
/// chamfer, chamfer_squared, mean_pred_to_ref, mean_ref_to_pred, and per tau
/// T (as written by format_number): precision@T, recall@T, f@T.
std::vector<std::string> cloud_audit_measures(const std::vector<double>& taus_m);

struct CloudAuditReport {
    CloudComparison comparison;  ///< distances in metres
    std::string crs;
    bool reprojected = false;
    AuditOutput output;
};

/// Compares two clouds (LAS/PLY/XYZ). The prediction is reprojected into the
/// reference's CRS when they differ; a cloud without any CRS is assumed to
/// share the other's only when both have none (said in the report).
CloudAuditReport audit_clouds(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                              const CloudAuditOptions& options);

}  // namespace cityforge
