#include "core/large_buffer.hpp"

#include <algorithm>
#include <cstdint>
#include <mutex>
#include <unistd.h>

namespace cityforge {

namespace {

struct Block {
    char* p;
    std::size_t bytes;
};

// The cache: blocks sorted by address (neighbours in memory join), their
// byte total, the limit and the counters, under one mutex.
struct BlockCache {
    std::mutex mutex;
    std::vector<Block> blocks;
    std::size_t limit = 0;
    LargeBufferCacheStats stats;
    BlockCache() {
        const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
        limit = pages > 0 && page > 0 ? static_cast<std::size_t>(pages) * static_cast<std::size_t>(page) / 4 : std::size_t(1) << 30;
    }
    void unmap(char* p, std::size_t bytes) noexcept {
        ::munmap(p, bytes);
        stats.unmapped_bytes += bytes;
    }
    void unmap_all() noexcept {
        for (const Block& b : blocks) unmap(b.p, b.bytes);
        blocks.clear();
        stats.cached_bytes = 0;
    }
    // Unmaps blocks, largest first, until the cache holds at most `bytes`.
    void shrink_to(std::size_t bytes) noexcept {
        while (stats.cached_bytes > bytes && !blocks.empty()) {
            const auto largest = std::max_element(blocks.begin(), blocks.end(), [](const Block& a, const Block& b) { return a.bytes < b.bytes; });
            unmap(largest->p, largest->bytes);
            stats.cached_bytes -= largest->bytes;
            blocks.erase(largest);
        }
    }
};

BlockCache& cache() {
    static BlockCache c;  // never destroyed before its users: blocks returned at exit are unmapped
    return c;
}

std::size_t rounded_bytes(std::size_t bytes) { return (bytes + kCachedBlockAlign - 1) / kCachedBlockAlign * kCachedBlockAlign; }

// A fresh mapping of `bytes` (a 2 MiB multiple), 2 MiB-aligned: one mapping
// 2 MiB longer, its unaligned head and tail unmapped.
char* map_aligned(std::size_t bytes) {
    const std::size_t span = bytes + kCachedBlockAlign;
    void* m = ::mmap(nullptr, span, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (m == MAP_FAILED) throw std::bad_alloc();
    char* const base = static_cast<char*>(m);
    const auto addr = reinterpret_cast<std::uintptr_t>(base);
    char* const p = base + ((kCachedBlockAlign - addr % kCachedBlockAlign) % kCachedBlockAlign);
    if (p > base) ::munmap(base, static_cast<std::size_t>(p - base));
    if (p + bytes < base + span) ::munmap(p + bytes, static_cast<std::size_t>(base + span - (p + bytes)));
    ::madvise(p, bytes, MADV_HUGEPAGE);  // a hint: failure is harmless
    return p;
}

}  // namespace

void* acquire_cached_block(std::size_t bytes) {
    if (bytes > std::size_t(-1) - kCachedBlockAlign) throw std::bad_alloc();
    const std::size_t need = rounded_bytes(std::max<std::size_t>(bytes, 1));
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    // The smallest cached block that holds the request (the lowest address among equals).
    auto best = c.blocks.end();
    for (auto it = c.blocks.begin(); it != c.blocks.end(); ++it)
        if (it->bytes >= need && (best == c.blocks.end() || it->bytes < best->bytes)) best = it;
    if (best != c.blocks.end()) {
        char* const p = best->p;
        if (best->bytes == need) c.blocks.erase(best);
        else best->p += need, best->bytes -= need;  // the rest stays cached
        c.stats.cached_bytes -= need;
        c.stats.reused_bytes += need;
        c.stats.cached_blocks = c.blocks.size();
        return p;
    }
    c.unmap_all();  // before mapping: cached memory never sits beside the new block
    c.stats.cached_blocks = 0;
    char* const p = map_aligned(need);
    c.stats.mapped_bytes += need;
    return p;
}

void return_cached_block(void* ptr, std::size_t bytes) noexcept {
    if (!ptr) return;
    char* const p = static_cast<char*>(ptr);
    const std::size_t size = rounded_bytes(std::max<std::size_t>(bytes, 1));
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    if (c.stats.cached_bytes + size > c.limit) {
        c.unmap(p, size);
        return;
    }
    auto next = std::lower_bound(c.blocks.begin(), c.blocks.end(), p, [](const Block& b, const char* q) { return b.p < q; });
    const bool joins_prev = next != c.blocks.begin() && std::prev(next)->p + std::prev(next)->bytes == p;
    const bool joins_next = next != c.blocks.end() && p + size == next->p;
    if (joins_prev && joins_next) std::prev(next)->bytes += size + next->bytes, c.blocks.erase(next);
    else if (joins_prev) std::prev(next)->bytes += size;
    else if (joins_next) next->p = p, next->bytes += size;
    else c.blocks.insert(next, Block{p, size});
    c.stats.cached_bytes += size;
    c.stats.cached_blocks = c.blocks.size();
}

void release_large_buffer_cache() noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    c.unmap_all();
    c.stats.cached_blocks = 0;
}

void set_large_buffer_cache_limit(std::size_t bytes) noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    c.limit = bytes;
    c.shrink_to(bytes);
    c.stats.cached_blocks = c.blocks.size();
}

std::size_t large_buffer_cache_limit() noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    return c.limit;
}

LargeBufferCacheStats large_buffer_cache_stats() noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    return c.stats;
}

}  // namespace cityforge
