#include "audit/footprint_match.hpp"

#include <algorithm>
#include <cmath>
#include <tbb/parallel_for.h>

#include "footprint/rectangle_fit.hpp"

namespace cityforge {
namespace {

// Intersection area of two multipolygons whose parts do not overlap among themselves.
double multi_intersection(const std::vector<Polygon>& a, const std::vector<Polygon>& b) {
    double inter = 0.0;
    for (const Polygon& p : a)
        for (const Polygon& q : b) {
            const double iou = polygon_iou(p, q);
            if (iou > 0) {
                const double ap = polygon_area(p), aq = polygon_area(q);
                inter += iou * (ap + aq) / (1.0 + iou);  // iou = i / (ap + aq - i)
            }
        }
    return inter;
}

// Mean over the vertices of `from` of the distance to the nearest boundary of `to`.
double mean_vertex_distance(const std::vector<Polygon>& from, const std::vector<Polygon>& to) {
    double sum = 0.0;
    std::size_t n = 0;
    auto ring = [&](const Ring& r) {
        for (const MapPoint& v : r) {
            double best = INFINITY;
            for (const Polygon& q : to) best = std::min(best, distance_to_boundary(q, v.x, v.y));
            sum += best, ++n;
        }
    };
    for (const Polygon& p : from) {
        ring(p.outer);
        for (const Ring& h : p.holes) ring(h);
    }
    return n ? sum / double(n) : 0.0;
}

}  // namespace

double polis_distance(const std::vector<Polygon>& a, const std::vector<Polygon>& b) {
    return 0.5 * mean_vertex_distance(a, b) + 0.5 * mean_vertex_distance(b, a);
}

FootprintScores match_footprints(const std::vector<std::vector<Polygon>>& pred, const std::vector<std::vector<Polygon>>& ref,
                                 double threshold) {
    struct Candidate {
        double iou;
        std::size_t p, r;
    };
    std::vector<Extent> pe(pred.size()), re(ref.size());
    for (std::size_t i = 0; i < pred.size(); ++i) pe[i] = parts_extent(pred[i]);
    for (std::size_t i = 0; i < ref.size(); ++i) re[i] = parts_extent(ref[i]);
    std::vector<std::vector<Candidate>> per_pred(pred.size());
    std::vector<double> inter_of_pred(pred.size(), 0.0);
    tbb::parallel_for(std::size_t(0), pred.size(), [&](std::size_t p) {
        const double ap = parts_area(pred[p]);
        for (std::size_t r = 0; r < ref.size(); ++r) {
            if (pe[p].max_x < re[r].min_x || re[r].max_x < pe[p].min_x || pe[p].max_y < re[r].min_y || re[r].max_y < pe[p].min_y) continue;
            const double inter = multi_intersection(pred[p], ref[r]);
            inter_of_pred[p] += inter;
            const double uni = ap + parts_area(ref[r]) - inter;
            const double iou = uni > 0 ? std::min(1.0, inter / uni) : 0.0;
            if (iou >= threshold) per_pred[p].push_back({iou, p, r});
        }
    });
    std::vector<Candidate> all;
    for (const auto& v : per_pred) all.insert(all.end(), v.begin(), v.end());
    std::sort(all.begin(), all.end(), [](const Candidate& a, const Candidate& b) {
        if (a.iou != b.iou) return a.iou > b.iou;
        return a.p != b.p ? a.p < b.p : a.r < b.r;
    });
    std::vector<uint8_t> pu(pred.size(), 0), ru(ref.size(), 0);
    FootprintScores s;
    s.predicted = pred.size(), s.reference = ref.size();
    for (const Candidate& c : all) {
        if (pu[c.p] || ru[c.r]) continue;
        pu[c.p] = ru[c.r] = 1;
        const double ar = parts_area(ref[c.r]);
        s.matches.push_back({c.p, c.r, c.iou, ar > 0 ? (parts_area(pred[c.p]) - ar) / ar * 100.0 : 0.0, polis_distance(pred[c.p], ref[c.r])});
    }
    std::sort(s.matches.begin(), s.matches.end(), [](const FootprintMatch& a, const FootprintMatch& b) { return a.reference < b.reference; });
    s.true_positives = s.matches.size();
    s.precision = pred.empty() ? 0.0 : double(s.true_positives) / double(pred.size());
    s.recall = ref.empty() ? 0.0 : double(s.true_positives) / double(ref.size());
    const std::size_t union_count = pred.size() + ref.size() - s.true_positives;
    s.object_quality = union_count ? double(s.true_positives) / double(union_count) : 0.0;
    s.f1 = s.precision + s.recall > 0 ? 2 * s.precision * s.recall / (s.precision + s.recall) : 0.0;
    for (const FootprintMatch& m : s.matches)
        s.mean_iou += m.iou, s.mean_abs_area_error_pct += std::abs(m.area_error_pct), s.mean_polis += m.polis;
    if (s.true_positives) {
        const double n = double(s.true_positives);
        s.mean_iou /= n, s.mean_abs_area_error_pct /= n, s.mean_polis /= n;
    }
    double inter = 0.0, area_pred = 0.0, area_ref = 0.0;
    for (std::size_t p = 0; p < pred.size(); ++p) inter += inter_of_pred[p], area_pred += parts_area(pred[p]);
    for (const auto& r : ref) area_ref += parts_area(r);
    inter = std::min({inter, area_pred, area_ref});  // rounding must not push the ratios above 1
    s.area_completeness = area_ref > 0 ? inter / area_ref : 0.0;
    s.area_correctness = area_pred > 0 ? inter / area_pred : 0.0;
    s.area_quality = area_pred + area_ref - inter > 0 ? inter / (area_pred + area_ref - inter) : 0.0;
    return s;
}

}  // namespace cityforge
