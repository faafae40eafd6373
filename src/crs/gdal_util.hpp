#pragma once
// GDAL plumbing shared by the I/O modules: one-time driver registration and a
// scoped capture of GDAL's error messages (so they end up in our Error text
// instead of being printed by GDAL's default handler).
#include <string>

namespace cityforge {

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
