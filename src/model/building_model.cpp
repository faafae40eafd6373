#include "model/building_model.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "core/error.hpp"

namespace cityforge {

std::string ModelCrs::gml_srs_name() const {
    // The composed form names both parts explicitly, as CityGML producers commonly do.
    if (horizontal_epsg && vertical_epsg)
        return "urn:ogc:def:crs,crs:EPSG::" + std::to_string(*horizontal_epsg) + ",crs:EPSG::" + std::to_string(*vertical_epsg);
    if (compound_epsg) return "urn:ogc:def:crs:EPSG::" + std::to_string(*compound_epsg);
    if (horizontal_epsg) return "urn:ogc:def:crs:EPSG::" + std::to_string(*horizontal_epsg);
    return {};
}

std::string ModelCrs::cityjson_reference_system() const {
    // CityJSON 2.0 names one CRS by URL (its schema requires .../def/crs/...):
    // the compound code when one exists, else the horizontal CRS.
    const std::string base = "https://www.opengis.net/def/crs/EPSG/0/";
    if (compound_epsg) return base + std::to_string(*compound_epsg);
    if (horizontal_epsg) return base + std::to_string(*horizontal_epsg);
    return {};
}

void complete_building(Building& b, const ModelCrs& crs, const SolidValidityOptions& validity) {
    b.lod1.clear();
    b.lod1_errors.clear();
    b.lod2_errors.clear();
    b.lod1_volume = b.lod2_volume = 0.0;
    b.roof_parts.clear();
    b.roof_parts_unsplit.clear();
    if (b.footprint.empty()) {
        b.status = "no_footprint", b.reason = "building has no footprint polygon";
        return;
    }
    if (!b.ground_z || !b.height_m) {
        b.roof_z.reset();
        if (b.status == "ok") b.status = "no_height", b.reason = !b.ground_z ? "ground height unknown" : "height unknown";
    } else if (!(*b.height_m > 0)) {
        b.roof_z.reset();
        if (b.status == "ok") b.status = "no_height", b.reason = "height is not above ground";
    } else {
        const double top = *b.ground_z + *b.height_m / crs.z_unit_m;
        b.roof_z = top;
        for (const Polygon& part : b.footprint) {
            Polygon p = part;
            orient_polygon(p);
            b.lod1.push_back(extrude_prism(p, *b.ground_z, top));
        }
        for (std::size_t i = 0; i < b.lod1.size(); ++i) {
            for (const std::string& e : validate_solid(b.lod1[i], validity))
                b.lod1_errors.push_back(b.lod1.size() > 1 ? "part " + std::to_string(i) + ": " + e : e);
            b.lod1_volume += solid_volume(b.lod1[i]);
        }
        if (!b.lod1_errors.empty() && b.status == "ok") b.status = "invalid_lod1", b.reason = b.lod1_errors.front();
    }
    for (std::size_t i = 0; i < b.lod2.size(); ++i) {
        for (const std::string& e : validate_solid(b.lod2[i], validity))
            b.lod2_errors.push_back(b.lod2.size() > 1 ? "part " + std::to_string(i) + ": " + e : e);
        b.lod2_volume += solid_volume(b.lod2[i]);
    }
    if (!b.lod2_errors.empty() && b.status == "ok") b.status = "invalid_lod2", b.reason = b.lod2_errors.front();
    RoofPartsResult parts = roof_parts(b.lod2, validity);
    b.roof_parts = std::move(parts.parts);
    b.roof_parts_unsplit = std::move(parts.unsplit);
    for (std::size_t i = 0; i < b.roof_parts.size() && b.status == "ok"; ++i)
        if (!b.roof_parts[i].lod13_errors.empty())
            b.status = "invalid_lod13", b.reason = "part " + std::to_string(i) + ": " + b.roof_parts[i].lod13_errors.front();
}

namespace {
void grow_extent(std::array<double, 6>& e, const Building& b) {
    auto grow = [&](double x, double y, std::optional<double> z) {
        e[0] = std::min(e[0], x), e[1] = std::min(e[1], y), e[3] = std::max(e[3], x), e[4] = std::max(e[4], y);
        if (z) e[2] = std::min(e[2], *z), e[5] = std::max(e[5], *z);
    };
    for (const Polygon& p : b.footprint)
        for (const MapPoint& q : p.outer) grow(q.x, q.y, b.ground_z);
    for (const auto* solids : {&b.lod1, &b.lod2})
        for (const Solid& s : *solids)
            for (const Face& f : s.faces)
                for (const Point3& q : f.outer) grow(q.x, q.y, q.z);
}
std::array<double, 6> finish_extent(std::array<double, 6> e) {
    if (!std::isfinite(e[2])) e[2] = e[5] = 0.0;
    if (!std::isfinite(e[0])) e = {0, 0, 0, 0, 0, 0};
    return e;
}
constexpr std::array<double, 6> kEmpty{INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
}  // namespace

std::array<double, 6> building_extent(const Building& b) {
    std::array<double, 6> e = kEmpty;
    grow_extent(e, b);
    return finish_extent(e);
}

double fallback_footprint_z(const CityModel& m) {
    std::vector<double> z;
    for (const Building& b : m.buildings)
        if (b.ground_z) z.push_back(*b.ground_z);
    if (z.empty()) return 0.0;
    std::nth_element(z.begin(), z.begin() + static_cast<std::ptrdiff_t>(z.size() / 2), z.end());
    return z[z.size() / 2];
}

std::array<double, 6> model_extent(const CityModel& m) {
    std::array<double, 6> e = kEmpty;
    for (const Building& b : m.buildings) grow_extent(e, b);
    return finish_extent(e);
}

}  // namespace cityforge
