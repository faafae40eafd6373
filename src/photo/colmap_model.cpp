#include "photo/colmap_model.hpp"

#include <fstream>
#include <sstream>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "core/error.hpp"

namespace cityforge::photo {

double ColmapModel::mean_reprojection_error_px() const {
    double s = 0;
    for (const auto& p : points) s += p.error_px;
    return points.empty() ? 0.0 : s / static_cast<double>(points.size());
}

namespace {

std::vector<std::string> data_lines(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open COLMAP model file");
    std::vector<std::string> lines;
    std::string line;
    while (std::getline(in, line)) {
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty() || line[0] == '#') continue;
        lines.push_back(line);
    }
    return lines;
}

}  // namespace

ColmapModel read_colmap_text_model(const std::string& dir) {
    ColmapModel m;
    const std::string cam_path = dir + "/cameras.txt", img_path = dir + "/images.txt", pts_path = dir + "/points3D.txt";
    for (const std::string& line : data_lines(cam_path)) {
        std::istringstream s(line);
        ColmapCamera c;
        if (!(s >> c.id >> c.model >> c.width >> c.height)) throw Error(cam_path, "malformed camera line: " + line);
        double v;
        while (s >> v) c.params.push_back(v);
        m.cameras[c.id] = c;
    }
    // images.txt: two lines per image (pose line, then the 2-D points line).
    const auto img_lines = [&] {
        std::ifstream in(img_path);
        if (!in) throw Error(img_path, "cannot open COLMAP model file");
        std::vector<std::string> lines;
        std::string line;
        while (std::getline(in, line)) {
            if (!line.empty() && line.back() == '\r') line.pop_back();
            if (!line.empty() && line[0] == '#') continue;
            lines.push_back(line);
        }
        return lines;
    }();
    for (std::size_t i = 0; i < img_lines.size(); i += 2) {
        if (img_lines[i].empty()) break;
        std::istringstream s(img_lines[i]);
        ColmapImage im;
        if (!(s >> im.id >> im.qvec[0] >> im.qvec[1] >> im.qvec[2] >> im.qvec[3] >> im.tvec[0] >> im.tvec[1] >> im.tvec[2] >>
              im.camera_id >> im.name))
            throw Error(img_path, "malformed image line: " + img_lines[i]);
        if (i + 1 < img_lines.size()) {
            std::istringstream p(img_lines[i + 1]);
            double x, y;
            long long id;
            while (p >> x >> y >> id)
                if (id >= 0) ++im.observations;
        }
        m.images.push_back(im);
    }
    for (const std::string& line : data_lines(pts_path)) {
        std::istringstream s(line);
        long long id;
        ColmapPoint p;
        int r, g, b;
        if (!(s >> id >> p.xyz[0] >> p.xyz[1] >> p.xyz[2] >> r >> g >> b >> p.error_px))
            throw Error(pts_path, "malformed point line");
        p.rgb = {static_cast<uint8_t>(r), static_cast<uint8_t>(g), static_cast<uint8_t>(b)};
        long long a, c;
        while (s >> a >> c) ++p.track_length;
        m.points.push_back(p);
    }
    if (m.images.empty()) throw Error(img_path, "no oriented image in the model");
    return m;
}

std::vector<PhotoCamera> pinhole_cameras(const ColmapModel& model, const std::string& subject) {
    std::vector<PhotoCamera> out;
    for (const ColmapImage& im : model.images) {
        const auto it = model.cameras.find(im.camera_id);
        if (it == model.cameras.end()) throw Error(subject, "image " + im.name + " refers to a missing camera");
        const ColmapCamera& c = it->second;
        PhotoCamera pc;
        pc.image = im.name;
        pc.width = c.width, pc.height = c.height;
        if (c.model == "PINHOLE" && c.params.size() == 4) {
            pc.fx = c.params[0], pc.fy = c.params[1], pc.cx = c.params[2] - 0.5, pc.cy = c.params[3] - 0.5;
        } else if (c.model == "SIMPLE_PINHOLE" && c.params.size() == 3) {
            pc.fx = pc.fy = c.params[0], pc.cx = c.params[1] - 0.5, pc.cy = c.params[2] - 0.5;
        } else {
            throw Error(subject, "camera model " + c.model + " has distortion: undistort the images first");
        }
        const Eigen::Quaterniond q(im.qvec[0], im.qvec[1], im.qvec[2], im.qvec[3]);
        pc.rotation = q.normalized().toRotationMatrix();
        pc.centre = -pc.rotation.transpose() * im.tvec;
        out.push_back(pc);
    }
    return out;
}

Similarity fit_similarity(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to,
                          const std::string& subject) {
    if (from.size() != to.size() || from.size() < 3)
        throw Error(subject, "georeferencing needs at least 3 images with both a pose and a GPS position (have " +
                                 std::to_string(std::min(from.size(), to.size())) + ")");
    const std::size_t n = from.size();
    Eigen::Matrix3Xd a(3, n), b(3, n);
    for (std::size_t i = 0; i < n; ++i) a.col(i) = from[i], b.col(i) = to[i];
    const Eigen::Vector3d ma = a.rowwise().mean(), mb = b.rowwise().mean();
    a.colwise() -= ma, b.colwise() -= mb;
    // Collinear positions leave the rotation about their line undetermined.
    Eigen::JacobiSVD<Eigen::Matrix3d> spread(a * a.transpose());
    if (spread.singularValues()(1) < 1e-6 * std::max(1e-12, spread.singularValues()(0)))
        throw Error(subject, "camera positions are collinear: the georeferencing rotation is undetermined");
    const Eigen::Matrix3d cov = b * a.transpose() / double(n);
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) d(2, 2) = -1;
    Similarity s;
    s.rotation = svd.matrixU() * d * svd.matrixV().transpose();
    const double var_a = a.squaredNorm() / double(n);
    s.scale = (svd.singularValues().asDiagonal() * d).trace() / var_a;
    s.translation = mb - s.scale * s.rotation * ma;
    return s;
}

PhotoCamera transform_camera(const PhotoCamera& c, const Similarity& s) {
    PhotoCamera out = c;
    out.centre = s.apply(c.centre);
    out.rotation = c.rotation * s.rotation.transpose();
    return out;
}

}  // namespace cityforge::photo
