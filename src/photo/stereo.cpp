#include "photo/stereo.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.hpp"
#include "photo/photo_point.hpp"

namespace cityforge::photo {

void StereoOptions::validate() const {
    if (block_size_px < 3 || block_size_px > 11 || block_size_px % 2 == 0)
        throw Error("--block-size", "must be odd, 3..11 pixels");
    if (uniqueness_ratio < 0 || uniqueness_ratio > 50) throw Error("--uniqueness", "must be 0..50 percent");
    if (speckle_window_px < 0 || speckle_window_px > 10000) throw Error("--speckle-window", "must be 0..10000 pixels");
    if (!(lr_max_diff_px > 0 && lr_max_diff_px <= 10)) throw Error("--lr-max-diff", "must be in (0, 10] pixels");
    if (std::isfinite(z_min_m) != std::isfinite(z_max_m)) throw Error("--z-range", "give both the lowest and highest height");
    if (std::isfinite(z_min_m) && !(z_max_m > z_min_m)) throw Error("--z-range", "highest height must exceed the lowest");
    if (subsample < 1 || subsample > 64) throw Error("--subsample", "must be 1..64");
}

namespace {

cv::Mat to_cv(const Eigen::Matrix3d& m) {
    cv::Mat out(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) out.at<double>(r, c) = m(r, c);
    return out;
}

Eigen::Matrix3d from_cv(const cv::Mat& m) {
    Eigen::Matrix3d out;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) out(r, c) = m.at<double>(r, c);
    return out;
}

// The camera of an image rotated 90 degrees clockwise (cv::ROTATE_90_CLOCKWISE):
// u' = (H - 1) - v, v' = u.
PhotoCamera rotated_clockwise(const PhotoCamera& c) {
    PhotoCamera r = c;
    r.width = c.height, r.height = c.width;
    r.fx = c.fy, r.fy = c.fx;
    r.cx = (c.height - 1) - c.cy, r.cy = c.cx;
    Eigen::Matrix3d rz;
    rz << 0, -1, 0, 1, 0, 0, 0, 0, 1;
    r.rotation = rz * c.rotation;
    return r;
}

}  // namespace

StereoResult stereo_pair_cloud(const cv::Mat& left_in, const cv::Mat& right_in, const PhotoCamera& cl_in,
                               const PhotoCamera& cr_in, const StereoOptions& o, const std::array<double, 2>& scene_z,
                               const std::string& subject, const Progress& progress) {
    o.validate();
    if (left_in.empty() || right_in.empty() || left_in.type() != CV_8UC3 || right_in.type() != CV_8UC3)
        throw Error(subject, "images must be 8-bit colour");
    if (left_in.cols != cl_in.width || left_in.rows != cl_in.height)
        throw Error(subject, "left image is " + std::to_string(left_in.cols) + " x " + std::to_string(left_in.rows) +
                                 " px but its camera says " + std::to_string(cl_in.width) + " x " + std::to_string(cl_in.height));
    if (right_in.cols != cr_in.width || right_in.rows != cr_in.height)
        throw Error(subject, "right image is " + std::to_string(right_in.cols) + " x " + std::to_string(right_in.rows) +
                                 " px but its camera says " + std::to_string(cr_in.width) + " x " + std::to_string(cr_in.height));
    double zmin = o.z_min_m, zmax = o.z_max_m;
    if (!std::isfinite(zmin)) zmin = scene_z[0], zmax = scene_z[1];
    if (!(zmax > zmin)) throw Error(subject, "height range of the scene unknown: give --z-range");

    StereoResult res;
    res.baseline_m = (cr_in.centre - cl_in.centre).norm();
    if (res.baseline_m < 1e-3) throw Error(subject, "the two cameras coincide (no baseline)");

    // Baseline direction in the left camera's image: match along rows, or on
    // rotated images when it runs mostly along the columns.
    const Eigen::Vector3d b_cam = cl_in.rotation * (cr_in.centre - cl_in.centre);
    res.vertical_baseline = std::abs(b_cam.y()) > std::abs(b_cam.x());
    PhotoCamera cl = cl_in, cr = cr_in;
    cv::Mat left = left_in, right = right_in;
    if (res.vertical_baseline) {
        cl = rotated_clockwise(cl_in), cr = rotated_clockwise(cr_in);
        cv::rotate(left_in, left, cv::ROTATE_90_CLOCKWISE);
        cv::rotate(right_in, right, cv::ROTATE_90_CLOCKWISE);
    }
    // OpenCV's convention: the right camera lies along +x of the left one.
    if ((cl.rotation * (cr.centre - cl.centre)).x() < 0) std::swap(cl, cr), std::swap(left, right);

    const Eigen::Matrix3d rel_r = cr.rotation * cl.rotation.transpose();
    const Eigen::Vector3d rel_t = cr.rotation * (cl.centre - cr.centre);
    cv::Mat R1, R2, P1, P2, Q;
    const cv::Mat T = (cv::Mat_<double>(3, 1) << rel_t.x(), rel_t.y(), rel_t.z());
    const cv::Size size(cl.width, cl.height);
    cv::stereoRectify(to_cv(cl.intrinsics()), cv::Mat(), to_cv(cr.intrinsics()), cv::Mat(), size, to_cv(rel_r), T, R1, R2,
                      P1, P2, Q, cv::CALIB_ZERO_DISPARITY, 0.0, size);
    const double f = P1.at<double>(0, 0);
    const double B = -P2.at<double>(0, 3) / P2.at<double>(0, 0);
    if (!(B > 0)) throw Error(subject, "rectification failed (degenerate pair)");

    // Disparity range from the height range: rays of a grid of left pixels
    // meet the lowest and highest planes; depths in the rectified frame.
    const Eigen::Matrix3d r1 = from_cv(R1);
    double dmin = 1e30, dmax = -1e30;
    for (int gy = 0; gy <= 4; ++gy)
        for (int gx = 0; gx <= 4; ++gx) {
            const Eigen::Vector3d ray = cl.ray(gx * (cl.width - 1) / 4.0, gy * (cl.height - 1) / 4.0);
            if (ray.z() > -1e-6) continue;
            for (double z : {zmin, zmax}) {
                const double t = (z - cl.centre.z()) / ray.z();
                if (t <= 0) continue;
                const Eigen::Vector3d pr = r1 * (cl.rotation * (t * ray));
                if (pr.z() <= 0) continue;
                const double d = f * B / pr.z();
                dmin = std::min(dmin, d), dmax = std::max(dmax, d);
            }
        }
    if (!(dmax >= dmin)) throw Error(subject, "the scene's height range is not in front of the cameras");
    const double span = dmax - dmin;
    res.min_disparity_px = static_cast<int>(std::floor(dmin - 0.1 * span - 4));
    res.num_disparities_px = ((static_cast<int>(std::ceil(dmax + 0.1 * span + 4)) - res.min_disparity_px + 15) / 16) * 16;
    if (res.num_disparities_px > 1024) throw Error(subject, "disparity range above 1024 px: narrow --z-range or downscale the images");
    progress(0.1, "rectify");

    cv::Mat m1x, m1y, m2x, m2y, left_r, right_r;
    cv::initUndistortRectifyMap(to_cv(cl.intrinsics()), cv::Mat(), R1, P1, size, CV_32FC1, m1x, m1y);
    cv::initUndistortRectifyMap(to_cv(cr.intrinsics()), cv::Mat(), R2, P2, size, CV_32FC1, m2x, m2y);
    cv::remap(left, left_r, m1x, m1y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
    cv::remap(right, right_r, m2x, m2y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
    // Pixels that come from inside each source image (black borders are not matched).
    cv::Mat valid_l, valid_r, ones(size, CV_8U, cv::Scalar(255));
    cv::remap(ones, valid_l, m1x, m1y, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::remap(ones, valid_r, m2x, m2y, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::Mat gray_l, gray_r;
    cv::cvtColor(left_r, gray_l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(right_r, gray_r, cv::COLOR_BGR2GRAY);

    const int bs = o.block_size_px;
    auto sgbm = cv::StereoSGBM::create(res.min_disparity_px, res.num_disparities_px, bs, 8 * bs * bs, 32 * bs * bs, 0, 0,
                                       o.uniqueness_ratio, o.speckle_window_px, 2, cv::StereoSGBM::MODE_SGBM);
    cv::Mat disp_l, disp_r_flipped, flip_l, flip_r;
    sgbm->compute(gray_l, gray_r, disp_l);
    progress(0.5, "match left");
    // Right-image disparities: match the mirrored pair (mirrored right as the left image).
    cv::flip(gray_l, flip_l, 1);
    cv::flip(gray_r, flip_r, 1);
    sgbm->compute(flip_r, flip_l, disp_r_flipped);
    cv::Mat disp_r;
    cv::flip(disp_r_flipped, disp_r, 1);
    progress(0.85, "match right");

    const Eigen::Matrix3d to_world = cl.rotation.transpose() * r1.transpose();  // rectified left -> world axes
    const double cxr = P1.at<double>(0, 2), cyr = P1.at<double>(1, 2);
    const int invalid = (res.min_disparity_px - 1) * 16;
    const double zlo = zmin - 0.25 * (zmax - zmin) - 1.0, zhi = zmax + 0.25 * (zmax - zmin) + 1.0;
    for (int y = 0; y < size.height; y += 1) {
        const auto* dl = disp_l.ptr<int16_t>(y);
        const auto* dr = disp_r.ptr<int16_t>(y);
        for (int x = 0; x < size.width; x += 1) {
            if (dl[x] <= invalid || !valid_l.at<uint8_t>(y, x)) continue;
            const double d = dl[x] / 16.0;
            ++res.matched_pixels;
            const int xr = static_cast<int>(std::lround(x - d));
            if (xr < 0 || xr >= size.width || !valid_r.at<uint8_t>(y, xr) || dr[xr] <= invalid ||
                std::abs(dr[xr] / 16.0 - d) > o.lr_max_diff_px) {
                ++res.lr_rejected;
                continue;
            }
            if (d <= 0 || (y % o.subsample) || (x % o.subsample)) continue;
            const double depth = f * B / d;
            const Eigen::Vector3d pr((x - cxr) * depth / f, (y - cyr) * depth / f, depth);
            const Eigen::Vector3d w = cl.centre + to_world * pr;
            if (w.z() < zlo || w.z() > zhi) {
                ++res.range_rejected;
                continue;
            }
            const auto* px = left_r.ptr<uint8_t>(y) + 3 * x;
            append_photo_point(res.cloud, w, px, 0);
        }
    }
    if (res.cloud.size() == 0) throw Error(subject, "no consistent disparity: the images do not overlap or have no texture");
    progress(1.0, "triangulate");
    return res;
}

}  // namespace cityforge::photo
