#include "roof/roof_planes.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>

#include "cloud/kd_tree.hpp"
#include "core/error.hpp"
#include "roof/roof_planes_cgal.hpp"

namespace cityforge {

std::string to_string(PlaneDetector d) {
    switch (d) {
        case PlaneDetector::region_growing: return "region_growing";
        case PlaneDetector::cgal_region_growing: return "cgal_region_growing";
        case PlaneDetector::cgal_ransac: return "cgal_ransac";
    }
    return "region_growing";
}

PlaneDetector plane_detector_from_string(const std::string& s, const std::string& option) {
    for (PlaneDetector d : {PlaneDetector::region_growing, PlaneDetector::cgal_region_growing, PlaneDetector::cgal_ransac})
        if (s == to_string(d)) return d;
    throw Error(option, "unknown plane detector '" + s + "' (region_growing, cgal_region_growing, cgal_ransac)");
}

void RoofPlaneOptions::validate() const {
    if (!(distance_tolerance_m > 0)) throw Error("--plane-distance-m", "must be > 0");
    if (!(normal_tolerance_deg > 0 && normal_tolerance_deg < 90)) throw Error("--plane-normal-deg", "must be in (0, 90)");
    if (min_points < 3) throw Error("--plane-min-points", "must be >= 3");
    if (k_neighbours < 3) throw Error("--plane-neighbours", "must be >= 3");
    if (!(merge_angle_deg >= 0) || !(merge_distance_m >= 0)) throw Error("plane merging", "tolerances must be >= 0");
    if (!(max_slope_deg > 0 && max_slope_deg < 90)) throw Error("--max-roof-slope-deg", "must be in (0, 90)");
}

namespace {
constexpr double kPi = 3.14159265358979323846;
double deg(double r) { return r * 180.0 / kPi; }
}  // namespace

RoofPlane fit_roof_plane(const std::vector<std::array<double, 3>>& p, std::vector<uint32_t> idx) {
    RoofPlane pl;
    if (idx.size() < 3) return pl;
    // Centred normal equations: well conditioned in local metres.
    double mx = 0, my = 0, mz = 0;
    for (uint32_t i : idx) mx += p[i][0], my += p[i][1], mz += p[i][2];
    const double n = double(idx.size());
    mx /= n, my /= n, mz /= n;
    Eigen::Matrix2d A = Eigen::Matrix2d::Zero();
    Eigen::Vector2d r = Eigen::Vector2d::Zero();
    for (uint32_t i : idx) {
        const double dx = p[i][0] - mx, dy = p[i][1] - my, dz = p[i][2] - mz;
        A(0, 0) += dx * dx, A(0, 1) += dx * dy, A(1, 1) += dy * dy;
        r(0) += dx * dz, r(1) += dy * dz;
    }
    A(1, 0) = A(0, 1);
    const Eigen::Vector2d ab = A.ldlt().solve(r);
    pl.a = std::isfinite(ab(0)) ? ab(0) : 0.0, pl.b = std::isfinite(ab(1)) ? ab(1) : 0.0;
    pl.c = mz - pl.a * mx - pl.b * my;
    double s2 = 0;
    for (uint32_t i : idx) {
        const double d = p[i][2] - pl.z(p[i][0], p[i][1]);
        s2 += d * d;
    }
    pl.rmse_m = std::sqrt(s2 / n);
    pl.slope_deg = deg(std::atan(std::hypot(pl.a, pl.b)));
    // Downhill direction (-a, -b) as a compass bearing.
    pl.azimuth_deg = pl.slope_deg < 1e-6 ? 0.0 : std::fmod(deg(std::atan2(-pl.a, -pl.b)) + 360.0, 360.0);
    std::sort(idx.begin(), idx.end());
    pl.points = std::move(idx);
    return pl;
}

std::vector<RoofPlane> detect_roof_planes(const std::vector<std::array<double, 3>>& p, const RoofPlaneOptions& o) {
    o.validate();
    const std::size_t n = p.size();
    if (n < static_cast<std::size_t>(o.min_points)) return {};
    LocalPoints lp;
    lp.xyz.resize(3 * n);
    for (std::size_t i = 0; i < n; ++i)
        for (int d = 0; d < 3; ++d) lp.xyz[3 * i + d] = static_cast<float>(p[i][d]);
    PointTree tree(3, lp, nanoflann::KDTreeSingleIndexAdaptorParams(10));
    tree.buildIndex();
    const std::size_t k = std::min<std::size_t>(static_cast<std::size_t>(o.k_neighbours), n);
    std::vector<uint32_t> nbr(n * k);
    std::vector<Eigen::Vector3d> normal(n);
    std::vector<double> curvature(n);
    std::vector<float> d2(k);
    for (std::size_t i = 0; i < n; ++i) {
        tree.knnSearch(&lp.xyz[3 * i], k, &nbr[i * k], d2.data());
        Eigen::Vector3d m = Eigen::Vector3d::Zero();
        for (std::size_t j = 0; j < k; ++j) m += Eigen::Vector3d(p[nbr[i * k + j]][0], p[nbr[i * k + j]][1], p[nbr[i * k + j]][2]);
        m /= double(k);
        Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
        for (std::size_t j = 0; j < k; ++j) {
            const Eigen::Vector3d d = Eigen::Vector3d(p[nbr[i * k + j]][0], p[nbr[i * k + j]][1], p[nbr[i * k + j]][2]) - m;
            C += d * d.transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
        Eigen::Vector3d nv = es.eigenvectors().col(0);
        if (nv.z() < 0) nv = -nv;
        normal[i] = nv;
        const double sum = es.eigenvalues().sum();
        curvature[i] = sum > 0 ? es.eigenvalues()(0) / sum : 0.0;
    }
    std::vector<std::vector<uint32_t>> segments;
    if (o.detector != PlaneDetector::region_growing) {
        segments = cgal_plane_segments(p, normal, o, o.detector == PlaneDetector::cgal_ransac);
    } else {
    std::vector<uint32_t> order(n);
    std::iota(order.begin(), order.end(), 0u);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return curvature[a] != curvature[b] ? curvature[a] < curvature[b] : a < b; });
    const double cos_tol = std::cos(o.normal_tolerance_deg * kPi / 180.0);
    std::vector<int> label(n, -1);
    for (uint32_t seed : order) {
        if (label[seed] >= 0) continue;
        if (normal[seed].z() < std::cos(o.max_slope_deg * kPi / 180.0)) continue;  // wall-like seed
        const int id = static_cast<int>(segments.size());
        std::vector<uint32_t> members{seed}, queue{seed};
        label[seed] = id;
        Eigen::Vector3d pn = normal[seed];
        Eigen::Vector3d pc(p[seed][0], p[seed][1], p[seed][2]);
        std::size_t next_refit = 8;
        for (std::size_t q = 0; q < queue.size(); ++q) {
            const uint32_t i = queue[q];
            for (std::size_t j = 0; j < k; ++j) {
                const uint32_t c = nbr[i * k + j];
                if (label[c] >= 0) continue;
                if (std::abs(normal[c].dot(pn)) < cos_tol) continue;
                const double dist = std::abs((Eigen::Vector3d(p[c][0], p[c][1], p[c][2]) - pc).dot(pn));
                if (dist > o.distance_tolerance_m) continue;
                label[c] = id;
                members.push_back(c), queue.push_back(c);
            }
            if (members.size() >= next_refit) {
                // Refit the segment's plane (PCA) as it grows: the seed's normal is noisy.
                Eigen::Vector3d m = Eigen::Vector3d::Zero();
                for (uint32_t a : members) m += Eigen::Vector3d(p[a][0], p[a][1], p[a][2]);
                m /= double(members.size());
                Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
                for (uint32_t a : members) {
                    const Eigen::Vector3d d = Eigen::Vector3d(p[a][0], p[a][1], p[a][2]) - m;
                    C += d * d.transpose();
                }
                Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
                pn = es.eigenvectors().col(0);
                if (pn.z() < 0) pn = -pn;
                pc = m;
                next_refit = members.size() * 2;
            }
        }
        if (members.size() < static_cast<std::size_t>(o.min_points)) {
            for (uint32_t a : members) label[a] = -2;  // too small: stays unassigned for good
            segments.emplace_back();
            continue;
        }
        segments.push_back(std::move(members));
    }
    }
    std::vector<RoofPlane> planes;
    for (auto& s : segments)
        if (!s.empty()) {
            RoofPlane pl = fit_roof_plane(p, s);
            if (pl.slope_deg <= o.max_slope_deg) planes.push_back(std::move(pl));
        }
    // Merge adjacent near-coplanar planes (greedy, largest first, repeated until stable).
    auto plane_normal = [](const RoofPlane& pl) { return Eigen::Vector3d(-pl.a, -pl.b, 1.0).normalized(); };
    const double cos_merge = std::cos(o.merge_angle_deg * kPi / 180.0);
    bool merged = true;
    while (merged) {
        merged = false;
        std::sort(planes.begin(), planes.end(), [](const RoofPlane& a, const RoofPlane& b) {
            return a.points.size() != b.points.size() ? a.points.size() > b.points.size() : a.points.front() < b.points.front();
        });
        std::vector<int> owner(n, -1);
        for (std::size_t i = 0; i < planes.size(); ++i)
            for (uint32_t a : planes[i].points) owner[a] = static_cast<int>(i);
        for (std::size_t i = 0; i < planes.size() && !merged; ++i)
            for (std::size_t j = i + 1; j < planes.size() && !merged; ++j) {
                if (plane_normal(planes[i]).dot(plane_normal(planes[j])) < cos_merge) continue;
                // Adjacent: some point of j has a neighbour in i.
                bool adjacent = false;
                for (uint32_t a : planes[j].points) {
                    for (std::size_t t = 0; t < k && !adjacent; ++t) adjacent = owner[nbr[a * k + t]] == static_cast<int>(i);
                    if (adjacent) break;
                }
                if (!adjacent) continue;
                double dist = 0;
                for (uint32_t a : planes[j].points) dist += std::abs(p[a][2] - planes[i].z(p[a][0], p[a][1]));
                dist /= double(planes[j].points.size());
                if (dist > o.merge_distance_m) continue;
                std::vector<uint32_t> all = planes[i].points;
                all.insert(all.end(), planes[j].points.begin(), planes[j].points.end());
                planes[i] = fit_roof_plane(p, std::move(all));
                planes.erase(planes.begin() + static_cast<std::ptrdiff_t>(j));
                merged = true;
            }
    }
    std::sort(planes.begin(), planes.end(), [](const RoofPlane& a, const RoofPlane& b) {
        return a.points.size() != b.points.size() ? a.points.size() > b.points.size() : a.points.front() < b.points.front();
    });
    return planes;
}

}  // namespace cityforge
