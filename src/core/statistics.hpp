#pragma once
// Small robust statistics shared by the stages: percentiles and a trimmed
// least-squares plane. Pure algorithm (no I/O).
#include <array>
#include <cstdint>
#include <optional>
#include <vector>

namespace cityforge {

/// Percentile (0..100) by linear interpolation between order statistics
/// (NumPy's default); sorts `values`. Empty input -> nullopt.
std::optional<double> percentile(std::vector<double>& values, double p);

/// Options of fit_trimmed_plane. Units are those of the points' z.
struct TrimmedPlaneOptions {
    int iterations = 4;           ///< fits at most (stops early when the inliers stay the same)
    double trim_sigmas = 3.0;     ///< inliers: |residual| <= max(min_trim, trim_sigmas x 1.4826 x MAD of the inliers' residuals)
    double min_trim = 0.0;        ///< floor of that limit (z units)
    std::size_t min_points = 6;   ///< fewer inliers than this: no plane
    /// Smallest variance of the inliers' xy across their narrowest direction
    /// (xy units squared); below it the points are a line: no plane.
    double min_spread_sq = 0.0;
};

/// z = a x + b y + c by least squares (centred normal equations), refitted on
/// the points whose residual lies within the limit of TrimmedPlaneOptions.
struct TrimmedPlane {
    double a = 0.0, b = 0.0, c = 0.0;
    std::vector<uint8_t> inlier;  ///< per point, after the last fit
    double z(double x, double y) const { return a * x + b * y + c; }
};

/// The trimmed plane of `points` (x, y, z), or nullopt when too few points
/// or a line-like set (see TrimmedPlaneOptions).
std::optional<TrimmedPlane> fit_trimmed_plane(const std::vector<std::array<double, 3>>& points, const TrimmedPlaneOptions& options = {});

}  // namespace cityforge
