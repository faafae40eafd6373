#pragma once
// The photogrammetric subcommands joined to files: `stereo` (one oriented
// pair to a dense LAS), `orient` (COLMAP as the engine, our georeferencing),
// `densify` (patch-based MVS from an oriented folder) and `photo` (the chain).
// Images are read with OpenCV; outputs are LAS 1.4 with RGB in the cameras' CRS.
#include <string>

#include "core/progress.hpp"
#include "crs/crs.hpp"
#include "photo/densify.hpp"
#include "photo/stereo.hpp"
#include "photo/orthophoto.hpp"
#include "photo/true_ortho.hpp"
#include "pipeline/city_run.hpp"

namespace cityforge {

struct StereoRunOptions {
    std::string left_path, right_path;  ///< image files; their file names must be in the cameras file
    std::string cameras_path;           ///< cameras JSON (cameras_truth.json of synth, cameras.json of orient)
    std::string out_path;               ///< LAS 1.4 output
    bool overwrite = false;             ///< replace an existing output
    photo::StereoOptions stereo;
    void validate() const;
};

struct StereoRunResult {
    uint64_t points = 0;
    double baseline_m = 0, seconds = 0;
    int min_disparity_px = 0, num_disparities_px = 0;
    std::size_t matched_pixels = 0, lr_rejected = 0;
    std::string crs;
};

/// Reads both images and their cameras, matches the pair, writes the cloud.
/// Throws Error (one line naming the file) on bad input; writes nothing then.
StereoRunResult run_stereo(const StereoRunOptions& options, const Progress& progress = {});

/// Refuses to replace `path` unless `overwrite` (Error naming the file).
void check_output_free(const std::string& path, bool overwrite);

}  // namespace cityforge

namespace cityforge {

struct OrientRunOptions {
    std::string images_dir;          ///< JPEG/PNG/TIFF photos (at least two)
    std::string out_dir;             ///< created; must not exist unless overwrite
    std::string camera_path;         ///< optional K.txt (3 x 3 camera matrix, pixels of the original images)
    std::string gps = "exif";        ///< "exif" or a file of lines "image lat_deg lon_deg height_m"
    std::string crs;                 ///< output CRS (projected, metres); empty = UTM zone of the site
    /// Vertical CRS of the GPS heights: "EPSG:5773" (EGM96 height; EXIF's
    /// GPSAltitude is "above sea level", as drones and receivers report it),
    /// any vertical CRS PROJ knows, or "ellipsoid" (heights above the WGS 84
    /// ellipsoid, e.g. RTK logs). The outputs' heights are in the vertical
    /// CRS of `crs` when it has one, else in this one ("ellipsoid": EGM96,
    /// through PROJ's geoid grid); every output names it.
    std::string gps_height_crs = "EPSG:5773";
    int max_image_px = 2000;         ///< photos are downscaled to this longest side before matching
    int threads = 2;                 ///< threads of feature extraction and matching (the output does not depend on it)
    int max_features = 4096;         ///< SIFT features per image (COLMAP's SiftExtraction.max_num_features)
    /// "exhaustive" (every pair; best for small blocks) or "sequential" (each
    /// photo with the next `sequential_overlap` in file-name order = flight order).
    std::string matcher = "exhaustive";
    int sequential_overlap = 6;      ///< photos after each one that it is matched with (sequential matcher)
    std::string colmap = "colmap";   ///< the COLMAP executable
    bool overwrite = false;
    void validate() const;
};

/// The CRS of the GPS positions (lon/lat with the vertical CRS of
/// `gps_height_crs`; EPSG:4979 for "ellipsoid") and the output CRS (`crs`, or
/// the UTM zone of `lat_deg`/`lon_deg`; its vertical part when it has one,
/// else the GPS heights' vertical CRS, EGM96 for ellipsoidal heights).
/// Throws Error naming the option when either cannot be used (a geographic
/// output CRS, a height CRS that is not vertical).
struct GpsFrames {
    CrsInfo gps, out;
};
GpsFrames gps_frames(const OrientRunOptions& o, double lat_deg, double lon_deg);

struct OrientImageResidual {
    std::string image;
    double dx_m = 0, dy_m = 0, dz_m = 0;  ///< oriented minus GPS position, map axes
};

struct OrientRunResult {
    int images = 0, oriented = 0;
    uint64_t sparse_points = 0;
    double mean_reprojection_error_px = 0;
    double gps_rmse_m = 0;            ///< of the camera centres after the similarity fit
    double scale = 0;                 ///< model units -> metres
    std::vector<OrientImageResidual> residuals;
    std::string crs;
    double seconds = 0;
    std::string cameras_path, sparse_path, report_path, images_dir;
};

/// Orients the photos with COLMAP (SIFT on the CPU; our deterministic
/// brute-force matching of its features, which COLMAP verifies; incremental
/// mapping with bundle adjustment in one thread; undistortion) and
/// georeferences the model by a similarity to the GPS positions in the output
/// CRS. The same photos and options give the same bytes whatever `threads`. Writes
/// OUT/images/ (undistorted, possibly downscaled), OUT/cameras.json,
/// OUT/sparse.las, OUT/orient_report.json, OUT/colmap/ (work files and log).
/// All or nothing: the folder appears only when every step succeeded.
OrientRunResult run_orient(const OrientRunOptions& options, const Progress& progress = {});

}  // namespace cityforge


namespace cityforge {

struct DensifyRunOptions {
    /// An oriented folder: cameras.json + images/ (+ sparse.las) from `orient`,
    /// or a folder with cameras_truth.json and the images (synth's views/).
    std::string model_dir;
    std::string out_path;   ///< LAS 1.4 output (RGB, class 1, cameras' CRS)
    bool overwrite = false;
    bool use_sparse = true;  ///< also seed from model_dir/sparse.las when present
    photo::DensifyOptions densify;
    void validate() const;
};

struct DensifyRunResult {
    uint64_t points = 0;
    std::size_t seeds = 0, expanded = 0, filtered = 0;
    int images = 0;
    std::string crs;
    double seconds = 0;
};

/// Reads the oriented folder, densifies, writes the cloud. All or nothing.
DensifyRunResult run_densify(const DensifyRunOptions& options, const Progress& progress = {});

struct PhotoRunOptions {
    OrientRunOptions orient;       ///< images_dir, camera, gps, crs, max_image_px; out_dir = OUT/orient
    photo::DensifyOptions densify;
    std::string out_dir;           ///< OUT
    bool overwrite = false;
    /// An oriented folder of `orient` (or an earlier OUT/orient) to start from:
    /// orientation is skipped and its report reused; empty = orient the images.
    std::string oriented_dir;
    /// Also run the building chain (`run`) on the dense cloud: OUT/ortho.tif
    /// (true ortho from the cloud) and OUT/run/ (DSM, footprints, heights, LOD2).
    bool run = false;
    double ortho_gsd_m = 0.25;     ///< cell of OUT/ortho.tif, metres (the run's grid)
    photo::TrueOrthoOptions ortho;
    photo::OrthophotoOptions orthophoto;  ///< OUT/orthophoto.tif: colours from the photos on the cloud's surface
    /// The run's ortho: "photos" (OUT/orthophoto.tif) or "cloud" (OUT/ortho.tif, the cloud's own colours).
    std::string run_ortho = "photos";
    RunOptions city;               ///< the run's options; ortho and cloud are set by the chain
    void validate() const;
};

struct PhotoRunResult {
    OrientRunResult orient;
    DensifyRunResult densify;
    std::string cloud_path, sparse_path, cameras_path, report_path;
    std::string ortho_path, orthophoto_path, run_dir;  ///< empty without `run`
    photo::OrthophotoStats orthophoto;                 ///< cells measured, filled, coloured, occluded
    RunReport city;                   ///< the run's report (with `run`)
    double ortho_seconds = 0, orthophoto_seconds = 0;
    double seconds = 0;
};

/// The orientation result recorded in an oriented folder (orient_report.json).
/// Throws Error naming the folder when it is not one.
OrientRunResult read_orient_folder(const std::string& dir);

/// The chain: orient -> densify [-> true ortho -> run]. Writes OUT/orient/
/// (oriented folder), OUT/cameras.json, OUT/sparse.las, OUT/cloud.las,
/// OUT/photo_report.json, and with `run` OUT/ortho.tif (the cloud's colours),
/// OUT/orthophoto.tif (the photos' colours) and OUT/run/.
/// All or nothing: on an error OUT is removed.
PhotoRunResult run_photo(const PhotoRunOptions& options, const Progress& progress = {});

}  // namespace cityforge
