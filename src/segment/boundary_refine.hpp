#pragma once
// Pixel-level refinement of segment boundaries. A gradient watershed puts a
// step edge's two flanking pixels (equal Sobel magnitude) on either side at
// random, so outlines wander by one pixel; reassigning boundary pixels to the
// adjacent segment whose mean colour is closest puts them back on the edge.
// No GDAL; pixel units.
#include <cstdint>

#include "core/image.hpp"

namespace cityforge {

/// Moves every pixel on a segment boundary to the 4-adjacent segment (or its
/// own) whose mean over `bands` first bands of `image` is nearest (Euclidean;
/// ties keep the own segment, then the smallest label), `passes` times;
/// segment means are computed once, before the first pass. Labels 0 (nodata)
/// are neither moved nor taken. The same input gives the same output.
void refine_segment_boundaries(const Image<float>& image, int bands, Image<uint32_t>& labels, uint32_t count, int passes);

}  // namespace cityforge
