#include "audit/cloud_compare.hpp"

#include <algorithm>
#include <cmath>
#include <tbb/parallel_for.h>

#include "cloud/kd_tree.hpp"
#include "core/error.hpp"

namespace cityforge {
namespace {

// Nearest distance from every point of `from` to `to`.
std::vector<double> nearest(const LocalPoints& from, const LocalPoints& to) {
    PointTree tree(3, to, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    tree.buildIndex();
    const std::size_t n = from.kdtree_get_point_count();
    std::vector<double> d(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8192), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
            uint32_t idx = 0;
            float d2 = 0.0f;
            tree.knnSearch(&from.xyz[3 * i], 1, &idx, &d2);
            d[i] = std::sqrt(static_cast<double>(d2));
        }
    });
    return d;
}

double quantile(std::vector<double> v, double q) {
    const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(q * double(v.size())));
    std::nth_element(v.begin(), v.begin() + k, v.end());
    return v[k];
}

}  // namespace

CloudComparison compare_clouds(const PointCloud& pred, const PointCloud& ref, const std::vector<double>& taus, double histogram_max,
                                int histogram_bins) {
    if (pred.size() == 0) throw Error("cloud audit", "predicted cloud is empty");
    if (ref.size() == 0) throw Error("cloud audit", "reference cloud is empty");
    for (double t : taus)
        if (!(t > 0)) throw Error("--tau", "every tau must be > 0");
    // A common local origin keeps float coordinates exact to ~0.1 mm over 10 km.
    const double ox = ref.x[0], oy = ref.y[0], oz = ref.z[0];
    const LocalPoints a = local_points(pred, ox, oy, oz), b = local_points(ref, ox, oy, oz);
    const std::vector<double> da = nearest(a, b), db = nearest(b, a);
    CloudComparison c;
    c.predicted_points = pred.size(), c.reference_points = ref.size();
    // Sums in index order: the result does not depend on the thread count.
    double sa = 0, sb = 0, qa = 0, qb = 0;
    for (double d : da) sa += d, qa += d * d;
    for (double d : db) sb += d, qb += d * d;
    c.mean_pred_to_ref = sa / double(da.size());
    c.mean_ref_to_pred = sb / double(db.size());
    c.chamfer = c.mean_pred_to_ref + c.mean_ref_to_pred;
    c.chamfer_squared = qa / double(da.size()) + qb / double(db.size());
    c.median_pred_to_ref = quantile(da, 0.5), c.p95_pred_to_ref = quantile(da, 0.95);
    c.median_ref_to_pred = quantile(db, 0.5), c.p95_ref_to_pred = quantile(db, 0.95);
    if (!(histogram_max > 0)) histogram_max = taus.empty() ? 1.0 : 2.0 * *std::max_element(taus.begin(), taus.end());
    histogram_bins = std::max(1, histogram_bins);
    c.histogram_max = histogram_max;
    auto histogram = [&](const std::vector<double>& d) {
        std::vector<uint64_t> h(histogram_bins, 0);
        for (double x : d) ++h[std::min<std::size_t>(histogram_bins - 1, static_cast<std::size_t>(x / histogram_max * histogram_bins))];
        return h;
    };
    c.histogram_pred_to_ref = histogram(da), c.histogram_ref_to_pred = histogram(db);
    for (double t : taus) {
        CloudFScore s;
        s.tau = t;
        s.precision = double(std::count_if(da.begin(), da.end(), [t](double d) { return d <= t; })) / double(da.size());
        s.recall = double(std::count_if(db.begin(), db.end(), [t](double d) { return d <= t; })) / double(db.size());
        s.f_score = s.precision + s.recall > 0 ? 2 * s.precision * s.recall / (s.precision + s.recall) : 0.0;
        c.scores.push_back(s);
    }
    return c;
}

}  // namespace cityforge
