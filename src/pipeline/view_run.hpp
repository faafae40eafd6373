#pragma once
// `cityforge view DIR` (also written by `cityforge run` as DIR/view/index.html):
// one self-contained HTML page, opened from disk without a server, that shows
// the ortho quick-look with the footprints coloured by status or an attribute,
// the LOD1/LOD2 model in 3D (DIR/buildings.glb: the same mesh as the glTF
// export, roofs, walls and ground by surface type), each building's attributes,
// quality flags and failure reason on click, and the figures of the audits
// found in DIR (DIR/*/report.json).
#include <string>

namespace cityforge {

struct ViewOptions {
    std::string out;               ///< page path; empty = DIR/view/index.html
    std::string buildings;         ///< building table; empty = DIR/buildings.gpkg
    std::string glb;               ///< 3D model; empty = DIR/buildings.glb (none: the page has no 3D pane)
    /// 3D Tiles tileset; empty = DIR/3dtiles/tileset.json when it exists. Its tiles are
    /// bundled next to the page (tiles.js, a script: a page opened from disk cannot fetch).
    std::string tileset;
    std::string ortho;             ///< raster under the footprints; empty = the run's ortho (DIR/manifest.json) when readable
    int ortho_max_px = 2048;       ///< longer side of the ortho quick-look, pixels
    bool overwrite = false;        ///< replace an existing page
    void validate() const;
};

struct ViewReport {
    std::string path;              ///< page written
    std::size_t buildings = 0;     ///< buildings listed (every row of the table)
    std::size_t meshed = 0;        ///< buildings in the 3D model
    std::size_t tiles = 0;         ///< 3D Tiles content tiles bundled (0: no tileset)
    std::string tiles_bundle;      ///< the bundle's path (empty: none)
    bool ortho = false;            ///< an ortho quick-look is shown
    std::size_t audits = 0;        ///< audit reports whose figures are shown
    std::size_t bytes = 0;         ///< page size
};

/// Throws Error naming the file when DIR has no building table, the table
/// is empty or has no CRS, or the page exists and `overwrite` is false.
ViewReport write_view(const std::string& run_dir, const ViewOptions& options = {});

}  // namespace cityforge
