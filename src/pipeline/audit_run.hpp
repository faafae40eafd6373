#pragma once
// `cityforge audit footprints`: score predicted footprints against reference
// footprints (any OGR polygon layers), reprojecting the prediction when the
// CRSs differ, and write report.json + report.md.
#include <string>

#include "audit/cloud_compare.hpp"
#include "audit/footprint_match.hpp"
#include <vector>

namespace cityforge {

/// Gates for CI: "f1=0.8,iou=0.7" -> {{"f1", 0.8}, {"iou", 0.7}}. Throws Error
/// naming `option` on malformed text.
std::vector<std::pair<std::string, double>> parse_gates(const std::string& text, const std::string& option);

struct FootprintAuditOptions {
    double iou_threshold = 0.5;
    /// Minimum values (precision, recall, f1, iou, completeness, correctness,
    /// quality); a report below any of them has passed = false.
    std::vector<std::pair<std::string, double>> fail_below;
    std::string pred_layer, ref_layer;  ///< empty = first layer
    void validate() const;
};

struct FootprintAuditReport {
    FootprintScores scores;
    bool passed = true;              ///< false when a fail_below gate is not met
    std::vector<std::string> failed;  ///< the gates that failed, e.g. "f1 0.71 < 0.8"
    std::string crs;            ///< CRS the scores were computed in (the reference's)
    bool reprojected = false;   ///< the prediction was reprojected to it
    std::string json_path, markdown_path;
};

/// Writes `out_dir`/report.json and report.md. Throws Error naming the file
/// for unreadable inputs, missing CRSs or projections PROJ cannot relate.
FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& options);

struct HeightAuditOptions {
    std::string pred_field = "height_m";  ///< numeric attribute of the prediction
    std::string ref_field;                ///< numeric attribute of the reference (required)
    double iou_threshold = 0.5;           ///< footprints are matched one to one at this IoU
    void validate() const;
};

struct HeightError {
    int64_t reference_fid = 0, predicted_fid = 0;
    double predicted = 0.0, reference = 0.0, error = 0.0;  ///< metres (predicted - reference)
};

struct HeightAuditReport {
    std::size_t matched = 0, with_values = 0, reference = 0;
    double mae = 0.0, rmse = 0.0, bias = 0.0, max_abs = 0.0;  ///< metres
    std::vector<HeightError> rows;
    std::string json_path, markdown_path;
};

/// Matches footprints (reprojecting the prediction if needed) and compares the
/// two height attributes of the matches. Throws Error naming the file when a
/// field is missing.
HeightAuditReport audit_heights(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                const HeightAuditOptions& options);

struct CloudAuditOptions {
    std::vector<double> taus_m{1.0, 2.0};  ///< distance thresholds, metres
    std::string pred_crs, ref_crs;         ///< CRS overrides for clouds that carry none
};

struct CloudAuditReport {
    CloudComparison comparison;  ///< distances in metres
    std::string crs;
    bool reprojected = false;
    std::string json_path, markdown_path;
};

/// Compares two clouds (LAS/PLY/XYZ) and writes `out_dir`/report.json and
/// report.md. The prediction is reprojected into the reference's CRS when
/// they differ; a cloud without any CRS is assumed to share the other's only
/// when both have none (said in the report).
CloudAuditReport audit_clouds(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                              const CloudAuditOptions& options);

}  // namespace cityforge
