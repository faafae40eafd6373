#pragma once
// GDAL plumbing shared by the I/O modules: one-time driver registration and a
// scoped capture of GDAL's error messages (so they end up in our Error text
// instead of being printed by GDAL's default handler).
#include <string>

namespace cityforge {

/// True for a GDAL/OGR dataset name that is not a plain file path: a virtual
/// file system path ("/vsizip/a.zip/b.gpkg", "/vsicurl/...") or a connection
/// string with a driver prefix ("PG:dbname=city", "WFS:https://...",
/// "GPKG:file.gpkg:layer"); a Windows drive letter ("C:") is a path. Such
/// names are handed to GDAL as they are, never stat()ed as files.
bool is_gdal_dataset_name(const std::string& name);

/// Throws Error(name, "file not found") when `name` is a plain path that does
/// not exist; GDAL dataset names (is_gdal_dataset_name) pass.
void require_dataset_exists(const std::string& name);

/// Registers GDAL/OGR drivers once per process (thread-safe).
void ensure_gdal_registered();

/// While alive, GDAL errors are silenced and the last message is kept.
class GdalErrorCapture {
public:
    GdalErrorCapture();
    ~GdalErrorCapture();
    GdalErrorCapture(const GdalErrorCapture&) = delete;
    GdalErrorCapture& operator=(const GdalErrorCapture&) = delete;
    /// The last GDAL error message seen ("" if none).
    std::string message() const;
    /// " (GDAL: message)" or "" — ready to append to an Error text.
    std::string suffix() const;
};

}  // namespace cityforge
