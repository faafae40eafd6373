// Large-cloud inputs for the memory benchmark (bench/bench_stream.sh): a
// synthetic town written NX x NY times side by side, as one LAS file and one
// footprint layer, so that a 200 M-point file needs no generator run of a
// 25 km² town. Prints what it wrote; asserts nothing.
//
//   build/bin/bench_stream DIR SIZE_M NX NY [DENSITY] [SEED]
//   -> DIR/town/ (the synth town), DIR/mosaic.las, DIR/mosaic_footprints.gpkg
#include "bench_main.hpp"
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "cloud/las.hpp"
#include "io/vector.hpp"
#include "synth/synth.hpp"

using namespace cityforge;

static int run_bench(int argc, char** argv) {
    if (argc < 5) {
        std::fprintf(stderr, "usage: bench_stream DIR SIZE_M NX NY [DENSITY] [SEED]\n");
        return 2;
    }
    const std::filesystem::path dir = argv[1];
    SynthOptions so;
    so.size_m = cityforge::bench::parse_number(argv[2], "SIZE_M");
    const int nx = static_cast<int>(cityforge::bench::parse_number(argv[3], "NX")), ny = static_cast<int>(cityforge::bench::parse_number(argv[4], "NY"));
    so.cloud_density_m2 = argc > 5 ? cityforge::bench::parse_number(argv[5], "DENSITY") : 8.0;
    so.seed = argc > 6 ? static_cast<uint64_t>(cityforge::bench::parse_number(argv[6], "SEED")) : 1;
    std::filesystem::create_directories(dir);
    const SynthResult s = write_synthetic_town((dir / "town").string(), so);
    const LasHeader header = LasReader(s.cloud_path).header();
    PolygonLayer fp = read_polygon_layer(s.truth_path);
    const PointCloud town = read_las(s.cloud_path);
    std::string wkt = fp.crs.wkt;
    LasWriter out((dir / "mosaic.las").string(), header.scale, header.offset, wkt);
    std::vector<Feature> features;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const double dx = i * so.size_m, dy = j * so.size_m;
            PointCloud c = town;
            for (double& x : c.x) x += dx;
            for (double& y : c.y) y += dy;
            out.write(c);
            for (Feature f : fp.features) {
                for (Polygon& p : f.geometry) {
                    for (MapPoint& q : p.outer) q.x += dx, q.y += dy;
                    for (Ring& r : p.holes)
                        for (MapPoint& q : r) q.x += dx, q.y += dy;
                }
                features.push_back(std::move(f));
            }
        }
    out.close();
    std::vector<FieldDefinition> fields;
    for (std::size_t k = 0; k < fp.field_names.size(); ++k) fields.push_back({fp.field_names[k], fp.field_types[k]});
    write_polygon_features((dir / "mosaic_footprints.gpkg").string(), fp.crs, fields, features);
    std::printf("%s: %llu points (%d x %d towns of %.0f m), %zu footprints\n", (dir / "mosaic.las").c_str(),
                static_cast<unsigned long long>(out.points_written()), nx, ny, so.size_m, features.size());
    return 0;
}

int main(int argc, char** argv) {
    return cityforge::bench::run_main(argc, argv, "bench_stream", "bench_stream DIR SIZE_M NX NY [DENSITY] [SEED]", run_bench);
}
