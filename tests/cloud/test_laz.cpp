// LAZ / COPC decoding against the corpus oracle (laz-perf's decode of real
// files from LASzip, laz-perf, PDAL and IGN writers), `cloud translate`,
// window reads and corrupt input.
#include <catch2/catch.hpp>
#include <algorithm>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <tbb/global_control.h>

#include "same_cloud.hpp"
#include "cloud/cloud_reader.hpp"
#include "cloud/cloud_translate.hpp"
#include "cloud/copc.hpp"
#include "cloud/las.hpp"
#include "core/error.hpp"
#include "core/sha256.hpp"
#include "test_support.hpp"

using namespace cityforge;
using cityforge::test::ScratchDir;
using cityforge::test::shared_data;
using cityforge::test::slurp;

namespace {

nlohmann::json oracle() {
    std::ifstream f(shared_data("laz_corpus/oracle.json"));
    return nlohmann::json::parse(f);
}
std::string corpus(const std::string& name) { return shared_data("laz_corpus/" + name); }

// SHA-256 of every point record `reader` hands out.
std::string records_sha(LasReader& reader, uint64_t* count = nullptr) {
    Sha256 sha;
    std::vector<char> rec;
    uint64_t n = 0;
    while (const std::size_t k = reader.read_records(rec, 100000)) {
        sha.update(rec.data(), rec.size());
        n += k;
    }
    if (count) *count = n;
    return sha.hex();
}

// Reads every point; returns the Error message, or "" when it decoded.
std::string decode_all(const std::string& path) {
    try {
        LasReader reader(path);
        records_sha(reader);
        return "";
    } catch (const Error& e) {
        return e.what();
    }
}

void write_file(const std::string& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

}  // namespace

TEST_CASE("Sha256 matches the FIPS 180-4 test vectors", "[laz]") {
    Sha256 empty;
    CHECK(empty.hex() == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    Sha256 abc;
    abc.update("abc", 3);
    CHECK(abc.hex() == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    Sha256 split;  // two blocks, fed in uneven pieces
    const std::string msg = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq";
    split.update(msg.data(), 5);
    split.update(msg.data() + 5, msg.size() - 5);
    CHECK(split.hex() == "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
}

TEST_CASE("cloud translate of every corpus LAZ gives laz-perf's point records byte for byte", "[laz][corpus]") {
    ScratchDir dir("laz_oracle");
    int checked = 0;
    const nlohmann::json o_json = oracle();
    for (const auto& entry : o_json["files"]) {
        const std::string name = entry["file"];
        if (!entry.value("decoded", false)) continue;
        INFO(name);
        CloudTranslateOptions o;
        o.input = corpus(name);
        o.output = dir / (name + ".las");
        const CloudTranslateResult r = translate_cloud(o);
        CHECK(r.decompressed);
        CHECK(r.points_written == entry["point_count"].get<uint64_t>());
        CHECK(r.points_sha256 == entry["points_sha256"].get<std::string>());
        // The output is a plain LAS: compression bit cleared, same format, no LASzip/COPC records.
        LasReader out(o.output);
        CHECK_FALSE(out.header().laz.has_value());
        CHECK(out.header().point_format == entry["point_format"].get<int>());
        CHECK(out.header().point_record_length == entry["point_record_length"].get<int>());
        CHECK(out.header().point_count == r.points_written);
        CHECK(records_sha(out) == entry["points_sha256"].get<std::string>());
        const std::string bytes = slurp(o.output);
        CHECK(bytes.find("laszip encoded") == std::string::npos);
        ++checked;
    }
    CHECK(checked == 26);
}

TEST_CASE("LAZ info: compressor, chunks and items are read from the LASzip VLR", "[laz]") {
    LasReader pointwise(corpus("autzen_trim.laz"));
    REQUIRE(pointwise.header().laz);
    CHECK(pointwise.header().laz->compressor == 2);
    CHECK(pointwise.header().laz->chunk_size == 50000);
    REQUIRE(pointwise.header().laz->items.size() == 3);
    CHECK(to_string(pointwise.header().laz->items[0]) == "POINT10 v2");
    CHECK(pointwise.laz_source()->chunks().size() == 3);
    CHECK(pointwise.laz_source()->has_chunk_table());

    LasReader layered(corpus("870000_6618000.subset.postValidation.laz"));
    REQUIRE(layered.header().laz);
    CHECK(layered.header().laz->compressor == 3);
    CHECK(layered.header().point_format == 8);
    CHECK(to_string(layered.header().laz->items.back()) == "BYTE14[56] v3");

    LasReader empty(corpus("no-points-1.3.laz"));
    CHECK(empty.laz_source()->chunks().empty());
    uint64_t n = 1;
    records_sha(empty, &n);
    CHECK(n == 0);
}

TEST_CASE("LAZ compressor 1 (LASzip 1.x, not chunked, item version 1) decodes to its LAS twin", "[laz]") {
    // laz-perf aborts on this file (no oracle); PDAL's 1.2-with-color.las holds the same 1,065 points.
    const std::string p = corpus("simple-laszip-compressor-version-1.2r0.laz");
    LasReader laz(p), las(corpus("reference_las/1.2-with-color.las"));
    REQUIRE(laz.header().laz);
    CHECK(laz.header().laz->compressor == 1);
    CHECK(laz.header().laz->items[0].version == 1);
    CHECK(laz.laz_source()->chunks().size() == 1);
    CHECK_FALSE(laz.laz_source()->has_chunk_table());
    uint64_t n = 0;
    CHECK(records_sha(laz, &n) == records_sha(las));
    CHECK(n == 1065);
    // Cut inside its one stream: a one-line error naming the file, never a crash.
    ScratchDir dir("laz_c1");
    std::string bytes = slurp(p);
    bytes.resize(bytes.size() / 2);
    write_file(dir / "cut.laz", bytes);
    CHECK_THAT(decode_all(dir / "cut.laz"), Catch::Contains("cut.laz") && !Catch::Contains("\n"));
}

TEST_CASE("LAZ decodes the same points as its uncompressed LAS twin", "[laz]") {
    // Upstream LAS files written by other software (the oracle's reference check).
    const std::pair<const char*, const char*> twins[] = {{"laz_corpus/point10.las.laz", "laz_corpus/reference_las/point10.las"},
                                                         {"laz_corpus/autzen_trim.laz", "autzen_oregon/autzen_trim.las"}};
    for (const auto& [laz, las] : twins) {
        INFO(laz);
        if (!std::filesystem::exists(shared_data(las))) continue;
        LasReader a(shared_data(laz)), b(shared_data(las));
        CHECK(records_sha(a) == records_sha(b));
        const PointCloud ca = read_point_cloud(shared_data(laz)), cb = read_point_cloud(shared_data(las));
        CHECK(ca.x == cb.x);
        CHECK(ca.z == cb.z);
        CHECK(ca.classification == cb.classification);
    }
}

TEST_CASE("COPC: every hierarchy node decodes alone to the oracle's node hash", "[laz][copc]") {
    const nlohmann::json o_json = oracle();
    int files = 0;
    for (const auto& entry : o_json["files"]) {
        if (!entry.contains("copc_nodes_in_file_order")) continue;
        const std::string name = entry["file"];
        INFO(name);
        LasReader probe(corpus(name));
        const auto h = read_copc_hierarchy(probe.file(), probe.header());
        REQUIRE(h);
        const auto& nodes = entry["copc_nodes_in_file_order"];
        REQUIRE(h->nodes.size() == nodes.size());
        REQUIRE(probe.laz_source()->chunks().size() == nodes.size());
        for (std::size_t i = 0; i < nodes.size(); ++i) {
            CHECK(h->nodes[i].key() == nodes[i]["key"].get<std::string>());
            CHECK(h->nodes[i].offset == nodes[i]["offset"].get<uint64_t>());
            LasReader one(corpus(name));
            std::vector<bool> keep(nodes.size(), false);
            keep[i] = true;
            one.select_laz_chunks(keep);
            uint64_t n = 0;
            CHECK(records_sha(one, &n) == nodes[i]["points_sha256"].get<std::string>());
            CHECK(n == nodes[i]["point_count"].get<uint64_t>());
        }
        ++files;
    }
    CHECK(files == 3);
}

TEST_CASE("COPC window reads decode only the nodes that meet the window and miss no point", "[laz][copc]") {
    const std::string p = corpus("lone-star.copc.laz");
    CloudReader probe(p);
    CHECK(probe.copc());
    const PointCloud all = read_point_cloud(p);
    const double x0 = all.x[0], y0 = all.y[0];
    const double box[4] = {x0 - 10, y0 - 10, x0 + 10, y0 + 10};
    std::size_t inside = 0;
    for (std::size_t i = 0; i < all.size(); ++i)
        if (all.x[i] >= box[0] && all.x[i] < box[2] && all.y[i] >= box[1] && all.y[i] < box[3]) ++inside;
    REQUIRE(inside > 0);
    const PointCloud window = read_point_cloud_in(p, box[0], box[1], box[2], box[3]);
    CHECK(window.size() == inside);
    // The hierarchy really is used: fewer nodes than the whole file.
    LasReader reader(p);
    const auto h = read_copc_hierarchy(reader.file(), reader.header());
    REQUIRE(h);
    const auto keep = copc_chunks_in_box(*h, reader.laz_source()->chunks(), box[0], box[1], box[2], box[3], 0.001, -1, p);
    const auto kept = static_cast<std::size_t>(std::count(keep.begin(), keep.end(), true));
    CHECK(kept > 0);
    CHECK(kept < keep.size());
    // A translate crop of a COPC file skips nodes too and keeps the same points.
    ScratchDir dir("copc_crop");
    CloudTranslateOptions o;
    o.input = p;
    o.output = dir / "crop.las";
    o.bounds = std::array<double, 4>{box[0], box[1], box[2] - 1e-9, box[3] - 1e-9};
    const auto r = translate_cloud(o);
    CHECK(r.copc_nodes_skipped);
    CHECK(r.points_written == inside);
}

TEST_CASE("Window reads on layered LAZ skip the chunks whose XY layer misses the window and give the same points", "[laz][window]") {
    // 14 chunks of 50,000 points; their footprints differ (a scan order), so
    // a window in the south-west corner misses several of them.
    const std::string p = corpus("las_with_several_extra_byte_bloc.laz");
    const double box[4] = {484649, 6632629, 484800, 6632800};
    LasReader probe(p);
    const LasHeader& h = probe.header();
    const auto keep = probe.laz_source()->chunks_meeting_box({box[0], box[1], box[2], box[3], h.scale[0], h.scale[1], h.offset[0], h.offset[1]});
    REQUIRE(keep.size() == 14);
    const auto skipped = static_cast<std::size_t>(std::count(keep.begin(), keep.end(), false));
    CHECK(skipped >= 3);
    CHECK(skipped < keep.size());
    // Exact both ways: a chunk is kept if and only if one of its points (full
    // decode) lies in the closed box.
    LasReader full(p);
    std::vector<char> rec;
    std::vector<bool> truth(14, false);
    uint64_t index = 0;
    Sha256 inside_sha;
    uint64_t inside_closed = 0;
    while (const std::size_t n = full.read_records(rec, 100000)) {
        for (std::size_t i = 0; i < n; ++i, ++index) {
            const char* q = rec.data() + i * h.point_record_length;
            int32_t xi, yi;
            std::memcpy(&xi, q, 4);
            std::memcpy(&yi, q + 4, 4);
            const double x = xi * h.scale[0] + h.offset[0], y = yi * h.scale[1] + h.offset[1];
            if (x >= box[0] && x <= box[2] && y >= box[1] && y <= box[3]) {
                truth[index / 50000] = true;
                inside_sha.update(q, h.point_record_length);
                ++inside_closed;
            }
        }
    }
    CHECK(keep == truth);
    REQUIRE(inside_closed > 0);
    // Window read (the path of run's tiles and heights): the same points as a full decode + crop.
    const PointCloud all = read_point_cloud(p);
    PointCloud crop;
    for (std::size_t i = 0; i < all.size(); ++i)
        if (all.x[i] >= box[0] && all.x[i] < box[2] && all.y[i] >= box[1] && all.y[i] < box[3]) crop.append(all, i);
    const PointCloud window = read_point_cloud_in(p, box[0], box[1], box[2], box[3]);
    cityforge::test::check_same_cloud(window, crop);  // every attribute, not only coordinates, time and class
    // cloud translate --bounds: the same records, byte for byte, fewer chunks decoded.
    ScratchDir dir("laz_window");
    CloudTranslateOptions o;
    o.input = p;
    o.output = dir / "crop.las";
    o.bounds = std::array<double, 4>{box[0], box[1], box[2], box[3]};
    const auto r = translate_cloud(o);
    CHECK(r.laz_chunks == 14);
    CHECK(r.laz_chunks_skipped == skipped);
    CHECK(r.points_written == inside_closed);
    CHECK(r.points_read < h.point_count);
    CHECK(r.points_sha256 == inside_sha.hex());
    // Pointwise chunks interleave every field in one stream: no XY-only scan.
    LasReader pointwise(corpus("lone-star.laz"));
    CHECK(pointwise.laz_source()->chunks_meeting_box({0, 0, 1, 1, 0.01, 0.01, 0, 0}).empty());
}

TEST_CASE("cloud translate crops, converts XYZ and refuses to overwrite", "[laz]") {
    ScratchDir dir("translate");
    CloudTranslateOptions o;
    o.input = corpus("autzen_trim.laz");
    o.output = dir / "crop.las";
    o.bounds = std::array<double, 4>{636500, 849000, 636800, 849300};
    const auto r = translate_cloud(o);
    const PointCloud all = read_point_cloud(o.input);
    std::size_t inside = 0;
    for (std::size_t i = 0; i < all.size(); ++i)
        if (all.x[i] >= 636500 && all.x[i] <= 636800 && all.y[i] >= 849000 && all.y[i] <= 849300) ++inside;
    CHECK(r.points_written == inside);
    LasReader crop(o.output);
    CHECK(crop.header().point_count == inside);
    CHECK(crop.header().min[0] >= 636500);
    CHECK(crop.header().max[1] <= 849300);
    CHECK(crop.header().crs.wkt == LasReader(o.input).header().crs.wkt);
    CHECK_THROWS_WITH(translate_cloud(o), Catch::Contains("crop.las") && Catch::Contains("--overwrite"));
    o.bounds = std::array<double, 4>{0, 0, 1, 1};
    o.overwrite = true;
    CHECK_THROWS_WITH(translate_cloud(o), Catch::Contains("no point lies inside"));
    CHECK(LasReader(o.output).header().point_count == inside);  // the old output is untouched

    write_file(dir / "pts.xyz", "x y z intensity\n1000.5 2000.25 3.125 7\n1001.5 2001.25 4.5 9\n");
    CloudTranslateOptions x;
    x.input = dir / "pts.xyz";
    x.output = dir / "pts.las";
    CHECK(translate_cloud(x).points_written == 2);
    const PointCloud back = read_las(x.output);
    REQUIRE(back.size() == 2);
    CHECK(back.x[1] == Approx(1001.5).margin(1e-9));
    CHECK(back.z[0] == Approx(3.125).margin(1e-9));
    CHECK(back.intensity[1] == 9);
}

TEST_CASE("Corrupt LAZ gets a one-line error naming the file and never crashes", "[laz][corrupt]") {
    ScratchDir dir("laz_corrupt");
    const std::string pointwise = slurp(corpus("point-color-time.las.laz"));
    const std::string layered = slurp(corpus("crop_duplicate.laz"));
    const std::string copc = slurp(corpus("autzen_clip_native.copc.laz"));
    LasReader pr(corpus("point-color-time.las.laz"));
    const uint64_t points_at = pr.header().offset_to_points;
    int64_t table_at = 0;
    std::memcpy(&table_at, pointwise.data() + points_at, 8);

    SECTION("truncated inside the chunk") {
        const std::string p = dir / "trunc.laz";
        std::string b = pointwise.substr(0, points_at + 8 + 3000);
        b += pointwise.substr(static_cast<std::size_t>(table_at));  // chunk table kept, chunk cut
        write_file(p, b);
        const std::string msg = decode_all(p);
        CHECK_THAT(msg, Catch::Contains("trunc.laz") && !Catch::Contains("\n"));
    }
    SECTION("chunk table pointer outside the file / chunk count past the file") {
        const std::string p = dir / "table.laz";
        std::string b = pointwise;
        const int64_t bad = static_cast<int64_t>(b.size()) + 1000;
        std::memcpy(b.data() + points_at, &bad, 8);
        write_file(p, b);
        // Fixed-size chunks can still be read one after the other.
        CHECK(decode_all(p).empty());
        b = pointwise;
        const uint32_t many = 1000000;
        std::memcpy(b.data() + table_at + 4, &many, 4);
        write_file(p, b);
        CHECK_THAT(decode_all(p), Catch::Contains("table.laz") && Catch::Contains("chunk table lists 1000000 chunks"));
    }
    SECTION("a layer shorter than its data: the decoder runs off its buffer") {
        const std::string p = dir / "layer.laz";
        std::string b = layered;
        LasReader lr(corpus("crop_duplicate.laz"));
        const std::size_t chunk = lr.laz_source()->chunks().at(0).offset;
        const std::size_t xy_size_at = chunk + static_cast<std::size_t>(lr.header().point_record_length) + 4;
        const uint32_t tiny = 8;
        std::memcpy(b.data() + xy_size_at, &tiny, 4);
        write_file(p, b);
        CHECK_THAT(decode_all(p), Catch::Contains("layer.laz: chunk 0: arithmetic decoder ran off the end of its data"));
    }
    SECTION("unknown item type") {
        const std::string p = dir / "item.laz";
        std::string b = layered;
        const std::size_t vlr = b.find("laszip encoded");
        REQUIRE(vlr != std::string::npos);
        const std::size_t payload = vlr - 2 + 54;
        const uint16_t type = 42;
        std::memcpy(b.data() + payload + 34, &type, 2);  // first item's type
        write_file(p, b);
        CHECK_THAT(decode_all(p), Catch::Contains("item.laz") && Catch::Contains("not supported"));
    }
    SECTION("mutations: random bytes in the compressed points decode or fail cleanly") {
        std::mt19937 rng(18);
        int clean_errors = 0, decoded = 0;
        const std::pair<const std::string*, const char*> files[] = {{&pointwise, "m_pw.laz"}, {&layered, "m_ly.laz"}, {&copc, "m_copc.laz"}};
        for (const auto& [bytes, name] : files) {
            LasReader base([&] {
                write_file(dir / name, *bytes);
                return dir / name;
            }());
            const std::size_t start = base.header().offset_to_points + 8;
            for (int it = 0; it < 60; ++it) {
                std::string b = *bytes;
                const int flips = 1 + static_cast<int>(rng() % 8);
                for (int f = 0; f < flips; ++f) {
                    const std::size_t at = start + rng() % (b.size() - start);
                    b[at] = static_cast<char>(rng() & 0xFF);
                }
                if (it % 10 == 9) b.resize(start + rng() % (b.size() - start));  // and truncations
                write_file(dir / name, b);
                const std::string msg = decode_all(dir / name);
                if (msg.empty()) {
                    ++decoded;
                } else {
                    CHECK_THAT(msg, Catch::Contains(name) && !Catch::Contains("\n"));
                    ++clean_errors;
                }
            }
        }
        CHECK(clean_errors > 0);
        CHECK(clean_errors + decoded == 180);
    }
}

TEST_CASE("heights on a LAZ gives the same output bytes as on its LAS twin", "[laz][heights]") {
    ScratchDir dir("laz_heights");
    // Four 80 ft squares over the Autzen strip (EPSG:2994, feet).
    std::string fc = R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::2994"}},"features":[)";
    const double centres[4][2] = {{636300, 849100}, {636600, 849200}, {636900, 849300}, {637100, 849400}};
    for (int i = 0; i < 4; ++i) {
        const double x = centres[i][0], y = centres[i][1], h = 40;
        fc += std::string(i ? "," : "") + R"({"type":"Feature","properties":{"id":)" + std::to_string(i) +
              R"(},"geometry":{"type":"Polygon","coordinates":[[[)" + std::to_string(x - h) + "," + std::to_string(y - h) + "],[" +
              std::to_string(x + h) + "," + std::to_string(y - h) + "],[" + std::to_string(x + h) + "," + std::to_string(y + h) + "],[" +
              std::to_string(x - h) + "," + std::to_string(y + h) + "],[" + std::to_string(x - h) + "," + std::to_string(y - h) + "]]]}}";
    }
    fc += "]}";
    write_file(dir / "fp.geojson", fc);
    // Same file name in two folders, so that nothing but the encoding differs.
    std::filesystem::create_directories(dir / "laz");
    std::filesystem::create_directories(dir / "las");
    std::filesystem::copy_file(corpus("autzen_trim.laz"), dir / "laz/autzen_trim.cloud");
    std::filesystem::copy_file(shared_data("autzen_oregon/autzen_trim.las"), dir / "las/autzen_trim.cloud");
    const auto a = cityforge::test::run_cli("heights --footprints " + dir / "fp.geojson" + " --cloud " + dir / "laz/autzen_trim.cloud" +
                                            " --out " + dir / "laz.geojson");
    const auto b = cityforge::test::run_cli("heights --footprints " + dir / "fp.geojson" + " --cloud " + dir / "las/autzen_trim.cloud" +
                                            " --out " + dir / "las.geojson");
    INFO(a.err);
    INFO(b.err);
    REQUIRE(a.exit_code == 0);
    REQUIRE(b.exit_code == 0);
    const std::string la = slurp(dir / "laz.geojson"), lb = slurp(dir / "las.geojson");
    CHECK(la.size() > 200);
    CHECK(la == lb);
}

TEST_CASE("CLI: cloud translate and info on LAZ - refusals are one line and non-zero", "[laz][cli]") {
    ScratchDir dir("laz_cli");
    const auto ok = cityforge::test::run_cli("cloud translate " + corpus("Semis_2022_0906_6665_LA93_IGN69_ok.laz") + " " + dir / "o.las");
    INFO(ok.err);
    REQUIRE(ok.exit_code == 0);
    std::string sha;
    const nlohmann::json o_json = oracle();
    for (const auto& e : o_json["files"])
        if (e["file"] == "Semis_2022_0906_6665_LA93_IGN69_ok.laz") sha = e["points_sha256"];
    CHECK_THAT(ok.err, Catch::Contains(sha) && Catch::Contains("decompressed from LAZ"));
    const auto again = cityforge::test::run_cli("cloud translate " + corpus("Semis_2022_0906_6665_LA93_IGN69_ok.laz") + " " + dir / "o.las");
    CHECK(again.exit_code != 0);
    CHECK_THAT(again.err, Catch::Contains("--overwrite"));

    const auto info = cityforge::test::run_cli("info " + corpus("lone-star.copc.laz"));
    REQUIRE(info.exit_code == 0);
    CHECK_THAT(info.out, Catch::Contains("LAZ:       compressor 3 (layered chunked)") && Catch::Contains("chunk size variable") &&
                             Catch::Contains("POINT14 v3") && Catch::Contains("COPC:"));

    // Compressor 1 (LASzip 1.x) through the CLI: the records of its LAS twin.
    const auto c1 = cityforge::test::run_cli("cloud translate " + corpus("simple-laszip-compressor-version-1.2r0.laz") + " " + dir / "c1.las");
    REQUIRE(c1.exit_code == 0);
    {
        LasReader twin(corpus("reference_las/1.2-with-color.las"));
        CHECK_THAT(c1.err, Catch::Contains(records_sha(twin)) && Catch::Contains("1065 of 1065 points"));
    }
    // An unknown compressor (the LASzip VLR's first field patched to 5): refused in one line.
    std::string unknown = slurp(corpus("simple-laszip-compressor-version-1.2r0.laz"));
    unknown[227 + 54] = 5;  // payload of the only VLR, after the 227-byte header and the 54-byte VLR header
    write_file(dir / "c5.laz", unknown);
    const auto refused = cityforge::test::run_cli("cloud translate " + dir / "c5.laz" + " " + dir / "s.las");
    CHECK(refused.exit_code != 0);
    CHECK_THAT(refused.err, Catch::Contains("c5.laz") && Catch::Contains("compressor 5"));
    CHECK(std::count(refused.err.begin(), refused.err.end(), '\n') == 1);
    CHECK_FALSE(std::filesystem::exists(dir / "s.las"));

    std::string bad = slurp(corpus("crop_duplicate.laz"));
    bad.resize(bad.size() - 2000);  // cut through the only chunk and the chunk table
    write_file(dir / "cut.laz", bad);
    const auto cut = cityforge::test::run_cli("info --stats " + dir / "cut.laz");
    CHECK(cut.exit_code != 0);
    CHECK_THAT(cut.err, Catch::Contains("cut.laz") && Catch::Contains("chunk 0"));
    CHECK(std::count(cut.err.begin(), cut.err.end(), '\n') == 1);
}

TEST_CASE("Selective layer decoding gives the same PointCloud as a full decode", "[laz]") {
    ScratchDir dir("laz_selective");
    for (const char* name : {"las_with_several_extra_byte_bloc.laz", "Semis_2022_0906_6665_LA93_IGN69_ok.laz", "1.2-with-color.copc.laz"}) {
        INFO(name);
        CloudTranslateOptions o;
        o.input = corpus(name);
        o.output = dir / "full.las";
        o.overwrite = true;
        translate_cloud(o);  // full decode, every layer
        const PointCloud a = read_point_cloud(corpus(name));  // PointCloud path: some layers skipped
        const PointCloud b = read_point_cloud(o.output);
        cityforge::test::check_same_cloud(a, b);
    }
}

TEST_CASE("Fixtures of laz-perf (v3, changing scanner channels) and LASzip (item version 4) decode to their LAS twins", "[laz]") {
    const std::string dir = cityforge::test::source_dir() + "/tests/data/laz/";
    for (const char* stem : {"pdrf6-1.4", "pdrf8-1.4", "pdrf7-v4-1.4"}) {
        INFO(stem);
        LasReader laz(dir + stem + ".laz"), las(dir + stem + ".las");
        REQUIRE(laz.header().laz);
        CHECK(laz.header().point_count == 1024);
        CHECK(laz.header().point_record_length == las.header().point_record_length);
        uint64_t n = 0;
        CHECK(records_sha(laz, &n) == records_sha(las));
        CHECK(n == 1024);
    }
    LasReader v4(dir + "pdrf7-v4-1.4.laz");
    CHECK(v4.header().laz->items[0].version == 4);
}

TEST_CASE("LAZ decoding gives the same bytes whatever the thread count", "[laz]") {
    const std::string p = corpus("lone-star.laz");  // 11 chunks
    std::string one, many;
    {
        tbb::global_control single(tbb::global_control::max_allowed_parallelism, 1);
        LasReader r(p);
        one = records_sha(r);
    }
    LasReader r(p);
    many = records_sha(r);
    CHECK(one == many);
    const nlohmann::json o_json = oracle();
    for (const auto& e : o_json["files"])
        if (e["file"] == "lone-star.laz") CHECK(one == e["points_sha256"].get<std::string>());
}

TEST_CASE("LAZ point format 4 (POINT10 + GPSTIME11 + WAVEPACKET13 v1) is read, records byte for byte", "[laz][wavepacket]") {
    // No file with wave packets exists in the corpus: this one is built by
    // hand with one point per chunk (each chunk's first point is stored raw,
    // followed by the 4 bytes an empty arithmetic-coded stream holds) and no
    // chunk table, so its records are known exactly.
    ScratchDir dir("laz_wavepacket");
    const std::string path = dir / "wave.laz";
    auto put = [](std::string& b, std::size_t at, const void* v, std::size_t n) { std::memcpy(b.data() + at, v, n); };
    std::string h(235, '\0');
    put(h, 0, "LASF", 4);
    h[24] = 1;
    h[25] = 3;
    const uint16_t header_size = 235, record_length = 57, vlr_payload = 34 + 3 * 6;
    const uint32_t offset_to_points = 235 + 54 + vlr_payload, n_vlrs = 1, n_points = 3;
    put(h, 94, &header_size, 2);
    put(h, 96, &offset_to_points, 4);
    put(h, 100, &n_vlrs, 4);
    h[104] = static_cast<char>(4 | 0x80);
    put(h, 105, &record_length, 2);
    put(h, 107, &n_points, 4);
    put(h, 111, &n_points, 4);
    const double scale = 0.01, zero = 0.0, mx = 10.0, mn = 0.0;
    for (int i = 0; i < 3; ++i) put(h, 131 + 8 * i, &scale, 8);
    for (int i = 0; i < 3; ++i) put(h, 155 + 8 * i, &zero, 8);
    for (int i = 0; i < 3; ++i) {
        put(h, 179 + 16 * i, &mx, 8);
        put(h, 187 + 16 * i, &mn, 8);
    }
    std::string vlr(54, '\0');
    put(vlr, 2, "laszip encoded", 14);
    const uint16_t record_id = 22204;
    put(vlr, 18, &record_id, 2);
    put(vlr, 20, &vlr_payload, 2);
    std::string pay(vlr_payload, '\0');
    const uint16_t compressor = 2, rev = 0;
    const uint32_t chunk_size = 1;
    const int64_t minus1 = -1;
    put(pay, 0, &compressor, 2);
    pay[4] = 2;
    pay[5] = 2;
    put(pay, 6, &rev, 2);
    put(pay, 12, &chunk_size, 4);
    put(pay, 16, &minus1, 8);
    put(pay, 24, &minus1, 8);
    const uint16_t n_items = 3, items[9] = {6, 20, 2, 7, 8, 2, 9, 29, 1};
    put(pay, 32, &n_items, 2);
    put(pay, 34, items, sizeof items);
    std::string file = h + vlr + pay;
    file.append(reinterpret_cast<const char*>(&minus1), 8);  // no chunk table
    std::string records;
    for (uint32_t i = 0; i < n_points; ++i) {
        std::string r(record_length, '\0');
        const int32_t xyz[3] = {static_cast<int32_t>(100 * i + 1), static_cast<int32_t>(200 * i + 2), static_cast<int32_t>(300 * i + 3)};
        put(r, 0, xyz, 12);
        r[14] = 0x11;  // return 1 of 1
        const double t = 1000.5 + i;
        put(r, 20, &t, 8);
        r[28] = static_cast<char>(1 + i);  // wave packet descriptor index
        const uint64_t offset = 60 + 256ull * i;
        const uint32_t size = 256;
        const float loc = 12.5f + static_cast<float>(i), dxyz[3] = {0.25f, -0.5f, -1.0f};
        put(r, 29, &offset, 8);
        put(r, 37, &size, 4);
        put(r, 41, &loc, 4);
        put(r, 45, dxyz, 12);
        records += r;
        file += r;
        file += std::string("\x01\x00\x00\x00", 4);  // an empty arithmetic-coded stream
    }
    write_file(path, file);
    LasReader reader(path);
    CHECK(reader.header().point_format == 4);
    std::vector<char> got;
    std::string all;
    while (const std::size_t k = reader.read_records(got, 2)) {
        CHECK(k <= 2);
        all.append(got.data(), got.size());
    }
    REQUIRE(all.size() == records.size());
    CHECK(all == records);
}

TEST_CASE("Wave packet LAZ written by LASzip (WAVEPACKET13 v1, WAVEPACKET14 v3/v4, formats 4, 5, 9, 10) decodes to its LAS twin", "[laz][wavepacket]") {
    // tests/data/laz/wavepacket/: nine files compressed by the LASzip library
    // (its README says how), each with the twin LASzip decompressed, 650
    // points in 4 chunks; formats 9/10 switch between four scanner channels.
    const std::string dir = cityforge::test::source_dir() + "/tests/data/laz/wavepacket/";
    std::ifstream mf(dir + "manifest.json");
    const nlohmann::json manifest = nlohmann::json::parse(mf);
    int checked = 0;
    for (const char* stem : {"pf4-1.3", "pf4-1.3-eb3", "pf5-1.3", "pf5-1.3-eb3", "pf9-1.4", "pf9-1.4-eb3", "pf10-1.4", "pf10-1.4-eb3",
                             "pf10-1.4-eb3-v4"}) {
        INFO(stem);
        LasReader laz(dir + stem + ".laz"), las(dir + stem + ".las");
        REQUIRE(laz.header().laz);
        CHECK(laz.header().point_format == las.header().point_format);
        CHECK(laz.header().point_record_length == las.header().point_record_length);
        const bool layered = laz.header().point_format >= 9;
        bool has_wave = false;
        for (const LazItem& it : laz.header().laz->items) has_wave |= it.type == (layered ? 13 : 9);
        CHECK(has_wave);
        uint64_t n = 0;
        const std::string sha = records_sha(laz, &n);
        CHECK(n == 650);
        CHECK(sha == records_sha(las));
        const nlohmann::json& entry = manifest.at(std::string(stem) + ".laz");
        CHECK(sha == entry["points_sha256"].get<std::string>());
        CHECK(laz.header().laz->items.size() == entry["laszip_vlr"]["items"].size());
        ++checked;
        // The PointCloud path skips the wave packet layer: same points as the twin.
        const PointCloud a = read_point_cloud(dir + stem + ".laz");
        const PointCloud b = read_point_cloud(dir + stem + ".las");
        CHECK(a.x == b.x);
        CHECK(a.z == b.z);
        CHECK(a.gps_time == b.gps_time);
        CHECK(a.classification == b.classification);
    }
    CHECK(checked == 9);
}

TEST_CASE("Layered chunks decoded layer by layer in parallel give the same bytes and the same errors", "[laz]") {
    // decode_laz_chunk with split_layers: the XY layer first, then the other
    // layers and items as tasks; every layered fixture (v3 and v4, RGB, NIR,
    // extra bytes, wave packets, changing scanner channels), both decodes.
    const std::string dir = cityforge::test::source_dir() + "/tests/data/laz/";
    std::vector<std::string> files = {dir + "pdrf6-1.4.laz", dir + "pdrf7-v4-1.4.laz", dir + "pdrf8-1.4.laz"};
    for (const char* stem : {"pf9-1.4", "pf9-1.4-eb3", "pf10-1.4", "pf10-1.4-eb3", "pf10-1.4-eb3-v4"})
        files.push_back(dir + "wavepacket/" + stem + ".laz");
    files.push_back(corpus("crop_duplicate.laz"));
    int chunks = 0, errors = 0;
    std::mt19937 rng(1818);
    for (const std::string& path : files) {
        INFO(path);
        LasReader reader(path);
        const LasHeader& h = reader.header();
        REQUIRE(h.laz);
        REQUIRE(h.laz->compressor == 3);
        const std::string bytes = slurp(path);
        for (const LazChunk& c : reader.laz_source()->chunks()) {
            const auto* data = reinterpret_cast<const uint8_t*>(bytes.data()) + c.offset;
            const std::size_t rl = static_cast<std::size_t>(h.point_record_length);
            for (const bool fields_only : {false, true}) {
                std::vector<char> one(c.point_count * rl), split(c.point_count * rl, 1);
                const std::size_t used1 = decode_laz_chunk(*h.laz, h.point_record_length, data, c.bytes, c.point_count, one.data(), path, 0, fields_only);
                const std::size_t used2 =
                    decode_laz_chunk(*h.laz, h.point_record_length, data, c.bytes, c.point_count, split.data(), path, 0, fields_only, true);
                CHECK(used1 == used2);
                CHECK(one == split);
            }
            ++chunks;
            // Corrupt copies: the split decode fails with the one-piece decode's message.
            for (int it = 0; it < 8; ++it) {
                std::vector<uint8_t> bad(data, data + c.bytes);
                const std::size_t at = rl + rng() % (bad.size() - rl);
                bad[at] = static_cast<uint8_t>(rng() & 0xFF);
                if (it % 2) bad.resize(at);
                std::string m1, m2;
                std::vector<char> out(c.point_count * rl);
                try {
                    decode_laz_chunk(*h.laz, h.point_record_length, bad.data(), bad.size(), c.point_count, out.data(), path, 3);
                } catch (const Error& e) {
                    m1 = e.what();
                }
                try {
                    decode_laz_chunk(*h.laz, h.point_record_length, bad.data(), bad.size(), c.point_count, out.data(), path, 3, false, true);
                } catch (const Error& e) {
                    m2 = e.what();
                }
                CHECK(m1 == m2);
                errors += !m1.empty();
            }
        }
    }
    CHECK(chunks >= 9 * 2);
    CHECK(errors > 0);
}
