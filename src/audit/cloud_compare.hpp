#pragma once
// Point cloud accuracy: precision / recall / F-score of points within a
// distance tau, and the chamfer distance, with 3-D k-d trees (nanoflann) on
// both clouds, parallel and deterministic. Both clouds in one CRS. No GDAL.
#include <cstdint>
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
    double median_pred_to_ref = 0.0, p95_pred_to_ref = 0.0;  ///< nearest-distance quantiles
    double median_ref_to_pred = 0.0, p95_ref_to_pred = 0.0;
    std::vector<CloudFScore> scores;  ///< one per tau
    /// Nearest-distance histograms on [0, histogram_max): equal bins; the last
    /// bin also counts every distance beyond histogram_max.
    double histogram_max = 0.0;
    std::vector<uint64_t> histogram_pred_to_ref, histogram_ref_to_pred;
};

/// `histogram_max` defaults (0) to twice the largest tau (or 1 unit).
/// Throws Error if either cloud is empty or a tau is not > 0.
CloudComparison compare_clouds(const PointCloud& predicted, const PointCloud& reference, const std::vector<double>& taus,
                                double histogram_max = 0.0, int histogram_bins = 40);

}  // namespace cityforge
