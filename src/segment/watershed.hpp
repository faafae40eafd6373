#pragma once
// Watershed over-segmentation of a multi-band image. No GDAL: the image comes
// in memory, in pixel units; georeferencing stays with the caller.
#include <cstdint>
#include <vector>

#include "core/image.hpp"
#include "core/progress.hpp"

namespace cityforge {

struct WatershedOptions {
    /// Weight of each band in the gradient; empty = 1 for every band.
    std::vector<double> band_weights;
    /// Gaussian pre-smoothing, standard deviation in pixels (0 = none).
    double smoothing_sigma_px = 1.0;
    /// Dynamics threshold (h-minima) in gradient units of the 0..255-normalised
    /// image: a basin whose depth below the pass to a deeper basin is < h is
    /// absorbed. Larger h -> fewer regions. 0 = every regional minimum is a marker.
    double h_minima = 4.0;
    /// Throws Error naming the option on bad values (`bands` = image band count).
    void validate(int bands) const;
};

struct Oversegmentation {
    Image<uint32_t> labels;    ///< 1..region_count per valid pixel, 0 = nodata; row-major, one band
    uint32_t region_count = 0;
};

/// Scales every band to 0..255 using its 0.5th and 99.5th percentiles over the
/// valid pixels, so gradient and colour thresholds mean the same for Byte,
/// UInt16 or float inputs. `valid` (may be empty) marks pixels with data.
void normalize_bands(Image<float>& image, const std::vector<uint8_t>& valid);

/// Gradient magnitude (Sobel, band-weighted root sum of squares) of the image
/// after optional Gaussian smoothing. Output has one band.
Image<float> multiband_gradient(const Image<float>& image, const WatershedOptions& options);

/// Flooding watershed on the gradient with dynamics-based marker selection
/// (union-find, 4-connectivity). Every valid pixel gets a label (no watershed
/// lines); invalid pixels get 0. Labels are numbered in raster-scan order of
/// first appearance, so the result is deterministic.
Oversegmentation watershed_oversegment(const Image<float>& image, const std::vector<uint8_t>& valid,
                                       const WatershedOptions& options, const Progress& progress = {});

}  // namespace cityforge
