#pragma once
// Deterministic SIFT matching on the features COLMAP extracted into its
// database.db: brute-force nearest neighbours (COLMAP's ratio, distance and
// cross-check rules), pairs in a fixed order, parallel over pairs with the
// results kept per pair, so the matches are the same bytes whatever the
// thread count. COLMAP's own CPU matcher builds FLANN's randomised kd-trees
// from the unseeded C rand() and matches differ by 1-2 per pair from run to
// run. The matches go back to COLMAP through `colmap matches_importer`
// (write_colmap_match_list). No GDAL; sqlite3 reads the database.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/progress.hpp"

namespace cityforge::photo {

/// One image's SIFT features as COLMAP stored them.
struct ImageFeatures {
    int image_id = 0;                  ///< COLMAP's image_id
    std::string name;                  ///< image name in the database (relative to the image folder)
    int width = 0, height = 0;         ///< image size, pixels (of its camera)
    std::size_t count = 0;             ///< number of keypoints (= descriptors)
    std::vector<float> xy;             ///< keypoint positions, pixels (COLMAP's: pixel centres at +0.5), x0 y0 x1 y1 ...
    std::vector<float> scale;          ///< keypoint scale (SIFT sigma), pixels; 0 when the database has none
    std::vector<uint8_t> descriptors;  ///< count x 128, row-major (COLMAP's L1-root SIFT, length ~512)
};

/// Reads every image's keypoints and descriptors from COLMAP's database.db,
/// ordered by image_id. Throws Error naming the file when it cannot be read,
/// has no images, or a descriptor is not 128 bytes.
std::vector<ImageFeatures> read_colmap_features(const std::string& database_path);

/// Gives the images of COLMAP's database.db the ids 1..n in the byte order of
/// their names (with their keypoints and descriptors). COLMAP's feature
/// extractor numbers images in the order its threads finish them, which
/// varies from run to run, and the mapper visits images by id. Call it before
/// any matches are stored; throws Error naming the file on a database error
/// or when matches exist.
void renumber_colmap_images(const std::string& database_path);

/// The matching rules (COLMAP's SiftMatching defaults).
struct FeatureMatchOptions {
    double max_ratio = 0.8;     ///< best / second-best angular distance must be below this
    double max_distance = 0.7;  ///< angular distance of the best neighbour at most this, radians
    bool cross_check = true;    ///< keep only mutual best neighbours
    /// Keypoints closer to the image edge than border_margin_px +
    /// border_margin_sigma * scale are not matched. COLMAP's CPU SIFT (VLFeat)
    /// returns early for a keypoint on the last row of its octave and leaves
    /// its descriptor uninitialised memory: different bytes from run to run.
    double border_margin_px = 1.0;
    double border_margin_sigma = 1.5;  ///< see border_margin_px
    void validate() const;
};

/// Whether feature `k` of `f` lies far enough from the image edge to be
/// matched (see FeatureMatchOptions::border_margin_px). True when the size is unknown.
bool matchable_feature(const ImageFeatures& f, std::size_t k, const FeatureMatchOptions& options);

/// Matches of one image pair: indices of features in image `first` and `second`.
struct PairMatches {
    int first = 0, second = 0;  ///< indices into the feature list (not image ids)
    std::vector<std::pair<uint32_t, uint32_t>> matches;
};

/// Every pair (i, j), i < j, of `n` images, in row order.
std::vector<std::pair<int, int>> exhaustive_pairs(int n);

/// Each image with the next `overlap` in list order (i, i + 1 .. i + overlap).
std::vector<std::pair<int, int>> sequential_pairs(int n, int overlap);

/// Mutual nearest neighbours of two descriptor sets (count x 128 each) by
/// exact dot products, as COLMAP's brute-force CPU matcher decides them (ties
/// go to the lower index; a tie for best fails the ratio test). Matches are
/// ordered by the index in the first set.
std::vector<std::pair<uint32_t, uint32_t>> match_descriptors(const uint8_t* first, std::size_t first_count,
                                                             const uint8_t* second, std::size_t second_count,
                                                             const FeatureMatchOptions& options);

/// Matches every pair in `pairs` (matchable features only; parallel over pairs with TBB; each pair's
/// result is independent of the others, so the output does not depend on the
/// thread count). The result is in the order of `pairs`.
std::vector<PairMatches> match_image_pairs(const std::vector<ImageFeatures>& features, const std::vector<std::pair<int, int>>& pairs,
                                           const FeatureMatchOptions& options, const Progress& progress = {});

/// Writes the matches in the match-list format of `colmap matches_importer`
/// ("name1 name2" then one "idx1 idx2" line per match, a blank line between
/// pairs). Pairs without matches are left out. Throws Error on a write error
/// or an image name with white space (the importer cannot read it).
void write_colmap_match_list(const std::string& path, const std::vector<ImageFeatures>& features,
                             const std::vector<PairMatches>& matches);

}  // namespace cityforge::photo
