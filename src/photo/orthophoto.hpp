#pragma once
// An orthophoto from the oriented photos themselves (the product OpenDroneMap
// and photogrammetry suites call the orthomosaic): each cell of a north-up
// grid takes its colour from one photo that sees the cell's surface point,
// chosen as the most nadir view among those whose line of sight to the point
// the surface does not block. The surface is the cloud's top (highest point
// per cell) with its gaps filled from their neighbours up to
// `max_gap_fill_m`, so a cell the cloud missed still gets the photos' colour;
// cells farther than that from any point, or seen by no photo, are 0 in every
// band (nodata; colours are at least 1). No GDAL; images as OpenCV BGR.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "cloud/cloud_rasters.hpp"
#include "cloud/point_cloud.hpp"
#include "core/image.hpp"
#include "photo/camera.hpp"

namespace cityforge::photo {

struct OrthophotoOptions {
    /// Gaps of the cloud's surface are filled from their neighbours up to this
    /// distance from a measured cell, metres; farther cells stay nodata.
    double max_gap_fill_m = 5.0;
    /// A surface cell more than this above the line of sight from a cell's
    /// point to a camera hides the point from that camera, metres (cloud z units).
    double occlusion_tolerance_m = 0.5;
    /// Views whose line of sight is more than this from the vertical are not used, degrees.
    double max_off_nadir_deg = 60.0;
    /// Throws Error on out-of-range values.
    void validate() const;
};

/// What the orthophoto took from where.
struct OrthophotoStats {
    std::size_t cells_measured = 0;  ///< cells with a point of the cloud
    std::size_t cells_filled = 0;    ///< cells whose surface height was filled from neighbours
    std::size_t cells_coloured = 0;  ///< cells given a colour (a photo saw them)
    std::size_t cells_occluded = 0;  ///< cells with a surface that every photo in view has hidden
};

/// Reads the photo of `cameras.cameras[i]` (BGR, 8-bit, the camera's size).
using PhotoLoader = std::function<cv::Mat(std::size_t i)>;

/// RGB (3 bands, 8-bit, 0 = no data) on `grid` (the cameras' and the cloud's
/// CRS). Each cell's view is chosen from the cameras alone; then the photos
/// that colour at least one cell are read one at a time, in camera order, by
/// `load` (memory: one photo, whatever the block's size). Deterministic and
/// independent of the thread count (each cell on its own). Throws Error
/// naming `subject` when no point of the cloud falls on the grid, or the
/// camera's image when a loaded photo's size or type differs from its camera.
Image<uint8_t> orthophoto_from_photos(const PointCloud& cloud, const GridSpec& grid, const PhotoLoader& load, const CameraSet& cameras,
                                      const OrthophotoOptions& options, const std::string& subject, OrthophotoStats* stats = nullptr);

/// The same with the photos in memory: `images[i]` is the photo of
/// `cameras.cameras[i]`; one image per camera is required.
Image<uint8_t> orthophoto_from_photos(const PointCloud& cloud, const GridSpec& grid, const std::vector<cv::Mat>& images,
                                      const CameraSet& cameras, const OrthophotoOptions& options, const std::string& subject,
                                      OrthophotoStats* stats = nullptr);

}  // namespace cityforge::photo
