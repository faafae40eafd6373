#pragma once
// LASzip (LAZ) decoding, our own implementation of the published format
// (Debian 12 has neither LASzip nor laz-perf). Supports compressor 1 =
// pointwise, not chunked (LASzip 1.x: one stream for all points), and the
// chunked compressors: 2 = pointwise (item versions 1 and 2: POINT10,
// GPSTIME11, RGB12, BYTE extra bytes; WAVEPACKET13 version 1) for point
// formats 0-5, and 3 = layered (item versions 3 and 4: POINT14, RGB14,
// RGBNIR14, WAVEPACKET14, BYTE14 extra bytes) for point formats 6-10; fixed
// and variable chunk sizes, with or without a chunk table. Decoded records
// are byte-identical to LASzip / laz-perf output (tested against the corpus
// oracle and LAS twins written by LASzip). Everything else (other versions,
// unknown items or compressors) is refused with a one-line Error naming the
// file.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/random_access_file.hpp"

namespace cityforge {

/// One item of the LASzip VLR (a field group of the point record).
struct LazItem {
    uint16_t type = 0;     ///< 0 BYTE, 6 POINT10, 7 GPSTIME11, 8 RGB12, 9 WAVEPACKET13, 10 POINT14, 11 RGB14, 12 RGBNIR14, 13 WAVEPACKET14, 14 BYTE14
    uint16_t size = 0;     ///< bytes of the record this item covers
    uint16_t version = 0;  ///< item compression version
};
/// "POINT10 v2" etc.
std::string to_string(const LazItem& item);

/// The LASzip VLR (user "laszip encoded", record 22204).
struct LazInfo {
    uint16_t compressor = 0;  ///< 0 none, 1 pointwise (one stream, chunk_size 0), 2 pointwise chunked, 3 layered chunked
    uint16_t coder = 0;       ///< 0 = arithmetic
    int version_major = 0, version_minor = 0, version_revision = 0;  ///< of the writing LASzip
    uint32_t options = 0;
    uint32_t chunk_size = 0;  ///< points per chunk; 0xFFFFFFFF = variable (sizes in the chunk table)
    std::vector<LazItem> items;
    bool variable_chunks() const { return chunk_size == 0xFFFFFFFFu; }
    /// "2 (pointwise chunked)" etc.
    std::string compressor_name() const;
};

/// Parses the VLR payload; throws Error(path, ...) when it is malformed.
LazInfo parse_laszip_vlr(const std::vector<char>& payload, const std::string& path);

/// Throws Error(path, ...) unless we can decode `info` for this point format
/// and record length (items cover the record exactly, known types/versions).
void check_laz_supported(const LazInfo& info, int point_format, int record_length, const std::string& path);

/// One chunk of compressed points.
struct LazChunk {
    uint64_t offset = 0;       ///< file offset of the chunk's first byte
    uint64_t bytes = 0;        ///< compressed size (0 = unknown: no chunk table)
    uint64_t first_point = 0;  ///< index of its first point in file order
    uint64_t point_count = 0;
};

/// Decodes one chunk: `data`/`size` are its compressed bytes, `count` points
/// of `record_length` bytes are written to `out`. Returns the bytes the chunk
/// used. Throws Error("<path>: chunk <index>: <problem>") on corrupt data; it
/// never reads outside `data` or writes outside `out`. With
/// `point_fields_only`, layered chunks skip the layers a PointCloud does not
/// use (flags, scan angle, user data, point source, NIR, extra bytes): those
/// bytes of the records then hold the chunk's first value. With
/// `split_layers`, a layered chunk decodes its XY layer first and then its
/// other layers as TBB tasks that idle threads may take (for batches with
/// fewer chunks than threads can share); the same bytes either way.
std::size_t decode_laz_chunk(const LazInfo& info, int record_length, const uint8_t* data, std::size_t size, uint64_t count,
                             char* out, const std::string& path, std::size_t chunk_index, bool point_fields_only = false,
                             bool split_layers = false);

/// Decodes only the XY layer of a layered (compressor 3) chunk: the records'
/// X and Y (and return numbers, scanner channel) are exact, every other field
/// holds a stale value. The XY layer is the first of POINT14's nine and
/// depends on no other, so this costs a fraction of a full decode. Throws
/// Error for a pointwise chunk or corrupt data, as decode_laz_chunk.
std::size_t decode_laz_chunk_xy(const LazInfo& info, int record_length, const uint8_t* data, std::size_t size, uint64_t count,
                                char* out, const std::string& path, std::size_t chunk_index);

/// A closed box in the file CRS and the header's X/Y scale and offset: a
/// point is inside when min_x <= X * scale_x + offset_x <= max_x (the
/// readers' arithmetic), likewise for y.
struct LazXYBox {
    double min_x = 0, min_y = 0, max_x = 0, max_y = 0;
    double scale_x = 1, scale_y = 1, offset_x = 0, offset_y = 0;
};

/// Streams the decoded point records of a LAZ file, chunk by chunk, several
/// chunks decoded in parallel (TBB) and handed out in file order. With a
/// chunk table, the whole chunks that fit in a read() are decoded straight
/// into the caller's buffer; only a chunk split between two reads is buffered.
class LazPointSource {
public:
    /// Reads the chunk table (or plans a sequential read when there is none).
    /// `file` is borrowed: it must outlive this source (LasReader owns both).
    LazPointSource(const RandomAccessFile& file, const LazInfo& info, uint64_t offset_to_points, uint64_t point_count,
                   int record_length);
    ~LazPointSource();
    LazPointSource(const LazPointSource&) = delete;
    LazPointSource& operator=(const LazPointSource&) = delete;

    /// Chunks in file order (offsets and sizes known only with a chunk table).
    const std::vector<LazChunk>& chunks() const { return chunks_; }
    bool has_chunk_table() const { return has_table_; }
    /// Layered chunks with a chunk table: per chunk (size == chunks().size()),
    /// whether one of its points lies in `box`, found by decoding only the
    /// XY layer of each selected chunk (in parallel). LAZ has no per-chunk
    /// bounds; this is how a window read skips chunks of a non-COPC file.
    /// Empty for pointwise chunks (one stream interleaves all fields, so x
    /// and y cost a full decode) and without a chunk table. Before the first read.
    std::vector<bool> chunks_meeting_box(const LazXYBox& box);
    /// Decode only the chunks with keep[i] (size == chunks().size()); before the first read.
    void select_chunks(const std::vector<bool>& keep);
    /// Before the first read: decode only what a PointCloud holds (see decode_laz_chunk).
    void set_point_fields_only(bool on) { point_fields_only_ = on; }
    /// Whether chunk `c` is decoded with split_layers (see decode_laz_chunk).
    bool split_layers(const LazChunk& c) const;
    /// Points that the selected chunks hold.
    uint64_t selected_points() const { return selected_points_; }
    /// Writes up to `max_points` records to `out` (room for max_points ×
    /// record length); returns how many (0 at the end).
    std::size_t read(char* out, std::size_t max_points);

private:
    void fill();
    /// Decodes the next whole chunks that fit into max_points straight into `out`; returns their points (0: none fits).
    std::size_t decode_direct(char* out, std::size_t max_points);
    /// Reads chunk `chunk`'s compressed bytes (chunk table known) into `raw`.
    void read_raw(std::size_t chunk, std::vector<uint8_t>& raw);
    std::string path_;
    LazInfo info_;
    int record_length_;
    uint64_t point_count_;
    const RandomAccessFile* file_;
    uint64_t file_size_ = 0;
    std::vector<LazChunk> chunks_;
    bool has_table_ = false;
    bool point_fields_only_ = false;
    std::vector<std::size_t> order_;  ///< selected chunk indices
    std::size_t next_ = 0;            ///< next entry of order_ to decode
    uint64_t selected_points_ = 0;
    uint64_t sequential_offset_ = 0;  ///< no chunk table: where the next chunk starts
    std::vector<std::vector<char>> decoded_;  ///< current batch, in order
    std::vector<std::vector<uint8_t>> raw_;   ///< compressed bytes of the current batch
    std::size_t batch_index_ = 0;
    std::size_t batch_pos_ = 0;       ///< records handed out of decoded_[batch_index_]
};

}  // namespace cityforge
