#pragma once
// In-memory point cloud, structure of arrays. Coordinates are in the cloud's
// CRS (horizontal units of that CRS, z in its vertical datum/units).
#include <cstddef>
#include <cstdint>
#include <vector>

namespace cityforge {

/// ASPRS LAS classification codes we use by name.
namespace las_class {
inline constexpr uint8_t unclassified = 1;
inline constexpr uint8_t ground = 2;
inline constexpr uint8_t vegetation_high = 5;
inline constexpr uint8_t building = 6;
inline constexpr uint8_t low_noise = 7;
inline constexpr uint8_t water = 9;
inline constexpr uint8_t high_noise = 18;
}  // namespace las_class

struct PointCloud {
    std::vector<double> x, y, z;          ///< CRS units
    std::vector<uint16_t> intensity;
    std::vector<uint8_t> classification;  ///< ASPRS class (0..255)
    std::vector<uint8_t> return_number;   ///< 1-based
    std::vector<uint8_t> number_of_returns;
    std::vector<double> gps_time;         ///< empty when the source has none
    std::vector<uint16_t> red, green, blue;  ///< 16-bit colour; empty when none

    std::size_t size() const { return x.size(); }
    bool has_color() const { return !red.empty(); }
    bool has_gps_time() const { return !gps_time.empty(); }
    void clear();
    /// Keeps the first `n` points (n <= size()) with all their attributes;
    /// an attribute array shorter than `n` (empty: the cloud has no such
    /// attribute) is left as it is.
    void truncate(std::size_t n);
    void reserve(std::size_t n, bool color, bool gps);
    /// Appends `n` points of zeros (colour and GPS time too when asked: the
    /// points before them get zeros if the cloud had none), to be filled by
    /// index; one reservation, then one resize per array.
    void grow(std::size_t n, bool color, bool gps);
    /// What a cloud holds before an append: its size and which attributes it has.
    struct Mark {
        std::size_t size;
        bool gps_time, color;
    };
    Mark mark() const { return {size(), has_gps_time(), has_color()}; }
    /// Back to `m` (taken from this cloud, with no point removed since): the
    /// points after it are taken off, and an attribute the cloud did not have
    /// then is dropped (how a failed read leaves the caller's cloud as it was).
    void roll_back(const Mark& m);
    /// Appends point `i` of `src` with all its attributes (colour and GPS time
    /// when `src` has them; mixing clouds with and without them is the caller's error).
    void append(const PointCloud& src, std::size_t i);
    /// Removes the points i >= `first` for which `drop(i)` is true (indices
    /// as before the call), keeping the order of the others and all their
    /// attributes; returns how many were removed.
    template <class Drop>
    std::size_t remove_from(std::size_t first, Drop&& drop) {
        const std::size_t n = size();
        std::size_t w = first;
        auto move_all = [&](std::size_t to, std::size_t from) {
            x[to] = x[from], y[to] = y[from], z[to] = z[from], intensity[to] = intensity[from];
            classification[to] = classification[from], return_number[to] = return_number[from];
            number_of_returns[to] = number_of_returns[from];
            if (!gps_time.empty()) gps_time[to] = gps_time[from];
            if (!red.empty()) red[to] = red[from], green[to] = green[from], blue[to] = blue[from];
        };
        for (std::size_t i = first; i < n; ++i)
            if (!drop(i)) {
                if (w != i) move_all(w, i);
                ++w;
            }
        truncate(w);
        return n - w;
    }
};

}  // namespace cityforge
