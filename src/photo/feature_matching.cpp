#include "photo/feature_matching.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>

// GCC 12 warns about Eigen's matrix-vector fallback of the product (a loop it
// believes may run 2^62 times: a false positive in Eigen 3.4's GEMV).
#pragma GCC diagnostic ignored "-Waggressive-loop-optimizations"
#include <Eigen/Core>
#include <sqlite3.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"

namespace cityforge::photo {

namespace {

constexpr int kDescriptorBytes = 128;

struct Database {
    sqlite3* db = nullptr;
    ~Database() {
        if (db) sqlite3_close(db);
    }
};

struct Statement {
    sqlite3_stmt* stmt = nullptr;
    ~Statement() {
        if (stmt) sqlite3_finalize(stmt);
    }
};

void prepare(const Database& d, const std::string& path, const char* sql, Statement& s) {
    if (sqlite3_prepare_v2(d.db, sql, -1, &s.stmt, nullptr) != SQLITE_OK)
        throw Error(path, std::string("not a COLMAP database: ") + sqlite3_errmsg(d.db));
}

using FloatRows = Eigen::Matrix<float, Eigen::Dynamic, kDescriptorBytes, Eigen::RowMajor>;

FloatRows to_float(const uint8_t* d, std::size_t n) {
    FloatRows m(static_cast<Eigen::Index>(n), kDescriptorBytes);
    for (std::size_t i = 0; i < n * kDescriptorBytes; ++i) m.data()[i] = static_cast<float>(d[i]);
    return m;
}

// Best and second-best similarity (dot product) seen so far for one
// descriptor, updated in ascending order of the other set's index: COLMAP's
// FindBestMatchesOneWayBruteForce, so ties resolve the same way.
struct Best {
    int index = -1;
    int best = 0, second = 0;
    void add(int dist, int idx) {
        if (dist > best) {
            index = idx;
            second = best;
            best = dist;
        } else if (dist > second) {
            second = dist;
        }
    }
    // COLMAP's acceptance, in single precision as it computes it.
    bool accepted(float max_ratio, float max_distance) const {
        if (index < 0) return false;
        const float norm = 1.0f / (512.0f * 512.0f);
        const float best_angle = std::acos(std::min(norm * static_cast<float>(best), 1.0f));
        if (best_angle > max_distance) return false;
        const float second_angle = std::acos(std::min(norm * static_cast<float>(second), 1.0f));
        return !(best_angle >= max_ratio * second_angle);
    }
};

std::vector<std::pair<uint32_t, uint32_t>> match_float(const FloatRows& a, const FloatRows& b, const FeatureMatchOptions& o) {
    const Eigen::Index n1 = a.rows(), n2 = b.rows();
    std::vector<std::pair<uint32_t, uint32_t>> out;
    if (n1 == 0 || n2 == 0) return out;
    std::vector<Best> rows(static_cast<std::size_t>(n1)), cols(static_cast<std::size_t>(n2));
    // Dot products of uint8 descriptors are integers below 128 * 255^2 < 2^24,
    // and so is every partial sum: single precision is exact in any order of
    // summation, so the GEMM's blocking and vector width change nothing.
    constexpr Eigen::Index kBlock = 256;
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> dots;
    for (Eigen::Index r0 = 0; r0 < n1; r0 += kBlock) {
        const Eigen::Index nr = std::min(kBlock, n1 - r0);
        dots.noalias() = a.middleRows(r0, nr) * b.transpose();
        for (Eigen::Index r = 0; r < nr; ++r) {
            const float* row = dots.data() + r * n2;
            Best& br = rows[static_cast<std::size_t>(r0 + r)];
            for (Eigen::Index c = 0; c < n2; ++c) {
                const int d = static_cast<int>(row[c]);
                br.add(d, static_cast<int>(c));
                cols[static_cast<std::size_t>(c)].add(d, static_cast<int>(r0 + r));
            }
        }
    }
    const float ratio = static_cast<float>(o.max_ratio), distance = static_cast<float>(o.max_distance);
    std::vector<int> back(static_cast<std::size_t>(n2), -1);
    if (o.cross_check)
        for (Eigen::Index c = 0; c < n2; ++c)
            if (cols[static_cast<std::size_t>(c)].accepted(ratio, distance)) back[static_cast<std::size_t>(c)] = cols[static_cast<std::size_t>(c)].index;
    for (Eigen::Index r = 0; r < n1; ++r) {
        const Best& br = rows[static_cast<std::size_t>(r)];
        if (!br.accepted(ratio, distance)) continue;
        if (o.cross_check && back[static_cast<std::size_t>(br.index)] != static_cast<int>(r)) continue;
        out.emplace_back(static_cast<uint32_t>(r), static_cast<uint32_t>(br.index));
    }
    return out;
}

}  // namespace

void FeatureMatchOptions::validate() const {
    if (!(max_ratio > 0 && max_ratio <= 1)) throw Error("feature matching", "max_ratio must be in (0, 1]");
    if (!(max_distance > 0 && max_distance <= 3.2)) throw Error("feature matching", "max_distance must be in (0, pi] radians");
    if (!(border_margin_px >= 0 && border_margin_px < 1000)) throw Error("feature matching", "border_margin_px must be 0..1000");
    if (!(border_margin_sigma >= 0 && border_margin_sigma < 100)) throw Error("feature matching", "border_margin_sigma must be 0..100");
}

bool matchable_feature(const ImageFeatures& f, std::size_t k, const FeatureMatchOptions& o) {
    if (f.width <= 0 || f.height <= 0) return true;
    const double s = k < f.scale.size() ? f.scale[k] : 0.0;
    const double margin = o.border_margin_px + o.border_margin_sigma * s;
    const double x = f.xy[2 * k], y = f.xy[2 * k + 1];
    return x >= margin && y >= margin && x <= f.width - margin && y <= f.height - margin;
}

void renumber_colmap_images(const std::string& database_path) {
    Database d;
    if (sqlite3_open_v2(database_path.c_str(), &d.db, SQLITE_OPEN_READWRITE, nullptr) != SQLITE_OK)
        throw Error(database_path, "cannot open the COLMAP database");
    auto exec = [&](const std::string& sql) {
        char* msg = nullptr;
        if (sqlite3_exec(d.db, sql.c_str(), nullptr, nullptr, &msg) != SQLITE_OK) {
            const std::string m = msg ? msg : "unknown error";
            sqlite3_free(msg);
            sqlite3_exec(d.db, "ROLLBACK", nullptr, nullptr, nullptr);
            throw Error(database_path, "cannot renumber the images: " + m);
        }
    };
    std::vector<std::pair<std::string, int>> images;  // name, old id
    {
        Statement s;
        prepare(d, database_path, "SELECT name, image_id FROM images", s);
        while (sqlite3_step(s.stmt) == SQLITE_ROW) {
            const unsigned char* name = sqlite3_column_text(s.stmt, 0);
            images.emplace_back(name ? reinterpret_cast<const char*>(name) : "", sqlite3_column_int(s.stmt, 1));
        }
        Statement m;
        prepare(d, database_path, "SELECT (SELECT COUNT(*) FROM matches) + (SELECT COUNT(*) FROM two_view_geometries)", m);
        if (sqlite3_step(m.stmt) == SQLITE_ROW && sqlite3_column_int(m.stmt, 0) != 0)
            throw Error(database_path, "has matches already: images cannot be renumbered");
    }
    std::sort(images.begin(), images.end());
    const std::string shift = std::to_string(1 << 30);
    exec("BEGIN");
    for (const char* table : {"images", "keypoints", "descriptors"})
        exec(std::string("UPDATE ") + table + " SET image_id = image_id + " + shift);
    for (std::size_t k = 0; k < images.size(); ++k) {
        const std::string from = std::to_string(static_cast<long long>(images[k].second) + (1 << 30)), to = std::to_string(k + 1);
        for (const char* table : {"images", "keypoints", "descriptors"})
            exec(std::string("UPDATE ") + table + " SET image_id = " + to + " WHERE image_id = " + from);
    }
    exec("UPDATE sqlite_sequence SET seq = " + std::to_string(images.size()) + " WHERE name = 'images'");
    exec("COMMIT");
}

std::vector<ImageFeatures> read_colmap_features(const std::string& database_path) {
    Database d;
    if (sqlite3_open_v2(database_path.c_str(), &d.db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK)
        throw Error(database_path, "cannot open the COLMAP database");
    std::vector<ImageFeatures> out;
    {
        Statement s;
        prepare(d, database_path,
                "SELECT images.image_id, images.name, cameras.width, cameras.height FROM images "
                "LEFT JOIN cameras ON cameras.camera_id = images.camera_id ORDER BY images.image_id",
                s);
        while (sqlite3_step(s.stmt) == SQLITE_ROW) {
            ImageFeatures f;
            f.image_id = sqlite3_column_int(s.stmt, 0);
            const unsigned char* name = sqlite3_column_text(s.stmt, 1);
            f.name = name ? reinterpret_cast<const char*>(name) : "";
            f.width = sqlite3_column_int(s.stmt, 2), f.height = sqlite3_column_int(s.stmt, 3);
            out.push_back(std::move(f));
        }
    }
    if (out.empty()) throw Error(database_path, "the COLMAP database has no images");
    Statement kp, desc;
    prepare(d, database_path, "SELECT rows, cols, data FROM keypoints WHERE image_id = ?", kp);
    prepare(d, database_path, "SELECT rows, cols, data FROM descriptors WHERE image_id = ?", desc);
    for (ImageFeatures& f : out) {
        sqlite3_reset(kp.stmt);
        sqlite3_bind_int(kp.stmt, 1, f.image_id);
        std::size_t nk = 0;
        if (sqlite3_step(kp.stmt) == SQLITE_ROW) {
            const int rows = sqlite3_column_int(kp.stmt, 0), cols = sqlite3_column_int(kp.stmt, 1);
            const auto* data = static_cast<const float*>(sqlite3_column_blob(kp.stmt, 2));
            const int bytes = sqlite3_column_bytes(kp.stmt, 2);
            if (rows < 0 || (rows > 0 && (cols < 2 || bytes != rows * cols * int(sizeof(float)) || !data)))
                throw Error(database_path, "malformed keypoints of image " + f.name);
            nk = static_cast<std::size_t>(rows);
            f.xy.resize(2 * nk);
            for (std::size_t i = 0; i < nk; ++i) f.xy[2 * i] = data[i * cols], f.xy[2 * i + 1] = data[i * cols + 1];
            // Columns: x y (2), x y scale orientation (4), x y a11 a12 a21 a22 (6).
            if (cols == 4 || cols == 6) {
                f.scale.resize(nk);
                for (std::size_t i = 0; i < nk; ++i)
                    f.scale[i] = cols == 4 ? data[i * cols + 2] : std::hypot(data[i * cols + 2], data[i * cols + 4]);
            }
        }
        sqlite3_reset(desc.stmt);
        sqlite3_bind_int(desc.stmt, 1, f.image_id);
        std::size_t nd = 0;
        if (sqlite3_step(desc.stmt) == SQLITE_ROW) {
            const int rows = sqlite3_column_int(desc.stmt, 0), cols = sqlite3_column_int(desc.stmt, 1);
            const auto* data = static_cast<const uint8_t*>(sqlite3_column_blob(desc.stmt, 2));
            const int bytes = sqlite3_column_bytes(desc.stmt, 2);
            if (rows < 0 || (rows > 0 && (cols != kDescriptorBytes || bytes != rows * cols || !data)))
                throw Error(database_path, "descriptors of image " + f.name + " are not 128-byte SIFT");
            nd = static_cast<std::size_t>(rows);
            f.descriptors.assign(data, data + nd * kDescriptorBytes);
        }
        if (nk != nd)
            throw Error(database_path, "image " + f.name + " has " + std::to_string(nk) + " keypoints but " + std::to_string(nd) + " descriptors");
        f.count = nk;
    }
    return out;
}

std::vector<std::pair<int, int>> exhaustive_pairs(int n) {
    std::vector<std::pair<int, int>> p;
    for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n; ++j) p.emplace_back(i, j);
    return p;
}

std::vector<std::pair<int, int>> sequential_pairs(int n, int overlap) {
    std::vector<std::pair<int, int>> p;
    for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n && j <= i + overlap; ++j) p.emplace_back(i, j);
    return p;
}

std::vector<std::pair<uint32_t, uint32_t>> match_descriptors(const uint8_t* first, std::size_t first_count, const uint8_t* second,
                                                             std::size_t second_count, const FeatureMatchOptions& options) {
    options.validate();
    return match_float(to_float(first, first_count), to_float(second, second_count), options);
}

std::vector<PairMatches> match_image_pairs(const std::vector<ImageFeatures>& features, const std::vector<std::pair<int, int>>& pairs,
                                           const FeatureMatchOptions& options, const Progress& progress) {
    options.validate();
    const int n = static_cast<int>(features.size());
    for (const auto& [i, j] : pairs)
        if (i < 0 || j < 0 || i >= n || j >= n || i == j) throw Error("feature matching", "pair index out of range");
    // Matchable descriptors as floats once per image (shared read-only by
    // the pairs), with their indices among the image's features.
    std::vector<FloatRows> f(features.size());
    std::vector<std::vector<uint32_t>> index(features.size());
    tbb::parallel_for(std::size_t(0), features.size(), [&](std::size_t i) {
        const ImageFeatures& im = features[i];
        for (std::size_t k = 0; k < im.count; ++k)
            if (matchable_feature(im, k, options)) index[i].push_back(static_cast<uint32_t>(k));
        f[i].resize(static_cast<Eigen::Index>(index[i].size()), kDescriptorBytes);
        for (std::size_t r = 0; r < index[i].size(); ++r)
            for (int c = 0; c < kDescriptorBytes; ++c)
                f[i](static_cast<Eigen::Index>(r), c) = static_cast<float>(im.descriptors[index[i][r] * kDescriptorBytes + static_cast<std::size_t>(c)]);
    });
    std::vector<PairMatches> out(pairs.size());
    // Chunks of pairs so that progress is reported from this thread only.
    const std::size_t chunk = 16;
    for (std::size_t k0 = 0; k0 < pairs.size(); k0 += chunk) {
        const std::size_t k1 = std::min(pairs.size(), k0 + chunk);
        tbb::parallel_for(k0, k1, [&](std::size_t k) {
            const auto [i, j] = pairs[k];
            out[k].first = i, out[k].second = j;
            const auto& ii = index[static_cast<std::size_t>(i)];
            const auto& jj = index[static_cast<std::size_t>(j)];
            out[k].matches = match_float(f[static_cast<std::size_t>(i)], f[static_cast<std::size_t>(j)], options);
            for (auto& [a, b] : out[k].matches) a = ii[a], b = jj[b];
        });
        progress(double(k1) / double(pairs.size()), "matching " + std::to_string(k1) + "/" + std::to_string(pairs.size()) + " pairs");
    }
    return out;
}

void write_colmap_match_list(const std::string& path, const std::vector<ImageFeatures>& features, const std::vector<PairMatches>& matches) {
    // The importer reads "name1 name2" with >>: a name with white space would
    // be cut (and the pair skipped in silence).
    for (const ImageFeatures& f : features)
        if (f.name.find_first_of(" \t\r\n") != std::string::npos)
            throw Error(f.name, "image name with white space: COLMAP's matches_importer cannot read it (rename the photo)");
    std::ofstream out(path, std::ios::binary);
    if (!out) throw Error(path, "cannot write the match list");
    for (const PairMatches& p : matches) {
        if (p.matches.empty()) continue;
        out << features.at(static_cast<std::size_t>(p.first)).name << ' ' << features.at(static_cast<std::size_t>(p.second)).name << '\n';
        for (const auto& [a, b] : p.matches) out << a << ' ' << b << '\n';
        out << '\n';
    }
    out.flush();
    if (!out) throw Error(path, "cannot write the match list");
}

}  // namespace cityforge::photo
