#include "core/large_buffer.hpp"

#include "core/memory.hpp"

#include <algorithm>
#include <mutex>
#include <unordered_map>
#include <unistd.h>

namespace cityforge {

namespace {
// How much larger than a request a cached block handed out for it may be: twice, plus this.
constexpr std::size_t kMaxSurplusBytes = std::size_t(64) << 20;


struct Block {
    void* p;
    std::size_t bytes;
};

// The cache: the blocks held, the size of every block handed out (a request
// may get a larger block whole), the limit and the counters, under one mutex.
// Blocks come from aligned_alloc, as LargeBufferAllocator's: memory freed
// back goes where it went before (glibc's heap keeps what it keeps and gives
// it to the next malloc, so a window-by-window run holds no more than it did).
struct BlockCache {
    std::mutex mutex;
    std::vector<Block> blocks;
    std::unordered_map<void*, std::size_t> out;
    std::size_t limit = 0;
    LargeBufferCacheStats stats;
    // A quarter of the memory this process may use (usable_memory_bytes: the
    // address-space limit when lower than the machine's RAM), as the tile
    // planning counts memory.
    BlockCache() {
        const double usable = usable_memory_bytes();
        limit = usable > 0 ? static_cast<std::size_t>(usable / 4) : std::size_t(1) << 30;
    }
    void free_block(void* p, std::size_t bytes) noexcept {
        std::free(p);
        stats.freed_bytes += bytes;
    }
    void free_all() noexcept {
        for (const Block& b : blocks) free_block(b.p, b.bytes);
        blocks.clear();
        stats.cached_bytes = 0, stats.cached_blocks = 0;
    }
    // Frees blocks, largest first, until the cache holds at most `bytes`.
    void shrink_to(std::size_t bytes) noexcept {
        while (stats.cached_bytes > bytes && !blocks.empty()) {
            const auto largest = std::max_element(blocks.begin(), blocks.end(), [](const Block& a, const Block& b) { return a.bytes < b.bytes; });
            free_block(largest->p, largest->bytes);
            stats.cached_bytes -= largest->bytes;
            blocks.erase(largest);
        }
        stats.cached_blocks = blocks.size();
    }
};

BlockCache& cache() {
    static BlockCache c;
    return c;
}

}  // namespace

void* acquire_cached_block(std::size_t bytes) {
    if (bytes > std::size_t(-1) - kCachedBlockAlign) throw std::bad_alloc();
    const std::size_t need = (std::max<std::size_t>(bytes, 1) + kCachedBlockAlign - 1) / kCachedBlockAlign * kCachedBlockAlign;
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    // The smallest cached block that holds the request, used whole; not one
    // more than twice the request (+ 64 MiB): with tiles at once in one
    // process, a small tile taking a large tile's blocks would make that
    // tile allocate them again, both held beyond what the tile planning counts.
    auto best = c.blocks.end();
    for (auto it = c.blocks.begin(); it != c.blocks.end(); ++it)
        if (it->bytes >= need && it->bytes - need <= need + kMaxSurplusBytes && (best == c.blocks.end() || it->bytes < best->bytes)) best = it;
    if (best != c.blocks.end()) {
        const Block b = *best;
        c.out.emplace(b.p, b.bytes);  // first: if the bookkeeping cannot grow, the block stays cached
        c.blocks.erase(best);
        c.stats.cached_bytes -= b.bytes, c.stats.cached_blocks = c.blocks.size();
        c.stats.reused_bytes += b.bytes;
        return b.p;
    }
    c.free_all();  // before allocating: cached memory never sits beside the new block
    void* p = std::aligned_alloc(kCachedBlockAlign, need);
    if (!p) throw std::bad_alloc();
    ::madvise(p, need, MADV_HUGEPAGE);  // a hint: failure is harmless
    try {
        c.out.emplace(p, need);
    } catch (...) {
        std::free(p);
        throw;
    }
    c.stats.allocated_bytes += need;
    return p;
}

void return_cached_block(void* p, std::size_t) noexcept {
    if (!p) return;
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    const auto it = c.out.find(p);
    if (it == c.out.end()) return;  // not a block of this cache: a caller's bug, never freed twice
    const std::size_t size = it->second;
    c.out.erase(it);
    if (c.stats.cached_bytes + size > c.limit) {
        c.free_block(p, size);
        return;
    }
    try {
        c.blocks.push_back(Block{p, size});
    } catch (...) {  // no room to list it: freed, not leaked (this function never throws)
        c.free_block(p, size);
        return;
    }
    c.stats.cached_bytes += size, c.stats.cached_blocks = c.blocks.size();
}

void release_large_buffer_cache() noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    c.free_all();
}

void set_large_buffer_cache_limit(std::size_t bytes) noexcept {
    BlockCache& c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    c.limit = bytes;
    c.shrink_to(bytes);
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
