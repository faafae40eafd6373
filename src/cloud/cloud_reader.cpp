#include "cloud/cloud_reader.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <vector>

#include "cloud/copc.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "core/log.hpp"
#include "core/random_access_file.hpp"

namespace cityforge {

std::string to_string(CloudFormat f) {
    switch (f) {
        case CloudFormat::las: return "LAS";
        case CloudFormat::ply: return "PLY";
        case CloudFormat::xyz: return "XYZ";
    }
    return "LAS";
}

namespace {

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return s;
}

// Does the box min_x..max_x, min_y..max_y hold the bounds x0..x1, y0..y1?
bool box_holds(double min_x, double min_y, double max_x, double max_y, double x0, double y0, double x1, double y1) {
    return x0 >= min_x && y0 >= min_y && x1 <= max_x && y1 <= max_y;
}

class LasFormatReader final : public CloudFormatReader {
public:
    explicit LasFormatReader(RandomAccessFile file) : path_(file.path()), reader_(std::move(file)) {
        if (reader_.laz_source()) copc_ = read_copc_hierarchy(reader_.file(), reader_.header());
    }
    std::size_t read_chunk(PointCloud& out, std::size_t max_points) override { return reader_.read_chunk(out, max_points); }
    std::size_t reserve_hint() const override { return reader_.reserve_hint(); }
    void restrict_to_box(double min_x, double min_y, double max_x, double max_y) override {
        LazPointSource* laz = reader_.laz_source();
        const LasHeader& h = reader_.header();
        if (!laz) {
            // Only the points in the box kept while decoding, unless the
            // header's bounds say the box holds them all (a tile's own window).
            if (!box_holds(min_x, min_y, max_x, max_y, h.min[0], h.min[1], h.max[0], h.max[1])) reader_.restrict_to_box(min_x, min_y, max_x, max_y);
            return;
        }
        if (copc_) {
            // Pad by one quantum: points sit on the scale grid, the cubes need not.
            const double pad = std::max(h.scale[0], h.scale[1]);
            reader_.select_laz_chunks(copc_chunks_in_box(*copc_, laz->chunks(), min_x, min_y, max_x, max_y, pad, -1, path_));
            return;
        }
        // Layered LAZ: skip the chunks whose XY layer has no point in the box
        // (closed box: a superset of the caller's half-open one).
        const auto keep = laz->chunks_meeting_box({min_x, min_y, max_x, max_y, h.scale[0], h.scale[1], h.offset[0], h.offset[1]});
        if (!keep.empty()) reader_.select_laz_chunks(keep);
    }
    std::string path_;
    LasReader reader_;
    std::optional<CopcHierarchy> copc_;
};

// ------------------------------------------------------------------ PLY
enum class PlyType { i8, u8, i16, u16, i32, u32, f32, f64 };
int ply_size(PlyType t) {
    switch (t) {
        case PlyType::i8: case PlyType::u8: return 1;
        case PlyType::i16: case PlyType::u16: return 2;
        case PlyType::i32: case PlyType::u32: case PlyType::f32: return 4;
        case PlyType::f64: return 8;
    }
    return 1;
}
bool ply_type(const std::string& s, PlyType& t) {
    static const std::pair<const char*, PlyType> names[] = {
        {"char", PlyType::i8},   {"int8", PlyType::i8},     {"uchar", PlyType::u8},   {"uint8", PlyType::u8},
        {"short", PlyType::i16}, {"int16", PlyType::i16},   {"ushort", PlyType::u16}, {"uint16", PlyType::u16},
        {"int", PlyType::i32},   {"int32", PlyType::i32},   {"uint", PlyType::u32},   {"uint32", PlyType::u32},
        {"float", PlyType::f32}, {"float32", PlyType::f32}, {"double", PlyType::f64}, {"float64", PlyType::f64}};
    for (const auto& [n, v] : names)
        if (s == n) {
            t = v;
            return true;
        }
    return false;
}

enum class Field { x, y, z, red, green, blue, classification, intensity, ignore };

class PlyFormatReader final : public CloudFormatReader {
public:
    PlyFormatReader(const std::string& path, uint64_t& announced) : path_(path), in_(path, std::ios::binary) {
        if (!in_) throw Error(path, "cannot open for reading");
        std::string line;
        std::getline(in_, line);
        if (line.rfind("ply", 0) != 0) throw Error(path, "not a PLY file");
        bool in_vertex = false, seen_vertex = false, other_before_vertex = false, other_after_vertex = false;
        while (std::getline(in_, line)) {
            if (!line.empty() && line.back() == '\r') line.pop_back();
            std::istringstream ls(line);
            std::string word;
            ls >> word;
            if (word == "format") {
                std::string f;
                ls >> f;
                if (f == "ascii") ascii_ = true;
                else if (f == "binary_little_endian") big_endian_ = false;
                else if (f == "binary_big_endian") big_endian_ = true;
                else throw Error(path, "unknown PLY format '" + f + "'");
            } else if (word == "element") {
                std::string name;
                uint64_t count = 0;
                ls >> name >> count;
                in_vertex = name == "vertex";
                if (in_vertex) {
                    seen_vertex = true;
                    count_ = count;
                } else if (!seen_vertex && count > 0) {
                    other_before_vertex = true;
                } else if (count > 0) {
                    other_after_vertex = true;
                }
            } else if (word == "property" && in_vertex) {
                std::string type, name;
                ls >> type;
                if (type == "list") throw Error(path, "PLY vertex element has a list property (unsupported)");
                ls >> name;
                PlyType t;
                if (!ply_type(type, t)) throw Error(path, "unknown PLY property type '" + type + "'");
                const std::string n = lower(name);
                Field f = Field::ignore;
                if (n == "x") f = Field::x;
                else if (n == "y") f = Field::y;
                else if (n == "z") f = Field::z;
                else if (n == "red" || n == "r" || n == "diffuse_red") f = Field::red;
                else if (n == "green" || n == "g" || n == "diffuse_green") f = Field::green;
                else if (n == "blue" || n == "b" || n == "diffuse_blue") f = Field::blue;
                else if (n == "classification" || n == "class" || n == "scalar_classification" || n == "label") f = Field::classification;
                else if (n == "intensity" || n == "scalar_intensity") f = Field::intensity;
                props_.push_back({t, f});
                record_ += ply_size(t);
            } else if (word == "end_header") {
                break;
            }
        }
        if (!in_) throw Error(path, "PLY header has no end_header");
        if (!seen_vertex) throw Error(path, "PLY file has no vertex element");
        if (other_before_vertex) throw Error(path, "PLY elements before 'vertex' are not supported");
        bool has[3] = {false, false, false};
        for (const auto& p : props_) {
            if (p.field == Field::x) has[0] = true;
            if (p.field == Field::y) has[1] = true;
            if (p.field == Field::z) has[2] = true;
            if (p.field == Field::red || p.field == Field::green || p.field == Field::blue) color_ = true;
            if (p.field == Field::red || p.field == Field::green || p.field == Field::blue) color_16_ = color_16_ || ply_size(p.type) == 2;
        }
        if (!has[0] || !has[1] || !has[2]) throw Error(path, "PLY vertex element lacks x, y or z");
        if (!ascii_) {
            const auto start = static_cast<uint64_t>(in_.tellg());
            const auto size = static_cast<uint64_t>(std::filesystem::file_size(path));
            const uint64_t room = size - std::min(size, start);
            // As quotients: count x record can wrap 2^64.
            if (count_ > room / record_)
                throw Error(path, "PLY header announces " + std::to_string(count_) + " vertices of " + std::to_string(record_) +
                                      " bytes but the file holds only " + std::to_string(room / record_) + " (truncated, or property types that do not match the data)");
            // With nothing after the vertices, their data must end the file: a
            // file declaring float and holding doubles is twice as long.
            if (!other_after_vertex && room - count_ * record_ >= record_)
                throw Error(path, "PLY vertex data takes " + std::to_string(count_ * record_) + " bytes by its header (" + std::to_string(count_) +
                                      " x " + std::to_string(record_) + ") but the file holds " + std::to_string(room) +
                                      " after the header: the declared property types do not match the data");
        }
        announced = count_;
    }

    std::size_t read_chunk(PointCloud& out, std::size_t max_points) override {
        const auto n = static_cast<std::size_t>(std::min<uint64_t>(max_points, count_ - read_));
        if (n == 0) return 0;
        out.reserve(out.size() + n, color_, false);
        std::vector<char> buf;
        if (!ascii_) {
            buf.resize(n * record_);
            in_.read(buf.data(), static_cast<std::streamsize>(buf.size()));
            if (static_cast<std::size_t>(in_.gcount()) != buf.size()) throw Error(path_, "truncated PLY vertex data");
        }
        std::string line;
        for (std::size_t i = 0; i < n; ++i) {
            double v[8] = {0, 0, 0, 0, 0, 0, 1, 0};  // x y z r g b class intensity
            if (ascii_) {
                if (!std::getline(in_, line)) throw Error(path_, "PLY has fewer vertex lines than announced (truncated)");
                const char* p = line.data();
                const char* end = line.data() + line.size();
                for (const auto& prop : props_) {
                    while (p < end && (*p == ' ' || *p == '\t')) ++p;
                    double value = 0.0;
                    const auto r = std::from_chars(p, end, value);
                    if (r.ec != std::errc()) throw Error(path_, "bad number in PLY vertex line " + std::to_string(read_ + i + 1));
                    p = r.ptr;
                    store(prop.field, value, v);
                }
            } else {
                const char* p = buf.data() + i * record_;
                for (const auto& prop : props_) {
                    store(prop.field, decode(p, prop.type), v);
                    p += ply_size(prop.type);
                }
            }
            out.x.push_back(v[0]), out.y.push_back(v[1]), out.z.push_back(v[2]);
            out.classification.push_back(static_cast<uint8_t>(std::clamp(v[6], 0.0, 255.0)));
            out.intensity.push_back(static_cast<uint16_t>(std::clamp(v[7], 0.0, 65535.0)));
            out.return_number.push_back(1), out.number_of_returns.push_back(1);
            if (color_) {
                const double k = color_16_ ? 1.0 : 257.0;  // 8-bit colour to LAS-style 16-bit
                out.red.push_back(static_cast<uint16_t>(std::clamp(v[3] * k, 0.0, 65535.0)));
                out.green.push_back(static_cast<uint16_t>(std::clamp(v[4] * k, 0.0, 65535.0)));
                out.blue.push_back(static_cast<uint16_t>(std::clamp(v[5] * k, 0.0, 65535.0)));
            }
        }
        read_ += n;
        return n;
    }

private:
    struct Prop {
        PlyType type;
        Field field;
    };
    static void store(Field f, double value, double* v) {
        switch (f) {
            case Field::x: v[0] = value; break;
            case Field::y: v[1] = value; break;
            case Field::z: v[2] = value; break;
            case Field::red: v[3] = value; break;
            case Field::green: v[4] = value; break;
            case Field::blue: v[5] = value; break;
            case Field::classification: v[6] = value; break;
            case Field::intensity: v[7] = value; break;
            case Field::ignore: break;
        }
    }
    template <typename T>
    T get(const char* p) const {
        std::array<char, sizeof(T)> b;
        std::memcpy(b.data(), p, sizeof(T));
        if (big_endian_ != (std::endian::native == std::endian::big)) std::reverse(b.begin(), b.end());
        T v;
        std::memcpy(&v, b.data(), sizeof(T));
        return v;
    }
    double decode(const char* p, PlyType t) const {
        switch (t) {
            case PlyType::i8: return get<int8_t>(p);
            case PlyType::u8: return get<uint8_t>(p);
            case PlyType::i16: return get<int16_t>(p);
            case PlyType::u16: return get<uint16_t>(p);
            case PlyType::i32: return get<int32_t>(p);
            case PlyType::u32: return get<uint32_t>(p);
            case PlyType::f32: return get<float>(p);
            case PlyType::f64: return get<double>(p);
        }
        return 0.0;
    }

    std::string path_;
    std::ifstream in_;
    bool ascii_ = false, big_endian_ = false, color_ = false, color_16_ = false;
    uint64_t count_ = 0, read_ = 0;
    std::size_t record_ = 0;
    std::vector<Prop> props_;
};

// ------------------------------------------------------------------ XYZ
class XyzFormatReader final : public CloudFormatReader {
public:
    explicit XyzFormatReader(const std::string& path) : path_(path), in_(path) {
        if (!in_) throw Error(path, "cannot open for reading");
    }
    std::size_t read_chunk(PointCloud& out, std::size_t max_points) override {
        std::string line;
        std::size_t n = 0;
        std::vector<double> v;
        while (n < max_points && std::getline(in_, line)) {
            ++line_no_;
            for (char& c : line)
                if (c == ',' || c == ';' || c == '\t' || c == '\r') c = ' ';
            v.clear();
            const char* p = line.data();
            const char* end = p + line.size();
            bool numeric = true;
            while (p < end) {
                while (p < end && *p == ' ') ++p;
                if (p >= end) break;
                double value;
                const auto r = std::from_chars(p, end, value);
                if (r.ec != std::errc()) {
                    numeric = false;
                    break;
                }
                v.push_back(value);
                p = r.ptr;
            }
            if (v.empty() && numeric) continue;  // blank line
            if (!numeric) {
                if (points_ == 0 && !header_seen_) {  // a header line naming the columns
                    header_seen_ = true;
                    parse_header(line);
                    continue;
                }
                throw Error(path_, "line " + std::to_string(line_no_) + " is not numeric");
            }
            if (columns_ == 0) columns_ = static_cast<int>(v.size());
            if (static_cast<int>(v.size()) != columns_ || columns_ < 3)
                throw Error(path_, "line " + std::to_string(line_no_) + " has " + std::to_string(v.size()) + " columns, expected " +
                                       std::to_string(std::max(3, columns_)));
            append(out, v);
            ++n;
            ++points_;
        }
        return n;
    }

private:
    void parse_header(const std::string& line) {
        std::istringstream s(line);
        std::string name;
        int i = 0;
        while (s >> name) {
            name = lower(name);
            if (name == "x") ix_ = i;
            else if (name == "y") iy_ = i;
            else if (name == "z") iz_ = i;
            else if (name == "r" || name == "red") ir_ = i;
            else if (name == "g" || name == "green") ig_ = i;
            else if (name == "b" || name == "blue") ib_ = i;
            else if (name == "classification" || name == "class") ic_ = i;
            else if (name == "intensity" || name == "i") ii_ = i;
            ++i;
        }
        named_ = true;
    }
    void append(PointCloud& out, const std::vector<double>& v) {
        if (!named_) {
            // Unnamed columns: x y z [intensity] | x y z r g b [class]
            ix_ = 0, iy_ = 1, iz_ = 2;
            if (columns_ == 4) ii_ = 3;
            if (columns_ >= 6) ir_ = 3, ig_ = 4, ib_ = 5;
            if (columns_ == 7) ic_ = 6;
            named_ = true;
        }
        if (ix_ < 0 || iy_ < 0 || iz_ < 0) throw Error(path_, "header does not name x, y and z columns");
        const int need = std::max({ix_, iy_, iz_, ii_, ic_, ir_, ig_, ib_});
        if (static_cast<int>(v.size()) <= need)  // a short line (found by fuzzing: it read past the row)
            throw Error(path_, "a line has " + std::to_string(v.size()) + " columns where " + std::to_string(need + 1) + " are expected");
        out.x.push_back(v[ix_]), out.y.push_back(v[iy_]), out.z.push_back(v[iz_]);
        out.classification.push_back(ic_ >= 0 ? static_cast<uint8_t>(std::clamp(v[ic_], 0.0, 255.0)) : uint8_t(1));
        out.intensity.push_back(ii_ >= 0 ? static_cast<uint16_t>(std::clamp(v[ii_], 0.0, 65535.0)) : uint16_t(0));
        out.return_number.push_back(1), out.number_of_returns.push_back(1);
        if (ir_ >= 0 && ig_ >= 0 && ib_ >= 0) {
            if (out.red.size() + 1 < out.x.size()) throw Error(path_, "colour columns appear midway");
            const double k = 257.0;  // text colour is 8-bit by convention
            out.red.push_back(static_cast<uint16_t>(std::clamp(v[ir_] * k, 0.0, 65535.0)));
            out.green.push_back(static_cast<uint16_t>(std::clamp(v[ig_] * k, 0.0, 65535.0)));
            out.blue.push_back(static_cast<uint16_t>(std::clamp(v[ib_] * k, 0.0, 65535.0)));
        }
    }

    std::string path_;
    std::ifstream in_;
    uint64_t line_no_ = 0, points_ = 0;
    bool header_seen_ = false, named_ = false;
    int columns_ = 0;
    int ix_ = -1, iy_ = -1, iz_ = -1, ir_ = -1, ig_ = -1, ib_ = -1, ic_ = -1, ii_ = -1;
};

}  // namespace

CloudReader::CloudReader(const std::string& path) : path_(path) {
    // The format is read off the first bytes of the file that a LAS reader
    // then reads from (one open for LAS: a file replaced under its path in
    // between cannot be taken for another format). PLY and text files are
    // opened again as streams by their readers.
    RandomAccessFile file(path, "a point cloud file");  // "file not found", "is a directory, ..."
    const std::string ext = lower(std::filesystem::path(path).extension().string());
    char magic[4] = {};
    file.read_at(0, magic, sizeof magic);
    if (std::memcmp(magic, "LASF", 4) == 0 || ext == ".las" || ext == ".laz") {
        auto las = std::make_unique<LasFormatReader>(std::move(file));
        crs_records_ = las->reader_.header().crs;
        announced_ = las->reader_.header().point_count;
        const LasHeader& h = las->reader_.header();
        announced_bounds_ = std::array<double, 4>{h.min[0], h.min[1], h.max[0], h.max[1]};
        copc_ = las->copc_.has_value();
        color_ = las->reader_.header().has_color(), gps_ = las->reader_.header().has_gps_time();
        format_ = CloudFormat::las;
        impl_ = std::move(las);
    } else if (std::memcmp(magic, "ply", 3) == 0 || ext == ".ply") {
        format_ = CloudFormat::ply;
        impl_ = std::make_unique<PlyFormatReader>(path, announced_);
    } else if (ext == ".xyz" || ext == ".txt" || ext == ".csv" || ext == ".pts") {
        format_ = CloudFormat::xyz;
        impl_ = std::make_unique<XyzFormatReader>(path);
    } else {
        throw Error(path, "unknown point cloud format (expected LAS, PLY or XYZ/CSV text)");
    }
}

std::size_t CloudReader::read_chunk(PointCloud& out, std::size_t max_points) {
    while (true) {
        const std::size_t base = out.size();
        const std::size_t n = impl_->read_chunk(out, max_points);
        if (n == 0) {
            if (!end_reported_ && dropped_non_finite_ > 0) {
                end_reported_ = true;
                const std::string what = std::to_string(dropped_non_finite_) + " of " + std::to_string(seen_) +
                                         " points have a NaN or infinite coordinate";
                if (dropped_non_finite_ == seen_) throw Error(path_, "all " + what);
                log::warning(path_ + ": " + what + " and were dropped");
            }
            return 0;
        }
        seen_ += n;
        // LAS coordinates are integers x a scale of at most 1e4 + an offset of
        // at most 1e12 (checked on open): always finite, nothing to scan.
        if (format_ == CloudFormat::las) return n;
        auto non_finite = [&](std::size_t i) { return !std::isfinite(out.x[i]) || !std::isfinite(out.y[i]) || !std::isfinite(out.z[i]); };
        if (!any_point(base, out.size(), non_finite)) return n;  // the usual case: no compaction pass
        const std::size_t dropped = out.remove_from(base, non_finite);
        dropped_non_finite_ += dropped;
        if (dropped < n) return n - dropped;  // else: read on, 0 means the end
    }
}

void CloudReader::reserve_for_all(PointCloud& cloud) const {
    if (const std::size_t n = impl_->reserve_hint()) cloud.reserve(cloud.size() + n, color_, gps_);
}

CloudReader::~CloudReader() = default;
CloudReader::CloudReader(CloudReader&&) noexcept = default;
CloudReader& CloudReader::operator=(CloudReader&&) noexcept = default;

PointCloud read_point_cloud(const std::string& path) {
    CloudReader reader(path);
    PointCloud cloud;
    reader.reserve_for_all(cloud);
    while (reader.read_chunk(cloud, 1u << 20) > 0) {
    }
    if (cloud.size() == 0) throw Error(path, "point cloud is empty");
    return cloud;
}

void append_point_cloud_in(const std::string& path, double min_x, double min_y, double max_x, double max_y, PointCloud& out) {
    CloudReader reader(path);
    reader.restrict_to_box(min_x, min_y, max_x, max_y);
    // A file whose header bounds lie inside the box (a run's tile split file
    // read for its own window) has all its points kept: their arrays are
    // reserved once, not regrown chunk by chunk.
    if (const auto& b = reader.announced_bounds(); b && box_holds(min_x, min_y, max_x, max_y, (*b)[0], (*b)[1], (*b)[2], (*b)[3]))
        reader.reserve_for_all(out);
    // Chunks are read straight into `out`, and the points outside the box of
    // each are taken off again (in file order) only when it holds some.
    auto outside = [&](std::size_t i) { return !(out.x[i] >= min_x && out.x[i] < max_x && out.y[i] >= min_y && out.y[i] < max_y); };
    // Every attribute array holds one value per point or none (a file with
    // colour or GPS time read after parts without them: the LAS reader gives
    // the earlier points zeros; a PLY or text file after parts with them
    // would leave the arrays short).
    auto aligned = [&] {
        for (const std::size_t k : {out.gps_time.size(), out.red.size(), out.green.size(), out.blue.size()})
            if (k != 0 && k != out.size()) return false;
        return true;
    };
    // A file that fails part-way leaves `out` as it was: its points (and the
    // attributes it added) are taken off again.
    const PointCloud::Mark before = out.mark();
    try {
        while (true) {
            const std::size_t base = out.size();
            if (reader.read_chunk(out, 1u << 20) == 0) break;
            if (!aligned()) throw Error(path, "its points carry other attributes (colour, GPS time) than the cloud parts read before it for the same window");
            if (any_point(base, out.size(), outside)) out.remove_from(base, outside);
        }
    } catch (...) {
        out.roll_back(before);
        throw;
    }
}

PointCloud read_point_cloud_in(const std::string& path, double min_x, double min_y, double max_x, double max_y) {
    PointCloud out;
    append_point_cloud_in(path, min_x, min_y, max_x, max_y, out);
    return out;
}

}  // namespace cityforge
