#pragma once
// Binocular stereo of one oriented image pair: epipolar rectification
// (OpenCV stereoRectify), semi-global matching (StereoSGBM, sub-pixel
// disparities), left-right consistency, triangulation to map coordinates,
// colours from the left image. No GDAL; images are OpenCV BGR matrices.
#include <array>
#include <cstdint>
#include <limits>
#include <string>

#include <opencv2/core.hpp>

#include "cloud/point_cloud.hpp"
#include "core/progress.hpp"
#include "photo/camera.hpp"

namespace cityforge::photo {

struct StereoOptions {
    int block_size_px = 5;          ///< SGBM matching window (odd, 3..11)
    int uniqueness_ratio = 10;      ///< SGBM: best cost must beat the second best by this percentage
    int speckle_window_px = 100;    ///< SGBM speckle filter: region size (0 = off)
    double lr_max_diff_px = 1.0;    ///< left-right consistency: max |d_left - d_right|, pixels
    /// Surface heights searched (map z, metres). NaN = from the cameras' scene_z_range_m.
    double z_min_m = std::numeric_limits<double>::quiet_NaN();
    double z_max_m = std::numeric_limits<double>::quiet_NaN();
    int subsample = 1;              ///< keep every n-th valid pixel in rows and columns (1 = all)
    /// Throws Error on out-of-range values.
    void validate() const;
};

struct StereoResult {
    PointCloud cloud;               ///< map coordinates of the cameras' CRS, RGB, class 1
    double baseline_m = 0.0;
    int min_disparity_px = 0, num_disparities_px = 0;
    bool vertical_baseline = false;   ///< the pair was matched on 90-degree-rotated images
    std::size_t matched_pixels = 0;   ///< valid SGBM disparities
    std::size_t lr_rejected = 0;      ///< removed by the left-right check
    std::size_t range_rejected = 0;   ///< triangulated outside the height range
};

/// Dense cloud of one image pair. `left`/`right` are 8-bit BGR images of the
/// sizes of `cl`/`cr`. Throws Error (naming `subject`) when the images do not
/// match their cameras, the cameras coincide, the height range is unknown or
/// the pair has no overlap (no valid disparity).
StereoResult stereo_pair_cloud(const cv::Mat& left, const cv::Mat& right, const PhotoCamera& cl, const PhotoCamera& cr,
                               const StereoOptions& options, const std::array<double, 2>& scene_z_range_m,
                               const std::string& subject, const Progress& progress = {});

}  // namespace cityforge::photo
