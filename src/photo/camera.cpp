#include "photo/camera.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include <Eigen/Dense>

#include "core/atomic_file.hpp"
#include "core/error.hpp"

namespace cityforge::photo {

Eigen::Matrix3d PhotoCamera::intrinsics() const {
    Eigen::Matrix3d k;
    k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
    return k;
}

std::optional<Eigen::Vector2d> PhotoCamera::project(const Eigen::Vector3d& world) const {
    const Eigen::Vector3d c = to_camera(world);
    if (c.z() <= 1e-9) return std::nullopt;
    return Eigen::Vector2d(fx * c.x() / c.z() + cx, fy * c.y() / c.z() + cy);
}

Eigen::Vector3d PhotoCamera::ray(double u, double v) const {
    const Eigen::Vector3d d((u - cx) / fx, (v - cy) / fy, 1.0);
    return (rotation.transpose() * d).normalized();
}

std::size_t CameraSet::find(const std::string& image, const std::string& subject) const {
    for (std::size_t i = 0; i < cameras.size(); ++i)
        if (cameras[i].image == image) return i;
    throw Error(subject, "no camera for image '" + image + "'");
}

PoseError compare_poses(const CameraSet& estimated, const CameraSet& truth) {
    PoseError e;
    for (const PhotoCamera& t : truth.cameras)
        for (const PhotoCamera& c : estimated.cameras) {
            if (c.image != t.image) continue;
            const double dp = (c.centre - t.centre).norm();
            const double cos_a = std::clamp(((c.rotation * t.rotation.transpose()).trace() - 1.0) / 2.0, -1.0, 1.0);
            const double da = std::acos(cos_a) * 180.0 / 3.14159265358979323846;
            ++e.matched;
            e.mean_position_m += dp, e.mean_angle_deg += da;
            e.max_position_m = std::max(e.max_position_m, dp), e.max_angle_deg = std::max(e.max_angle_deg, da);
        }
    if (e.matched) e.mean_position_m /= e.matched, e.mean_angle_deg /= e.matched;
    return e;
}

CameraSet read_cameras_json(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open cameras file");
    nlohmann::json j;
    try {
        in >> j;
    } catch (const std::exception&) {
        throw Error(path, "not a JSON cameras file");
    }
    CameraSet set;
    try {
        if (!j.is_object() || !j.contains("cameras") || !j["cameras"].is_array())
            throw Error(path, "no 'cameras' array");
        set.crs = j.value("crs", std::string());
        set.crs_wkt = j.value("crs_wkt", std::string());
        if (j.contains("scene_z_range_m")) set.scene_z_range_m = j["scene_z_range_m"].get<std::array<double, 2>>();
        for (const auto& c : j["cameras"]) {
            PhotoCamera cam;
            cam.image = c.at("image").get<std::string>();
            cam.width = c.at("width").get<int>();
            cam.height = c.at("height").get<int>();
            cam.fx = c.at("fx").get<double>();
            cam.fy = c.at("fy").get<double>();
            cam.cx = c.at("cx").get<double>();
            cam.cy = c.at("cy").get<double>();
            const auto centre = c.at("centre").get<std::array<double, 3>>();
            cam.centre = {centre[0], centre[1], centre[2]};
            const auto r = c.at("rotation_world_to_camera").get<std::array<double, 9>>();
            for (int i = 0; i < 9; ++i) cam.rotation(i / 3, i % 3) = r[i];
            if (cam.width <= 0 || cam.height <= 0 || !(cam.fx > 0) || !(cam.fy > 0))
                throw Error(path, "camera of '" + cam.image + "' has a non-positive size or focal length");
            if ((cam.rotation * cam.rotation.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-6 ||
                cam.rotation.determinant() < 0)
                throw Error(path, "camera of '" + cam.image + "' has a rotation that is not a proper rotation matrix");
            set.cameras.push_back(std::move(cam));
        }
    } catch (const nlohmann::json::exception& e) {
        throw Error(path, std::string("bad cameras file: ") + e.what());
    }
    if (set.cameras.empty()) throw Error(path, "no cameras");
    return set;
}

void write_cameras_json(const std::string& path, const CameraSet& set) {
    nlohmann::json j;
    j["convention"] = "x_cam = R (X - C); pixel = (fx x/z + cx, fy y/z + cy); top-left pixel centre = (0, 0); undistorted";
    j["crs"] = set.crs;
    if (!set.crs_wkt.empty()) j["crs_wkt"] = set.crs_wkt;
    j["scene_z_range_m"] = set.scene_z_range_m;
    j["cameras"] = nlohmann::json::array();
    for (const PhotoCamera& c : set.cameras) {
        std::array<double, 9> r{};
        for (int i = 0; i < 9; ++i) r[i] = c.rotation(i / 3, i % 3);
        j["cameras"].push_back({{"image", c.image}, {"width", c.width}, {"height", c.height}, {"fx", c.fx}, {"fy", c.fy},
                                {"cx", c.cx}, {"cy", c.cy},
                                {"centre", std::array<double, 3>{c.centre.x(), c.centre.y(), c.centre.z()}},
                                {"rotation_world_to_camera", r}});
    }
    write_text_file(path, j.dump(2) + "\n");
}

}  // namespace cityforge::photo
