#pragma once
// `cityforge audit footprints`: score predicted footprints against reference
// footprints (any OGR polygon layers), reprojecting the prediction when the
// CRSs differ, and write report.json + report.md.
#include <string>

#include "audit/footprint_match.hpp"

namespace cityforge {

struct FootprintAuditOptions {
    double iou_threshold = 0.5;
    std::string pred_layer, ref_layer;  ///< empty = first layer
    void validate() const;
};

struct FootprintAuditReport {
    FootprintScores scores;
    std::string crs;            ///< CRS the scores were computed in (the reference's)
    bool reprojected = false;   ///< the prediction was reprojected to it
    std::string json_path, markdown_path;
};

/// Writes `out_dir`/report.json and report.md. Throws Error naming the file
/// for unreadable inputs, missing CRSs or projections PROJ cannot relate.
FootprintAuditReport audit_footprints(const std::string& pred_path, const std::string& ref_path, const std::string& out_dir,
                                      const FootprintAuditOptions& options);

}  // namespace cityforge
