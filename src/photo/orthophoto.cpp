#include "photo/orthophoto.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "core/grid_fill.hpp"

namespace cityforge::photo {

void OrthophotoOptions::validate() const {
    if (!(max_gap_fill_m >= 0 && max_gap_fill_m <= 1000)) throw Error("orthophoto max_gap_fill_m", "must be 0..1000 m");
    if (!(occlusion_tolerance_m >= 0 && occlusion_tolerance_m <= 100)) throw Error("orthophoto occlusion_tolerance_m", "must be 0..100 m");
    if (!(max_off_nadir_deg > 0 && max_off_nadir_deg < 90)) throw Error("orthophoto max_off_nadir_deg", "must be in (0, 90) degrees");
}

namespace {

// The cloud's top surface on the grid (NaN where no point), and whether each
// cell was measured; gaps filled from their neighbours (fill_from_neighbours).
std::vector<float> top_surface(const PointCloud& c, const GridSpec& g, int fill_passes, std::vector<uint8_t>& measured) {
    const std::size_t n = static_cast<std::size_t>(g.width) * g.height;
    std::vector<float> top(n, std::numeric_limits<float>::quiet_NaN());
    measured.assign(n, 0);
    for (std::size_t i = 0; i < c.size(); ++i) {
        const PixelPoint p = g.transform.map_to_pixel({c.x[i], c.y[i]});
        const long col = static_cast<long>(std::floor(p.col)), row = static_cast<long>(std::floor(p.row));
        if (col < 0 || row < 0 || col >= g.width || row >= g.height) continue;
        const std::size_t k = static_cast<std::size_t>(row) * g.width + col;
        const float z = static_cast<float>(c.z[i]);
        if (!measured[k] || z > top[k]) top[k] = z;
        measured[k] = 1;
    }
    fill_from_neighbours(top, g.width, g.height, 1, fill_passes);
    return top;
}

// Bilinear BGR sample at pixel (u, v) (top-left pixel centre = 0, 0), as RGB.
void sample_rgb(const cv::Mat& m, double u, double v, double rgb[3]) {
    const int x0 = std::clamp(static_cast<int>(std::floor(u)), 0, m.cols - 2), y0 = std::clamp(static_cast<int>(std::floor(v)), 0, m.rows - 2);
    const double fx = std::clamp(u - x0, 0.0, 1.0), fy = std::clamp(v - y0, 0.0, 1.0);
    const cv::Vec3b a = m.at<cv::Vec3b>(y0, x0), b = m.at<cv::Vec3b>(y0, x0 + 1), c = m.at<cv::Vec3b>(y0 + 1, x0),
                    d = m.at<cv::Vec3b>(y0 + 1, x0 + 1);
    for (int ch = 0; ch < 3; ++ch) {
        const double top = a[ch] * (1 - fx) + b[ch] * fx, bottom = c[ch] * (1 - fx) + d[ch] * fx;
        rgb[2 - ch] = top * (1 - fy) + bottom * fy;
    }
}

}  // namespace

Image<uint8_t> orthophoto_from_photos(const PointCloud& cloud, const GridSpec& g, const PhotoLoader& load, const CameraSet& cameras,
                                      const OrthophotoOptions& o, const std::string& subject, OrthophotoStats* stats) {
    o.validate();
    if (g.width <= 0 || g.height <= 0) throw Error(subject, "the orthophoto grid has no cells");
    const double cell_m = std::abs(g.transform.pixel_width);
    const int passes = static_cast<int>(std::ceil(o.max_gap_fill_m / std::max(1e-9, cell_m)));
    std::vector<uint8_t> measured;
    const std::vector<float> surface = top_surface(cloud, g, passes, measured);
    const std::size_t n = surface.size();
    float z_top = -std::numeric_limits<float>::infinity();
    std::size_t n_measured = 0, n_filled = 0;
    for (std::size_t k = 0; k < n; ++k) {
        n_measured += measured[k];
        if (!std::isnan(surface[k])) z_top = std::max(z_top, surface[k]), n_filled += !measured[k];
    }
    if (n_measured == 0) throw Error(subject, "no point of the cloud falls on the orthophoto grid");
    const double cos_limit = std::cos(o.max_off_nadir_deg * M_PI / 180.0);
    auto surface_at = [&](double x, double y) -> float {
        const PixelPoint p = g.transform.map_to_pixel({x, y});
        const long col = static_cast<long>(std::floor(p.col)), row = static_cast<long>(std::floor(p.row));
        if (col < 0 || row < 0 || col >= g.width || row >= g.height) return std::numeric_limits<float>::quiet_NaN();
        return surface[static_cast<std::size_t>(row) * g.width + col];
    };
    // Whether the surface hides point X from camera centre C: the line of
    // sight walked in half-cell steps from one cell away until it rises above
    // the highest surface.
    auto hidden = [&](const Eigen::Vector3d& X, const Eigen::Vector3d& C) {
        const Eigen::Vector3d d = C - X;
        const double horizontal = std::hypot(d.x(), d.y());
        if (horizontal < 1e-9) return false;
        const double step = 0.5 * cell_m / horizontal;  // in units of |d| per half cell horizontally
        for (double t = 2.0 * step; t < 1.0; t += step) {
            const Eigen::Vector3d P = X + t * d;
            if (P.z() > z_top + o.occlusion_tolerance_m) return false;
            const float s = surface_at(P.x(), P.y());
            if (!std::isnan(s) && s > P.z() + o.occlusion_tolerance_m) return true;
        }
        return false;
    };
    auto surface_point = [&](std::size_t k) {
        const int q = static_cast<int>(k % static_cast<std::size_t>(g.width)), r = static_cast<int>(k / static_cast<std::size_t>(g.width));
        const MapPoint m = g.transform.pixel_centre(q, r);
        return Eigen::Vector3d(m.x, m.y, surface[k]);
    };
    // 1. Each cell's view: the most nadir camera (ties by camera order) that
    // sees the cell's surface point unhidden; -1 = none.
    constexpr int32_t none = -1;
    std::vector<int32_t> view(n, none);
    std::vector<uint8_t> occluded(n, 0);
    tbb::parallel_for(0, g.height, [&](int r) {
        struct View {
            double neg_cos;      // most nadir first
            std::size_t camera;  // ties by camera order
            bool operator<(const View& v) const { return neg_cos != v.neg_cos ? neg_cos < v.neg_cos : camera < v.camera; }
        };
        std::vector<View> views;
        for (int q = 0; q < g.width; ++q) {
            const std::size_t k = static_cast<std::size_t>(r) * g.width + q;
            if (std::isnan(surface[k])) continue;
            const Eigen::Vector3d X = surface_point(k);
            views.clear();
            for (std::size_t i = 0; i < cameras.cameras.size(); ++i) {
                const PhotoCamera& cam = cameras.cameras[i];
                const Eigen::Vector3d d = (cam.centre - X).normalized();
                if (d.z() < cos_limit) continue;
                const auto px = cam.project(X);
                if (!px || !cam.inside(*px, 1.0)) continue;
                views.push_back({-d.z(), i});
            }
            std::sort(views.begin(), views.end());
            for (const View& v : views)
                if (!hidden(X, cameras.cameras[v.camera].centre)) {
                    view[k] = static_cast<int32_t>(v.camera);
                    break;
                }
            occluded[k] = view[k] == none && !views.empty();
        }
    });
    // 2. The cells of each camera (in cell order), then one photo at a time.
    std::vector<std::size_t> first(cameras.cameras.size() + 1, 0);
    for (std::size_t k = 0; k < n; ++k)
        if (view[k] != none) ++first[static_cast<std::size_t>(view[k]) + 1];
    std::partial_sum(first.begin(), first.end(), first.begin());
    std::vector<std::size_t> cells(first.back()), next(first.begin(), first.end() - 1);
    for (std::size_t k = 0; k < n; ++k)
        if (view[k] != none) cells[next[static_cast<std::size_t>(view[k])]++] = k;
    Image<uint8_t> out(g.width, g.height, 3, 0);
    for (std::size_t i = 0; i < cameras.cameras.size(); ++i) {
        if (first[i] == first[i + 1]) continue;
        const PhotoCamera& cam = cameras.cameras[i];
        const cv::Mat image = load(i);
        if (image.type() != CV_8UC3 || image.cols != cam.width || image.rows != cam.height || cam.width < 2 || cam.height < 2)
            throw Error(cam.image, "image size or type differs from its camera (" + std::to_string(cam.width) + " x " +
                                       std::to_string(cam.height) + " px, 8-bit colour)");
        tbb::parallel_for(first[i], first[i + 1], [&](std::size_t j) {
            const std::size_t k = cells[j];
            const auto px = cam.project(surface_point(k));  // as in step 1: in view, inside the photo
            double rgb[3];
            sample_rgb(image, px->x(), px->y(), rgb);
            const int q = static_cast<int>(k % static_cast<std::size_t>(g.width)), r = static_cast<int>(k / static_cast<std::size_t>(g.width));
            for (int b = 0; b < 3; ++b) out.at(b, q, r) = static_cast<uint8_t>(std::clamp(std::lround(rgb[b]), 1L, 255L));
        });
    }
    if (stats) {
        stats->cells_measured = n_measured;
        stats->cells_filled = n_filled;
        stats->cells_coloured = first.back();
        stats->cells_occluded = static_cast<std::size_t>(std::accumulate(occluded.begin(), occluded.end(), std::size_t(0)));
    }
    return out;
}

Image<uint8_t> orthophoto_from_photos(const PointCloud& cloud, const GridSpec& g, const std::vector<cv::Mat>& images,
                                      const CameraSet& cameras, const OrthophotoOptions& o, const std::string& subject,
                                      OrthophotoStats* stats) {
    if (images.size() != cameras.cameras.size()) throw Error(subject, "one image per camera is needed for the orthophoto");
    return orthophoto_from_photos(
        cloud, g, [&](std::size_t i) { return images[i]; }, cameras, o, subject, stats);
}

}  // namespace cityforge::photo
