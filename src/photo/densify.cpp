#include "photo/densify.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>
#include <optional>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.hpp"
#include "photo/photo_point.hpp"

namespace cityforge::photo {

void DensifyOptions::validate() const {
    if (cell_px < 1 || cell_px > 32) throw Error("--cell-px", "must be 1..32 pixels");
    if (!(cell_m >= 0 && cell_m <= 10)) throw Error("--cell-m", "must be 0..10 metres");
    if (patch_grid < 3 || patch_grid > 15 || patch_grid % 2 == 0) throw Error("--patch-grid", "must be odd, 3..15");
    if (!(min_ncc > -1 && min_ncc < 1)) throw Error("--min-ncc", "must be in (-1, 1)");
    if (min_views < 2 || min_views > 20) throw Error("--min-views", "must be 2..20");
    if (!(min_view_share >= 0 && min_view_share <= 1)) throw Error("--min-view-share", "must be 0..1");
    if (neighbour_images < 1 || neighbour_images > 50) throw Error("--neighbour-images", "must be 1..50");
    if (!(min_baseline_ratio >= 0 && min_baseline_ratio < 1)) throw Error("--min-baseline", "must be 0..1 of the depth");
    if (!(max_view_angle_deg > 10 && max_view_angle_deg < 89)) throw Error("--max-view-angle", "must be 10..89 degrees");
    if (iterations < 1 || iterations > 10) throw Error("--iterations", "must be 1..10");
    if (max_expansion_steps < 1 || max_expansion_steps > 10000) throw Error("--max-expansion-steps", "must be 1..10000");
    if (seed_features < 100 || seed_features > 100000) throw Error("--seed-features", "must be 100..100000");
    if (!(min_support >= 0 && min_support <= 1)) throw Error("--min-support", "must be 0..1");
    if (points_per_patch_side < 1 || points_per_patch_side > 9) throw Error("--points-per-patch", "must be 1..9");
    if (!(max_tilt_deg > 0 && max_tilt_deg < 90)) throw Error("--max-tilt", "must be in (0, 90) degrees");
}

namespace {

struct Patch {
    Eigen::Vector3d c, n;
    int ref = 0;
    std::vector<int> vis;  // V*(p), ref first
    double g = 1.0;        // mean 1 - NCC over V*(p) \ R(p)
};

struct View {
    const PhotoCamera* cam = nullptr;
    cv::Mat gray;          // CV_8U (a quarter of CV_32F's memory; the samples are the same values)
    Eigen::Vector3d c_local;  // centre relative to the block origin
    std::vector<int> neighbours;
    int cell = 1;            // cell side, pixels
    int cols = 0, rows = 0;  // cells
};

double bilinear(const cv::Mat& m, double x, double y) {
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const double tx = x - x0, ty = y - y0;
    const uint8_t* r0 = m.ptr<uint8_t>(y0);
    const uint8_t* r1 = m.ptr<uint8_t>(y0 + 1);
    return (r0[x0] * (1 - tx) + r0[x0 + 1] * tx) * (1 - ty) + (r1[x0] * (1 - tx) + r1[x0 + 1] * tx) * ty;
}

class Engine {
public:
    Engine(const std::vector<cv::Mat>& images, const CameraSet& set, const DensifyOptions& o) : o_(o) {
        origin_ = set.cameras[0].centre;
        local_.reserve(set.cameras.size());
        for (const PhotoCamera& c : set.cameras) {
            PhotoCamera l = c;
            l.centre -= origin_;
            local_.push_back(l);
        }
        views_.resize(images.size());
        for (std::size_t i = 0; i < images.size(); ++i) {
            View& v = views_[i];
            v.cam = &local_[i];
            cv::cvtColor(images[i], v.gray, cv::COLOR_BGR2GRAY);
            v.c_local = local_[i].centre;
        }
        // Cells: at least cell_px pixels and cell_m metres on the surface at
        // the middle of the scene's height range (along the optical axis).
        const bool z_known = set.scene_z_range_m[0] != 0.0 || set.scene_z_range_m[1] != 0.0;
        const double zmid = 0.5 * (set.scene_z_range_m[0] + set.scene_z_range_m[1]);
        for (std::size_t i = 0; i < views_.size(); ++i) {
            View& v = views_[i];
            v.cell = o.cell_px;
            const double down = -local_[i].rotation(2, 2);  // cosine of the optical axis' angle from nadir
            if (o.cell_m > 0 && z_known && down > 0.1 && set.cameras[i].centre.z() > zmid) {
                const double gsd = (set.cameras[i].centre.z() - zmid) / down / local_[i].fx;
                v.cell = std::clamp(static_cast<int>(std::lround(o.cell_m / gsd)), o.cell_px, 32);
            }
            v.cols = (local_[i].width + v.cell - 1) / v.cell;
            v.rows = (local_[i].height + v.cell - 1) / v.cell;
        }
        // Neighbours: images whose centres are closest, among those looking the
        // same way with a baseline: the heads of one oblique camera share a
        // centre, and a pure rotation sees every depth alike.
        for (std::size_t i = 0; i < views_.size(); ++i) {
            std::vector<std::pair<double, int>> d;
            const Eigen::Vector3d zi = local_[i].rotation.row(2).transpose();
            const double depth = z_known ? std::max(1.0, set.cameras[i].centre.z() - zmid) : 0.0;
            for (std::size_t j = 0; j < views_.size(); ++j) {
                if (j == i) continue;
                const Eigen::Vector3d zj = local_[j].rotation.row(2).transpose();
                if (zi.dot(zj) < std::cos(60.0 * std::numbers::pi / 180.0)) continue;
                if ((local_[j].centre - local_[i].centre).norm() < o.min_baseline_ratio * depth) continue;
                d.push_back({(local_[j].centre - local_[i].centre).norm(), static_cast<int>(j)});
            }
            std::sort(d.begin(), d.end());
            for (std::size_t k = 0; k < d.size() && static_cast<int>(k) < o.neighbour_images; ++k) views_[i].neighbours.push_back(d[k].second);
        }
        // Patch centres must lie within the scene's height range, widened by
        // half its span (at least 5 m): a depth search that ran away along a
        // textureless ray (km below the ground) is refused.
        if (z_known) {
            const double lo = set.scene_z_range_m[0], hi = set.scene_z_range_m[1];
            const double pad = std::max(5.0, 0.5 * (hi - lo));
            z_lo_ = lo - pad - origin_.z(), z_hi_ = hi + pad - origin_.z();
        }
        cells_.resize(views_.size());
        for (std::size_t i = 0; i < views_.size(); ++i) cells_[i].assign(static_cast<std::size_t>(views_[i].cols) * views_[i].rows, {});
    }

    const Eigen::Vector3d& origin() const { return origin_; }
    std::vector<Patch>& patches() { return patches_; }
    std::vector<uint8_t>& alive() { return alive_; }
    const View& view(int i) const { return views_[static_cast<std::size_t>(i)]; }
    int view_count() const { return static_cast<int>(views_.size()); }

    // Pixel size on the surface at depth of c in image i (metres).
    double footprint(const Eigen::Vector3d& c, int i) const {
        const PhotoCamera& cam = local_[static_cast<std::size_t>(i)];
        return cam.to_camera(c).z() / cam.fx;
    }

    // Samples of patch (c, n) projected into image i; false when outside.
    bool sample(const Eigen::Vector3d& c, const Eigen::Vector3d& n, int ref, int i, std::vector<double>& out) const {
        const int mu = o_.patch_grid;
        const PhotoCamera& rc = local_[static_cast<std::size_t>(ref)];
        // Patch axes: the reference image's x and y directions projected on the patch plane.
        Eigen::Vector3d ax = rc.rotation.row(0).transpose();
        ax = (ax - ax.dot(n) * n).normalized();
        const Eigen::Vector3d ay = n.cross(ax).normalized();
        const double s = footprint(c, ref);
        const PhotoCamera& cam = local_[static_cast<std::size_t>(i)];
        const cv::Mat& img = views_[static_cast<std::size_t>(i)].gray;
        out.resize(static_cast<std::size_t>(mu) * mu);
        const int h = mu / 2;
        std::size_t k = 0;
        for (int a = -h; a <= h; ++a)
            for (int b = -h; b <= h; ++b) {
                const Eigen::Vector3d p = c + s * (b * ax + a * ay);
                const Eigen::Vector3d q = cam.to_camera(p);
                if (q.z() <= 0) return false;
                const double u = cam.fx * q.x() / q.z() + cam.cx, v = cam.fy * q.y() / q.z() + cam.cy;
                if (u < 0 || v < 0 || u >= img.cols - 1.001 || v >= img.rows - 1.001) return false;
                out[k++] = bilinear(img, u, v);
            }
        return true;
    }

    static double ncc(const std::vector<double>& a, const std::vector<double>& b) {
        const double n = static_cast<double>(a.size());
        const double ma = std::accumulate(a.begin(), a.end(), 0.0) / n, mb = std::accumulate(b.begin(), b.end(), 0.0) / n;
        double sab = 0, saa = 0, sbb = 0;
        for (std::size_t k = 0; k < a.size(); ++k) {
            const double x = a[k] - ma, y = b[k] - mb;
            sab += x * y, saa += x * x, sbb += y * y;
        }
        if (saa < 1e-6 * n || sbb < 1e-6 * n) return -1.0;
        return sab / std::sqrt(saa * sbb);
    }

    // Images where the patch may be visible: reference first, then its
    // neighbours that see the patch's front side within the view angle.
    std::vector<int> candidates(const Eigen::Vector3d& c, const Eigen::Vector3d& n, int ref) const {
        std::vector<int> v{ref};
        const double cos_max = std::cos(o_.max_view_angle_deg * std::numbers::pi / 180.0);
        for (int j : views_[static_cast<std::size_t>(ref)].neighbours) {
            const Eigen::Vector3d d = (local_[static_cast<std::size_t>(j)].centre - c).normalized();
            if (d.dot(n) < cos_max) continue;
            const auto px = local_[static_cast<std::size_t>(j)].project(c);
            if (!px || !local_[static_cast<std::size_t>(j)].inside(*px, o_.patch_grid)) continue;
            v.push_back(j);
        }
        return v;
    }

    // Mean 1 - NCC over `vis` \ ref; 2 when the reference patch cannot be sampled.
    double score(const Eigen::Vector3d& c, const Eigen::Vector3d& n, int ref, const std::vector<int>& vis,
                 std::vector<double>* per_image = nullptr) const {
        std::vector<double> r, s;
        if (!sample(c, n, ref, ref, r)) return 2.0;
        double sum = 0;
        int cnt = 0;
        if (per_image) per_image->clear();
        for (int j : vis) {
            if (j == ref) continue;
            const double v = sample(c, n, ref, j, s) ? ncc(r, s) : -1.0;
            if (per_image) per_image->push_back(v);
            sum += 1.0 - v, ++cnt;
        }
        return cnt ? sum / cnt : 2.0;
    }

    // Refines depth along the reference ray and the normal (two tilts) by
    // pattern search on g over V*(p), then recomputes V*(p). nullopt if the
    // patch does not reach min_views images with NCC >= min_ncc.
    std::optional<Patch> optimise(Eigen::Vector3d c, Eigen::Vector3d n, int ref) const {
        const PhotoCamera& rc = local_[static_cast<std::size_t>(ref)];
        if (n.dot(rc.centre - c) <= 0) n = -n;
        std::vector<int> cand = candidates(c, n, ref);
        if (static_cast<int>(cand.size()) < o_.min_views) return std::nullopt;
        std::vector<double> per;
        score(c, n, ref, cand, &per);
        std::vector<int> vis{ref};
        for (std::size_t k = 0; k < per.size(); ++k)
            if (per[k] >= o_.min_ncc - 0.15) vis.push_back(cand[k + 1]);
        if (static_cast<int>(vis.size()) < o_.min_views) return std::nullopt;

        const Eigen::Vector3d ray = (c - rc.centre).normalized();
        double t = (c - rc.centre).norm();
        double theta = 0, phi = 0;  // tilts of n about the patch axes
        const Eigen::Vector3d n0 = n;
        Eigen::Vector3d ax = rc.rotation.row(0).transpose();
        ax = (ax - ax.dot(n0) * n0).normalized();
        const Eigen::Vector3d ay = n0.cross(ax).normalized();
        auto normal_of = [&](double th, double ph) {
            return (n0 * std::cos(th) * std::cos(ph) + ax * std::sin(th) * std::cos(ph) + ay * std::sin(ph)).normalized();
        };
        const double px = footprint(c, ref);
        const double max_tilt = o_.max_tilt_deg * std::numbers::pi / 180.0;
        double best = score(rc.centre + t * ray, n, ref, vis);
        double dt = 2.0 * px, da = 0.25;
        for (int level = 0; level < 5; ++level) {
            bool improved = true;
            for (int it = 0; it < 4 && improved; ++it) {
                improved = false;
                const double trial[6][3] = {{dt, 0, 0}, {-dt, 0, 0}, {0, da, 0}, {0, -da, 0}, {0, 0, da}, {0, 0, -da}};
                for (const auto& d : trial) {
                    const double nt = t + d[0], nth = theta + d[1], nph = phi + d[2];
                    if (std::abs(nth) > max_tilt || std::abs(nph) > max_tilt || nt <= 0) continue;
                    const double s = score(rc.centre + nt * ray, normal_of(nth, nph), ref, vis);
                    if (s < best - 1e-9) best = s, t = nt, theta = nth, phi = nph, improved = true;
                }
            }
            dt *= 0.5, da *= 0.5;
        }
        Patch p;
        p.c = rc.centre + t * ray;
        if (p.c.z() < z_lo_ || p.c.z() > z_hi_) return std::nullopt;
        p.n = normal_of(theta, phi);
        p.ref = ref;
        cand = candidates(p.c, p.n, ref);
        score(p.c, p.n, ref, cand, &per);
        p.vis = {ref};
        double sum = 0;
        for (std::size_t k = 0; k < per.size(); ++k)
            if (per[k] >= o_.min_ncc) p.vis.push_back(cand[k + 1]), sum += 1.0 - per[k];
        if (static_cast<int>(p.vis.size()) < o_.min_views) return std::nullopt;
        if (static_cast<double>(p.vis.size()) < std::ceil(o_.min_view_share * static_cast<double>(cand.size()) - 1e-9)) return std::nullopt;
        p.g = sum / static_cast<double>(p.vis.size() - 1);
        return p;
    }

    // Cell of point c in image i, or -1.
    long cell_of(const Eigen::Vector3d& c, int i) const {
        const auto px = local_[static_cast<std::size_t>(i)].project(c);
        if (!px || !local_[static_cast<std::size_t>(i)].inside(*px)) return -1;
        const View& v = views_[static_cast<std::size_t>(i)];
        const int cx = static_cast<int>(px->x()) / v.cell, cy = static_cast<int>(px->y()) / v.cell;
        return static_cast<long>(cy) * v.cols + cx;
    }

    bool occupied(int i, long cell) const { return cell >= 0 && !cells_[static_cast<std::size_t>(i)][static_cast<std::size_t>(cell)].empty(); }

    // Adds a patch (registered in the cells of all images of V*(p)) unless its
    // reference cell is taken; returns false when refused.
    bool commit(Patch p) {
        const long rc = cell_of(p.c, p.ref);
        if (rc < 0 || occupied(p.ref, rc)) return false;
        const int id = static_cast<int>(patches_.size());
        for (int i : p.vis) {
            const long cell = cell_of(p.c, i);
            if (cell >= 0) cells_[static_cast<std::size_t>(i)][static_cast<std::size_t>(cell)].push_back(id);
        }
        patches_.push_back(std::move(p));
        alive_.push_back(1);
        return true;
    }

    void rebuild_cells() {
        for (auto& v : cells_)
            for (auto& c : v) c.clear();
        for (std::size_t id = 0; id < patches_.size(); ++id) {
            if (!alive_[id]) continue;
            for (int i : patches_[id].vis) {
                const long cell = cell_of(patches_[id].c, i);
                if (cell >= 0) cells_[static_cast<std::size_t>(i)][static_cast<std::size_t>(cell)].push_back(static_cast<int>(id));
            }
        }
    }

    bool adjacent(const Patch& a, const Patch& b) const {
        const double rho = 2.0 * views_[static_cast<std::size_t>(a.ref)].cell * footprint(a.c, a.ref);
        const Eigen::Vector3d d = a.c - b.c;
        return std::abs(d.dot(a.n)) + std::abs(d.dot(b.n)) < 2.0 * rho;
    }

    // Expansion candidates of patch `id`: rays through the empty 4-neighbour
    // cells (in each image of V*(p)) meet p's plane.
    std::vector<Patch> expand(int id) const {
        std::vector<Patch> out;
        const Patch& p = patches_[static_cast<std::size_t>(id)];
        for (int i : p.vis) {
            const View& v = views_[static_cast<std::size_t>(i)];
            const long cell = cell_of(p.c, i);
            if (cell < 0) continue;
            const int cx = static_cast<int>(cell % v.cols), cy = static_cast<int>(cell / v.cols);
            const int nb[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
            for (const auto& d : nb) {
                const int x = cx + d[0], y = cy + d[1];
                if (x < 0 || y < 0 || x >= v.cols || y >= v.rows) continue;
                const long nc = static_cast<long>(y) * v.cols + x;
                // Skip cells holding a patch adjacent to p (or any patch: occupied).
                if (occupied(i, nc)) continue;
                const PhotoCamera& cam = local_[static_cast<std::size_t>(i)];
                const double u = (x + 0.5) * v.cell - 0.5, w = (y + 0.5) * v.cell - 0.5;
                const Eigen::Vector3d ray = cam.ray(u, w);
                // Planes through p.c to start from: p's own, then (at a roof
                // edge or a wall's foot, where p's plane misses the surface) a
                // wall facing the camera and a level plane.
                Eigen::Vector3d planes[3] = {p.n, Eigen::Vector3d(-ray.x(), -ray.y(), 0.0), Eigen::Vector3d::UnitZ()};
                const int hypotheses = o_.wall_hypotheses ? 3 : 1;
                for (int h = 0; h < hypotheses; ++h) {
                    Eigen::Vector3d n = planes[h];
                    if (n.norm() < 1e-6) continue;
                    n.normalize();
                    if (h > 0 && std::abs(n.dot(p.n)) > std::cos(30.0 * std::numbers::pi / 180.0)) continue;  // p's plane, tried
                    const double denom = ray.dot(n);
                    if (std::abs(denom) < 1e-6) continue;
                    const double t = (p.c - cam.centre).dot(n) / denom;
                    if (t <= 0) continue;
                    if (auto q = optimise(cam.centre + t * ray, n, i)) {
                        const long qc = cell_of(q->c, i);
                        if (qc != nc) continue;  // drifted away from the cell it was made for
                        out.push_back(std::move(*q));
                        break;
                    }
                }
            }
        }
        return out;
    }

    // Removes outliers: the visibility rule, then weak neighbourhood support.
    std::size_t filter() {
        const std::size_t n = patches_.size();
        std::vector<uint8_t> drop(n, 0);
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t id) {
            if (!alive_[id]) return;
            const Patch& p = patches_[id];
            double u_sum = 0;
            for (int i : p.vis) {
                const long cell = cell_of(p.c, i);
                if (cell < 0) continue;
                for (int q : cells_[static_cast<std::size_t>(i)][static_cast<std::size_t>(cell)]) {
                    if (static_cast<std::size_t>(q) == id || !alive_[static_cast<std::size_t>(q)]) continue;
                    const Patch& pq = patches_[static_cast<std::size_t>(q)];
                    if (!adjacent(p, pq)) u_sum += 1.0 - pq.g;
                }
            }
            if (static_cast<double>(p.vis.size()) * (1.0 - p.g) < u_sum) drop[id] = 1;
            // Support: adjacent patches among those in the 3 x 3 cells around p in R(p).
            const View& v = views_[static_cast<std::size_t>(p.ref)];
            const long cell = cell_of(p.c, p.ref);
            if (cell < 0) return;
            const int cx = static_cast<int>(cell % v.cols), cy = static_cast<int>(cell / v.cols);
            int total = 0, adj = 0;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int x = cx + dx, y = cy + dy;
                    if (x < 0 || y < 0 || x >= v.cols || y >= v.rows) continue;
                    for (int q : cells_[static_cast<std::size_t>(p.ref)][static_cast<std::size_t>(y) * v.cols + x]) {
                        if (static_cast<std::size_t>(q) == id || !alive_[static_cast<std::size_t>(q)]) continue;
                        ++total;
                        if (adjacent(p, patches_[static_cast<std::size_t>(q)])) ++adj;
                    }
                }
            if (total == 0 || adj < o_.min_support * total) drop[id] = 1;
        });
        std::size_t removed = 0;
        for (std::size_t id = 0; id < n; ++id)
            if (drop[id] && alive_[id]) alive_[id] = 0, ++removed;
        rebuild_cells();
        return removed;
    }

private:
    const DensifyOptions& o_;
    Eigen::Vector3d origin_;
    std::vector<PhotoCamera> local_;
    std::vector<View> views_;
    double z_lo_ = -1e300, z_hi_ = 1e300;  // allowed patch centre heights (local frame)
    std::vector<Patch> patches_;
    std::vector<uint8_t> alive_;
    std::vector<std::vector<std::vector<int>>> cells_;
};

// Seeds: SIFT matches between each image and its neighbours that satisfy the
// epipolar geometry, triangulated (linear, two views), in a fixed order.
std::vector<std::pair<Eigen::Vector3d, int>> feature_seeds(const std::vector<cv::Mat>& images, const Engine& e, int features) {
    const int n = e.view_count();
    std::vector<std::vector<cv::KeyPoint>> kps(static_cast<std::size_t>(n));
    std::vector<cv::Mat> desc(static_cast<std::size_t>(n));
    tbb::parallel_for(0, n, [&](int i) {
        auto sift = cv::SIFT::create(features);
        cv::Mat g;
        cv::cvtColor(images[static_cast<std::size_t>(i)], g, cv::COLOR_BGR2GRAY);
        sift->detectAndCompute(g, cv::noArray(), kps[static_cast<std::size_t>(i)], desc[static_cast<std::size_t>(i)]);
    });
    std::vector<std::pair<int, int>> pairs;
    for (int i = 0; i < n; ++i)
        for (int j : e.view(i).neighbours)
            if (j > i) pairs.push_back({i, j});
    std::vector<std::vector<std::pair<Eigen::Vector3d, int>>> per_pair(pairs.size());
    tbb::parallel_for(std::size_t(0), pairs.size(), [&](std::size_t k) {
        const int i = pairs[k].first, j = pairs[k].second;
        if (desc[static_cast<std::size_t>(i)].empty() || desc[static_cast<std::size_t>(j)].empty()) return;
        cv::BFMatcher matcher(cv::NORM_L2);
        std::vector<std::vector<cv::DMatch>> knn;
        matcher.knnMatch(desc[static_cast<std::size_t>(i)], desc[static_cast<std::size_t>(j)], knn, 2);
        const PhotoCamera& ci = *e.view(i).cam;
        const PhotoCamera& cj = *e.view(j).cam;
        Eigen::Matrix<double, 3, 4> Pi, Pj;
        Pi << ci.rotation, -ci.rotation * ci.centre;
        Pj << cj.rotation, -cj.rotation * cj.centre;
        Pi = ci.intrinsics() * Pi, Pj = cj.intrinsics() * Pj;
        for (const auto& m : knn) {
            if (m.size() < 2 || m[0].distance > 0.8f * m[1].distance) continue;
            const cv::Point2f a = kps[static_cast<std::size_t>(i)][static_cast<std::size_t>(m[0].queryIdx)].pt;
            const cv::Point2f b = kps[static_cast<std::size_t>(j)][static_cast<std::size_t>(m[0].trainIdx)].pt;
            Eigen::Matrix4d A;
            A.row(0) = a.x * Pi.row(2) - Pi.row(0);
            A.row(1) = a.y * Pi.row(2) - Pi.row(1);
            A.row(2) = b.x * Pj.row(2) - Pj.row(0);
            A.row(3) = b.y * Pj.row(2) - Pj.row(1);
            Eigen::JacobiSVD<Eigen::Matrix4d> svd(A, Eigen::ComputeFullV);
            const Eigen::Vector4d X = svd.matrixV().col(3);
            if (std::abs(X[3]) < 1e-12) continue;
            const Eigen::Vector3d x = X.head<3>() / X[3];
            const auto pa = ci.project(x), pb = cj.project(x);
            if (!pa || !pb) continue;
            if ((*pa - Eigen::Vector2d(a.x, a.y)).norm() > 1.5 || (*pb - Eigen::Vector2d(b.x, b.y)).norm() > 1.5) continue;
            per_pair[k].push_back({x, i});
        }
    });
    std::vector<std::pair<Eigen::Vector3d, int>> seeds;
    for (auto& v : per_pair) seeds.insert(seeds.end(), v.begin(), v.end());
    return seeds;
}

}  // namespace

DensifyResult densify_patches(const std::vector<cv::Mat>& images, const CameraSet& set,
                              const std::vector<Eigen::Vector3d>& sparse, const DensifyOptions& o,
                              const std::string& subject, const Progress& progress) {
    o.validate();
    if (images.size() < 2 || images.size() != set.cameras.size()) throw Error(subject, "densify needs at least two oriented images");
    for (std::size_t i = 0; i < images.size(); ++i)
        if (images[i].type() != CV_8UC3 || images[i].cols != set.cameras[i].width || images[i].rows != set.cameras[i].height)
            throw Error(subject, set.cameras[i].image + ": image does not match its camera (size or type)");
    Engine e(images, set, o);
    DensifyResult res;

    // Seeds from features, then the given sparse points (reference = the
    // camera that sees them closest to its centre).
    auto seeds = feature_seeds(images, e, o.seed_features);
    for (const Eigen::Vector3d& s : sparse) {
        const Eigen::Vector3d l = s - e.origin();
        int best = -1;
        double bd = 1e300;
        for (int i = 0; i < e.view_count(); ++i) {
            const auto px = e.view(i).cam->project(l);
            if (!px || !e.view(i).cam->inside(*px, o.patch_grid)) continue;
            const double d = (*px - Eigen::Vector2d(e.view(i).cam->cx, e.view(i).cam->cy)).norm();
            if (d < bd) bd = d, best = i;
        }
        if (best >= 0) seeds.push_back({l, best});
    }
    progress(0.1, std::to_string(seeds.size()) + " seeds");
    {
        std::vector<std::optional<Patch>> cand(seeds.size());
        tbb::parallel_for(std::size_t(0), seeds.size(), [&](std::size_t k) {
            const int ref = seeds[k].second;
            const Eigen::Vector3d n = (e.view(ref).cam->centre - seeds[k].first).normalized();
            cand[k] = e.optimise(seeds[k].first, n, ref);
        });
        for (auto& c : cand)
            if (c && e.commit(std::move(*c))) ++res.seeds;
    }
    if (res.seeds == 0) throw Error(subject, "no seed patch: the images do not overlap or have no texture");
    progress(0.2, std::to_string(res.seeds) + " seed patches");

    for (int iter = 0; iter < o.iterations; ++iter) {
        // Expansion fronts: all live patches first, then only the new ones.
        std::vector<int> front;
        for (std::size_t id = 0; id < e.patches().size(); ++id)
            if (e.alive()[id]) front.push_back(static_cast<int>(id));
        for (int step = 0; step < o.max_expansion_steps && !front.empty(); ++step) {
            std::vector<std::vector<Patch>> cand(front.size());
            tbb::parallel_for(std::size_t(0), front.size(), [&](std::size_t k) { cand[k] = e.expand(front[k]); });
            std::vector<int> next;
            for (auto& list : cand)
                for (Patch& p : list) {
                    const int id = static_cast<int>(e.patches().size());
                    if (e.commit(std::move(p))) next.push_back(id), ++res.expanded;
                }
            front.swap(next);
            // The fronts shrink as the cells fill: count the steps against a
            // horizon that grows with them (a guide, not a promise).
            const double within = double(step + 1) / double(step + 8);
            progress(0.2 + 0.8 * (iter + within) / o.iterations,
                     "round " + std::to_string(iter + 1) + "/" + std::to_string(o.iterations) + " step " + std::to_string(step + 1) + ": " +
                         std::to_string(e.patches().size()) + " patches, front " + std::to_string(front.size()));
        }
        res.filtered += e.filter();
        progress(0.2 + 0.8 * double(iter + 1) / o.iterations, "expand + filter");
    }

    // Output: each live patch as a small grid on its tangent plane covering
    // its reference cell, in map coordinates, colours from R(p).
    const int k = o.points_per_patch_side;
    for (std::size_t id = 0; id < e.patches().size(); ++id) {
        if (!e.alive()[id]) continue;
        const Patch& p = e.patches()[id];
        ++res.patches;
        const PhotoCamera& rc = *e.view(p.ref).cam;
        Eigen::Vector3d ax = rc.rotation.row(0).transpose();
        ax = (ax - ax.dot(p.n) * p.n).normalized();
        const Eigen::Vector3d ay = p.n.cross(ax).normalized();
        const double step = e.footprint(p.c, p.ref) * e.view(p.ref).cell / k;
        const cv::Mat& img = images[static_cast<std::size_t>(p.ref)];
        for (int a = 0; a < k; ++a)
            for (int b = 0; b < k; ++b) {
                const Eigen::Vector3d q = p.c + step * ((b - 0.5 * (k - 1)) * ax + (a - 0.5 * (k - 1)) * ay);
                const auto px = rc.project(q);
                if (!px) continue;
                const Eigen::Vector3d w = q + e.origin();
                const int u = std::clamp(static_cast<int>(std::lround(px->x())), 0, img.cols - 1);
                const int v = std::clamp(static_cast<int>(std::lround(px->y())), 0, img.rows - 1);
                const auto* bgr = img.ptr<uint8_t>(v) + 3 * u;
                append_photo_point(res.cloud, w, bgr, static_cast<uint16_t>(std::clamp((1.0 - p.g) * 65535.0, 0.0, 65535.0)));
            }
    }
    if (res.cloud.size() == 0) throw Error(subject, "no patch survived filtering: the images do not overlap or have no texture");
    progress(1.0, "done");
    return res;
}

}  // namespace cityforge::photo
