#include "core/statistics.hpp"

#include <algorithm>
#include <cmath>

namespace cityforge {

std::optional<double> percentile(std::vector<double>& v, double p) {
    if (v.empty()) return std::nullopt;
    std::sort(v.begin(), v.end());
    const double pos = p / 100.0 * static_cast<double>(v.size() - 1);
    const auto lo = static_cast<std::size_t>(std::floor(pos));
    const std::size_t hi = std::min(lo + 1, v.size() - 1);
    return v[lo] + (v[hi] - v[lo]) * (pos - static_cast<double>(lo));
}

std::optional<TrimmedPlane> fit_trimmed_plane(const std::vector<std::array<double, 3>>& q, const TrimmedPlaneOptions& o) {
    TrimmedPlane pl;
    pl.inlier.assign(q.size(), 1);
    std::vector<uint8_t>& use = pl.inlier;
    std::vector<double> res(q.size()), kept;
    for (int iter = 0; iter < o.iterations; ++iter) {
        double n = 0, mx = 0, my = 0, mz = 0;
        for (std::size_t i = 0; i < q.size(); ++i)
            if (use[i]) n += 1, mx += q[i][0], my += q[i][1], mz += q[i][2];
        if (n < static_cast<double>(std::max<std::size_t>(o.min_points, 3))) return std::nullopt;
        mx /= n, my /= n, mz /= n;
        double sxx = 0, sxy = 0, syy = 0, sxz = 0, syz = 0;
        for (std::size_t i = 0; i < q.size(); ++i)
            if (use[i]) {
                const double dx = q[i][0] - mx, dy = q[i][1] - my, dz = q[i][2] - mz;
                sxx += dx * dx, sxy += dx * dy, syy += dy * dy, sxz += dx * dz, syz += dy * dz;
            }
        // Spread across the narrowest direction: the smaller eigenvalue of the xy covariance.
        const double tr = (sxx + syy) / n, det = (sxx * syy - sxy * sxy) / (n * n);
        const double lmin = 0.5 * tr - std::sqrt(std::max(0.0, 0.25 * tr * tr - det));
        if (!(lmin > o.min_spread_sq)) return std::nullopt;
        const double d = sxx * syy - sxy * sxy;
        pl.a = (sxz * syy - syz * sxy) / d, pl.b = (syz * sxx - sxz * sxy) / d;
        pl.c = mz - pl.a * mx - pl.b * my;
        for (std::size_t i = 0; i < q.size(); ++i) res[i] = std::abs(q[i][2] - (pl.a * q[i][0] + pl.b * q[i][1] + pl.c));
        kept.clear();
        for (std::size_t i = 0; i < q.size(); ++i)
            if (use[i]) kept.push_back(res[i]);
        const double mad = *percentile(kept, 50.0);
        const double lim = std::max(o.min_trim, o.trim_sigmas * 1.4826 * mad);
        bool changed = false;
        for (std::size_t i = 0; i < q.size(); ++i) {
            const uint8_t u = res[i] <= lim;
            changed = changed || u != use[i];
            use[i] = u;
        }
        if (!changed && iter > 0) break;
    }
    return pl;
}

}  // namespace cityforge
