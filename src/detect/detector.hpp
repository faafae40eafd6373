#pragma once
// A learned building detector: segments of our segmentation, their features
// (segment_features.hpp) and a gradient-boosted classifier (booster.hpp),
// stored with the options, feature list, expected bands, a fingerprint of
// the training data and its cross-validation figures in one checksummed
// file. Pure algorithm and file format; no GDAL.
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/progress.hpp"
#include "detect/booster.hpp"
#include "detect/pixel_classifier.hpp"
#include "detect/segment_features.hpp"

namespace cityforge::detect {

/// Instance separation from building cores (off unless core_threshold > 0):
/// a second pixel-stage CNN, on cells of `cell_m`, maps the probability
/// that a pixel is a building *core* (labelled and at least `core_depth_m`
/// from every unlabelled pixel, so touching labels' cores are apart); the
/// cores (4-connected pixels of the building mask whose core probability
/// reaches core_threshold, at least min_core_m2) are grown back over the
/// building mask, most core-like pixels first, and buildings are cut
/// where two cores' growths meet (split_at_cores).
struct InstanceOptions {
    double core_threshold = 0.0;  ///< 0 = off; else in (0, 1) (the training command picks it by cross-validation)
    double core_depth_m = 1.0;    ///< core target: labelled pixels at least this far (metres) from an unlabelled one
    double min_core_m2 = 2.0;     ///< smaller cores are no building of their own
    double cell_m = 0.5;          ///< the core CNN's working cell, metres (1 pixel at 0.5 m)
    /// false: buildings are cut where two cores' growths meet (pixels);
    /// true: each building segment joins the core holding most of its
    /// pixels and buildings are cut between segments of different cores
    /// (outlines stay on segment boundaries). Header key only when true.
    bool by_segments = false;
    CnnOptions cnn;               ///< the core CNN
    bool enabled() const { return core_threshold > 0.0; }
    void validate() const;
    /// The pixel-stage options the core CNN trains and predicts with.
    PixelClassifierOptions pixel_options() const;
};

/// Everything that decides what a model learns and how it is applied.
struct DetectorOptions {
    DetectorSegmentationOptions segmentation;
    BoosterOptions booster;
    /// The pixel stage whose building-probability map adds segment features
    /// (models without it, e.g. older files, have enabled = false).
    PixelClassifierOptions pixel;
    /// A training segment is "building" when at least this share of its
    /// pixels lies inside the labels.
    double min_label_share = 0.5;
    /// Segments whose probability is at least this are building (the
    /// training command picks it by cross-validation unless fixed).
    double threshold = 0.5;
    /// How building segments become buildings: 0 = connected components of
    /// their pixels; l >= 1 = building pixels in different regions of
    /// context scale l are kept apart (cut along a one-pixel line), so
    /// touching roofs the merging saw as different objects stay separate
    /// (the training command picks it by cross-validation).
    int object_split_level = 0;
    /// Small or dark buildings the segments miss: pixels whose pixel-stage
    /// building probability reaches this join the building pixels (in
    /// segments below `threshold`); 0 = off (the training command picks it
    /// by cross-validation when the model has a pixel stage).
    double pixel_object_threshold = 0.0;
    /// > 0: building segments are grouped into buildings by the model's
    /// pair classifier (segment_merge.hpp): adjacent building segments whose
    /// "same building" probability reaches this are one building, the others
    /// are cut apart along a one-pixel line (replaces object_split_level);
    /// 0 = off (the training command picks it by cross-validation).
    double merge_threshold = 0.0;
    /// > 0: touching buildings joined by a neck narrower than about twice
    /// this (metres) are cut apart (split_at_necks: cores left by an erosion
    /// of this radius, grown back over the building pixels); 0 = off (the
    /// training command picks it by cross-validation).
    double neck_split_m = 0.0;
    /// > 0: map-guided first segments (split_segments_by_map): each
    /// 4-connected piece of a first-scale segment where the pixel stage's
    /// map is at or above this becomes a segment of its own (a segment
    /// straddling a small roof and its yard is split along the map's level
    /// set) before features, classes and objects; needs the pixel stage;
    /// 0 = off. Header key "map_split" only when on (older models keep
    /// their bytes).
    double map_split_threshold = 0.0;
    /// Pieces (and what they leave of their segment) smaller than this,
    /// square metres of ground, stay in the segment.
    double map_split_min_m2 = 4.0;
    /// Instance separation from the core CNN (off by default; header key
    /// "instance" only when on, so older models keep their bytes).
    InstanceOptions instance;
    double min_area_m2 = 8.0;  ///< building components smaller than this are dropped
    double min_hole_m2 = 6.0;  ///< holes smaller than this are filled
    void validate(int bands) const;
};

/// Brings one band of linear sensor counts (a source deeper than 8 bits:
/// UInt16 WorldView pan, ...) to a display-like tone before the per-band
/// normalisation: its square root (about the gamma 8-bit imagery already
/// carries), so dark roofs and tree shadows are not squeezed into a few grey
/// levels by the few bright pixels. Negative values become 0.
void encode_linear_counts(Image<float>& image, int band);

/// The bands a model expects, in the image's order (alpha bands are masks,
/// never counted): "pan" (1), "RGB" (3), "RGB+NIR" (4), or "N bands".
std::string describe_bands(const BandLayout& layout);

struct DetectorModel {
    BandLayout layout;
    std::vector<std::string> features;  ///< column names, feature_names(layout, context levels)
    DetectorOptions options;
    std::string fingerprint;            ///< hash of the training images, labels and options (hex)
    nlohmann::json training;            ///< sources, sample counts, per-fold figures (free form, recorded as given)
    std::vector<uint8_t> booster;       ///< XGBoost UBJSON model
    std::vector<uint8_t> pixel_model; ///< pixel model (options.pixel.enabled): XGBoost UBJSON, or CFCNN1 weights for kind cnn; else empty
    /// Pair ("same building") classifier, XGBoost UBJSON on pair_feature_names
    /// (options.merge_threshold > 0; else empty).
    std::vector<uint8_t> merge_model;
    /// Core CNN weights (CFCNN1, options.instance.enabled(); else empty).
    std::vector<uint8_t> core_model;
};

/// The model's bytes: "CFDET1\n", then header JSON, booster, the pixel
/// model when the model has a pixel stage (format_version 2; 3 when it has a
/// CNN), the pair classifier when options.merge_threshold > 0 (the header
/// then holds "merge_features") and an FNV-1a checksum, each length-prefixed; the same model gives the same bytes.
std::vector<uint8_t> serialize_model(const DetectorModel& model);
/// Parses bytes from serialize_model. Throws Error naming `subject` when the
/// magic, a length or the checksum is wrong (truncated or corrupt file) or
/// the header is incomplete.
DetectorModel parse_model(const std::vector<uint8_t>& bytes, const std::string& subject);
DetectorModel read_model_file(const std::string& path);
/// Written to a temporary sibling and renamed (never half-written).
void write_model_file(const std::string& path, const DetectorModel& model);

/// Throws a one-line Error naming `image` when its bands are not the ones
/// the model was trained on.
void check_bands(const DetectorModel& model, const BandLayout& image_layout, const std::string& image);

/// DetectorOptions::map_split_threshold applied to `segments` (nothing
/// when off or without a map): `pixel_map` per pixel, `gsd_m` the image's
/// ground sample distance in metres. Returns how many segments were added.
std::size_t apply_map_split(SceneSegments& segments, const DetectorOptions& options, const std::vector<float>* pixel_map, double gsd_m);

/// Building probability of every segment (index = label, 0 unused).
std::vector<float> segment_probabilities(const DetectorModel& model, const FeatureMatrix& features, int threads = 0);

/// Building pixels (1) of the segments whose probability reaches the
/// model's threshold (w x h of the labels); with `split_level` >= 1 the
/// pixels where two regions of context scale `split_level` meet are left
/// out (see DetectorOptions::object_split_level).
/// With `pixel_probability` (per pixel, or null) and `pixel_threshold` > 0,
/// pixels of the other segments whose pixel probability reaches it are
/// building too (DetectorOptions::pixel_object_threshold).
/// With `groups` (building object per segment, merge_groups) building
/// pixels of different groups are cut apart instead of the split level's regions.
std::vector<uint8_t> building_pixels(const SceneSegments& segments, const std::vector<float>& probability, double threshold,
                                     int split_level = 0, const std::vector<float>* pixel_probability = nullptr, double pixel_threshold = 0.0,
                                     const std::vector<uint32_t>* groups = nullptr);

/// Instance separation of a building mask (w x h, 1 = building): the cores
/// left by an erosion of `radius_px` (chessboard distance to the nearest
/// non-building pixel above it) of at least `min_core_px` pixels are grown
/// back over the building pixels (breadth first, 4-neighbours, cores in
/// raster order), and a building pixel whose right or lower neighbour was
/// reached from another core leaves the mask: a one-pixel cut at each neck
/// narrower than about 2 * radius_px + 1 between two cores. Pixels no core
/// reaches (parts thinner than the erosion) stay as they are. radius_px <= 0
/// returns the mask unchanged.
std::vector<uint8_t> split_at_necks(const std::vector<uint8_t>& building, int w, int h, int radius_px, int min_core_px);
/// split_at_necks with the model's DetectorOptions::neck_split_m on an image
/// of `gsd_m` metres (cores of at least 3 m2); unchanged when it is 0.
std::vector<uint8_t> split_at_necks(std::vector<uint8_t> building, int w, int h, const DetectorOptions& options, double gsd_m);

/// Instance separation of a building mask (w x h, 1 = building) by a core
/// probability map (w x h, 0..1): markers are the 4-connected building
/// pixels with core probability >= `threshold` (components of at least
/// `min_core_px`), grown over the building pixels in order of decreasing
/// core probability (4-neighbours; ties in raster order of arrival), and a
/// building pixel whose right or lower neighbour belongs to another marker
/// leaves the mask (a one-pixel cut). Pixels no marker reaches stay.
std::vector<uint8_t> split_at_cores(const std::vector<uint8_t>& building, int w, int h, const std::vector<float>& core, double threshold,
                                    int min_core_px);
/// The core instance (1-based; 0 = none) of every pixel: the markers and
/// growth of split_at_cores, before any cut.
std::vector<uint32_t> core_instances(const std::vector<uint8_t>& building, int w, int h, const std::vector<float>& core, double threshold,
                                     int min_core_px);

/// The building pixels of a detection with every object rule of the model's
/// options: building_pixels (threshold, split level or pair groups, pixel
/// map), the core instances when InstanceOptions::by_segments, the neck
/// split, then split_at_cores (pixel cuts). `pixel_map`, `groups`, `core_map`
/// may be null (not computed).
std::vector<uint8_t> object_pixels(const SceneSegments& segments, const std::vector<float>& probability, const DetectorOptions& options,
                                   const std::vector<float>* pixel_map, const std::vector<uint32_t>* groups, const std::vector<float>* core_map,
                                   double gsd_m);

/// split_at_cores with the model's InstanceOptions on an image of `gsd_m`
/// metres; unchanged when the instance stage is off or `core` is null.
std::vector<uint8_t> split_at_cores(std::vector<uint8_t> building, int w, int h, const std::vector<float>* core, const DetectorOptions& options,
                                    double gsd_m);

/// The whole detection on one image: segmentation with the model's options,
/// features, probabilities and building pixels. `normalised` = bands scaled
/// 0..255 (normalize_bands) in the model's band order.
struct Detection {
    SceneSegments segments;
    std::vector<float> pixel_probability;  ///< per pixel, 0..1 (models with a pixel stage; else empty)
    std::vector<float> core_probability;   ///< per pixel, 0..1 (models with the instance stage; else empty)
    std::vector<float> probability;  ///< per segment (index = label)
    std::vector<uint32_t> groups;    ///< building object per segment (merge_groups; empty without the pair classifier)
    std::vector<uint8_t> building;   ///< per pixel
};
Detection detect_buildings(const DetectorModel& model, const Image<float>& normalised, const std::vector<uint8_t>& valid, double gsd_m,
                           int threads = 0, const Progress& progress = {});

/// FNV-1a 64-bit hash, continued from `h` (for fingerprints).
uint64_t fnv1a64(const void* data, std::size_t n, uint64_t h = 0xcbf29ce484222325ULL);
std::string hex64(uint64_t v);

nlohmann::json to_json(const DetectorOptions& o);
DetectorOptions detector_options_from_json(const nlohmann::json& j);

}  // namespace cityforge::detect
