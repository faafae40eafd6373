// Export benchmark: a synthetic city's buildings (exact footprints, LOD1
// heights from the scene) written in every format (3D Tiles and glTF included). Prints buildings per
// second per format, output sizes and the peak memory.
//
//   build/bin/bench_export [size_m] [--lod2] [--texture-ortho ORTHO] [--lod2-cache FILE] [--formats a,b]
//
// Default 4000 m (~9,700 buildings), LOD1 only. --lod2 adds LOD2 solids
// reconstructed from roof points sampled on the exact roofs (8 pts/m², 3 cm
// noise, as bench_roofs; not part of the export times), so the meshes, 3D
// Tiles and CityJSON hold LOD2 / LOD2.2 parts. --texture-ortho textures their
// roofs from an ortho of the same scene: `cityforge synth --size-m SIZE
// --seed 1 --cloud-density 0 --out S` writes it as S/ortho.tif.
// --lod2-cache FILE keeps the reconstructed buildings (lossless JSON lines):
// written when FILE is missing, read instead of reconstructing when it exists
// (the reconstruction takes minutes at 4 km; the timed export then does not).
// --formats limits the formats written (default: every one). Process CPU
// seconds (user + sys) of the writing are printed beside its wall time.
#include "bench_main.hpp"
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <tbb/parallel_for.h>

#include "crs/crs.hpp"
#include "model/building_json.hpp"
#include "pipeline/export_run.hpp"
#include "roof/lod2_builder.hpp"
#include "synth/scene.hpp"

using namespace cityforge;

static int run_bench(int argc, char** argv) {
    synth::SceneLayout layout;
    layout.size_m = 4000.0;
    bool lod2 = false;
    std::string texture_ortho, cache, formats;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--lod2")) lod2 = true;
        else if (!std::strcmp(argv[i], "--lod2-cache") && i + 1 < argc) cache = argv[++i], lod2 = true;
        else if (!std::strcmp(argv[i], "--formats") && i + 1 < argc) formats = argv[++i];
        else if (!std::strcmp(argv[i], "--texture-ortho") && i + 1 < argc) texture_ortho = argv[++i], lod2 = true;
        else layout.size_m = cityforge::bench::parse_number(argv[i], "SIZE_M");
    }
    layout.seed = 1;
    const auto t0 = std::chrono::steady_clock::now();
    const synth::Scene scene = synth::generate_scene(layout);
    const CrsInfo crs = crs_from_user_input("EPSG:32650+5773", "bench");
    CityModel model;
    model.crs = model_crs_of(crs, Extent{500000.0, 4400000.0, 500000.0 + layout.size_m, 4400000.0 + layout.size_m});
    const double ox = 500000, oy = 4400000;
    const std::size_t n = scene.buildings.size();
    std::vector<Lod2Result> roofs(lod2 ? n : 0);
    double t_lod2 = 0;
    const bool cached = !cache.empty() && std::filesystem::exists(cache);
    if (cached) {
        const auto t1 = std::chrono::steady_clock::now();
        std::ifstream in(cache);
        std::string line;
        while (std::getline(in, line)) {
            Building b = building_from_json(nlohmann::json::parse(line), cache);
            complete_building(b, model.crs);
            model.buildings.push_back(std::move(b));
        }
        if (model.buildings.size() != n) {
            std::fprintf(stderr, "%s: %zu buildings, the scene has %zu\n", cache.c_str(), model.buildings.size(), n);
            return 1;
        }
        t_lod2 = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();  // read + LOD1 + validation
    } else if (lod2) {
        const auto t1 = std::chrono::steady_clock::now();
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
            const synth::SceneBuilding& sb = scene.buildings[i];
            Polygon p = sb.footprint(ox, oy);
            orient_polygon(p);
            std::vector<std::array<double, 3>> pts = synth::sample_roof_points(sb, 8.0, 0.03, 5);
            for (auto& q : pts) q[0] += ox, q[1] += oy;
            roofs[i] = reconstruct_lod2({p}, pts, sb.ground_z, sb.ground_z + sb.eave_height_m);
        });
        t_lod2 = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    }
    for (std::size_t i = 0; i < n && !cached; ++i) {
        const synth::SceneBuilding& sb = scene.buildings[i];
        Building b;
        b.id = std::to_string(sb.id);
        Polygon p = sb.footprint(ox, oy);
        b.footprint = {p};
        b.ground_z = sb.ground_z, b.height_m = sb.eave_height_m;
        b.attributes = {{"shape", synth::to_string(sb.shape)}, {"roof", synth::to_string(sb.roof)}, {"eave_height_m", sb.eave_height_m}};
        if (lod2) b.lod2 = std::move(roofs[i].solids), b.roof_type = roofs[i].roof_type;
        complete_building(b, model.crs);
        model.buildings.push_back(std::move(b));
    }
    const double t_model = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() - t_lod2;
    if (!cache.empty() && !cached) {
        std::ofstream out(cache);
        for (const Building& b : model.buildings) out << building_to_json(b).dump() << '\n';
    }
    const auto dir = std::filesystem::temp_directory_path() / "cityforge_bench_export";
    ExportOptions o;
    o.lods = lod2 ? std::vector<int>{0, 1, 2} : std::vector<int>{0, 1};
    o.texture_ortho = texture_ortho;
    if (!formats.empty()) {
        o.formats.clear();
        for (std::size_t a = 0, b; a <= formats.size(); a = b + 1) {
            b = formats.find(',', a);
            if (b == std::string::npos) b = formats.size();
            o.formats.push_back(formats.substr(a, b - a));
        }
    }
    const double cpu0 = cityforge::process_cpu_seconds();
    const auto tw = std::chrono::steady_clock::now();
    const ExportReport r = write_city_model(model, crs, dir.string(), o);
    const double t_write = std::chrono::duration<double>(std::chrono::steady_clock::now() - tw).count();
    const double cpu_write = cityforge::process_cpu_seconds() - cpu0;
    const double nb = double(model.buildings.size());
    std::printf("%.0f m city: %zu buildings, model + LOD1 solids + validation %.2f s (%.0f buildings/s); %zu valid LOD1\n", layout.size_m,
                model.buildings.size(), t_model, nb / t_model, r.valid_lod1);
    if (lod2) {
        std::size_t parts = 0, split = 0;
        for (const Building& b : model.buildings) parts += b.roof_parts.size(), split += b.roof_parts.size() > 1;
        std::printf("LOD2 %s %.2f s (not in the export times); %zu valid LOD2; %zu LOD2.2 parts, %zu buildings split%s\n", cached ? "read from the cache" : "from roof points", t_lod2,
                    r.valid_lod2, parts, split, texture_ortho.empty() ? "" : "; roofs textured from the ortho");
    }
    // Bytes of a format's output (3D Tiles: the whole tileset folder).
    auto bytes = [](const std::filesystem::path& p) {
        if (p.filename() != "tileset.json") return double(std::filesystem::file_size(p));
        double total = 0;
        for (const auto& e : std::filesystem::recursive_directory_iterator(p.parent_path()))
            if (e.is_regular_file()) total += double(e.file_size());
        return total;
    };
    for (const auto& [format, seconds] : r.seconds)
        std::printf("  %-13s %6.2f s  %8.0f buildings/s  %7.1f MB\n", format.c_str(), seconds, nb / seconds, bytes(r.files.at(format)) / 1e6);
    if (r.files.count("textures")) std::printf("  roof atlas    %7.1f MB (textures/roofs.png)\n", bytes(r.files.at("textures")) / 1e6);
    std::printf("all formats written in %.2f s wall, %.2f CPU s (roof atlas included)\n", t_write, cpu_write);
    std::printf("peak memory %.0f MB\n", cityforge::peak_memory_mb());
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_export", "bench_export [SIZE_M] [--lod2] [--lod2-cache FILE] [--formats LIST] [--texture-ortho]", run_bench);
}
