#pragma once
// Allocator for large pixel and point buffers. Blocks of 4 MiB and more are
// 2 MiB-aligned and marked for transparent huge pages (madvise), which cuts
// the page-fault cost of first touching hundreds of MB by ~500x on kernels
// where THP is in "madvise" mode (Debian's default). Smaller blocks use new
// (aligned new for over-aligned types).
//
// Besides, a process-wide cache of large blocks for temporary arrays that one
// step frees and the next one allocates again (canonical_order's permutation,
// then the outlier filter's arrays): a fresh block is memory the kernel zeroes
// on first touch (on a VM, memory the host may have to back anew: 5.3-5.6 s
// system time of the outlier filter at 127 M points), a cached one holds
// pages already touched. Only CachedArray uses it; LargeVector does not.
#include <cstddef>
#include <cstdlib>
#include <memory>
#include <new>
#include <sys/mman.h>
#include <type_traits>
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

/// Requests of at least this many bytes go through the block cache; smaller
/// ones are plain new / delete.
inline constexpr std::size_t kCachedBlockMinBytes = std::size_t(4) << 20;
/// Blocks are whole multiples of this (2 MiB, a huge page), aligned to it.
inline constexpr std::size_t kCachedBlockAlign = std::size_t(2) << 20;

/// A block of at least `bytes` (>= kCachedBlockMinBytes; rounded up to
/// 2 MiB), 2 MiB-aligned, marked for huge pages. The smallest cached block
/// that holds the request (and is at most twice it + 64 MiB) is handed out whole, its bytes stale: the caller
/// must write every byte it reads. When no cached block is large enough, the
/// cache is emptied first (its blocks freed) and a new block allocated
/// (aligned_alloc, as LargeBufferAllocator), so the process never holds
/// cached blocks beside a new one. Thread-safe. Throws std::bad_alloc.
void* acquire_cached_block(std::size_t bytes);

/// Gives back a block of acquire_cached_block (`bytes` as requested; the
/// cache knows the block's size): kept in the cache while the cache's bytes
/// stay within its limit, else freed. A pointer the cache did not hand out
/// is ignored. Thread-safe; never throws.
void return_cached_block(void* p, std::size_t bytes) noexcept;

/// Frees every cached block. A step that ends a chain of reuse calls it
/// (filter_outliers does when it returns), so cached blocks never sit beside
/// the next step's memory. Thread-safe.
void release_large_buffer_cache() noexcept;

/// Limit of the cache in bytes (default: a quarter of usable_memory_bytes(),
/// so a ulimit -v is respected); a lower limit frees blocks until the cache
/// fits. 0 disables caching.
void set_large_buffer_cache_limit(std::size_t bytes) noexcept;
std::size_t large_buffer_cache_limit() noexcept;

/// Counters of the cache since the process started (bytes of whole blocks,
/// 2 MiB multiples): for tests and benchmarks.
struct LargeBufferCacheStats {
    std::size_t cached_bytes = 0;     ///< held in the cache now
    std::size_t cached_blocks = 0;    ///< blocks held now
    std::size_t reused_bytes = 0;     ///< handed out from the cache
    std::size_t allocated_bytes = 0;  ///< newly allocated
    std::size_t freed_bytes = 0;      ///< freed (emptied, over the limit)
};
LargeBufferCacheStats large_buffer_cache_stats() noexcept;

/// Deleter of CachedArray: returns large blocks to the cache.
template <class T>
struct CachedArrayDelete {
    std::size_t n = 0;  ///< elements
    void operator()(T* p) const noexcept {
        if (n * sizeof(T) >= kCachedBlockMinBytes) return_cached_block(p, n * sizeof(T));
        else ::operator delete(p, std::align_val_t(alignof(T)));
    }
};
/// An array of trivial elements, NOT initialised (large ones may hold stale
/// bytes of an earlier array): every element must be written before it is read.
template <class T>
using CachedArray = std::unique_ptr<T[], CachedArrayDelete<T>>;

/// n uninitialised elements of a trivially copyable T, large arrays from the
/// block cache (see acquire_cached_block).
template <class T>
CachedArray<T> cached_array(std::size_t n) {
    static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>, "cached_array holds plain values");
    static_assert(alignof(T) <= kCachedBlockAlign);
    if (n > std::size_t(-1) / sizeof(T)) throw std::bad_alloc();
    const std::size_t bytes = n * sizeof(T);
    void* p = bytes >= kCachedBlockMinBytes ? acquire_cached_block(bytes) : ::operator new(bytes, std::align_val_t(alignof(T)));
    return CachedArray<T>(static_cast<T*>(p), CachedArrayDelete<T>{n});
}

}  // namespace cityforge
