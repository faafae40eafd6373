#pragma once
// Point cloud accuracy: precision / recall / F-score of points within a
// distance tau, and the chamfer distance, with 3-D k-d trees (nanoflann) on
// both clouds, parallel and deterministic. Both clouds in one CRS. No GDAL.
#include <vector>

#include "cloud/point_cloud.hpp"

namespace cityforge {

struct CloudFScore {
    double tau = 0.0;        ///< distance threshold, CRS units
    double precision = 0.0;  ///< share of predicted points within tau of the reference
    double recall = 0.0;     ///< share of reference points within tau of the prediction
    double f_score = 0.0;
};

struct CloudComparison {
    std::size_t predicted_points = 0, reference_points = 0;
    double mean_pred_to_ref = 0.0;  ///< mean nearest distance, predicted -> reference
    double mean_ref_to_pred = 0.0;  ///< mean nearest distance, reference -> predicted
    /// Chamfer distance, plain convention: mean_pred_to_ref + mean_ref_to_pred.
    double chamfer = 0.0;
    /// Chamfer distance, squared convention: mean of squared distances both ways, summed.
    double chamfer_squared = 0.0;
    std::vector<CloudFScore> scores;  ///< one per tau
};

/// Throws Error if either cloud is empty or a tau is not > 0.
CloudComparison compare_clouds(const PointCloud& predicted, const PointCloud& reference, const std::vector<double>& taus);

}  // namespace cityforge
