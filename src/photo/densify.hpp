#pragma once
// Patch-based multi-view stereo (after Furukawa & Ponce's PMVS): a patch is a
// centre c(p), a unit normal n(p) and a reference image R(p); its
// photo-consistency g(p) is the mean of 1 - NCC between R(p) and the other
// images of V*(p), sampled on a mu x mu grid spanning about mu pixels of R(p).
// Seeds come from SIFT matches between neighbouring images triangulated with
// the known cameras (and optional sparse points); patches expand into empty
// neighbouring image cells (beta x beta pixels); outliers are filtered by the
// visibility rule |V*(p)|(1 - g*(p)) < sum over U(p) of (1 - g*(p_i)) and by
// neighbourhood support. Deterministic: every round computes candidates in
// parallel from a frozen state and commits them in a fixed order, so the
// output does not depend on the thread count. No GDAL.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "cloud/point_cloud.hpp"
#include "core/progress.hpp"
#include "photo/camera.hpp"

namespace cityforge::photo {

struct DensifyOptions {
    int cell_px = 3;                 ///< beta: image cell size, pixels (one patch per cell and image); the smallest
    /// Cells are also at least this many metres on the surface (at the middle of
    /// the cameras' scene height range, along each optical axis; 0 or an
    /// unknown range = cell_px only): fine photos (3 cm GSD) get coarser
    /// cells in pixels, the same patches per square metre.
    double cell_m = 0.25;
    int patch_grid = 7;              ///< mu: samples per patch side (one per reference pixel)
    double min_ncc = 0.65;           ///< an image joins V*(p) when its NCC with R(p) is at least this
    int min_views = 2;               ///< |V*(p)| including R(p)
    /// |V*(p)| must also reach this share of the images that should see the
    /// patch (the reference and its neighbour images that hold it in frame
    /// within max_view_angle_deg; rounded up; 0 = off): on a surface that many
    /// photos see, two images agreeing on a wrong depth (repeated paving, weak
    /// texture) is not enough.
    double min_view_share = 0.5;
    int neighbour_images = 6;        ///< candidate images per reference image (closest centres)
    /// Neighbours need a baseline of at least this share of the reference
    /// camera's height above the scene (heads of one oblique camera have none).
    double min_baseline_ratio = 0.05;
    double max_view_angle_deg = 65;  ///< normal vs. viewing ray, for visibility
    /// Largest tilt of a patch's normal from its starting normal during the
    /// refinement (each of two axes), degrees.
    double max_tilt_deg = 69;
    /// Expansion also starts from a wall facing the camera and a level plane
    /// through the parent patch when the parent's own plane fails (roof edges,
    /// wall feet).
    bool wall_hypotheses = true;
    int iterations = 3;              ///< expansion + filtering rounds
    int max_expansion_steps = 400;   ///< expansion fronts per iteration (each grows by one cell)
    int seed_features = 4000;        ///< SIFT features per image for the seeds
    double min_support = 0.25;       ///< share of adjacent patches among neighbouring ones to survive the filter
    /// Output points per patch side: each patch is written as an n x n grid on
    /// its tangent plane covering its reference cell (1 = the centre only).
    int points_per_patch_side = 3;
    /// Throws Error on out-of-range values.
    void validate() const;
};

struct DensifyResult {
    PointCloud cloud;   ///< patch samples (map coordinates), RGB from R(p), class 1, intensity = NCC * 65535
    std::size_t patches = 0;  ///< patches kept
    std::size_t seeds = 0, expanded = 0, filtered = 0;
};

/// Densifies the oriented images. `images` are 8-bit BGR, one per camera (same
/// order and sizes). `sparse` are optional extra seed points (map coordinates).
/// Throws Error naming `subject` with fewer than two images, mismatched sizes
/// or when no patch survives (no overlap or no texture).
DensifyResult densify_patches(const std::vector<cv::Mat>& images, const CameraSet& cameras,
                              const std::vector<Eigen::Vector3d>& sparse, const DensifyOptions& options,
                              const std::string& subject, const Progress& progress = {});

}  // namespace cityforge::photo
