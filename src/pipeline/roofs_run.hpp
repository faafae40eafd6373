#pragma once
// `cityforge roofs`: footprints + a dense cloud -> LOD2 buildings (roof
// planes, walls, ground; closed solids) with their heights and LOD1 blocks,
// written through the exporters (GeoPackage, GeoJSON, CityGML LOD1/LOD2,
// CityJSON). The heights stage is `cityforge heights`'; buildings whose
// points are too thin for planes fall back to a flat roof (LOD1.2) and say so.
#include <map>
#include <string>

#include "pipeline/export_run.hpp"
#include "pipeline/heights_run.hpp"
#include "roof/lod2_builder.hpp"

namespace cityforge {

struct RoofsRunOptions {
    HeightsRunOptions heights;   ///< cloud CRS, cleaning, ground, height percentiles
    Lod2Options lod2;            ///< plane detection and partition (units are set from the CRSs)
    ExportOptions model;         ///< formats, LODs, ids and vertical CRS of the outputs
    void validate() const;
};

struct RoofsRunReport {
    HeightsRunReport heights;
    ExportReport model;
    std::map<std::string, std::size_t> roof_types;  ///< flat, shed, gable, hip, complex (fallbacks count as flat)
    std::size_t lod2 = 0, fallbacks = 0;            ///< buildings with plane roofs / with flat-roof fallback
    double mean_rmse_m = 0.0;                       ///< over buildings with plane roofs
    double lod2_seconds = 0.0;
    double seconds = 0.0;
};

/// The roof attributes build_lod2_model adds to every building, in order, with
/// their types. Input fields of these names are replaced (re-runs on our output).
const std::vector<FieldDefinition>& roof_output_fields();

/// The LOD2 stage on computed heights (made with keep_roof_points): the city
/// model of the footprints with LOD1 and LOD2 solids and the roof
/// attributes; fills the roof counts of `report`. `source` names the input in messages.
CityModel build_lod2_model(const HeightsStage& stage, const CrsInfo& crs, const RoofsRunOptions& options, const std::string& source,
                           RoofsRunReport& report);

/// Writes into `out_dir` what `cityforge export` writes, with LOD2. Throws
/// Error naming the file for the errors of `cityforge heights` and `export`.
RoofsRunReport run_roofs(const std::string& footprints_path, const std::string& cloud_path, const std::string& out_dir,
                         const RoofsRunOptions& options, const Progress& progress = {});

}  // namespace cityforge
