#pragma once
// COLMAP's text model (cameras.txt, images.txt, points3D.txt from
// `colmap model_converter --output_type TXT`) and the georeferencing of a
// model: a similarity transform from the model frame to map coordinates fitted
// to GPS camera positions (Umeyama), with per-image residuals. No GDAL.
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "photo/camera.hpp"

namespace cityforge::photo {

struct ColmapCamera {
    int id = 0;
    std::string model;            ///< PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, ...
    int width = 0, height = 0;
    std::vector<double> params;   ///< COLMAP's order for the model
};

struct ColmapImage {
    int id = 0, camera_id = 0;
    std::string name;
    Eigen::Vector4d qvec{1, 0, 0, 0};  ///< world -> camera rotation, (w, x, y, z)
    Eigen::Vector3d tvec = Eigen::Vector3d::Zero();
    int observations = 0;              ///< 2-D points with a 3-D point
};

struct ColmapPoint {
    Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
    std::array<uint8_t, 3> rgb{};
    double error_px = 0;  ///< mean reprojection error
    int track_length = 0;
};

struct ColmapModel {
    std::map<int, ColmapCamera> cameras;
    std::vector<ColmapImage> images;   ///< in file order
    std::vector<ColmapPoint> points;
    double mean_reprojection_error_px() const;
};

/// Parses a TXT model folder; throws Error naming the file on a missing file
/// or a malformed line.
ColmapModel read_colmap_text_model(const std::string& dir);

/// Pinhole cameras of the model (models PINHOLE and SIMPLE_PINHOLE only; run
/// COLMAP's image_undistorter first for others), in the model frame.
/// Principal points move to our convention (top-left pixel centre at 0, 0).
std::vector<PhotoCamera> pinhole_cameras(const ColmapModel& model, const std::string& subject);

/// x_map = scale * rotation * x_model + translation.
struct Similarity {
    double scale = 1.0;
    Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
    Eigen::Vector3d translation = Eigen::Vector3d::Zero();
    Eigen::Vector3d apply(const Eigen::Vector3d& p) const { return scale * rotation * p + translation; }
};

/// Least-squares similarity mapping `from[i]` to `to[i]` (Umeyama 1991).
/// Throws Error naming `subject` with fewer than 3 pairs or collinear points.
Similarity fit_similarity(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to,
                          const std::string& subject);

/// `camera` (model frame) moved into the map frame by `s`.
PhotoCamera transform_camera(const PhotoCamera& camera, const Similarity& s);

}  // namespace cityforge::photo
