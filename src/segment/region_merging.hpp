#pragma once
// Heap-queue hierarchical region merging with the Baatz–Schäpe heterogeneity
// criterion (the multiresolution segmentation of eCognition), three queue
// strategies and a multi-scale hierarchy. No GDAL; pixel units.
//
// Cost of merging regions i and j into m (n = area in pixels, σ_b = standard
// deviation of band b, l = perimeter in pixel edges, b = bounding-box perimeter):
//   h_color  = Σ_b w_b [ n_m σ_m,b − (n_i σ_i,b + n_j σ_j,b) ]
//   h_cmpct  = n_m l_m/√n_m − (n_i l_i/√n_i + n_j l_j/√n_j)
//   h_smooth = n_m l_m/b_m  − (n_i l_i/b_i  + n_j l_j/b_j)
//   h_shape  = w_cmpct h_cmpct + (1 − w_cmpct) h_smooth
//   f        = w_color h_color + (1 − w_color) h_shape
// A pair may merge while f < scale². Band weights are normalised to sum to 1.
//
// Merge order: always the pair with the lowest (f, min id, max id) among all
// adjacent pairs, so the result is one well-defined sequence. The strategies
// differ only in what the priority queue holds:
//  - rag:    every adjacent pair (lazy invalidation by region versions);
//  - nng:    each region's nearest neighbour (its lowest-cost neighbour, ties
//            by lower id), one entry per region with f < scale²;
//  - mutual: only pairs (i, j) where j is i's nearest neighbour AND i is j's
//            nearest neighbour AND f < scale². The globally cheapest pair is
//            always mutually nearest, so popping the cheapest mutual pair gives
//            exactly the rag merge sequence with a much shorter queue.
// After each merge the nearest neighbours of the merged region and of all its
// neighbours are recomputed; new mutual pairs among them are pushed.
#include <cstdint>
#include <string>
#include <vector>

#include "core/image.hpp"
#include "core/progress.hpp"
#include "segment/watershed.hpp"

namespace cityforge {

enum class QueueStrategy { rag, nng, mutual };
std::string to_string(QueueStrategy s);
/// "rag", "nng" or "mutual"; throws Error otherwise.
QueueStrategy queue_strategy_from_string(const std::string& s);

struct RegionMergingOptions {
    std::vector<double> scales{500, 1000, 1500, 2000, 2500, 3000};  ///< strictly increasing, > 0
    double color_weight = 0.9;     ///< w_color in [0, 1]; shape weight = 1 − w_color
    double compactness = 0.5;      ///< w_cmpct in [0, 1] within the shape term
    std::vector<double> band_weights;  ///< one per band (empty = equal)
    QueueStrategy strategy = QueueStrategy::mutual;
    /// Stop merging once this many regions remain (0 = no limit): the merge
    /// sequence is the same, only cut short, so every strategy still gives
    /// the same labels. Used to match another tool's final region count.
    uint32_t min_regions = 0;
    /// After every scale, check that region statistics still add up to the
    /// image totals (area, band sums and sums of squares) and that adjacency
    /// is symmetric; throws Error if not. For tests and debugging (O(regions)).
    bool verify_invariants = false;
    /// Throws Error naming the option on bad values (`bands` = image band count).
    void validate(int bands) const;
};

/// Result of one scale of the hierarchy.
struct ScaleLevel {
    double scale = 0.0;
    uint32_t regions_before = 0;
    uint32_t regions_after = 0;
    uint64_t initial_queue_length = 0;  ///< queue entries when the scale started
    uint64_t merges = 0;
    uint64_t queue_pushes = 0;          ///< all pushes during the scale (initial included)
    uint32_t max_degree = 0;            ///< most neighbours of a region formed during the scale
    double seconds = 0.0;               ///< wall time of the scale
    double cpu_seconds = 0.0;           ///< CPU time of the merging thread (less sensitive to machine load)
    /// Label at this scale (1..regions_after) of every over-segmentation
    /// region (index = input label, entry 0 = 0). Use relabel() for a raster.
    std::vector<uint32_t> label_of_input;
    /// parent[k] = label at this scale of region k (1-based) of the previous
    /// level (the over-segmentation for the first scale); parent[0] = 0.
    std::vector<uint32_t> parent;
};

struct RegionMergingResult {
    double graph_seconds = 0.0;   ///< building the region graph (statistics + adjacency)
    double graph_cpu_seconds = 0.0;  ///< the same in CPU seconds of the whole process (all threads)
    uint64_t adjacent_pairs = 0;  ///< edges of the initial region adjacency graph
    std::vector<ScaleLevel> levels;
};

/// Label raster of one level: table[input label] per pixel.
Image<uint32_t> relabel(const Image<uint32_t>& labels, const std::vector<uint32_t>& table);

/// Merges the regions of `labels` (1..N, 0 = nodata, never merged) over
/// `image` (any band count, same size) through every scale. Deterministic:
/// the same input gives the same labels for every strategy.
RegionMergingResult merge_regions(const Image<float>& image, const Image<uint32_t>& labels, uint32_t region_count,
                                  const RegionMergingOptions& options, const Progress& progress = {});

/// One level of segmentation: watershed over-segmentation of `image`
/// (normalised bands; `valid` may be empty), then merging at `scale` with the
/// watershed's band weights. Returns segments 1..count in raster order of
/// first appearance (0 = invalid pixels).
Image<uint32_t> segment_at_scale(const Image<float>& image, const std::vector<uint8_t>& valid, const WatershedOptions& watershed,
                                 double scale, uint32_t& count, const Progress& progress = {});

}  // namespace cityforge
