#include "segment/region_merging.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <queue>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "core/parallel.hpp"

namespace cityforge {

std::string to_string(QueueStrategy s) {
    switch (s) {
        case QueueStrategy::rag: return "rag";
        case QueueStrategy::nng: return "nng";
        case QueueStrategy::mutual: return "mutual";
    }
    return "mutual";
}

QueueStrategy queue_strategy_from_string(const std::string& s) {
    if (s == "rag") return QueueStrategy::rag;
    if (s == "nng") return QueueStrategy::nng;
    if (s == "mutual") return QueueStrategy::mutual;
    throw Error("--strategy", "must be rag, nng or mutual, not '" + s + "'");
}

void RegionMergingOptions::validate(int bands) const {
    if (scales.empty()) throw Error("--scales", "at least one scale is needed");
    for (std::size_t i = 0; i < scales.size(); ++i) {
        if (!(scales[i] > 0.0) || !std::isfinite(scales[i])) throw Error("--scales", "every scale must be > 0");
        if (i > 0 && !(scales[i] > scales[i - 1])) throw Error("--scales", "scales must be strictly increasing");
    }
    if (!(color_weight >= 0.0 && color_weight <= 1.0)) throw Error("--color-weight", "must be between 0 and 1");
    if (!(compactness >= 0.0 && compactness <= 1.0)) throw Error("--compactness", "must be between 0 and 1");
    if (!band_weights.empty() && static_cast<int>(band_weights.size()) != bands)
        throw Error("--band-weights", "has " + std::to_string(band_weights.size()) + " values but the image has " +
                                          std::to_string(bands) + " band(s)");
    double sum = 0.0;
    for (double w : band_weights) {
        if (!(w >= 0.0) || !std::isfinite(w)) throw Error("--band-weights", "weights must be finite and >= 0");
        sum += w;
    }
    if (!band_weights.empty() && sum <= 0.0) throw Error("--band-weights", "at least one weight must be > 0");
}

Image<uint32_t> relabel(const Image<uint32_t>& labels, const std::vector<uint32_t>& table) {
    Image<uint32_t> out(labels.width, labels.height, 1, 0u);
    const uint32_t* in = labels.band_data(0);
    uint32_t* o = out.band_data(0);
    parallel_for_each_index(labels.pixel_count(), [&](std::size_t i) { o[i] = table[in[i]]; });
    return out;
}

namespace {

__extension__ typedef __int128 int128;  // exact sums of squared fixed-point values

struct Neighbour {
    uint32_t id;
    double shared;  // boundary length in pixel edges
};

struct QueueEntry {
    double cost;
    uint32_t a, b;    // a < b
    uint32_t va, vb;  // versions of a and b when the cost was computed
    bool operator>(const QueueEntry& o) const {
        if (cost != o.cost) return cost > o.cost;
        if (a != o.a) return a > o.a;
        return b > o.b;
    }
};

class RegionGraph {
public:
    RegionGraph(const Image<float>& image, const Image<uint32_t>& labels, uint32_t n_regions, const RegionMergingOptions& o)
        : bands_(image.bands), n_(n_regions + 1), wc_(o.color_weight), wcmp_(o.compactness) {
        weights_.assign(bands_, 1.0 / bands_);
        if (!o.band_weights.empty()) {
            double s = 0.0;
            for (double w : o.band_weights) s += w;
            for (int b = 0; b < bands_; ++b) weights_[b] = o.band_weights[b] / s;
        }
        build(image, labels);
        for (auto& list : adj_) std::sort(list.begin(), list.end(), [](const Neighbour& p, const Neighbour& q) { return p.id < q.id; });
        alive_.assign(n_, 0);
        version_.assign(n_, 0);
        color_term_.assign(n_, 0.0);
        for (uint32_t r = 1; r < n_; ++r) {
            alive_[r] = area_[r] > 0;
            alive_count_ += alive_[r];
            color_term_[r] = color_term(r);
        }
        nn_.assign(n_, 0);
        nn_cost_.assign(n_, INFINITY);
    }

    // Region statistics and adjacency from the label raster, in parallel over
    // row blocks. Band values are accumulated as exact integers (fixed point,
    // 2^-k grey levels) so the totals do not depend on how rows were split
    // between threads: same labels and image -> same statistics, bit for bit.
    void build(const Image<float>& image, const Image<uint32_t>& labels) {
        const int w = labels.width, h = labels.height;
        const uint32_t* lab = labels.band_data(0);
        const float max_abs = tbb::parallel_reduce(
            tbb::blocked_range<std::size_t>(0, image.data.size(), 1 << 16), 0.0f,
            [&](const tbb::blocked_range<std::size_t>& r, float m) {
                for (std::size_t i = r.begin(); i != r.end(); ++i) m = std::max(m, std::abs(image.data[i]));
                return m;
            },
            [](float a, float b) { return std::max(a, b); });
        double fixed = 1.0;  // largest power of two keeping |v| * fixed <= 2^24
        while (max_abs * fixed * 2.0 <= 16777216.0 && fixed < 65536.0) fixed *= 2.0;
        while (max_abs * fixed > 16777216.0) fixed *= 0.5;
        const std::size_t nb = static_cast<std::size_t>(n_) * bands_;
        struct Partial {
            std::vector<int64_t> area, perimeter, sum;
            std::vector<int128> sumsq;
            std::vector<int> x0, y0, x1, y1;
            std::vector<std::pair<uint64_t, uint32_t>> pairs;  // (pair key, shared edges)
        };
        tbb::enumerable_thread_specific<Partial> partials([&] {
            Partial p;
            p.area.assign(n_, 0), p.perimeter.assign(n_, 0), p.sum.assign(nb, 0), p.sumsq.assign(nb, 0);
            p.x0.assign(n_, INT32_MAX), p.y0.assign(n_, INT32_MAX), p.x1.assign(n_, -1), p.y1.assign(n_, -1);
            return p;
        });
        tbb::parallel_for(tbb::blocked_range<int>(0, h, 64), [&](const tbb::blocked_range<int>& rows) {
            Partial& P = partials.local();
            for (int y = rows.begin(); y != rows.end(); ++y) {
                uint64_t last_down = 0;  // runs of the same vertical neighbour pair collapse into one entry
                for (int x = 0; x < w; ++x) {
                    const std::size_t i = static_cast<std::size_t>(y) * w + x;
                    const uint32_t a = lab[i];
                    if (!a) continue;
                    if (a >= n_) throw Error("region merging", "label " + std::to_string(a) + " exceeds the region count");
                    ++P.area[a];
                    for (int b = 0; b < bands_; ++b) {
                        const double v = image.band_data(b)[i] * fixed;  // round half away from zero
                        const auto q = static_cast<int64_t>(v + (v >= 0.0 ? 0.5 : -0.5));
                        P.sum[a * bands_ + b] += q;
                        P.sumsq[a * bands_ + b] += static_cast<int128>(q) * q;
                    }
                    P.x0[a] = std::min(P.x0[a], x), P.x1[a] = std::max(P.x1[a], x);
                    P.y0[a] = std::min(P.y0[a], y), P.y1[a] = std::max(P.y1[a], y);
                    const uint32_t left = x > 0 ? lab[i - 1] : 0, up = y > 0 ? lab[i - w] : 0;
                    const uint32_t right = x < w - 1 ? lab[i + 1] : 0, down = y < h - 1 ? lab[i + w] : 0;
                    P.perimeter[a] += (left != a) + (up != a) + (right != a) + (down != a);
                    if (right && right != a) P.pairs.push_back({key(a, right), 1});
                    if (down && down != a) {
                        const uint64_t k = key(a, down);
                        if (k == last_down && !P.pairs.empty() && P.pairs.back().first == k) ++P.pairs.back().second;
                        else P.pairs.push_back({k, 1});
                        last_down = k;
                    } else {
                        last_down = 0;
                    }
                }
            }
        });
        area_.assign(n_, 0.0), perimeter_.assign(n_, 0.0), sum_.assign(nb, 0.0), sumsq_.assign(nb, 0.0);
        x0_.assign(n_, INT32_MAX), y0_.assign(n_, INT32_MAX), x1_.assign(n_, -1), y1_.assign(n_, -1);
        std::vector<int64_t> area(n_, 0), perimeter(n_, 0), sum(nb, 0);
        std::vector<int128> sumsq(nb, 0);
        std::vector<std::pair<uint64_t, uint32_t>> pairs;
        for (Partial& P : partials) {
            for (uint32_t r = 0; r < n_; ++r) {
                area[r] += P.area[r], perimeter[r] += P.perimeter[r];
                x0_[r] = std::min(x0_[r], P.x0[r]), x1_[r] = std::max(x1_[r], P.x1[r]);
                y0_[r] = std::min(y0_[r], P.y0[r]), y1_[r] = std::max(y1_[r], P.y1[r]);
            }
            for (std::size_t k = 0; k < nb; ++k) sum[k] += P.sum[k], sumsq[k] += P.sumsq[k];
            pairs.insert(pairs.end(), P.pairs.begin(), P.pairs.end());
        }
        for (uint32_t r = 0; r < n_; ++r) area_[r] = static_cast<double>(area[r]), perimeter_[r] = static_cast<double>(perimeter[r]);
        for (std::size_t k = 0; k < nb; ++k) {
            sum_[k] = static_cast<double>(sum[k]) / fixed;
            sumsq_[k] = static_cast<double>(sumsq[k]) / (fixed * fixed);
        }
        tbb::parallel_sort(pairs.begin(), pairs.end());
        adj_.assign(n_, {});
        for (std::size_t k = 0; k < pairs.size();) {
            std::size_t e = k;
            uint32_t shared = 0;
            while (e < pairs.size() && pairs[e].first == pairs[k].first) shared += pairs[e++].second;
            const auto a = static_cast<uint32_t>(pairs[k].first >> 32), b = static_cast<uint32_t>(pairs[k].first & 0xFFFFFFFFu);
            adj_[a].push_back({b, double(shared)});
            adj_[b].push_back({a, double(shared)});
            k = e;
        }
    }

    static uint64_t key(uint32_t a, uint32_t b) {
        return a < b ? (uint64_t(a) << 32 | b) : (uint64_t(b) << 32 | a);
    }
    uint32_t size() const { return n_; }
    uint32_t alive_count() const { return alive_count_; }
    bool alive(uint32_t r) const { return alive_[r]; }
    uint32_t version(uint32_t r) const { return version_[r]; }
    const std::vector<Neighbour>& neighbours(uint32_t r) const { return adj_[r]; }

    // Σ_b w_b n σ_b of region r.
    double color_term(uint32_t r) const {
        const double n = area_[r];
        double t = 0.0;
        for (int b = 0; b < bands_; ++b) {
            const double m = sum_[r * bands_ + b] / n;
            const double var = std::max(0.0, sumsq_[r * bands_ + b] / n - m * m);
            t += weights_[b] * n * std::sqrt(var);
        }
        return t;
    }

    // Baatz–Schäpe fusion cost of a < b sharing `shared` pixel edges.
    double cost(uint32_t a, uint32_t b, double shared) const {
        const double na = area_[a], nb = area_[b], nm = na + nb;
        double hc = 0.0;
        for (int k = 0; k < bands_; ++k) {
            const double s = sum_[a * bands_ + k] + sum_[b * bands_ + k];
            const double q = sumsq_[a * bands_ + k] + sumsq_[b * bands_ + k];
            const double m = s / nm;
            hc += weights_[k] * nm * std::sqrt(std::max(0.0, q / nm - m * m));
        }
        hc -= color_term_[a] + color_term_[b];
        if (wc_ >= 1.0) return hc;
        const double la = perimeter_[a], lb = perimeter_[b], lm = la + lb - 2.0 * shared;
        const double bba = bbox_perimeter(a), bbb = bbox_perimeter(b);
        const double bbm = 2.0 * ((std::max(x1_[a], x1_[b]) - std::min(x0_[a], x0_[b]) + 1) +
                                  (std::max(y1_[a], y1_[b]) - std::min(y0_[a], y0_[b]) + 1));
        const double h_cmpct = lm * std::sqrt(nm) - (la * std::sqrt(na) + lb * std::sqrt(nb));
        const double h_smooth = nm * lm / bbm - (na * la / bba + nb * lb / bbb);
        return wc_ * hc + (1.0 - wc_) * (wcmp_ * h_cmpct + (1.0 - wcmp_) * h_smooth);
    }

    double pair_cost(uint32_t r, const Neighbour& k) const { return r < k.id ? cost(r, k.id, k.shared) : cost(k.id, r, k.shared); }

    // Nearest neighbour of r: lowest (cost, id).
    // Returns true when r's nearest neighbour or its cost changed.
    bool update_nn(uint32_t r) {
        const uint32_t old = nn_[r];
        const double old_cost = nn_cost_[r];
        uint32_t best = 0;
        double best_cost = INFINITY;
        for (const Neighbour& k : adj_[r]) {
            const double c = pair_cost(r, k);
            if (c < best_cost || (c == best_cost && k.id < best)) best = k.id, best_cost = c;
        }
        nn_[r] = best;
        nn_cost_[r] = best_cost;
        return best != old || best_cost != old_cost;
    }
    // Makes `candidate` r's nearest neighbour if it beats the current one on (cost, id).
    bool offer_candidate(uint32_t r, uint32_t candidate, double c) {
        if (c < nn_cost_[r] || (c == nn_cost_[r] && candidate < nn_[r])) {
            nn_[r] = candidate, nn_cost_[r] = c;
            return true;
        }
        return false;
    }
    uint32_t nn(uint32_t r) const { return nn_[r]; }
    double nn_cost(uint32_t r) const { return nn_cost_[r]; }

    // Merges b into a (a < b). Returns a.
    uint32_t merge(uint32_t a, uint32_t b) {
        double shared = 0.0;
        for (const Neighbour& k : adj_[a])
            if (k.id == b) shared = k.shared;
        area_[a] += area_[b];
        for (int k = 0; k < bands_; ++k) {
            sum_[a * bands_ + k] += sum_[b * bands_ + k];
            sumsq_[a * bands_ + k] += sumsq_[b * bands_ + k];
        }
        perimeter_[a] = perimeter_[a] + perimeter_[b] - 2.0 * shared;
        x0_[a] = std::min(x0_[a], x0_[b]), x1_[a] = std::max(x1_[a], x1_[b]);
        y0_[a] = std::min(y0_[a], y0_[b]), y1_[a] = std::max(y1_[a], y1_[b]);
        color_term_[a] = color_term(a);
        // Union of the two sorted neighbour lists, without a and b.
        std::vector<Neighbour> merged;
        merged.reserve(adj_[a].size() + adj_[b].size());
        auto ia = adj_[a].begin(), ib = adj_[b].begin();
        while (ia != adj_[a].end() || ib != adj_[b].end()) {
            if (ib == adj_[b].end() || (ia != adj_[a].end() && ia->id < ib->id)) merged.push_back(*ia++);
            else if (ia == adj_[a].end() || ib->id < ia->id) merged.push_back(*ib++);
            else merged.push_back({ia->id, ia->shared + ib->shared}), ++ia, ++ib;
        }
        merged.erase(std::remove_if(merged.begin(), merged.end(), [&](const Neighbour& k) { return k.id == a || k.id == b; }),
                     merged.end());
        // Neighbours of b now border a instead.
        for (const Neighbour& k : adj_[b]) {
            if (k.id == a) continue;
            auto& list = adj_[k.id];
            double len = 0.0;
            list.erase(std::remove_if(list.begin(), list.end(), [&](const Neighbour& q) {
                           if (q.id == b) len = q.shared;
                           return q.id == b;
                       }),
                       list.end());
            auto it = std::lower_bound(list.begin(), list.end(), a, [](const Neighbour& q, uint32_t id) { return q.id < id; });
            if (it != list.end() && it->id == a) it->shared += len;
            else list.insert(it, {a, len});
        }
        adj_[a] = std::move(merged);
        adj_[b].clear();
        adj_[b].shrink_to_fit();
        alive_[b] = 0;
        --alive_count_;
        ++version_[a];
        ++version_[b];
        return a;
    }

    // Invariants of the graph: totals over alive regions equal the totals of
    // the initial regions, adjacency is symmetric with equal shared lengths.
    void verify(const std::vector<double>& totals) const {
        std::vector<double> now(totals.size(), 0.0);
        for (uint32_t r = 1; r < n_; ++r) {
            if (!alive_[r]) {
                if (!adj_[r].empty()) throw Error("region merging", "dead region " + std::to_string(r) + " still has neighbours");
                continue;
            }
            now[0] += area_[r];
            for (int b = 0; b < bands_; ++b) now[1 + b] += sum_[r * bands_ + b], now[1 + bands_ + b] += sumsq_[r * bands_ + b];
            for (const Neighbour& k : adj_[r]) {
                if (!alive_[k.id]) throw Error("region merging", "region " + std::to_string(r) + " borders a dead region");
                const auto& other = adj_[k.id];
                const auto it = std::lower_bound(other.begin(), other.end(), r, [](const Neighbour& q, uint32_t id) { return q.id < id; });
                if (it == other.end() || it->id != r || it->shared != k.shared)
                    throw Error("region merging", "adjacency of " + std::to_string(r) + " and " + std::to_string(k.id) + " is not symmetric");
            }
        }
        for (std::size_t i = 0; i < totals.size(); ++i)
            if (std::abs(now[i] - totals[i]) > 1e-9 * std::max(1.0, std::abs(totals[i])))
                throw Error("region merging", "region statistics no longer add up to the image totals");
    }
    std::vector<double> totals() const {
        std::vector<double> t(1 + 2 * static_cast<std::size_t>(bands_), 0.0);
        for (uint32_t r = 1; r < n_; ++r) {
            if (!alive_[r]) continue;
            t[0] += area_[r];
            for (int b = 0; b < bands_; ++b) t[1 + b] += sum_[r * bands_ + b], t[1 + bands_ + b] += sumsq_[r * bands_ + b];
        }
        return t;
    }

private:
    double bbox_perimeter(uint32_t r) const { return 2.0 * ((x1_[r] - x0_[r] + 1) + (y1_[r] - y0_[r] + 1)); }

    int bands_;
    uint32_t n_;
    double wc_, wcmp_;
    std::vector<double> weights_;
    std::vector<double> area_, perimeter_, sum_, sumsq_, color_term_;
    std::vector<int> x0_, y0_, x1_, y1_;
    std::vector<std::vector<Neighbour>> adj_;
    std::vector<uint8_t> alive_;
    std::vector<uint32_t> version_;
    std::vector<uint32_t> nn_;
    std::vector<double> nn_cost_;
    uint32_t alive_count_ = 0;
};

using Heap = std::priority_queue<QueueEntry, std::vector<QueueEntry>, std::greater<QueueEntry>>;

}  // namespace

RegionMergingResult merge_regions(const Image<float>& image, const Image<uint32_t>& labels, uint32_t region_count,
                                  const RegionMergingOptions& o, const Progress& progress) {
    o.validate(image.bands);
    if (labels.width != image.width || labels.height != image.height)
        throw Error("region merging", "label raster and image differ in size");
    RegionMergingResult result;
    const auto t_graph = std::chrono::steady_clock::now();
    RegionGraph g(image, labels, region_count, o);
    const uint32_t n = g.size();
    for (uint32_t r = 1; r < n; ++r) result.adjacent_pairs += g.neighbours(r).size();
    result.adjacent_pairs /= 2;
    std::vector<uint32_t> uf(n);  // absorbed region -> survivor (union-find)
    for (uint32_t r = 0; r < n; ++r) uf[r] = r;
    auto find = [&](uint32_t x) {
        while (uf[x] != x) x = uf[x] = uf[uf[x]];
        return x;
    };
    const bool uses_nn = o.strategy != QueueStrategy::rag;
    if (uses_nn)
        for (uint32_t r = 1; r < n; ++r)
            if (g.alive(r)) g.update_nn(r);

    result.graph_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_graph).count();
    const std::vector<double> initial_totals = o.verify_invariants ? g.totals() : std::vector<double>{};
    std::vector<uint32_t> previous_compact(n, 0);  // survivor id -> label at previous level
    {
        for (uint32_t r = 1; r < n; ++r) previous_compact[r] = g.alive(r) ? r : 0;
    }
    uint32_t previous_count = region_count;
    for (std::size_t s = 0; s < o.scales.size(); ++s) {
        const auto t0 = std::chrono::steady_clock::now();
        const double threshold = o.scales[s] * o.scales[s];
        ScaleLevel level;
        level.scale = o.scales[s];
        level.regions_before = g.alive_count();
        Heap heap;
        auto push_pair = [&](uint32_t a, uint32_t b, double c) {
            if (a > b) std::swap(a, b);
            heap.push({c, a, b, g.version(a), g.version(b)});
            ++level.queue_pushes;
        };
        // Pushes r's nearest-neighbour pair if the strategy queues it.
        auto offer_nn = [&](uint32_t r) {
            const uint32_t k = g.nn(r);
            if (!k || !(g.nn_cost(r) < threshold)) return;
            if (o.strategy == QueueStrategy::mutual && g.nn(k) != r) return;
            push_pair(r, k, g.nn_cost(r));
        };
        for (uint32_t r = 1; r < n; ++r) {
            if (!g.alive(r)) continue;
            if (o.strategy == QueueStrategy::rag) {
                for (const Neighbour& k : g.neighbours(r))
                    if (k.id > r) push_pair(r, k.id, g.cost(r, k.id, k.shared));
            } else if (o.strategy == QueueStrategy::nng || g.nn(r) > r) {
                offer_nn(r);  // mutual pairs are offered once, from their lower id
            }
        }
        level.initial_queue_length = heap.size();
        std::vector<uint32_t> changed;
        while (!heap.empty()) {
            const QueueEntry e = heap.top();
            heap.pop();
            if (!g.alive(e.a) || !g.alive(e.b) || g.version(e.a) != e.va || g.version(e.b) != e.vb) continue;
            if (!(e.cost < threshold)) break;  // rag holds every pair: the cheapest is too dear
            const uint32_t m = g.merge(e.a, e.b);
            uf[e.b] = m;
            ++level.merges;
            if (o.strategy == QueueStrategy::rag) {
                for (const Neighbour& k : g.neighbours(m)) push_pair(m, k.id, g.pair_cost(m, k));
            } else {
                g.update_nn(m);
                // A neighbour's costs changed only towards m: rescan it fully only
                // when its nearest neighbour was one of the merged pair. Only
                // regions whose nearest neighbour changed need a (new) queue
                // entry: an unchanged pair keeps its valid entry, since its cost
                // can only change through a merge of one of its regions.
                changed.clear();
                for (const Neighbour& k : g.neighbours(m)) {
                    // A neighbour that pointed at the merged pair always needs a
                    // fresh entry: its old one carries the pair's old versions.
                    bool moved = true;
                    if (g.nn(k.id) == e.a || g.nn(k.id) == e.b) g.update_nn(k.id);
                    else moved = g.offer_candidate(k.id, m, g.pair_cost(k.id, {m, k.shared}));
                    if (moved) changed.push_back(k.id);
                }
                offer_nn(m);
                for (uint32_t k : changed) offer_nn(k);
            }
        }
        level.regions_after = g.alive_count();
        if (o.verify_invariants) g.verify(initial_totals);
        // Contiguous labels of this level in ascending survivor id; hierarchy links.
        std::vector<uint32_t> compact(n, 0);
        uint32_t next = 0;
        for (uint32_t r = 1; r < n; ++r)
            if (g.alive(r)) compact[r] = ++next;
        level.label_of_input.assign(n, 0);
        for (uint32_t r = 1; r < n; ++r) level.label_of_input[r] = compact[find(r)];
        level.parent.assign(previous_count + 1, 0);
        for (uint32_t r = 1; r < n; ++r)
            if (previous_compact[r]) level.parent[previous_compact[r]] = compact[find(r)];
        previous_compact = compact;
        previous_count = next;
        level.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        result.levels.push_back(std::move(level));
        progress(double(s + 1) / double(o.scales.size()), "merging");
    }
    return result;
}

Image<uint32_t> segment_at_scale(const Image<float>& image, const std::vector<uint8_t>& valid, const WatershedOptions& watershed,
                                 double scale, uint32_t& count, const Progress& progress) {
    const Oversegmentation over = watershed_oversegment(image, valid, watershed, progress.sub(0.0, 0.6));
    count = 0;
    if (over.region_count == 0) return over.labels;
    RegionMergingOptions rmo;
    rmo.scales = {scale};
    rmo.band_weights = watershed.band_weights;
    const RegionMergingResult merged = merge_regions(image, over.labels, over.region_count, rmo, progress.sub(0.6, 1.0));
    count = merged.levels[0].regions_after;
    return relabel(over.labels, merged.levels[0].label_of_input);
}

}  // namespace cityforge
