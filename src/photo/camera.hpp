#pragma once
// Oriented pinhole cameras of a photo block. Convention (OpenCV's): camera
// axes x right, y down, z forward (viewing direction); a world point X maps to
// x_cam = R (X - C) and pixel (u, v) = (fx x/z + cx, fy y/z + cy), with the
// centre of the top-left pixel at (0, 0). World coordinates are map
// coordinates of `crs` (easting, northing, height in metres). No GDAL here.
#include <array>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace cityforge::photo {

/// One oriented image. Images are undistorted (no lens distortion terms).
struct PhotoCamera {
    std::string image;                 ///< file name, relative to the image folder
    int width = 0, height = 0;         ///< pixels
    double fx = 0, fy = 0;             ///< focal lengths, pixels
    double cx = 0, cy = 0;             ///< principal point, pixels (top-left pixel centre = 0, 0)
    Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  ///< world -> camera
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();        ///< projection centre, world (map) coordinates

    Eigen::Matrix3d intrinsics() const;
    /// Camera coordinates of a world point (z = depth along the optical axis, metres).
    Eigen::Vector3d to_camera(const Eigen::Vector3d& world) const { return rotation * (world - centre); }
    /// Pixel of a world point; nullopt behind the camera.
    std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& world) const;
    /// Unit viewing ray (world axes) through pixel (u, v).
    Eigen::Vector3d ray(double u, double v) const;
    bool inside(const Eigen::Vector2d& px, double margin = 0.0) const {
        return px.x() >= margin && px.y() >= margin && px.x() <= width - 1 - margin && px.y() <= height - 1 - margin;
    }
};

/// An oriented photo block in one map CRS.
struct CameraSet {
    std::string crs;                         ///< label, e.g. "EPSG:32610"; empty = local frame
    std::string crs_wkt;                     ///< WKT of `crs` (written into LAS outputs); may be empty
    std::array<double, 2> scene_z_range_m{0.0, 0.0};  ///< lowest / highest surface height seen; 0,0 = unknown
    std::vector<PhotoCamera> cameras;

    /// Index of the camera of `image` (file name); throws Error naming `subject` when absent.
    std::size_t find(const std::string& image, const std::string& subject) const;
};

/// Pose errors of `estimated` against `truth`, matched by image name.
struct PoseError {
    int matched = 0;                   ///< images in both sets
    double mean_position_m = 0, max_position_m = 0;
    double mean_angle_deg = 0, max_angle_deg = 0;  ///< angle of R_est R_truth^T
};
PoseError compare_poses(const CameraSet& estimated, const CameraSet& truth);

/// Reads a cameras JSON (cameras_truth.json of `synth --views`, cameras.json of
/// `orient`). Throws Error naming the file on a missing file, bad JSON, a
/// missing field or an invalid camera (non-positive size or focal length,
/// non-orthonormal rotation).
CameraSet read_cameras_json(const std::string& path);
/// Writes `set` as JSON (atomically).
void write_cameras_json(const std::string& path, const CameraSet& set);

}  // namespace cityforge::photo
