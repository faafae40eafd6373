// Export benchmark: a synthetic city's buildings (exact footprints, LOD1
// heights from the scene) written in every format (3D Tiles and glTF included). Prints buildings per
// second per format, output sizes and the peak memory.
//
//   build/bin/bench_export [size_m]    (default 4000 m: ~9,700 buildings)
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sys/resource.h>

#include "crs/crs.hpp"
#include "pipeline/export_run.hpp"
#include "synth/scene.hpp"

using namespace cityforge;

int main(int argc, char** argv) {
    synth::SceneLayout layout;
    layout.size_m = argc > 1 ? std::atof(argv[1]) : 4000.0;
    layout.seed = 1;
    const auto t0 = std::chrono::steady_clock::now();
    const synth::Scene scene = synth::generate_scene(layout);
    const CrsInfo crs = crs_from_user_input("EPSG:32650+5773", "bench");
    CityModel model;
    model.crs = model_crs_of(crs, Extent{500000.0, 4400000.0, 500000.0 + layout.size_m, 4400000.0 + layout.size_m});
    const double ox = 500000, oy = 4400000;
    for (const synth::SceneBuilding& sb : scene.buildings) {
        Building b;
        b.id = std::to_string(sb.id);
        Polygon p = sb.footprint(ox, oy);
        b.footprint = {p};
        b.ground_z = sb.ground_z, b.height_m = sb.eave_height_m;
        b.attributes = {{"shape", synth::to_string(sb.shape)}, {"roof", synth::to_string(sb.roof)}, {"eave_height_m", sb.eave_height_m}};
        complete_building(b, model.crs);
        model.buildings.push_back(std::move(b));
    }
    const double t_model = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const auto dir = std::filesystem::temp_directory_path() / "cityforge_bench_export";
    ExportOptions o;
    o.lods = {0, 1};
    const ExportReport r = write_city_model(model, crs, dir.string(), o);
    const double n = double(model.buildings.size());
    std::printf("%.0f m city: %zu buildings, model + LOD1 solids + validation %.2f s (%.0f buildings/s); %zu valid LOD1\n", layout.size_m,
                model.buildings.size(), t_model, n / t_model, r.valid_lod1);
    // Bytes of a format's output (3D Tiles: the whole tileset folder).
    auto bytes = [](const std::filesystem::path& p) {
        if (p.filename() != "tileset.json") return double(std::filesystem::file_size(p));
        double total = 0;
        for (const auto& e : std::filesystem::recursive_directory_iterator(p.parent_path()))
            if (e.is_regular_file()) total += double(e.file_size());
        return total;
    };
    for (const auto& [format, seconds] : r.seconds)
        std::printf("  %-13s %6.2f s  %8.0f buildings/s  %7.1f MB\n", format.c_str(), seconds, n / seconds, bytes(r.files.at(format)) / 1e6);
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    std::printf("peak memory %.0f MB\n", double(ru.ru_maxrss) / 1024.0);
    return 0;
}
