#pragma once
// In-memory multi-band image, band-sequential (planar) like GDAL's default
// RasterIO layout: value(b, col, row) = data[(b * height + row) * width + col].
// No georeferencing here: a GeoRaster pairs an Image with its GeoTransform/CRS.
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "core/large_buffer.hpp"

namespace cityforge {

template <typename T>
struct Image {
    int width = 0;
    int height = 0;
    int bands = 0;
    LargeVector<T> data;  ///< band-sequential samples

    Image() = default;
    Image(int w, int h, int b, T fill = T{})
        : width(w), height(h), bands(b), data(static_cast<std::size_t>(w) * h * b, fill) {}

    std::size_t pixel_count() const { return static_cast<std::size_t>(width) * height; }
    std::size_t index(int band, int col, int row) const {
        return (static_cast<std::size_t>(band) * height + row) * width + col;
    }
    T& at(int band, int col, int row) { return data[index(band, col, row)]; }
    const T& at(int band, int col, int row) const { return data[index(band, col, row)]; }
    T* band_data(int band) { return data.data() + static_cast<std::size_t>(band) * pixel_count(); }
    const T* band_data(int band) const { return data.data() + static_cast<std::size_t>(band) * pixel_count(); }
};

}  // namespace cityforge
