#include "pipeline/photo_run.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <functional>
#include <gdal_priv.h>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <spawn.h>
#include <sstream>
#include <csignal>
#include <sys/wait.h>
#include <unistd.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <tbb/task_arena.h>

#include "cloud/las.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "crs/crs.hpp"
#include "photo/camera.hpp"
#include "photo/colmap_model.hpp"
#include "photo/feature_matching.hpp"
#include "raster/raster.hpp"

namespace cityforge {

namespace fs = std::filesystem;

void check_output_free(const std::string& path, bool overwrite) {
    if (!overwrite && fs::exists(path)) throw Error(path, "exists (give --overwrite to replace it)");
}

void StereoRunOptions::validate() const {
    if (left_path.empty() || right_path.empty()) throw Error("stereo", "give --left and --right images");
    if (cameras_path.empty()) throw Error("--cameras", "give the cameras file of the images");
    if (out_path.empty()) throw Error("--out", "give the output LAS file");
    stereo.validate();
}

namespace {

cv::Mat read_colour_image(const std::string& path) {
    if (!fs::exists(path)) throw Error(path, "no such image");
    cv::Mat m = cv::imread(path, cv::IMREAD_COLOR);
    if (m.empty()) throw Error(path, "not an image OpenCV can read");
    return m;
}

void write_cloud_las(const std::string& path, const PointCloud& cloud, const std::string& wkt, const std::string& software) {
    double ox = 0, oy = 0;
    if (cloud.size()) ox = std::floor(cloud.x[0] / 1000) * 1000, oy = std::floor(cloud.y[0] / 1000) * 1000;
    LasWriter w(path, {0.001, 0.001, 0.001}, {ox, oy, 0.0}, wkt, software);
    w.write(cloud);
    w.close();
}

}  // namespace

StereoRunResult run_stereo(const StereoRunOptions& o, const Progress& progress) {
    o.validate();
    const auto t0 = std::chrono::steady_clock::now();
    check_output_free(o.out_path, o.overwrite);
    const photo::CameraSet set = photo::read_cameras_json(o.cameras_path);
    const std::string lname = fs::path(o.left_path).filename().string(), rname = fs::path(o.right_path).filename().string();
    const photo::PhotoCamera& cl = set.cameras[set.find(lname, o.cameras_path)];
    const photo::PhotoCamera& cr = set.cameras[set.find(rname, o.cameras_path)];
    if (lname == rname) throw Error(o.right_path, "left and right are the same image");
    const cv::Mat left = read_colour_image(o.left_path), right = read_colour_image(o.right_path);
    if (left.cols != cl.width || left.rows != cl.height)
        throw Error(o.left_path, "image is " + std::to_string(left.cols) + " x " + std::to_string(left.rows) + " px but " +
                                     o.cameras_path + " says " + std::to_string(cl.width) + " x " + std::to_string(cl.height));
    if (right.cols != cr.width || right.rows != cr.height)
        throw Error(o.right_path, "image is " + std::to_string(right.cols) + " x " + std::to_string(right.rows) + " px but " +
                                      o.cameras_path + " says " + std::to_string(cr.width) + " x " + std::to_string(cr.height));
    const photo::StereoResult s =
        photo::stereo_pair_cloud(left, right, cl, cr, o.stereo, set.scene_z_range_m, lname + " + " + rname, progress.sub(0, 0.9));
    write_cloud_las(o.out_path, s.cloud, set.crs_wkt, "cityforge stereo");
    StereoRunResult r;
    r.points = s.cloud.size();
    r.baseline_m = s.baseline_m;
    r.min_disparity_px = s.min_disparity_px, r.num_disparities_px = s.num_disparities_px;
    r.matched_pixels = s.matched_pixels, r.lr_rejected = s.lr_rejected;
    r.crs = set.crs;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "done");
    return r;
}

}  // namespace cityforge

// ---------------------------------------------------------------- orient

extern char** environ;

namespace cityforge {

void OrientRunOptions::validate() const {
    if (images_dir.empty()) throw Error("--images", "give the folder of photos");
    if (out_dir.empty()) throw Error("--out", "give the output folder");
    if (max_image_px < 200 || max_image_px > 20000) throw Error("--max-image-px", "must be 200..20000");
    if (threads < 1 || threads > 256) throw Error("--threads", "must be 1..256");
    if (gps.empty()) throw Error("--gps", "give 'exif' or a file");
    if (gps_height_crs.empty()) throw Error("--gps-height-crs", "give a vertical CRS (e.g. EPSG:5773) or 'ellipsoid'");
    if (max_features < 256 || max_features > 65536) throw Error("--max-features", "must be 256..65536");
    if (matcher != "exhaustive" && matcher != "sequential") throw Error("--matcher", "must be 'exhaustive' or 'sequential', got '" + matcher + "'");
    if (sequential_overlap < 1 || sequential_overlap > 100) throw Error("--sequential-overlap", "must be 1..100");
}

namespace {

std::vector<std::string> list_images(const std::string& dir) {
    if (!fs::is_directory(dir)) throw Error(dir, "not a folder of images");
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir)) {
        if (!e.is_regular_file()) continue;
        std::string ext = e.path().extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
        if (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".tif" || ext == ".tiff") names.push_back(e.path().filename().string());
    }
    std::sort(names.begin(), names.end());
    if (names.size() < 2) throw Error(dir, "fewer than two images (" + std::to_string(names.size()) + ")");
    return names;
}

struct GpsFix {
    double lat = 0, lon = 0, h = 0;
};

// "(47) (36) (36.63)" -> degrees.
double exif_dms(const char* s) {
    double v[3] = {0, 0, 0};
    int k = 0;
    for (const char* p = s; *p && k < 3; ++p)
        if (*p == '(') v[k++] = std::atof(p + 1);
    if (k == 0) return std::atof(s);
    return v[0] + v[1] / 60.0 + v[2] / 3600.0;
}

std::map<std::string, GpsFix> read_gps(const std::string& source, const std::string& dir, const std::vector<std::string>& names) {
    std::map<std::string, GpsFix> out;
    if (source == "exif") {
        GDALAllRegister();
        for (const std::string& n : names) {
            const std::string path = (fs::path(dir) / n).string();
            GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen(path.c_str(), GA_ReadOnly));
            if (!ds) continue;
            const char* lat = ds->GetMetadataItem("EXIF_GPSLatitude");
            const char* lon = ds->GetMetadataItem("EXIF_GPSLongitude");
            if (lat && lon) {
                GpsFix f;
                f.lat = exif_dms(lat), f.lon = exif_dms(lon);
                const char* latref = ds->GetMetadataItem("EXIF_GPSLatitudeRef");
                const char* lonref = ds->GetMetadataItem("EXIF_GPSLongitudeRef");
                if (latref && (latref[0] == 'S' || latref[0] == 's')) f.lat = -f.lat;
                if (lonref && (lonref[0] == 'W' || lonref[0] == 'w')) f.lon = -f.lon;
                if (const char* alt = ds->GetMetadataItem("EXIF_GPSAltitude")) f.h = exif_dms(alt);
                if (const char* ref = ds->GetMetadataItem("EXIF_GPSAltitudeRef"))
                    if (std::atoi(ref) == 1 || std::string(ref).find("(1)") != std::string::npos) f.h = -f.h;
                out[n] = f;
            }
            GDALClose(ds);
        }
        if (out.size() < 3)
            throw Error(dir, "only " + std::to_string(out.size()) +
                                 " photos have GPS EXIF: give --gps FILE (lines: image lat lon height) to georeference");
    } else {
        std::ifstream in(source);
        if (!in) throw Error(source, "cannot open GPS file");
        std::string line;
        int line_no = 0;
        while (std::getline(in, line)) {
            ++line_no;
            if (line.empty() || line[0] == '#') continue;
            std::istringstream s(line);
            std::string n;
            GpsFix f;
            if (!(s >> n >> f.lat >> f.lon >> f.h) || std::abs(f.lat) > 90 || std::abs(f.lon) > 180)
                throw Error(source, "line " + std::to_string(line_no) + ": expected 'image lat_deg lon_deg height_m'");
            out[n] = f;
        }
        int found = 0;
        for (const auto& n : names) found += out.count(n) ? 1 : 0;
        if (found < 3) throw Error(source, "GPS positions for only " + std::to_string(found) + " of the photos (need 3)");
    }
    return out;
}

struct CameraMatrix {
    double fx = 0, fy = 0, cx = 0, cy = 0;
};

CameraMatrix read_camera_matrix(const std::string& path, int width, int height) {
    std::ifstream in(path);
    if (!in) throw Error(path, "cannot open camera matrix");
    std::vector<double> v;
    std::string tok;
    while (in >> tok) {
        for (char& c : tok)
            if (c == ',' || c == '[' || c == ']' || c == ';') c = ' ';
        std::istringstream s(tok);
        double x;
        while (s >> x) v.push_back(x);
    }
    if (v.size() != 9) throw Error(path, "expected a 3 x 3 camera matrix (9 numbers), found " + std::to_string(v.size()));
    CameraMatrix k{v[0], v[4], v[2], v[5]};
    if (!(k.fx > 0 && k.fy > 0) || std::abs(v[1]) > 1e-6 * k.fx || v[3] != 0 || v[6] != 0 || v[7] != 0 || v[8] != 1)
        throw Error(path, "not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]");
    if (std::abs(k.cx - 0.5 * width) > 0.15 * width || std::abs(k.cy - 0.5 * height) > 0.15 * height)
        throw Error(path, "principal point (" + std::to_string(k.cx) + ", " + std::to_string(k.cy) + ") does not fit " +
                              std::to_string(width) + " x " + std::to_string(height) + " px images: wrong camera file or image size");
    return k;
}

// The last "[a/b" counter in `text` (COLMAP logs "Processed file [3/12]",
// "Matching block [1/2, 2/2]", "Matching image [5/40]"), as a / b.
std::optional<std::pair<long, long>> last_counter(const std::string& text) {
    for (std::size_t p = text.rfind('['); p != std::string::npos; p = p ? text.rfind('[', p - 1) : std::string::npos) {
        long a = 0, b = 0;
        char slash = 0;
        std::istringstream in(text.substr(p + 1, 40));
        if (in >> a >> slash >> b && slash == '/' && a > 0 && b > 0 && a <= b) return std::pair<long, long>(a, b);
        if (p == 0) break;
    }
    return std::nullopt;
}

// Runs one COLMAP step with its output appended to `log`; while it runs, the
// log's counters feed `progress` ("matching 3/12 ...": count, rate, ETA).
void run_tool(const std::vector<std::string>& args, const fs::path& log, const std::string& step, const Progress& progress = {}) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const std::uintmax_t log_start = fs::exists(log) ? fs::file_size(log) : 0;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    pid_t pid = 0;
    const int rc = posix_spawnp(&pid, args[0].c_str(), &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) throw Error(args[0], "cannot run (is COLMAP installed? apt-get install colmap)");
    int status = 0;
    std::uintmax_t read_to = log_start;
    std::string tail;
    for (;;) {
        const pid_t w = waitpid(pid, &status, progress.active() ? WNOHANG : 0);
        if (w == pid) break;
        if (w < 0 && errno != EINTR) throw Error(step, "lost the COLMAP process");
        if (w == 0) {
            usleep(500000);
            std::error_code ec;
            const std::uintmax_t size = fs::file_size(log, ec);
            if (ec || size <= read_to) continue;
            std::ifstream in(log, std::ios::binary);
            in.seekg(static_cast<std::streamoff>(read_to));
            std::string chunk(static_cast<std::size_t>(size - read_to), '\0');
            in.read(chunk.data(), static_cast<std::streamsize>(chunk.size()));
            read_to = size;
            tail = tail.substr(tail.size() > 200 ? tail.size() - 200 : 0) + chunk;
            if (const auto c = last_counter(tail)) {
                try {
                    progress(double(c->first) / double(c->second), step + " " + std::to_string(c->first) + "/" + std::to_string(c->second));
                } catch (...) {
                    kill(pid, SIGTERM);
                    waitpid(pid, &status, 0);
                    throw;
                }
            }
        }
    }
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        // The work folder (and its log) is removed: quote the log's last line.
        std::ifstream in(log);
        std::string line, last;
        while (std::getline(in, line))
            if (line.find_first_not_of(" \t\r") != std::string::npos) last = line;
        if (last.size() > 200) last = last.substr(0, 200) + "...";
        throw Error(step, "COLMAP failed (exit " + std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ")" +
                              (last.empty() ? std::string() : ": " + last));
    }
}

std::string utm_for(double lat, double lon) {
    const int zone = std::clamp(static_cast<int>(std::floor((lon + 180.0) / 6.0)) + 1, 1, 60);
    return "EPSG:" + std::to_string((lat >= 0 ? 32600 : 32700) + zone);
}

}  // namespace

GpsFrames gps_frames(const OrientRunOptions& o, double lat_deg, double lon_deg) {
    GpsFrames f;
    CrsInfo vertical;
    if (o.gps_height_crs == "ellipsoid") {
        f.gps = crs_from_user_input("EPSG:4979", "--gps-height-crs");
        vertical = crs_from_user_input("EPSG:5773", "--gps-height-crs");
    } else {
        vertical = crs_from_user_input(o.gps_height_crs, "--gps-height-crs");
        if (!vertical.vertical_epsg || vertical.horizontal_epsg)
            throw Error("--gps-height-crs", "must be a vertical CRS with an EPSG code (e.g. EPSG:5773, EGM96 height) or 'ellipsoid', not \"" +
                                                o.gps_height_crs + "\"");
        f.gps = crs_from_user_input("EPSG:4326+" + std::to_string(*vertical.vertical_epsg), "--gps-height-crs");
    }
    const CrsInfo out = crs_from_user_input(o.crs.empty() ? utm_for(lat_deg, lon_deg) : o.crs, "--crs");
    if (out.geographic) throw Error("--crs", "must be a projected CRS in metres");
    f.out = out.vertical_epsg ? out : combine_with_vertical(out, vertical);
    return f;
}

namespace {
// The working folder of one orientation: COLMAP's files under colmap/.
struct OrientWork {
    fs::path colmap_dir, img_dir, log, db;
    explicit OrientWork(const fs::path& work)
        : colmap_dir(work / "colmap"), img_dir(colmap_dir / "images"), log(colmap_dir / "colmap.log"), db(colmap_dir / "database.db") {}
};

// Downscaled PNG copies of the photos (COLMAP and the dense steps see the
// same pixels), at most max_image_px on the longer side; returns the scale.
double write_working_images(const OrientRunOptions& o, const std::vector<std::string>& names, const cv::Mat& first, const OrientWork& w,
                            const Progress& progress) {
    ensure_directory(w.img_dir);
    double scale = 1.0;
    for (std::size_t i = 0; i < names.size(); ++i) {
        const std::string src = (fs::path(o.images_dir) / names[i]).string();
        cv::Mat m = read_colour_image(src);
        if (m.cols != first.cols || m.rows != first.rows)
            throw Error(src, "image size differs from " + names[0] + " (one camera per block)");
        const int longest = std::max(m.cols, m.rows);
        scale = longest > o.max_image_px ? double(o.max_image_px) / longest : 1.0;
        if (scale < 1.0) cv::resize(m, m, cv::Size(), scale, scale, cv::INTER_AREA);
        const fs::path dst = w.img_dir / (fs::path(names[i]).stem().string() + ".png");
        if (!cv::imwrite(dst.string(), m)) throw Error(dst.string(), "cannot write image");
        progress(0.1 * double(i + 1) / double(names.size()), "images " + std::to_string(i + 1) + "/" + std::to_string(names.size()));
    }
    return scale;
}

// COLMAP's SIFT features of the working images (one camera: the given
// pinhole matrix, scaled, or a simple radial model to self-calibrate).
void extract_features(const OrientRunOptions& o, const OrientWork& w, int longest_px, double scale, const std::optional<CameraMatrix>& k,
                      const Progress& progress) {
    std::vector<std::string> fe{o.colmap, "feature_extractor", "--database_path", w.db.string(), "--image_path", w.img_dir.string(),
                                "--ImageReader.single_camera", "1", "--SiftExtraction.use_gpu", "0",
                                "--SiftExtraction.num_threads", std::to_string(o.threads), "--SiftExtraction.max_num_features",
                                std::to_string(o.max_features),
                                // No up-sampled first octave on large photos: at 2000 px it quadruples
                                // the work for features finer than the block needs.
                                "--SiftExtraction.first_octave", longest_px * scale >= 1200 ? "0" : "-1"};
    if (k) {
        // COLMAP's principal point: top-left pixel centre at (0.5, 0.5).
        char params[200];
        std::snprintf(params, sizeof params, "%.6f,%.6f,%.6f,%.6f", k->fx * scale, k->fy * scale, (k->cx + 0.5) * scale,
                      (k->cy + 0.5) * scale);
        fe.insert(fe.end(), {"--ImageReader.camera_model", "PINHOLE", "--ImageReader.camera_params", params});
    } else {
        fe.insert(fe.end(), {"--ImageReader.camera_model", "SIMPLE_RADIAL"});
    }
    run_tool(fe, w.log, "feature extraction", progress);
}

struct MatchCounts {
    std::size_t matches = 0, pairs = 0;  ///< putative matches, and image pairs with any
};

// Matching is ours (photo/feature_matching): COLMAP's CPU matcher builds
// FLANN's randomised kd-trees from the unseeded rand() and its matches
// differ by 1-2 per pair from run to run. Brute force on COLMAP's
// descriptors with its rules, pairs in file order, the same bytes for any
// thread count (keypoints at the image edge are left out: COLMAP leaves
// their descriptors uninitialised); COLMAP then verifies them
// geometrically in one thread (matches_importer: its RANSAC draws from a
// PRNG seeded with 0).
MatchCounts match_and_verify(const OrientRunOptions& o, const OrientWork& w, const Progress& progress) {
    MatchCounts counts;
    photo::renumber_colmap_images(w.db.string());  // ids in name order, not in the order threads finished
    const std::vector<photo::ImageFeatures> features = photo::read_colmap_features(w.db.string());
    const int n = static_cast<int>(features.size());
    const auto pairs = o.matcher == "sequential" ? photo::sequential_pairs(n, o.sequential_overlap) : photo::exhaustive_pairs(n);
    std::vector<photo::PairMatches> matches;
    tbb::task_arena arena(o.threads);
    arena.execute([&] { matches = photo::match_image_pairs(features, pairs, {}, progress.sub(0.0, 0.75)); });
    for (const auto& p : matches) counts.matches += p.matches.size(), counts.pairs += p.matches.empty() ? 0 : 1;
    const fs::path list = w.colmap_dir / "matches.txt";
    photo::write_colmap_match_list(list.string(), features, matches);
    run_tool({o.colmap, "matches_importer", "--database_path", w.db.string(), "--match_list_path", list.string(), "--match_type", "raw",
              "--SiftMatching.use_gpu", "0", "--SiftMatching.num_threads", "1"},
             w.log, "match verification", progress.sub(0.75, 1.0));
    return counts;
}

// COLMAP's incremental mapping; returns the folder of the largest
// reconstruction. One mapper thread: with two, COLMAP's bundle adjustment
// and triangulation give a different model from run to run (measured); with
// one and the fixed seed the model is the same bytes.
fs::path map_block(const OrientRunOptions& o, const OrientWork& w, bool calibrated, const Progress& progress) {
    const fs::path sparse = w.colmap_dir / "sparse";
    ensure_directory(sparse);
    std::vector<std::string> mapper{o.colmap, "mapper", "--database_path", w.db.string(), "--image_path", w.img_dir.string(),
                                    "--output_path", sparse.string(), "--Mapper.num_threads", "1", "--random_seed", "0"};
    // A calibrated camera stays fixed: nadir blocks over flat ground make the
    // focal length nearly unobservable in self-calibration.
    if (calibrated) mapper.insert(mapper.end(), {"--Mapper.ba_refine_focal_length", "0", "--Mapper.ba_refine_extra_params", "0"});
    try {
        run_tool(mapper, w.log, "mapping", progress);
    } catch (const Error&) {
        throw Error(o.images_dir, "COLMAP could not orient the photos (no image pair to start from): the photos do not overlap or have no texture");
    }
    fs::path best;
    std::uintmax_t best_size = 0;
    if (fs::is_directory(sparse))
        for (const auto& e : fs::directory_iterator(sparse)) {
            const fs::path imgs = e.path() / "images.bin";
            if (fs::exists(imgs) && fs::file_size(imgs) > best_size) best = e.path(), best_size = fs::file_size(imgs);
        }
    if (best.empty()) throw Error(o.images_dir, "COLMAP oriented no image pair: the photos do not overlap or have no texture");
    return best;
}

// The reconstruction's undistorted images and its model as text; returns
// the undistortion folder (images/) and the text model's folder.
std::pair<fs::path, fs::path> undistort_model(const OrientRunOptions& o, const OrientWork& w, const fs::path& reconstruction) {
    const fs::path undist = w.colmap_dir / "undistorted";
    run_tool({o.colmap, "image_undistorter", "--image_path", w.img_dir.string(), "--input_path", reconstruction.string(), "--output_path",
              undist.string(), "--output_type", "COLMAP"},
             w.log, "undistortion");
    const fs::path txt = w.colmap_dir / "model_txt";
    ensure_directory(txt);
    run_tool({o.colmap, "model_converter", "--input_path", (undist / "sparse").string(), "--output_path", txt.string(), "--output_type", "TXT"},
             w.log, "model conversion");
    return {undist, txt};
}

// The similarity from the model frame to the output CRS, fitted on the
// oriented photos that have GPS positions.
struct BlockGeoreference {
    photo::Similarity similarity;
    std::vector<std::string> images;    ///< oriented photos with a GPS position (the model's PNG names)
    std::vector<Eigen::Vector3d> model; ///< their camera centres, model frame
    std::vector<Eigen::Vector3d> gps;   ///< their GPS positions in the output CRS, less `origin`
    Eigen::Vector3d origin;             ///< a round origin near the block (numerics)
};

BlockGeoreference georeference_block(const std::vector<photo::PhotoCamera>& cams, const std::map<std::string, GpsFix>& gps,
                                     const std::function<std::string(const std::string&)>& original_name, const GpsFrames& frames,
                                     const std::string& images_dir) {
    BlockGeoreference g;
    std::vector<double> gx, gy, gz;
    for (const auto& c : cams) {
        const auto it = gps.find(original_name(c.image));
        if (it == gps.end()) continue;
        g.images.push_back(c.image);
        gx.push_back(it->second.lon), gy.push_back(it->second.lat), gz.push_back(it->second.h);
    }
    if (g.images.size() < 3) throw Error(images_dir, "fewer than 3 oriented photos have GPS positions: cannot georeference (do the photos overlap?)");
    transform_points(frames.gps, frames.out, gx, gy, gz, "GPS positions");
    g.origin = Eigen::Vector3d(std::floor(gx[0] / 1000) * 1000, std::floor(gy[0] / 1000) * 1000, 0.0);
    for (std::size_t i = 0; i < g.images.size(); ++i) {
        for (const auto& c : cams)
            if (c.image == g.images[i]) g.model.push_back(c.centre);
        g.gps.push_back(Eigen::Vector3d(gx[i], gy[i], gz[i]) - g.origin);
    }
    g.similarity = photo::fit_similarity(g.model, g.gps, images_dir);
    g.similarity.translation += g.origin;
    return g;
}

// A block that does not fit its GPS positions is mis-oriented: refused when
// the RMSE exceeds max(2 m, 0.35 x the typical spacing of the photos).
void check_gps_fit(const BlockGeoreference& g, double rmse_m, bool calibrated, const std::string& images_dir) {
    std::vector<double> spacing;
    for (std::size_t i = 0; i < g.gps.size(); ++i) {
        double nearest = 1e300;
        for (std::size_t j = 0; j < g.gps.size(); ++j)
            if (j != i) nearest = std::min(nearest, (g.gps[i] - g.gps[j]).norm());
        spacing.push_back(nearest);
    }
    std::sort(spacing.begin(), spacing.end());
    const double typical = spacing[spacing.size() / 2];
    if (rmse_m > std::max(2.0, 0.35 * typical)) {
        char buf[300];
        std::snprintf(buf, sizeof buf,
                      "oriented camera centres disagree with the GPS positions (RMSE %.1f m, photo spacing %.1f m): "
                      "the orientation is wrong%s",
                      rmse_m, typical, calibrated ? "" : " (self-calibration of nadir photos is weak: give --camera K.txt)");
        throw Error(images_dir, buf);
    }
}

// The model's sparse points in the map frame, coloured; sets the height
// range the scene spans (1st-99th percentile, padded by 10 % + 1 m).
PointCloud sparse_cloud_in_map(const photo::ColmapModel& model, const photo::Similarity& sim, photo::CameraSet& set, const std::string& images_dir) {
    PointCloud cloud;
    std::vector<double> zs;
    for (const auto& p : model.points) {
        const Eigen::Vector3d w = sim.apply(p.xyz);
        cloud.x.push_back(w.x()), cloud.y.push_back(w.y()), cloud.z.push_back(w.z());
        cloud.classification.push_back(1);
        cloud.return_number.push_back(1), cloud.number_of_returns.push_back(1);
        cloud.intensity.push_back(0);
        cloud.red.push_back(p.rgb[0] * 257), cloud.green.push_back(p.rgb[1] * 257), cloud.blue.push_back(p.rgb[2] * 257);
        zs.push_back(w.z());
    }
    if (zs.size() < 10) throw Error(images_dir, "COLMAP triangulated fewer than 10 points: the photos do not overlap");
    std::sort(zs.begin(), zs.end());
    const double zlo = zs[zs.size() / 100], zhi = zs[zs.size() - 1 - zs.size() / 100];
    const double pad = 0.1 * (zhi - zlo) + 1.0;
    set.scene_z_range_m = {zlo - pad, zhi + pad};
    return cloud;
}

nlohmann::json orient_report_json(const OrientRunOptions& o, const OrientRunResult& r, const MatchCounts& matched, double scale,
                                  const GpsFrames& frames, const photo::CameraSet& set) {
    nlohmann::json j;
    j["crs"] = r.crs;
    j["engine"] = "COLMAP feature_extractor; cityforge brute-force SIFT matching (" + o.matcher +
                  " pairs), COLMAP matches_importer (geometric verification), mapper (1 thread, seed 0), image_undistorter; CPU";
    j["max_features"] = o.max_features;
    j["matched_pairs"] = matched.pairs;
    j["matches"] = matched.matches;
    j["images"] = r.images;
    j["oriented"] = r.oriented;
    j["sparse_points"] = r.sparse_points;
    j["mean_reprojection_error_px"] = r.mean_reprojection_error_px;
    j["image_scale"] = scale;
    j["georeferencing"] = {{"method", "similarity (Umeyama) from model camera centres to GPS positions in " + r.crs},
                           {"gps_source", o.gps}, {"gps_crs", frames.gps.label()}, {"scale_m_per_model_unit", r.scale}, {"rmse_m", r.gps_rmse_m}};
    j["vertical_crs"] = z_crs_label(frames.out);
    j["residuals_m"] = nlohmann::json::array();
    for (const auto& e : r.residuals) j["residuals_m"].push_back({{"image", e.image}, {"dx", e.dx_m}, {"dy", e.dy_m}, {"dz", e.dz_m}});
    j["scene_z_range_m"] = set.scene_z_range_m;
    j["seconds"] = r.seconds;
    return j;
}
}  // namespace

OrientRunResult run_orient(const OrientRunOptions& o, const Progress& progress) {
    o.validate();
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<std::string> names = list_images(o.images_dir);
    if (fs::exists(o.out_dir)) {
        if (!o.overwrite) throw Error(o.out_dir, "exists (give --overwrite to replace it)");
    }
    // Everything that can be refused is checked before any file is written.
    const cv::Mat first = read_colour_image((fs::path(o.images_dir) / names[0]).string());
    std::optional<CameraMatrix> k;
    if (!o.camera_path.empty()) k = read_camera_matrix(o.camera_path, first.cols, first.rows);
    const std::map<std::string, GpsFix> gps = read_gps(o.gps, o.images_dir, names);
    const GpsFix& g0 = gps.begin()->second;
    const GpsFrames frames = gps_frames(o, g0.lat, g0.lon);
    const CrsInfo& out_crs = frames.out;

    // Work in a sibling folder; it replaces OUT only at the end.
    const fs::path out = fs::path(o.out_dir);
    const fs::path work = fs::path(out.string() + ".part-" + std::to_string(getpid()));
    register_temporary(work);  // removed if the process is interrupted
    fs::remove_all(work);
    struct Cleanup {
        fs::path p;
        bool keep = false;
        ~Cleanup() {
            std::error_code ec;
            if (!keep) fs::remove_all(p, ec);
            unregister_temporary(p);
        }
    } cleanup{work};
    const OrientWork w(work);
    const double scale = write_working_images(o, names, first, w, progress);
    extract_features(o, w, std::max(first.cols, first.rows), scale, k, progress.sub(0.1, 0.3));
    progress(0.3, "features");
    const MatchCounts matched = match_and_verify(o, w, progress.sub(0.3, 0.5));
    progress(0.5, "matching");
    const fs::path reconstruction = map_block(o, w, k.has_value(), progress.sub(0.5, 0.8));
    progress(0.8, "mapping");
    const auto [undist, txt] = undistort_model(o, w, reconstruction);
    progress(0.9, "undistortion");

    const photo::ColmapModel model = photo::read_colmap_text_model(txt.string());
    const std::vector<photo::PhotoCamera> cams = photo::pinhole_cameras(model, txt.string());
    if (cams.size() < 2) throw Error(o.images_dir, "COLMAP oriented fewer than two photos: the photos do not overlap");
    // GPS positions in the output CRS; names in the model are the PNG copies.
    auto original_name = [&](const std::string& png) -> std::string {
        for (const auto& n : names)
            if (fs::path(n).stem().string() == fs::path(png).stem().string()) return n;
        return png;
    };
    const BlockGeoreference geo = georeference_block(cams, gps, original_name, frames, o.images_dir);

    OrientRunResult r;
    r.images = static_cast<int>(names.size());
    r.oriented = static_cast<int>(cams.size());
    r.scale = geo.similarity.scale;
    r.crs = out_crs.label();
    r.mean_reprojection_error_px = model.mean_reprojection_error_px();
    double sq = 0;
    for (std::size_t i = 0; i < geo.images.size(); ++i) {
        const Eigen::Vector3d d = geo.similarity.apply(geo.model[i]) - (geo.gps[i] + geo.origin);
        r.residuals.push_back({original_name(geo.images[i]), d.x(), d.y(), d.z()});
        sq += d.squaredNorm();
    }
    r.gps_rmse_m = std::sqrt(sq / double(geo.images.size()));
    check_gps_fit(geo, r.gps_rmse_m, k.has_value(), o.images_dir);

    photo::CameraSet set;
    set.crs = out_crs.label();
    set.crs_wkt = out_crs.wkt;
    for (const auto& c : cams) set.cameras.push_back(photo::transform_camera(c, geo.similarity));
    const PointCloud sparse_cloud = sparse_cloud_in_map(model, geo.similarity, set, o.images_dir);
    r.sparse_points = sparse_cloud.size();

    // Final layout.
    ensure_directory(work / "images");
    for (const auto& c : set.cameras) fs::rename(undist / "images" / c.image, work / "images" / c.image);
    photo::write_cameras_json((work / "cameras.json").string(), set);
    write_cloud_las((work / "sparse.las").string(), sparse_cloud, out_crs.wkt, "cityforge orient (COLMAP sparse)");
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    write_text_file(work / "orient_report.json", orient_report_json(o, r, matched, scale, frames, set).dump(2) + "\n");
    if (fs::exists(out)) fs::remove_all(out);
    fs::rename(work, out);
    cleanup.keep = true;
    r.cameras_path = (out / "cameras.json").string();
    r.sparse_path = (out / "sparse.las").string();
    r.report_path = (out / "orient_report.json").string();
    r.images_dir = (out / "images").string();
    progress(1.0, "done");
    return r;
}

}  // namespace cityforge

// ---------------------------------------------------------------- densify, photo

namespace cityforge {

void DensifyRunOptions::validate() const {
    if (model_dir.empty()) throw Error("--model", "give the oriented folder");
    if (out_path.empty()) throw Error("--out", "give the output LAS file");
    densify.validate();
}

DensifyRunResult run_densify(const DensifyRunOptions& o, const Progress& progress) {
    o.validate();
    const auto t0 = std::chrono::steady_clock::now();
    check_output_free(o.out_path, o.overwrite);
    const fs::path dir(o.model_dir);
    if (!fs::is_directory(dir)) throw Error(o.model_dir, "not an oriented folder");
    fs::path cams = dir / "cameras.json", images = dir / "images";
    if (!fs::exists(cams)) cams = dir / "cameras_truth.json", images = dir;
    if (!fs::exists(cams)) throw Error(o.model_dir, "no cameras.json (from `cityforge orient`) or cameras_truth.json");
    const photo::CameraSet set = photo::read_cameras_json(cams.string());
    if (set.cameras.size() < 2) throw Error(cams.string(), "fewer than two cameras");
    std::vector<cv::Mat> imgs;
    for (const auto& c : set.cameras) {
        const std::string path = (images / c.image).string();
        cv::Mat m = read_colour_image(path);
        if (m.cols != c.width || m.rows != c.height)
            throw Error(path, "image is " + std::to_string(m.cols) + " x " + std::to_string(m.rows) + " px but " + cams.string() +
                                  " says " + std::to_string(c.width) + " x " + std::to_string(c.height));
        imgs.push_back(std::move(m));
    }
    std::vector<Eigen::Vector3d> sparse;
    if (o.use_sparse && fs::exists(dir / "sparse.las")) {
        const PointCloud pc = read_las((dir / "sparse.las").string());
        for (std::size_t i = 0; i < pc.size(); ++i) sparse.push_back({pc.x[i], pc.y[i], pc.z[i]});
    }
    const photo::DensifyResult d = photo::densify_patches(imgs, set, sparse, o.densify, o.model_dir, progress.sub(0.05, 0.95));
    write_cloud_las(o.out_path, d.cloud, set.crs_wkt, "cityforge densify (patch-based MVS)");
    DensifyRunResult r;
    r.points = d.cloud.size();
    r.seeds = d.seeds, r.expanded = d.expanded, r.filtered = d.filtered;
    r.images = static_cast<int>(set.cameras.size());
    r.crs = set.crs;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress(1.0, "done");
    return r;
}

void PhotoRunOptions::validate() const {
    if (out_dir.empty()) throw Error("--out", "give the output folder");
    densify.validate();
    if (run) {
        if (!(ortho_gsd_m >= 0.02 && ortho_gsd_m <= 5.0)) throw Error("--ortho-gsd", "must be 0.02..5 m");
        ortho.validate();
        orthophoto.validate();
        if (run_ortho != "photos" && run_ortho != "cloud") throw Error("--run-ortho", "must be photos or cloud, not \"" + run_ortho + "\"");
    }
}

OrientRunResult read_orient_folder(const std::string& dir) {
    const fs::path d(dir), report = d / "orient_report.json";
    if (!fs::exists(report) || !fs::exists(d / "cameras.json") || !fs::exists(d / "sparse.las") || !fs::is_directory(d / "images"))
        throw Error(dir, "not an oriented folder of `cityforge orient` (orient_report.json, cameras.json, sparse.las, images/)");
    nlohmann::json j;
    try {
        std::ifstream in(report);
        j = nlohmann::json::parse(in);
        OrientRunResult r;
        r.images = j.at("images").get<int>();
        r.oriented = j.at("oriented").get<int>();
        r.sparse_points = j.at("sparse_points").get<uint64_t>();
        r.mean_reprojection_error_px = j.at("mean_reprojection_error_px").get<double>();
        r.gps_rmse_m = j.at("georeferencing").at("rmse_m").get<double>();
        r.scale = j.at("georeferencing").at("scale_m_per_model_unit").get<double>();
        r.crs = j.at("crs").get<std::string>();
        r.seconds = j.at("seconds").get<double>();
        for (const auto& e : j.at("residuals_m"))
            r.residuals.push_back({e.at("image").get<std::string>(), e.at("dx").get<double>(), e.at("dy").get<double>(), e.at("dz").get<double>()});
        r.cameras_path = (d / "cameras.json").string();
        r.sparse_path = (d / "sparse.las").string();
        r.report_path = report.string();
        r.images_dir = (d / "images").string();
        return r;
    } catch (const nlohmann::json::exception& e) {
        throw Error(report.string(), std::string("not an orient report: ") + e.what());
    }
}

PhotoRunResult run_photo(const PhotoRunOptions& o, const Progress& progress) {
    o.validate();
    const auto t0 = std::chrono::steady_clock::now();
    const fs::path out(o.out_dir);
    if (fs::exists(out) && !o.overwrite) throw Error(o.out_dir, "exists (give --overwrite to replace it)");
    OrientRunOptions oo = o.orient;
    oo.out_dir = (out / "orient").string();
    oo.overwrite = true;
    if (o.oriented_dir.empty()) oo.validate();
    else read_orient_folder(o.oriented_dir);  // refused before anything is written
    if (fs::exists(out)) fs::remove_all(out);
    ensure_directory(out);
    PhotoRunResult r;
    r.cloud_path = (out / "cloud.las").string();
    r.sparse_path = (out / "sparse.las").string();
    r.cameras_path = (out / "cameras.json").string();
    r.report_path = (out / "photo_report.json").string();
    const double dense_end = o.run ? 0.75 : 0.98;
    try {
        if (o.oriented_dir.empty()) {
            r.orient = run_orient(oo, progress.sub(0.0, 0.45));
        } else {
            r.orient = read_orient_folder(o.oriented_dir);
            oo.out_dir = o.oriented_dir;
        }
        DensifyRunOptions dd;
        dd.model_dir = oo.out_dir;
        dd.out_path = r.cloud_path;
        dd.overwrite = true;
        dd.densify = o.densify;
        r.densify = run_densify(dd, progress.sub(0.45, dense_end));
        fs::copy_file(r.orient.sparse_path, r.sparse_path, fs::copy_options::overwrite_existing);
        fs::copy_file(r.orient.cameras_path, r.cameras_path, fs::copy_options::overwrite_existing);
        if (o.run) {
            // The true ortho: the dense cloud's top-surface colours on a grid
            // of ortho_gsd_m in the cloud's CRS; it is the run's pixel grid.
            const auto t1 = std::chrono::steady_clock::now();
            const PointCloud dense = read_las(r.cloud_path);
            const GridSpec grid = grid_over_cloud(dense, o.ortho_gsd_m);
            const Image<uint8_t> ortho = photo::true_ortho_from_cloud(dense, grid, o.ortho, r.cloud_path);
            r.ortho_path = (out / "ortho.tif").string();
            GeoTiffWriteOptions wo;
            wo.nodata = 0.0;
            wo.rgb = true;
            const photo::CameraSet cams = photo::read_cameras_json(r.cameras_path);
            write_geotiff(r.ortho_path, ortho, grid.transform, cams.crs_wkt, wo);
            r.ortho_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
            // The orthophoto: the oriented photos' colours on the cloud's surface.
            const auto t2 = std::chrono::steady_clock::now();
            const photo::PhotoLoader load = [&](std::size_t i) {
                return read_colour_image((fs::path(oo.out_dir) / "images" / cams.cameras[i].image).string());
            };
            const Image<uint8_t> photo_ortho = photo::orthophoto_from_photos(dense, grid, load, cams, o.orthophoto, r.cloud_path, &r.orthophoto);
            r.orthophoto_path = (out / "orthophoto.tif").string();
            write_geotiff(r.orthophoto_path, photo_ortho, grid.transform, cams.crs_wkt, wo);
            r.orthophoto_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t2).count();
            progress.sub(dense_end, 0.8)(1.0, "orthos");
            RunOptions ro = o.city;
            ro.ortho = o.run_ortho == "photos" ? r.orthophoto_path : r.ortho_path;
            ro.cloud = r.cloud_path;
            ro.keep_rasters = true;  // the DSM (and DTM, nDSM) of the run
            r.run_dir = (out / "run").string();
            r.city = run_city(plan_run(ro), r.run_dir, {}, progress.sub(0.8, 0.99));
            std::size_t failed = 0;
            const TileReport* first = nullptr;
            for (const auto& t : r.city.tiles)
                if (t.status == "failed") ++failed, first = first ? first : &t;
            if (first)
                throw Error(r.run_dir, std::to_string(failed) + " tile(s) of the building run failed; first, tile " + std::to_string(first->index) +
                                           ": " + first->reason);
        }
    } catch (...) {
        std::error_code ec;
        fs::remove_all(out, ec);  // nothing half-written
        throw;
    }
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    nlohmann::json j;
    j["crs"] = r.orient.crs;
    j["steps"] = {
        {{"step", "orient"}, {"seconds", r.orient.seconds}, {"images", r.orient.images}, {"oriented", r.orient.oriented},
         {"sparse_points", r.orient.sparse_points}, {"mean_reprojection_error_px", r.orient.mean_reprojection_error_px},
         {"gps_rmse_m", r.orient.gps_rmse_m}},
        {{"step", "densify"}, {"seconds", r.densify.seconds}, {"points", r.densify.points}, {"seeds", r.densify.seeds},
         {"expanded", r.densify.expanded}, {"filtered", r.densify.filtered}}};
    j["files"] = {{"cloud", "cloud.las"}, {"sparse", "sparse.las"}, {"cameras", "cameras.json"},
                  {"oriented", o.oriented_dir.empty() ? std::string("orient/") : fs::absolute(o.oriented_dir).string()}};
    if (!o.oriented_dir.empty()) j["steps"][0]["reused_from"] = fs::absolute(o.oriented_dir).string();
    if (o.run) {
        j["steps"].push_back({{"step", "true_ortho"}, {"seconds", r.ortho_seconds}, {"gsd_m", o.ortho_gsd_m}});
        j["steps"].push_back({{"step", "orthophoto"}, {"seconds", r.orthophoto_seconds}, {"gsd_m", o.ortho_gsd_m},
                              {"cells_measured", r.orthophoto.cells_measured}, {"cells_filled", r.orthophoto.cells_filled},
                              {"cells_coloured", r.orthophoto.cells_coloured}, {"cells_occluded", r.orthophoto.cells_occluded},
                              {"run_ortho", o.run_ortho}});
        j["steps"].push_back({{"step", "run"}, {"seconds", r.city.seconds}, {"buildings", r.city.buildings},
                              {"valid_lod1", r.city.valid_lod1}, {"valid_lod2", r.city.valid_lod2}, {"tiles", r.city.tiles.size()},
                              {"warnings", r.city.warnings.size()}});
        j["files"]["ortho"] = "ortho.tif";
        j["files"]["orthophoto"] = "orthophoto.tif";
        j["files"]["run"] = "run/";
        j["files"]["run_report"] = "run/run_report.json";
    }
    j["seconds"] = r.seconds;
    write_text_file(r.report_path, j.dump(2) + "\n");
    progress(1.0, "done");
    return r;
}

}  // namespace cityforge
