// PostGIS in and out through GDAL's PG driver, against a real PostgreSQL 15 +
// PostGIS 3 server that the test starts on a private unix socket
// (tools/pg/test_server.sh) and stops: footprints from a table -> run ->
// buildings in another table, read back with the GeoPackage output's geometry
// and attributes, the horizontal EPSG code as SRID and the vertical CRS in a column.
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdlib>
#include <map>
#include <set>

#include "core/error.hpp"
#include "io/vector.hpp"
#include "synth_fixture.hpp"

using namespace cityforge;
using test::ScratchDir;

namespace {

// The database: an existing one named by CITYFORGE_TEST_PG ("PG:host=... dbname=... user=...", with
// PostGIS; the test's tables cityforge_test_* are dropped at the end), else a private server started
// here and stopped (its folder removed) at scope exit.
struct PostgisServer {
    std::string dir, connection;
    bool external = false;
    explicit PostgisServer(const std::string& folder) : dir(folder) {
        if (const char* env = std::getenv("CITYFORGE_TEST_PG"); env && *env) {
            connection = env, external = true;
            REQUIRE(connection.rfind("PG:", 0) == 0);
            return;
        }
        const auto r = test::run_command("bash " + test::source_dir() + "/tools/pg/test_server.sh start " + dir + " " +
                                         std::to_string(54000 + ::getpid() % 1000));
        INFO(r.err);
        REQUIRE(r.exit_code == 0);
        connection = r.out.substr(0, r.out.find('\n'));
    }
    ~PostgisServer() {
        if (external) psql("DROP TABLE IF EXISTS cityforge_test_footprints, cityforge_test_buildings");
        else test::run_command("bash " + test::source_dir() + "/tools/pg/test_server.sh stop " + dir);
    }
    // psql with the connection's key=value pairs (libpq's conninfo, the PG: prefix removed).
    std::string psql(const std::string& sql) const {
        const char* bin = std::getenv("CITYFORGE_PG_BIN");
        return test::run_command(std::string(bin && *bin ? bin : "/usr/lib/postgresql/15/bin") + "/psql -At '" + connection.substr(3) + "' -c \"" + sql + "\"").out;
    }
};

// GDAL's PG driver sends reals as text with 15 significant digits: equal to 1e-14 relative.
bool same_value(const AttributeValue& a, const AttributeValue& b) {
    if (std::holds_alternative<double>(a) && std::holds_alternative<double>(b))
        return std::abs(std::get<double>(a) - std::get<double>(b)) <= 1e-14 * std::max(1.0, std::abs(std::get<double>(a)));
    return a == b;
}

std::string quoted(const std::string& s) { return "'" + s + "'"; }

}  // namespace

TEST_CASE("PostGIS round trip: footprints from a table, buildings into another, same as the GeoPackage", "[postgis][pipeline]") {
    ScratchDir dir("postgis");
    const SynthResult town = test::make_town(dir, 200, 5, 8);
    const PostgisServer pg(dir / "pg");
    // Footprints written by another tool (ogr2ogr) into PostGIS.
    REQUIRE(test::run_command("ogr2ogr -overwrite -f PostgreSQL " + quoted(pg.connection) + " " + town.truth_path + " -nln cityforge_test_footprints").exit_code == 0);
    CHECK(pg.psql("SELECT count(*) FROM cityforge_test_footprints") == "" + std::to_string(read_polygon_layer(town.truth_path).features.size()) + "\n");

    const auto run = test::run_cli("run --quiet --ortho " + town.ortho_path + " --cloud " + town.cloud_path + " --footprints " +
                                   quoted(pg.connection + " tables=cityforge_test_footprints") + " --vertical-crs EPSG:5773 --formats gpkg --db " +
                                   quoted(pg.connection + " tables=cityforge_test_buildings") + " --out " + (dir / "run"));
    INFO(run.err);
    REQUIRE(run.exit_code == 0);

    const PolygonLayer gpkg = read_polygon_layer(dir / "run/buildings.gpkg");
    const PolygonLayer table = read_polygon_layer(pg.connection + " tables=cityforge_test_buildings");
    REQUIRE(gpkg.features.size() > 10);
    REQUIRE(table.features.size() == gpkg.features.size());
    // Real CRS: the horizontal EPSG code is the SRID; the vertical CRS (PostGIS SRIDs are 2-D) is in a column.
    CHECK(table.crs.horizontal_epsg == 32650);
    CHECK(pg.psql("SELECT DISTINCT ST_SRID(geom) FROM cityforge_test_buildings") == "32650\n");
    CHECK(pg.psql("SELECT DISTINCT crs_vertical FROM cityforge_test_buildings") == "EPSG:5773\n");
    CHECK(gpkg.crs.vertical_epsg == 5773);

    std::map<std::string, int> column;
    for (std::size_t k = 0; k < table.field_names.size(); ++k) column[table.field_names[k]] = int(k);
    for (const std::string& name : gpkg.field_names) CHECK(column.count(name) == 1);
    REQUIRE(column.count("cityforge_id"));
    std::map<std::string, std::size_t> row_of;
    for (std::size_t i = 0; i < table.features.size(); ++i) row_of[std::get<std::string>(table.features[i].values[column["cityforge_id"]])] = i;
    int id_k = -1;
    for (std::size_t k = 0; k < gpkg.field_names.size(); ++k)
        if (gpkg.field_names[k] == "cityforge_id") id_k = int(k);
    std::size_t same_geometry = 0, same_values = 0, values = 0;
    std::set<std::string> differing;
    for (const Feature& f : gpkg.features) {
        const std::string id = std::get<std::string>(f.values[id_k]);
        REQUIRE(row_of.count(id));
        const Feature& g = table.features[row_of[id]];
        bool geometry_equal = g.geometry.size() == f.geometry.size();
        for (std::size_t p = 0; geometry_equal && p < f.geometry.size(); ++p) {
            geometry_equal = g.geometry[p].outer.size() == f.geometry[p].outer.size() && g.geometry[p].holes.size() == f.geometry[p].holes.size();
            for (std::size_t v = 0; geometry_equal && v < f.geometry[p].outer.size(); ++v)
                geometry_equal = g.geometry[p].outer[v].x == f.geometry[p].outer[v].x && g.geometry[p].outer[v].y == f.geometry[p].outer[v].y;
        }
        same_geometry += geometry_equal;
        for (std::size_t k = 0; k < gpkg.field_names.size(); ++k) {
            ++values;
            const bool same = same_value(f.values[k], g.values[column[gpkg.field_names[k]]]);
            same_values += same;
            if (!same) differing.insert(gpkg.field_names[k]);
        }
    }
    CHECK(same_geometry == gpkg.features.size());
    std::string names;
    for (const std::string& n : differing) names += n + " ";
    INFO("attributes that differ: " << names);
    CHECK(same_values == values);

    // A second run replaces the table (one transaction), it does not append.
    REQUIRE(test::run_cli("export --quiet --in " + (dir / "run/buildings.gpkg") + " --formats geojson --db " +
                          quoted(pg.connection + " tables=cityforge_test_buildings") + " --out " + (dir / "again"))
                .exit_code == 0);
    CHECK(pg.psql("SELECT count(*) FROM cityforge_test_buildings") == std::to_string(gpkg.features.size()) + "\n");

    // A missing table is one line naming the connection.
    const auto bad = test::run_cli("heights --footprints " + quoted(pg.connection + " tables=nowhere") + " --cloud " + town.cloud_path +
                                   " --out " + (dir / "h.gpkg"));
    CHECK(bad.exit_code == 1);
    CHECK(bad.err.find("cityforge: error: PG:") == 0);
}
