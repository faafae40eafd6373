// One point of a photogrammetric cloud, as stereo and densify write it.
#pragma once

#include <cstdint>

#include <Eigen/Core>

#include "cloud/point_cloud.hpp"

namespace cityforge::photo {

// Appends world point `w` (map CRS, metres) as a single return of class 1
// (unclassified) with the colour of an 8-bit OpenCV BGR pixel (`bgr[0..2]`,
// scaled to LAS's 16-bit RGB) and `intensity`.
inline void append_photo_point(PointCloud& pc, const Eigen::Vector3d& w, const uint8_t* bgr, uint16_t intensity) {
    pc.x.push_back(w.x()), pc.y.push_back(w.y()), pc.z.push_back(w.z());
    pc.classification.push_back(1);
    pc.return_number.push_back(1), pc.number_of_returns.push_back(1);
    pc.intensity.push_back(intensity);
    pc.red.push_back(static_cast<uint16_t>(bgr[2] * 257));
    pc.green.push_back(static_cast<uint16_t>(bgr[1] * 257));
    pc.blue.push_back(static_cast<uint16_t>(bgr[0] * 257));
}

}  // namespace cityforge::photo
