#pragma once
// SHA-256 (FIPS 180-4), incremental. Used to fingerprint decoded point
// records (LAZ oracle checks, `cloud translate --hash`) without OpenSSL.
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

namespace cityforge {

class Sha256 {
public:
    Sha256();
    void update(const void* data, std::size_t n);
    /// Lower-case hex digest; the object must not be updated afterwards.
    std::string hex();

private:
    void block(const uint8_t* p);
    std::array<uint32_t, 8> h_;
    std::array<uint8_t, 64> buf_{};
    std::size_t used_ = 0;
    uint64_t bytes_ = 0;
};

}  // namespace cityforge
