#include "photo/feature_matching.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

// Descriptors as int16 rows (count x 128) for the dot-product kernel.
struct Rows {
    std::size_t count = 0;
    std::vector<int16_t> v;
};

Rows to_rows(const uint8_t* d, std::size_t n) {
    Rows m;
    m.count = n;
    m.v.assign(d, d + n * kDescriptorBytes);
    return m;
}

#if defined(__SSE2__)
inline int32_t horizontal_sum(__m128i v) {
    v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0x4E));
    v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0xB1));
    return _mm_cvtsi128_si32(v);
}
#endif

inline int32_t dot_scalar(const int16_t* a, const int16_t* b) {
    int32_t s = 0;
    for (int k = 0; k < kDescriptorBytes; ++k) s += int32_t(a[k]) * int32_t(b[k]);
    return s;
}

// out[r * n2 + c] = a_r . b_c for rows [0, nr) of `a` and every row of `b`:
// exact integer dot products (pmaddwd: int16 products summed in int32, far
// from overflow at 128 * 255^2), so any order of summation gives the same
// numbers. 4 x 2 blocks of descriptors share their loads.
void dot_block(const int16_t* a, std::size_t nr, const int16_t* b, std::size_t n2, int32_t* out) {
    std::size_t r = 0;
#if defined(__SSE2__)
    for (; r + 4 <= nr; r += 4) {
        const int16_t* a0 = a + r * kDescriptorBytes;
        const int16_t *a1 = a0 + kDescriptorBytes, *a2 = a1 + kDescriptorBytes, *a3 = a2 + kDescriptorBytes;
        std::size_t c = 0;
        for (; c + 2 <= n2; c += 2) {
            const int16_t* b0 = b + c * kDescriptorBytes;
            const int16_t* b1 = b0 + kDescriptorBytes;
            __m128i s00 = _mm_setzero_si128(), s01 = s00, s10 = s00, s11 = s00, s20 = s00, s21 = s00, s30 = s00, s31 = s00;
            for (int k = 0; k < kDescriptorBytes; k += 8) {
                const __m128i v0 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b0 + k));
                const __m128i v1 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b1 + k));
                __m128i u = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a0 + k));
                s00 = _mm_add_epi32(s00, _mm_madd_epi16(u, v0)), s01 = _mm_add_epi32(s01, _mm_madd_epi16(u, v1));
                u = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a1 + k));
                s10 = _mm_add_epi32(s10, _mm_madd_epi16(u, v0)), s11 = _mm_add_epi32(s11, _mm_madd_epi16(u, v1));
                u = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a2 + k));
                s20 = _mm_add_epi32(s20, _mm_madd_epi16(u, v0)), s21 = _mm_add_epi32(s21, _mm_madd_epi16(u, v1));
                u = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a3 + k));
                s30 = _mm_add_epi32(s30, _mm_madd_epi16(u, v0)), s31 = _mm_add_epi32(s31, _mm_madd_epi16(u, v1));
            }
            int32_t* o = out + r * n2 + c;
            o[0] = horizontal_sum(s00), o[1] = horizontal_sum(s01);
            o[n2] = horizontal_sum(s10), o[n2 + 1] = horizontal_sum(s11);
            o[2 * n2] = horizontal_sum(s20), o[2 * n2 + 1] = horizontal_sum(s21);
            o[3 * n2] = horizontal_sum(s30), o[3 * n2 + 1] = horizontal_sum(s31);
        }
        for (; c < n2; ++c)
            for (std::size_t i = 0; i < 4; ++i) out[(r + i) * n2 + c] = dot_scalar(a + (r + i) * kDescriptorBytes, b + c * kDescriptorBytes);
    }
#endif
    for (; r < nr; ++r)
        for (std::size_t c = 0; c < n2; ++c) out[r * n2 + c] = dot_scalar(a + r * kDescriptorBytes, b + c * kDescriptorBytes);
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

std::vector<std::pair<uint32_t, uint32_t>> match_rows(const Rows& a, const Rows& b, const FeatureMatchOptions& o) {
    const std::size_t n1 = a.count, n2 = b.count;
    std::vector<std::pair<uint32_t, uint32_t>> out;
    if (n1 == 0 || n2 == 0) return out;
    std::vector<Best> rows(n1), cols(n2);
    // Blocks of rows of `a` against all of `b`, rows in ascending order: each
    // descriptor's candidates are seen in ascending index, as COLMAP scans them.
    constexpr std::size_t kBlock = 64;
    std::vector<int32_t> dots(kBlock * n2);
    for (std::size_t r0 = 0; r0 < n1; r0 += kBlock) {
        const std::size_t nr = std::min(kBlock, n1 - r0);
        dot_block(a.v.data() + r0 * kDescriptorBytes, nr, b.v.data(), n2, dots.data());
        for (std::size_t r = 0; r < nr; ++r) {
            const int32_t* row = dots.data() + r * n2;
            Best& br = rows[r0 + r];
            for (std::size_t c = 0; c < n2; ++c) {
                br.add(row[c], static_cast<int>(c));
                cols[c].add(row[c], static_cast<int>(r0 + r));
            }
        }
    }
    const float ratio = static_cast<float>(o.max_ratio), distance = static_cast<float>(o.max_distance);
    std::vector<int> back(n2, -1);
    if (o.cross_check)
        for (std::size_t c = 0; c < n2; ++c)
            if (cols[c].accepted(ratio, distance)) back[c] = cols[c].index;
    for (std::size_t r = 0; r < n1; ++r) {
        const Best& br = rows[r];
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
    // One image's row of a feature table: rows x cols elements of `element`
    // bytes, checked against the blob's size (64-bit: a corrupt header must
    // not wrap). No row: 0 rows.
    struct Blob {
        std::size_t rows = 0, cols = 0;
        const void* data = nullptr;
    };
    auto fetch = [&](Statement& st, int image_id, std::size_t element, bool cols_ok(std::size_t), const std::string& what) {
        sqlite3_reset(st.stmt);
        sqlite3_bind_int(st.stmt, 1, image_id);
        Blob b;
        if (sqlite3_step(st.stmt) != SQLITE_ROW) return b;
        const long long rows = sqlite3_column_int64(st.stmt, 0), cols = sqlite3_column_int64(st.stmt, 1);
        const long long bytes = sqlite3_column_bytes(st.stmt, 2);
        b.data = sqlite3_column_blob(st.stmt, 2);
        if (rows < 0 || (rows > 0 && (cols <= 0 || !cols_ok(static_cast<std::size_t>(cols)) || !b.data ||
                                      rows > bytes || cols > bytes || bytes != rows * cols * static_cast<long long>(element))))
            throw Error(database_path, what);
        b.rows = static_cast<std::size_t>(rows), b.cols = static_cast<std::size_t>(cols);
        return b;
    };
    for (ImageFeatures& f : out) {
        // Keypoint columns: x y (2), x y scale orientation (4), x y a11 a12 a21 a22 (6).
        const Blob k = fetch(kp, f.image_id, sizeof(float), [](std::size_t c) { return c >= 2; }, "malformed keypoints of image " + f.name);
        const std::size_t nk = k.rows;
        if (nk > 0) {
            const auto* data = static_cast<const float*>(k.data);
            const std::size_t cols = k.cols;
            f.xy.resize(2 * nk);
            for (std::size_t i = 0; i < nk; ++i) f.xy[2 * i] = data[i * cols], f.xy[2 * i + 1] = data[i * cols + 1];
            if (cols == 4 || cols == 6) {
                f.scale.resize(nk);
                for (std::size_t i = 0; i < nk; ++i)
                    f.scale[i] = cols == 4 ? data[i * cols + 2] : std::hypot(data[i * cols + 2], data[i * cols + 4]);
            }
        }
        const Blob dsc = fetch(desc, f.image_id, 1, [](std::size_t c) { return c == kDescriptorBytes; },
                               "descriptors of image " + f.name + " are not 128-byte SIFT");
        const std::size_t nd = dsc.rows;
        if (nd > 0) f.descriptors.assign(static_cast<const uint8_t*>(dsc.data), static_cast<const uint8_t*>(dsc.data) + nd * kDescriptorBytes);
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
    return match_rows(to_rows(first, first_count), to_rows(second, second_count), options);
}

std::vector<PairMatches> match_image_pairs(const std::vector<ImageFeatures>& features, const std::vector<std::pair<int, int>>& pairs,
                                           const FeatureMatchOptions& options, const Progress& progress) {
    options.validate();
    const int n = static_cast<int>(features.size());
    for (const auto& [i, j] : pairs)
        if (i < 0 || j < 0 || i >= n || j >= n || i == j) throw Error("feature matching", "pair index out of range");
    // Matchable descriptors once per image (shared read-only by the pairs),
    // with their indices among the image's features.
    std::vector<Rows> f(features.size());
    std::vector<std::vector<uint32_t>> index(features.size());
    tbb::parallel_for(std::size_t(0), features.size(), [&](std::size_t i) {
        const ImageFeatures& im = features[i];
        for (std::size_t k = 0; k < im.count; ++k)
            if (matchable_feature(im, k, options)) index[i].push_back(static_cast<uint32_t>(k));
        f[i].count = index[i].size();
        f[i].v.resize(f[i].count * kDescriptorBytes);
        for (std::size_t r = 0; r < index[i].size(); ++r)
            std::copy_n(im.descriptors.data() + index[i][r] * kDescriptorBytes, kDescriptorBytes, f[i].v.data() + r * kDescriptorBytes);
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
            out[k].matches = match_rows(f[static_cast<std::size_t>(i)], f[static_cast<std::size_t>(j)], options);
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
