#pragma once
// Little-endian fixed-size fields of LAS/LAZ/COPC records (the formats are
// little-endian, as is every platform we build on): one reader and one writer
// for las.cpp, copc.cpp, cloud_translate.cpp and the LAZ decoder.
#include <cstddef>
#include <cstring>
#include <vector>

namespace cityforge::bytes {

/// The T stored at `p` (unaligned reads allowed).
template <typename T>
T get(const void* p) {
    T v;
    std::memcpy(&v, p, sizeof(T));
    return v;
}

/// Stores `v` at `p` (unaligned writes allowed).
template <typename T>
void store(void* p, T v) {
    std::memcpy(p, &v, sizeof(T));
}

/// Stores `v` at byte `pos` of `buf` (pos + sizeof(T) <= buf.size()).
template <typename T>
void put(std::vector<char>& buf, std::size_t pos, T v) {
    store(buf.data() + pos, v);
}

}  // namespace cityforge::bytes
