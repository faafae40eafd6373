#include "crs/gdal_util.hpp"

#include <cpl_error.h>
#include <gdal.h>
#include <mutex>

namespace cityforge {

void ensure_gdal_registered() {
    static std::once_flag once;
    std::call_once(once, [] { GDALAllRegister(); });
}

GdalErrorCapture::GdalErrorCapture() {
    CPLPushErrorHandler(CPLQuietErrorHandler);
    CPLErrorReset();
}
GdalErrorCapture::~GdalErrorCapture() { CPLPopErrorHandler(); }

std::string GdalErrorCapture::message() const {
    const char* m = CPLGetLastErrorMsg();
    std::string s = m ? m : "";
    for (char& c : s)
        if (c == '\n' || c == '\r') c = ' ';
    return s;
}

std::string GdalErrorCapture::suffix() const {
    const std::string m = message();
    return m.empty() ? std::string() : " (GDAL: " + m + ")";
}

}  // namespace cityforge
