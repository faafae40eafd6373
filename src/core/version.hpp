#pragma once
// The cityforge version ("MAJOR.MINOR.PATCH"), set by CMake from project().
namespace cityforge {
inline const char* version() { return CITYFORGE_VERSION; }
}  // namespace cityforge
