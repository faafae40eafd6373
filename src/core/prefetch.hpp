#pragma once
// Starts loading the cache line holding p (a hint: never faults, changes no
// result). An asm statement rather than __builtin_prefetch: GCC 12 dropped
// loops of __builtin_prefetch that had no other effect (no prefetch
// instruction was left in RegionGraph::merge or in the watershed's
// flooding), while an asm volatile is always emitted. prefetcht0 for reads
// and writes alike (PREFETCHW is not in the x86-64 baseline).
namespace cityforge {

inline void prefetch_line(const void* p) {
#if defined(__x86_64__) || defined(__i386__)
    asm volatile("prefetcht0 %0" : : "m"(*static_cast<const char*>(p)));
#else
    __builtin_prefetch(p);
#endif
}

// Starts loading the cache line holding p into the second-level cache, not
// the first (prefetcht1): for data needed one step later. On the AMD cores
// we measured, prefetcht0 requests hold first-level miss buffers, and
// dozens issued at once stall the thread until earlier misses complete;
// loads to L2 do not, and a later prefetch_line or load then hits L2.
inline void prefetch_line_l2(const void* p) {
#if defined(__x86_64__) || defined(__i386__)
    asm volatile("prefetcht1 %0" : : "m"(*static_cast<const char*>(p)));
#else
    __builtin_prefetch(p, 0, 2);
#endif
}

}  // namespace cityforge
