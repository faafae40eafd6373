#pragma once
// Allocator for large pixel and point buffers. Blocks of 4 MiB and more are
// 2 MiB-aligned and marked for transparent huge pages (madvise), which cuts
// the page-fault cost of first touching hundreds of MB by ~500x on kernels
// where THP is in "madvise" mode (Debian's default). Smaller blocks use new
// (aligned new for over-aligned types).
#include <cstddef>
#include <cstdlib>
#include <new>
#include <sys/mman.h>
#include <vector>

namespace cityforge {

template <typename T>
struct LargeBufferAllocator {
    using value_type = T;
    LargeBufferAllocator() noexcept = default;
    template <typename U>
    LargeBufferAllocator(const LargeBufferAllocator<U>&) noexcept {}

    static constexpr std::size_t kHuge = std::size_t(2) << 20;
    static constexpr std::size_t kThreshold = std::size_t(4) << 20;

    // Types aligned beyond what plain new guarantees (e.g. alignas(64) records) get aligned new.
    static constexpr bool kOverAligned = alignof(T) > __STDCPP_DEFAULT_NEW_ALIGNMENT__;

    T* allocate(std::size_t n) {
        const std::size_t bytes = n * sizeof(T);
        if (bytes < kThreshold) {
            if constexpr (kOverAligned) return static_cast<T*>(::operator new(bytes, std::align_val_t(alignof(T))));
            else return static_cast<T*>(::operator new(bytes));
        }
        const std::size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
        void* p = std::aligned_alloc(kHuge, rounded);
        if (!p) throw std::bad_alloc();
        ::madvise(p, rounded, MADV_HUGEPAGE);  // a hint: failure is harmless
        return static_cast<T*>(p);
    }
    void deallocate(T* p, std::size_t n) noexcept {
        if (n * sizeof(T) >= kThreshold) std::free(p);
        else if constexpr (kOverAligned) ::operator delete(p, std::align_val_t(alignof(T)));
        else ::operator delete(p);
    }
    template <typename U>
    bool operator==(const LargeBufferAllocator<U>&) const noexcept { return true; }
};

/// std::vector whose large allocations use transparent huge pages.
template <typename T>
using LargeVector = std::vector<T, LargeBufferAllocator<T>>;

}  // namespace cityforge
