#include "crs/gdal_util.hpp"

#include <cpl_error.h>
#include <gdal.h>
#include <cctype>
#include <filesystem>
#include <mutex>

#include "core/error.hpp"

namespace cityforge {

bool is_gdal_dataset_name(const std::string& name) {
    if (name.rfind("/vsi", 0) == 0) return true;
    const std::size_t colon = name.find(':');
    if (colon == std::string::npos || colon < 2) return false;  // no prefix, or a drive letter
    for (std::size_t i = 0; i < colon; ++i) {
        const auto c = static_cast<unsigned char>(name[i]);
        if (!std::isalnum(c) && c != '_') return false;
    }
    return true;
}

void require_dataset_exists(const std::string& name) {
    if (!is_gdal_dataset_name(name) && !std::filesystem::exists(name)) throw Error(name, "file not found");
}

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
