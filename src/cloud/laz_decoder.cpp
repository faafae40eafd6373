#include "cloud/laz_decoder.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <limits>

#include "cloud/le_bytes.hpp"
#include "core/error.hpp"

// Our own implementation of the LASzip format (LASzip's public description and
// the behaviour of its reference decoder): an adaptive arithmetic decoder
// (Said/Moffat style, 32-bit interval, 15-bit symbol and 13-bit bit models),
// integer correctors coded by magnitude class, and the item predictors.
namespace cityforge {
namespace {

// Thrown inside the decoder, turned into an Error naming file and chunk.
struct Corrupt {
    const char* what;
};


// ------------------------------------------------------------ byte input
// Bytes of one arithmetic-coded stream. Past its end it yields zeros and
// counts them: a decoder that needs more than the 4 look-ahead bytes of its
// initialisation has run off its buffer (corrupt input).
class ByteIn {
public:
    ByteIn() = default;
    ByteIn(const uint8_t* p, std::size_t n) : begin_(p), cur_(p), end_(p + n) {}
    uint32_t get() {
        if (cur_ < end_) return *cur_++;
        if (++overrun_ > 4) throw Corrupt{"arithmetic decoder ran off the end of its data"};
        return 0;
    }
    /// At least 4 bytes left: peek32() and skip() may be used instead of get().
    bool has4() const { return end_ - cur_ >= 4; }
    /// The next 4 bytes, first byte highest (needs has4()).
    uint32_t peek32() const { return __builtin_bswap32(bytes::get<uint32_t>(cur_)); }
    void skip(std::size_t n) { cur_ += n; }
    std::size_t pos() const { return static_cast<std::size_t>(cur_ - begin_); }

private:
    const uint8_t* begin_ = nullptr;
    const uint8_t* cur_ = nullptr;
    const uint8_t* end_ = nullptr;
    std::size_t overrun_ = 0;
};

constexpr uint32_t kMinLength = 0x01000000u;
constexpr uint32_t kMaxLength = 0xFFFFFFFFu;
constexpr uint32_t kBitShift = 13;
constexpr uint32_t kBitMaxCount = 1u << kBitShift;
constexpr uint32_t kSymShift = 15;
constexpr uint32_t kSymMaxCount = 1u << kSymShift;

// Adaptive binary model.
struct BitModel {
    uint32_t update_cycle = 4, until_update = 4;
    uint32_t bit0_prob = 1u << (kBitShift - 1), bit0_count = 1, bit_count = 2;
    void update() {
        if ((bit_count += update_cycle) > kBitMaxCount) {
            bit_count = (bit_count + 1) >> 1;
            bit0_count = (bit0_count + 1) >> 1;
            if (bit0_count == bit_count) ++bit_count;
        }
        const uint32_t scale = 0x80000000u / bit_count;
        bit0_prob = (bit0_count * scale) >> (31 - kBitShift);
        update_cycle = std::min<uint32_t>((5 * update_cycle) >> 2, 64);
        until_update = update_cycle;
    }
};

// Adaptive multi-symbol model. The coded stream depends only on the
// distribution (LASzip's ArithmeticModel); the decoding table is ours and
// decoder-side only: table_[t] is the symbol whose interval holds
// t << table_shift_, for every model (LASzip keeps one only for > 16 symbols
// and searches the rest by bisection with a multiplication per step). The
// table has about 4 entries per symbol (at most 1024), so the search after
// the look-up is almost always empty; the symbol found is the same.
// table_[i] = 2 i: see SymbolModel::bind_store.
constexpr std::array<uint32_t, 260> kUnreadyTable = [] {
    std::array<uint32_t, 260> a{};
    for (uint32_t i = 0; i < a.size(); ++i) a[i] = 2 * i;
    return a;
}();

class SymbolModel {
public:
    // Cheap: the buffers are built on the model's first use (init), so the
    // many models a chunk never touches (high corrector classes, contexts
    // and channels that do not occur) cost nothing. A fresh model equals one
    // initialised later, so the stream decodes the same.
    explicit SymbolModel(uint32_t symbols) : symbols_(symbols), last_symbol_(symbols - 1) { bind_store(); }
    bool ready() const { return distribution_ != nullptr; }
    [[gnu::noinline]] void init() {
        const uint32_t symbols = symbols_;
        uint32_t bits = 2;
        while (bits < 8 && (1u << bits) < 4 * symbols) ++bits;
        table_size_ = 1u << bits;
        table_shift_ = kSymShift - bits;
        // One allocation: distribution (symbols + 1, the last entry
        // kSymMaxCount as a sentinel), counts (symbols), table (size + 2, and
        // 8 of slack for update's block stores).
        store_.assign(2 * static_cast<std::size_t>(symbols) + 1 + table_size_ + 2 + 8, 0);
        bind_store();
        for (uint32_t n = 0; n < symbols; ++n) count_[n] = 1;
        distribution_[symbols] = std::numeric_limits<uint32_t>::max();  // sentinel above any dv (<= kSymMaxCount)
        total_count_ = 0;
        update_cycle_ = symbols;
        update();
        until_update_ = update_cycle_ = (symbols + 6) >> 1;
    }
    SymbolModel(const SymbolModel& o) { *this = o; }
    SymbolModel& operator=(const SymbolModel& o) {
        if (this != &o) take_state(o, o.store_);
        return *this;
    }
    SymbolModel(SymbolModel&& o) noexcept { *this = std::move(o); }
    SymbolModel& operator=(SymbolModel&& o) noexcept {
        if (this != &o) take_state(o, std::move(o.store_));
        return *this;
    }
    void update() {
        if ((total_count_ += update_cycle_) > kSymMaxCount) {
            total_count_ = 0;
            for (uint32_t n = 0; n < symbols_; ++n) total_count_ += (count_[n] = (count_[n] + 1) >> 1);
        }
        // table_[j] = the last symbol k with (distribution_[k] >> table_shift_) < j
        // (0 for j = 0): symbol k - 1 fills the entries from the end of the
        // previous run to its start w, in blocks of 8 (the excess is
        // overwritten by the next symbols or the tail; the buffer has 8
        // entries of slack), so the loop count hardly depends on the data.
        uint32_t sum = 0;
        const uint32_t scale = 0x80000000u / total_count_;
        uint32_t s = 1;  // next entry to fill
        for (uint32_t k = 0; k < symbols_; ++k) {
            const uint32_t d = (scale * sum) >> (31 - kSymShift);
            distribution_[k] = d;
            sum += count_[k];
            const uint32_t w = d >> table_shift_;
            for (uint32_t j = s; j <= w; j += 8)
                for (uint32_t q = 0; q < 8; ++q) table_[j + q] = k - 1;
            s = std::max(s, w + 1);
        }
        table_[0] = 0;
        for (; s <= table_size_ + 1; s += 8)
            for (uint32_t q = 0; q < 8; ++q) table_[s + q] = symbols_ - 1;
        update_cycle_ = std::min((5 * update_cycle_) >> 2, (symbols_ + 6) << 3);
        until_update_ = update_cycle_;
    }

    uint32_t symbols_ = 0, last_symbol_ = 0;
    uint32_t table_size_ = 0, table_shift_ = 0;
    uint32_t total_count_ = 0, update_cycle_ = 0, until_update_ = 0;
    uint32_t* distribution_ = nullptr;
    uint32_t* count_ = nullptr;
    uint32_t* table_ = nullptr;

private:
    // The pointers into store_ (distribution, then counts, then the table).
    void bind_store() {
        if (store_.empty()) {
            // Not initialised: a table that sends every look-up to the slow
            // search (table_[t + 1] > table_[t] + 1), which initialises.
            distribution_ = count_ = nullptr;
            table_ = const_cast<uint32_t*>(kUnreadyTable.data());
            table_shift_ = kSymShift - 8;  // t <= 2^8 + 1 (see decode_symbol)
            return;
        }
        distribution_ = store_.data();
        count_ = distribution_ + symbols_ + 1;
        table_ = count_ + symbols_;
    }
    // Copy or move: the scalars from `o`, the buffer given, the pointers rebound to it.
    template <typename Store>
    void take_state(const SymbolModel& o, Store&& store) {
        symbols_ = o.symbols_;
        last_symbol_ = o.last_symbol_;
        table_size_ = o.table_size_;
        table_shift_ = o.table_shift_;
        total_count_ = o.total_count_;
        update_cycle_ = o.update_cycle_;
        until_update_ = o.until_update_;
        store_ = std::forward<Store>(store);
        bind_store();
    }
    std::vector<uint32_t> store_;
};

// The decoder holds its byte input by value: a copy of it in a local
// variable (see the item loops) then lives in registers.
class ArithDecoder {
public:
    void init(const uint8_t* p, std::size_t n) {
        in_ = ByteIn(p, n);
        length_ = kMaxLength;
        value_ = in_.get() << 24;
        value_ |= in_.get() << 16;
        value_ |= in_.get() << 8;
        value_ |= in_.get();
        // An encoder's first word is below the initial length; the decoder
        // keeps value_ < length_ from here on, which bounds every table index.
        if (value_ == kMaxLength) throw Corrupt{"arithmetic-coded stream starts with an impossible value"};
    }
    // Branch-free where the outcome is data-dependent (the coded bit, the
    // renormalisation); the same arithmetic as LASzip's decoder.
    [[gnu::always_inline]] uint32_t decode_bit(BitModel& m) {
        const uint32_t x = m.bit0_prob * (length_ >> kBitShift);
        const uint32_t sym = value_ >= x;
        value_ -= sym ? x : 0;
        length_ = sym ? length_ - x : x;
        m.bit0_count += sym ^ 1u;
        renorm();
        if (--m.until_update == 0) m.update();
        return sym;
    }
    [[gnu::always_inline]] uint32_t decode_symbol(SymbolModel& m) {
        const uint32_t y0 = length_;
        length_ >>= kSymShift;
        const uint32_t dv = value_ / length_;
        // value_ < length_ (see init) gives dv < 2^15 + 2^7, so t <= table_size_.
        const uint32_t t = dv >> m.table_shift_;
        uint32_t sym = m.table_[t];
        const uint32_t n = m.table_[t + 1] + 1;
        uint32_t lo, hi;  // the interval of the symbol found
        if (n > sym + 2) [[unlikely]] {
            // Several candidates, or a model not yet initialised (its table
            // always lands here).
            sym = slow_search(m, dv);
            lo = m.distribution_[sym];
            hi = m.distribution_[sym + 1];
        } else {
            // sym or sym + 1 (distribution_[symbols] is a sentinel above any
            // dv). The three bounds are loaded before the choice, off the
            // decoder's dependency chain; sym + 2 <= symbols + 1 stays inside
            // the model's buffer (its value is used only when sym + 1 is not
            // the last symbol).
            const uint32_t d0 = m.distribution_[sym], d1 = m.distribution_[sym + 1], d2 = m.distribution_[sym + 2];
            const bool up = d1 <= dv;
            sym += up;
            lo = up ? d1 : d0;
            hi = up ? d2 : d1;
        }
        const uint32_t x = lo * length_;
        const uint32_t y = sym != m.last_symbol_ ? hi * length_ : y0;
        value_ -= x;
        length_ = y - x;
        renorm();
        ++m.count_[sym];
        if (--m.until_update_ == 0) m.update();
        return sym;
    }
    [[gnu::always_inline]] uint32_t read_bits(uint32_t bits) {
        if (bits > 19) [[unlikely]] {
            const uint32_t low = read_short();
            return (read_bits_19(bits - 16) << 16) | low;
        }
        return read_bits_19(bits);
    }
    [[gnu::always_inline]] uint32_t read_bits_19(uint32_t bits) {
        const uint32_t sym = value_ / (length_ >>= bits);
        value_ -= length_ * sym;
        if (length_ < kMinLength) renorm();
        if (sym >= (1u << bits)) throw Corrupt{"invalid raw bits in the arithmetic-coded stream"};
        return sym;
    }
    uint32_t read_short() {
        const uint32_t sym = value_ / (length_ >>= 16);
        value_ -= length_ * sym;
        if (length_ < kMinLength) renorm();
        if (sym >= (1u << 16)) throw Corrupt{"invalid raw bits in the arithmetic-coded stream"};
        return sym;
    }
    uint32_t read_int() {
        const uint32_t low = read_short();
        return (read_short() << 16) | low;
    }
    /// Bytes of the stream consumed so far.
    std::size_t pos() const { return in_.pos(); }

private:
    // The symbol of dv by bisection between the table's bounds; first
    // initialises a model never used before.
    [[gnu::noinline]] static uint32_t slow_search(SymbolModel& m, uint32_t dv) {
        if (!m.ready()) m.init();
        const uint32_t t = dv >> m.table_shift_;
        uint32_t sym = m.table_[t];
        uint32_t n = m.table_[t + 1] + 1;
        while (n > sym + 1) {
            const uint32_t k = (sym + n) >> 1;
            if (m.distribution_[k] > dv) n = k;
            else sym = k;
        }
        return sym;
    }
    // Shifts in whole bytes until length_ >= kMinLength: the byte count is
    // the leading zero bytes of length_ (length_ > 0 always), read as one
    // big-endian word while 4 bytes remain.
    [[gnu::always_inline]] void renorm() {
        if (in_.has4()) [[likely]] {
            const uint32_t sh = static_cast<uint32_t>(__builtin_clz(length_)) & 24u;
            const uint64_t w = in_.peek32();
            value_ = static_cast<uint32_t>((static_cast<uint64_t>(value_) << sh) | (w >> (32 - sh)));
            length_ <<= sh;
            in_.skip(sh >> 3);
        } else if (length_ < kMinLength) {
            *this = renorm_tail(*this);
        }
    }
    // The last bytes of the stream, one at a time. By value, so that no
    // pointer to the decoder escapes the hot loops.
    [[gnu::noinline]] static ArithDecoder renorm_tail(ArithDecoder d) {
        do {
            d.value_ = (d.value_ << 8) | d.in_.get();
        } while ((d.length_ <<= 8) < kMinLength);
        return d;
    }
    ByteIn in_;
    uint32_t value_ = 0, length_ = kMaxLength;
};

// Integer corrector: the magnitude class k of (real - prediction) is coded
// with a context model, then the offset within the class.
class IntegerDecompressor {
public:
    IntegerDecompressor(uint32_t bits, uint32_t contexts, uint32_t bits_high = 8) : bits_high_(bits_high) {
        if (bits && bits < 32) {
            corr_bits_ = bits;
            corr_range_ = 1u << bits;
            corr_min_ = -static_cast<int32_t>(corr_range_ / 2);
        } else {
            corr_bits_ = 32;
            corr_range_ = 0;
            corr_min_ = std::numeric_limits<int32_t>::min();
        }
        for (uint32_t i = 0; i < contexts; ++i) k_models_.emplace_back(corr_bits_ + 1);
        for (uint32_t i = 1; i <= corr_bits_; ++i) corrector_.emplace_back(i <= bits_high_ ? (1u << i) : (1u << bits_high_));
    }
    [[gnu::always_inline]] int32_t decompress(ArithDecoder& dec, int32_t pred, uint32_t context = 0) {
        uint32_t real = static_cast<uint32_t>(pred) + static_cast<uint32_t>(read_corrector(dec, k_models_[context]));
        // Wrap into the corrector's range (a no-op for 32 bits, range 0), without branches.
        const int32_t sreal = static_cast<int32_t>(real);
        const uint32_t add = sreal < 0 ? corr_range_ : 0u;
        const uint32_t sub = (sreal >= 0 && real >= corr_range_) ? corr_range_ : 0u;
        return static_cast<int32_t>(real + add - sub);
    }
    uint32_t k() const { return k_; }

private:
    [[gnu::always_inline]] int32_t read_corrector(ArithDecoder& dec, SymbolModel& model) {
        k_ = dec.decode_symbol(model);
        if (k_ == 0) return static_cast<int32_t>(dec.decode_bit(bit_));
        if (k_ >= 32) return corr_min_;
        uint32_t c = dec.decode_symbol(corrector_[k_ - 1]);
        if (k_ > bits_high_) {
            const uint32_t k1 = k_ - bits_high_;
            c = (c << k1) | dec.read_bits(k1);
        }
        // c >= 2^(k-1): c + 1; else c - (2^k - 1) (the negative half), without a branch.
        c = c + 1u - (static_cast<uint32_t>(c < (1u << (k_ - 1))) << k_);
        return static_cast<int32_t>(c);
    }
    uint32_t bits_high_, corr_bits_, corr_range_;
    int32_t corr_min_;
    uint32_t k_ = 0;
    std::vector<SymbolModel> k_models_;
    BitModel bit_;
    std::vector<SymbolModel> corrector_;  // [k-1] for k = 1..corr_bits
};

// Lazily created model (LASzip creates these on first use; a fresh model
// equals a re-initialised one, so per-chunk creation gives the same stream).
struct LazyModel {
    std::unique_ptr<SymbolModel> m;
    SymbolModel& get(uint32_t symbols) {
        if (!m) m = std::make_unique<SymbolModel>(symbols);
        return *m;
    }
};

uint8_t fold(int32_t v) { return static_cast<uint8_t>(v & 0xFF); }
int32_t clamp_u8(int32_t v) { return v < 0 ? 0 : (v > 255 ? 255 : v); }

// LASzip's streaming median of the last five values: five sorted values
// and a flag; a new value replaces the largest (flag set) or the smallest
// (flag clear) and the flag flips when the value lands on the other side of
// the middle. Written as a branch-free sorted insertion (the values are
// data, their order unpredictable): the same five values in the same order.
class Median5 {
public:
    [[gnu::always_inline]] void add(int32_t v) {
        const int32_t* a = values_.data() + (high_ ? 0 : 1);  // the four that stay
        const int32_t a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
        const int32_t mid = values_[2];
        values_[0] = std::min(a0, v);
        values_[1] = std::min(a1, std::max(a0, v));
        values_[2] = std::min(a2, std::max(a1, v));
        values_[3] = std::min(a3, std::max(a2, v));
        values_[4] = std::max(a3, v);
        high_ = v < mid || (!high_ && v == mid);
    }
    int32_t get() const { return values_[2]; }

private:
    std::array<int32_t, 5> values_{};
    bool high_ = true;
};

// Context tables of the point predictors (return number r, number of returns n).
constexpr uint8_t kReturnMap[8][8] = {{15, 14, 13, 12, 11, 10, 9, 8}, {14, 0, 1, 3, 6, 10, 10, 9}, {13, 1, 2, 4, 7, 11, 11, 10},
                                      {12, 3, 4, 5, 8, 12, 12, 11},   {11, 6, 7, 8, 9, 13, 13, 12},  {10, 10, 11, 12, 13, 14, 14, 13},
                                      {9, 10, 11, 12, 13, 14, 15, 14}, {8, 9, 10, 11, 12, 13, 14, 15}};
uint32_t return_level(uint32_t n, uint32_t r, uint32_t cap) {
    const uint32_t d = n > r ? n - r : r - n;
    return std::min(d, cap);
}
constexpr uint8_t kReturnMap6[16][16] = {
    {0, 1, 2, 3, 4, 5, 3, 4, 4, 5, 5, 5, 5, 5, 5, 5}, {1, 0, 1, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3},
    {2, 1, 2, 4, 4, 4, 4, 4, 4, 4, 4, 3, 3, 3, 3, 3}, {3, 3, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {3, 3, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {4, 3, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4},
    {5, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 4, 4, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5}};

// ------------------------------------------------------------ GPS time
// The GPS time predictor (shared by GPSTIME11 v2 and POINT14 v3, which differ
// only in their symbol codes): four interleaved sequences, each with its last
// time and last 32-bit difference.
struct GpsTimeState {
    explicit GpsTimeState(bool layered) : v3(layered), multi(layered ? 515 : 516), zero_diff(layered ? 5 : 6), ic(32, 9) {}
    void reset(uint64_t first) {
        last = next = 0;
        diff.fill(0);
        extreme.fill(0);
        time = {first, 0, 0, 0};
    }
    // Decodes the next time into time[last]; v2 may signal "unchanged".
    [[gnu::always_inline]] void read(ArithDecoder& dec) {
        const uint32_t code_full = v3 ? 511 : 512;
        for (int guard = 0; guard < 8; ++guard) {
            if (diff[last] == 0) {
                const uint32_t m = dec.decode_symbol(zero_diff);
                const uint32_t d32 = v3 ? 0 : 1, full = v3 ? 1 : 2;
                if (!v3 && m == 0) return;  // unchanged
                if (m == d32) {
                    diff[last] = ic.decompress(dec, 0, 0);
                    time[last] += static_cast<uint64_t>(static_cast<int64_t>(diff[last]));
                    extreme[last] = 0;
                } else if (m == full) {
                    read_full(dec);
                } else {
                    last = (last + m - (v3 ? 1 : 2)) & 3;
                    continue;
                }
                return;
            }
            const uint32_t m = dec.decode_symbol(multi);
            if (m == 1) {
                time[last] += static_cast<uint64_t>(static_cast<int64_t>(ic.decompress(dec, diff[last], 1)));
                extreme[last] = 0;
            } else if (m < 511) {
                int32_t d;
                const uint32_t ld = static_cast<uint32_t>(diff[last]);
                if (m == 0) {
                    d = ic.decompress(dec, 0, 7);
                    bump(d);
                } else if (m < 500) {
                    d = ic.decompress(dec, static_cast<int32_t>(m * ld), m < 10 ? 2 : 3);
                } else if (m == 500) {
                    d = ic.decompress(dec, static_cast<int32_t>(500u * ld), 4);
                    bump(d);
                } else {
                    const int32_t mm = 500 - static_cast<int32_t>(m);  // -1 .. -10
                    if (mm > -10) {
                        d = ic.decompress(dec, static_cast<int32_t>(static_cast<uint32_t>(mm) * ld), 5);
                    } else {
                        d = ic.decompress(dec, static_cast<int32_t>(static_cast<uint32_t>(-10) * ld), 6);
                        bump(d);
                    }
                }
                time[last] += static_cast<uint64_t>(static_cast<int64_t>(d));
            } else if (!v3 && m == 511) {
                return;  // unchanged
            } else if (m == code_full) {
                read_full(dec);
            } else {
                last = (last + m - code_full) & 3;
                continue;
            }
            return;
        }
        throw Corrupt{"GPS time sequence switches without end"};
    }
    void bump(int32_t d) {
        if (++extreme[last] > 3) {
            diff[last] = d;
            extreme[last] = 0;
        }
    }
    void read_full(ArithDecoder& dec) {
        next = (next + 1) & 3;
        const int32_t high = ic.decompress(dec, static_cast<int32_t>(time[last] >> 32), 8);
        time[next] = (static_cast<uint64_t>(static_cast<uint32_t>(high)) << 32) | dec.read_int();
        last = next;
        diff[last] = 0;
        extreme[last] = 0;
    }
    bool v3;
    uint32_t last = 0, next = 0;
    std::array<uint64_t, 4> time{};
    std::array<int32_t, 4> diff{};
    std::array<int32_t, 4> extreme{};
    SymbolModel multi, zero_diff;
    IntegerDecompressor ic;
};

// RGB predictor shared by RGB12 v2 and RGB14/RGBNIR14 v3.
struct RgbModels {
    SymbolModel used{128};
    std::array<SymbolModel, 6> diff{SymbolModel(256), SymbolModel(256), SymbolModel(256),
                                    SymbolModel(256), SymbolModel(256), SymbolModel(256)};
    [[gnu::always_inline]] void read(ArithDecoder& dec, const uint16_t* last, uint16_t* out) {
        const uint32_t sym = dec.decode_symbol(used);
        auto lo = [](uint16_t v) { return static_cast<int32_t>(v & 0xFF); };
        auto hi = [](uint16_t v) { return static_cast<int32_t>(v >> 8); };
        int32_t r_lo = lo(last[0]), r_hi = hi(last[0]);
        if (sym & 1) r_lo = fold(static_cast<int32_t>(dec.decode_symbol(diff[0])) + lo(last[0]));
        if (sym & 2) r_hi = fold(static_cast<int32_t>(dec.decode_symbol(diff[1])) + hi(last[0]));
        out[0] = static_cast<uint16_t>(r_lo | (r_hi << 8));
        if (sym & (1 << 6)) {
            int32_t d = r_lo - lo(last[0]);
            int32_t g_lo = lo(last[1]), b_lo = lo(last[2]);
            if (sym & 4) g_lo = fold(static_cast<int32_t>(dec.decode_symbol(diff[2])) + clamp_u8(d + lo(last[1])));
            if (sym & 16) {
                const int32_t dd = (d + (g_lo - lo(last[1]))) / 2;
                b_lo = fold(static_cast<int32_t>(dec.decode_symbol(diff[4])) + clamp_u8(dd + lo(last[2])));
            }
            d = r_hi - hi(last[0]);
            int32_t g_hi = hi(last[1]), b_hi = hi(last[2]);
            if (sym & 8) g_hi = fold(static_cast<int32_t>(dec.decode_symbol(diff[3])) + clamp_u8(d + hi(last[1])));
            if (sym & 32) {
                const int32_t dd = (d + (g_hi - hi(last[1]))) / 2;
                b_hi = fold(static_cast<int32_t>(dec.decode_symbol(diff[5])) + clamp_u8(dd + hi(last[2])));
            }
            out[1] = static_cast<uint16_t>(g_lo | (g_hi << 8));
            out[2] = static_cast<uint16_t>(b_lo | (b_hi << 8));
        } else {
            out[1] = out[2] = out[0];
        }
    }
};

// ============================================================ pointwise v2
class ItemV2 {
public:
    virtual ~ItemV2() = default;
    virtual void read(ArithDecoder& dec, uint8_t* item) = 0;
};

class Point10V2 final : public ItemV2 {
public:
    explicit Point10V2(const uint8_t* first) {
        std::memcpy(last_, first, 20);
        last_[12] = last_[13] = 0;  // intensity predicted from zero
    }
    void read(ArithDecoder& dec, uint8_t* item) override { read_inline(dec, item); }
    [[gnu::always_inline]] void read_inline(ArithDecoder& dec, uint8_t* item) {
        const uint32_t changed = dec.decode_symbol(changed_values_);
        uint32_t r, n, m, l;
        if (changed) {
            if (changed & 32) last_[14] = static_cast<uint8_t>(dec.decode_symbol(bit_byte_[last_[14]].get(256)));
            r = last_[14] & 7;
            n = (last_[14] >> 3) & 7;
            m = kReturnMap[n][r];
            l = return_level(n, r, 7);
            if (changed & 16) {
                const auto v = static_cast<uint16_t>(ic_intensity_.decompress(dec, last_intensity_[m], m < 3 ? m : 3));
                last_intensity_[m] = v;
                bytes::store<uint16_t>(last_ + 12, v);
            } else {
                bytes::store<uint16_t>(last_ + 12, last_intensity_[m]);
            }
            if (changed & 8) last_[15] = static_cast<uint8_t>(dec.decode_symbol(classification_[last_[15]].get(256)));
            if (changed & 4) {
                const uint32_t sd = (last_[14] >> 6) & 1;
                last_[16] = fold(static_cast<int32_t>(dec.decode_symbol(scan_angle_[sd])) + last_[16]);
            }
            if (changed & 2) last_[17] = static_cast<uint8_t>(dec.decode_symbol(user_data_[last_[17]].get(256)));
            if (changed & 1)
                bytes::store<uint16_t>(last_ + 18, static_cast<uint16_t>(ic_point_source_.decompress(dec, bytes::get<uint16_t>(last_ + 18))));
        } else {
            r = last_[14] & 7;
            n = (last_[14] >> 3) & 7;
            m = kReturnMap[n][r];
            l = return_level(n, r, 7);
            bytes::store<uint16_t>(last_ + 12, last_intensity_[m]);
        }
        const int32_t dx = ic_dx_.decompress(dec, median_x_[m].get(), n == 1);
        bytes::store<uint32_t>(last_, bytes::get<uint32_t>(last_) + static_cast<uint32_t>(dx));
        median_x_[m].add(dx);
        uint32_t k = ic_dx_.k();
        const int32_t dy = ic_dy_.decompress(dec, median_y_[m].get(), (n == 1) + (k < 20 ? (k & ~1u) : 20));
        bytes::store<uint32_t>(last_ + 4, bytes::get<uint32_t>(last_ + 4) + static_cast<uint32_t>(dy));
        median_y_[m].add(dy);
        k = (ic_dx_.k() + ic_dy_.k()) / 2;
        const int32_t z = ic_z_.decompress(dec, last_height_[l], (n == 1) + (k < 18 ? (k & ~1u) : 18));
        bytes::store<int32_t>(last_ + 8, z);
        last_height_[l] = z;
        std::memcpy(item, last_, 20);
    }

private:
    uint8_t last_[20];
    std::array<uint16_t, 16> last_intensity_{};
    std::array<Median5, 16> median_x_{}, median_y_{};
    std::array<int32_t, 8> last_height_{};
    SymbolModel changed_values_{64};
    IntegerDecompressor ic_intensity_{16, 4};
    std::array<SymbolModel, 2> scan_angle_{SymbolModel(256), SymbolModel(256)};
    IntegerDecompressor ic_point_source_{16, 1};
    std::array<LazyModel, 256> bit_byte_, classification_, user_data_;
    IntegerDecompressor ic_dx_{32, 2}, ic_dy_{32, 22}, ic_z_{32, 20};
};

class GpsTime11V2 final : public ItemV2 {
public:
    explicit GpsTime11V2(const uint8_t* first) : state_(false) { state_.reset(bytes::get<uint64_t>(first)); }
    void read(ArithDecoder& dec, uint8_t* item) override { read_inline(dec, item); }
    [[gnu::always_inline]] void read_inline(ArithDecoder& dec, uint8_t* item) {
        state_.read(dec);
        bytes::store<uint64_t>(item, state_.time[state_.last]);
    }

private:
    GpsTimeState state_;
};

class Rgb12V2 final : public ItemV2 {
public:
    explicit Rgb12V2(const uint8_t* first) { std::memcpy(last_, first, 6); }
    void read(ArithDecoder& dec, uint8_t* item) override { read_inline(dec, item); }
    [[gnu::always_inline]] void read_inline(ArithDecoder& dec, uint8_t* item) {
        uint16_t out[3];
        models_.read(dec, last_, out);
        std::memcpy(last_, out, 6);
        std::memcpy(item, out, 6);
    }

private:
    uint16_t last_[3];
    RgbModels models_;
};

class ByteV2 final : public ItemV2 {
public:
    ByteV2(const uint8_t* first, std::size_t n) : last_(first, first + n) {
        for (std::size_t i = 0; i < n; ++i) models_.emplace_back(256);
    }
    void read(ArithDecoder& dec, uint8_t* item) override {
        for (std::size_t i = 0; i < last_.size(); ++i) {
            last_[i] = fold(static_cast<int32_t>(last_[i]) + static_cast<int32_t>(dec.decode_symbol(models_[i])));
            item[i] = last_[i];
        }
    }

private:
    std::vector<uint8_t> last_;
    std::vector<SymbolModel> models_;
};

// ------------------------------------------------------------ pointwise v1
// Item version 1 (LASzip 1.x, compressor 1 and early compressor 2 files):
// simpler predictors than version 2 over the same arithmetic coder and
// integer correctors.

// POINT10 v1: x and y predicted by the median of the last three differences,
// z by the last z; the other fields only when the "changed" symbol says so.
class Point10V1 final : public ItemV2 {
public:
    explicit Point10V1(const uint8_t* first) { std::memcpy(last_, first, 20); }
    void read(ArithDecoder& dec, uint8_t* item) override {
        const int32_t median_x = median3(last_x_diff_), median_y = median3(last_y_diff_);
        const int32_t x_diff = ic_dx_.decompress(dec, median_x);
        bytes::store<uint32_t>(last_, bytes::get<uint32_t>(last_) + static_cast<uint32_t>(x_diff));
        uint32_t k = ic_dx_.k();
        const int32_t y_diff = ic_dy_.decompress(dec, median_y, std::min<uint32_t>(k, 19));
        bytes::store<uint32_t>(last_ + 4, bytes::get<uint32_t>(last_ + 4) + static_cast<uint32_t>(y_diff));
        k = (k + ic_dy_.k()) / 2;
        bytes::store<int32_t>(last_ + 8, ic_z_.decompress(dec, bytes::get<int32_t>(last_ + 8), std::min<uint32_t>(k, 19)));
        if (const uint32_t changed = dec.decode_symbol(changed_values_)) {
            if (changed & 32)
                bytes::store<uint16_t>(last_ + 12, static_cast<uint16_t>(ic_intensity_.decompress(dec, bytes::get<uint16_t>(last_ + 12))));
            if (changed & 16) last_[14] = static_cast<uint8_t>(dec.decode_symbol(bit_byte_[last_[14]].get(256)));
            if (changed & 8) last_[15] = static_cast<uint8_t>(dec.decode_symbol(classification_[last_[15]].get(256)));
            if (changed & 4) last_[16] = static_cast<uint8_t>(ic_scan_angle_.decompress(dec, last_[16], k < 3 ? 1 : 0));
            if (changed & 2) last_[17] = static_cast<uint8_t>(dec.decode_symbol(user_data_[last_[17]].get(256)));
            if (changed & 1)
                bytes::store<uint16_t>(last_ + 18, static_cast<uint16_t>(ic_point_source_.decompress(dec, bytes::get<uint16_t>(last_ + 18))));
        }
        last_x_diff_[incr_] = x_diff;
        last_y_diff_[incr_] = y_diff;
        incr_ = incr_ == 2 ? 0 : incr_ + 1;
        std::memcpy(item, last_, 20);
    }

private:
    static int32_t median3(const std::array<int32_t, 3>& d) {
        if (d[0] < d[1]) return d[1] < d[2] ? d[1] : (d[0] < d[2] ? d[2] : d[0]);
        return d[0] < d[2] ? d[0] : (d[1] < d[2] ? d[2] : d[1]);
    }
    uint8_t last_[20];
    std::array<int32_t, 3> last_x_diff_{}, last_y_diff_{};
    uint32_t incr_ = 0;
    IntegerDecompressor ic_dx_{32, 1}, ic_dy_{32, 20}, ic_z_{32, 20};
    IntegerDecompressor ic_intensity_{16, 1}, ic_scan_angle_{8, 2}, ic_point_source_{16, 1};
    SymbolModel changed_values_{64};
    std::array<LazyModel, 256> bit_byte_, classification_, user_data_;
};

// GPSTIME11 v1: one sequence; the difference to the last time as a multiple
// of the last 32-bit difference, a new difference, a raw 64-bit time, or "same".
class GpsTime11V1 final : public ItemV2 {
public:
    explicit GpsTime11V1(const uint8_t* first) : time_(bytes::get<uint64_t>(first)) {}
    void read(ArithDecoder& dec, uint8_t* item) override {
        constexpr uint32_t kMulti = 512;
        if (diff_ == 0) {
            const uint32_t m = dec.decode_symbol(zero_diff_);
            if (m == 1) {
                diff_ = ic_.decompress(dec, 0, 0);
                time_ += static_cast<uint64_t>(static_cast<int64_t>(diff_));
            } else if (m == 2) {
                time_ = read_int64(dec);
            }
        } else {
            const uint32_t m = dec.decode_symbol(multi_);
            if (m < kMulti - 2) {
                int32_t d;
                const uint32_t ld = static_cast<uint32_t>(diff_);
                if (m == 1) {
                    d = ic_.decompress(dec, diff_, 1);
                    diff_ = d;
                    extreme_ = 0;
                } else if (m == 0) {
                    d = ic_.decompress(dec, diff_ / 4, 2);
                    if (++extreme_ > 3) {
                        diff_ = d;
                        extreme_ = 0;
                    }
                } else {
                    d = ic_.decompress(dec, static_cast<int32_t>(m * ld), m < 10 ? 3 : (m < 50 ? 4 : 5));
                    if (m == kMulti - 3 && ++extreme_ > 3) {
                        diff_ = d;
                        extreme_ = 0;
                    }
                }
                time_ += static_cast<uint64_t>(static_cast<int64_t>(d));
            } else if (m < kMulti - 1) {
                time_ = read_int64(dec);
            }
        }
        bytes::store<uint64_t>(item, time_);
    }

private:
    static uint64_t read_int64(ArithDecoder& dec) {
        const uint64_t low = dec.read_int();
        return (static_cast<uint64_t>(dec.read_int()) << 32) | low;
    }
    uint64_t time_;
    int32_t diff_ = 0;
    uint32_t extreme_ = 0;
    SymbolModel multi_{512}, zero_diff_{3};
    IntegerDecompressor ic_{32, 6};
};

// RGB12 v1: which of the six colour bytes changed, then each changed byte
// as an 8-bit correction of the last one (contexts 0..5).
class Rgb12V1 final : public ItemV2 {
public:
    explicit Rgb12V1(const uint8_t* first) { std::memcpy(last_, first, 6); }
    void read(ArithDecoder& dec, uint8_t* item) override {
        const uint32_t sym = dec.decode_symbol(byte_used_);
        uint16_t out[3];
        for (uint32_t c = 0; c < 3; ++c) {
            const uint32_t lo = (sym >> (2 * c)) & 1 ? static_cast<uint32_t>(ic_.decompress(dec, last_[c] & 0xFF, 2 * c)) : (last_[c] & 0xFFu);
            const uint32_t hi = (sym >> (2 * c + 1)) & 1 ? static_cast<uint32_t>(ic_.decompress(dec, last_[c] >> 8, 2 * c + 1)) << 8
                                                         : (last_[c] & 0xFF00u);
            out[c] = static_cast<uint16_t>(lo | hi);
        }
        std::memcpy(last_, out, 6);
        std::memcpy(item, out, 6);
    }

private:
    uint16_t last_[3];
    SymbolModel byte_used_{64};
    IntegerDecompressor ic_{8, 6};
};

// BYTE v1 (extra bytes): each byte an 8-bit correction of the last, context = its index.
class ByteV1 final : public ItemV2 {
public:
    ByteV1(const uint8_t* first, std::size_t n) : last_(first, first + n), ic_(8, static_cast<uint32_t>(n)) {}
    void read(ArithDecoder& dec, uint8_t* item) override {
        for (std::size_t i = 0; i < last_.size(); ++i) {
            last_[i] = static_cast<uint8_t>(ic_.decompress(dec, last_[i], static_cast<uint32_t>(i)));
            item[i] = last_[i];
        }
    }

private:
    std::vector<uint8_t> last_;
    IntegerDecompressor ic_;
};

// The wave packet descriptor coder shared by WAVEPACKET13 v1 (point formats
// 4 and 5) and WAVEPACKET14 v3/v4 (formats 9 and 10, one set per scanner
// channel). An item is 29 bytes: the descriptor index (a byte, coded as a
// symbol), the 64-bit offset to the waveform data, coded as "same",
// "previous offset + previous packet size", "previous + a 32-bit difference"
// or raw; then the packet size, return point location and x(t), y(t), z(t)
// (the floats' bit patterns) as integer differences from the previous item.
struct WavePacketCoder {
    // Decodes one item predicted from `last` (29 bytes) into `item` (29 bytes).
    void read(ArithDecoder& dec, const uint8_t* last, uint8_t* item) {
        item[0] = static_cast<uint8_t>(dec.decode_symbol(packet_index));
        const uint8_t* prev = last + 1;
        uint8_t* cur = item + 1;
        const uint64_t last_offset = bytes::get<uint64_t>(prev);
        const uint32_t last_size = bytes::get<uint32_t>(prev + 8);
        sym_last_offset_diff = dec.decode_symbol(offset_diff[sym_last_offset_diff]);
        uint64_t offset;
        if (sym_last_offset_diff == 0) {
            offset = last_offset;
        } else if (sym_last_offset_diff == 1) {
            offset = last_offset + last_size;
        } else if (sym_last_offset_diff == 2) {
            last_diff_32 = ic_offset_diff.decompress(dec, last_diff_32);
            offset = last_offset + static_cast<uint64_t>(static_cast<int64_t>(last_diff_32));
        } else {
            const uint64_t low = dec.read_int();
            offset = (static_cast<uint64_t>(dec.read_int()) << 32) | low;
        }
        bytes::store<uint64_t>(cur, offset);
        bytes::store<uint32_t>(cur + 8, static_cast<uint32_t>(ic_packet_size.decompress(dec, bytes::get<int32_t>(prev + 8))));
        bytes::store<int32_t>(cur + 12, ic_return_point.decompress(dec, bytes::get<int32_t>(prev + 12)));
        for (uint32_t c = 0; c < 3; ++c)
            bytes::store<int32_t>(cur + 16 + 4 * c, ic_xyz.decompress(dec, bytes::get<int32_t>(prev + 16 + 4 * c), c));
    }
    int32_t last_diff_32 = 0;
    uint32_t sym_last_offset_diff = 0;
    SymbolModel packet_index{256};
    std::array<SymbolModel, 4> offset_diff{SymbolModel(4), SymbolModel(4), SymbolModel(4), SymbolModel(4)};
    IntegerDecompressor ic_offset_diff{32, 1}, ic_packet_size{32, 1}, ic_return_point{32, 1}, ic_xyz{32, 3};
};

// WAVEPACKET13 v1 (point formats 4 and 5, 29 bytes; pointwise).
class WavePacket13V1 final : public ItemV2 {
public:
    explicit WavePacket13V1(const uint8_t* first) { std::memcpy(last_, first, 29); }
    void read(ArithDecoder& dec, uint8_t* item) override {
        coder_.read(dec, last_, item);
        std::memcpy(last_, item, 29);
    }

private:
    uint8_t last_[29];
    WavePacketCoder coder_;
};

// POINT10 [+ GPSTIME11] [+ RGB12], in that order, nothing else.
template <bool Gps, bool Rgb>
void decode_fused(ArithDecoder& dec, const std::vector<std::unique_ptr<ItemV2>>& items, uint8_t* out, int rl, uint64_t count) {
    auto& point = static_cast<Point10V2&>(*items[0]);
    GpsTime11V2* gps = Gps ? static_cast<GpsTime11V2*>(items[1].get()) : nullptr;
    Rgb12V2* rgb = Rgb ? static_cast<Rgb12V2*>(items[Gps ? 2 : 1].get()) : nullptr;
    // A local copy of the decoder, its address never taken: its state stays
    // in registers through the record stores (which may alias anything).
    ArithDecoder d = dec;
    for (uint64_t i = 1; i < count; ++i) {
        uint8_t* rec = out + i * static_cast<std::size_t>(rl);
        point.read_inline(d, rec);
        if constexpr (Gps) gps->read_inline(d, rec + 20);
        if constexpr (Rgb) rgb->read_inline(d, rec + (Gps ? 28 : 20));
    }
    dec = d;
}

std::size_t decode_pointwise(const LazInfo& info, int rl, const uint8_t* data, std::size_t size, uint64_t count, char* out_chars) {
    if (count == 0) return 0;
    if (size < static_cast<std::size_t>(rl)) throw Corrupt{"truncated chunk (shorter than one raw point)"};
    auto* out = reinterpret_cast<uint8_t*>(out_chars);
    std::memcpy(out, data, rl);
    std::vector<std::unique_ptr<ItemV2>> items;
    std::vector<std::size_t> offsets;
    std::size_t off = 0;
    for (const LazItem& it : info.items) {
        const uint8_t* first = out + off;
        const bool v1 = it.version == 1;
        switch (it.type) {
            case 6: items.push_back(v1 ? std::unique_ptr<ItemV2>(std::make_unique<Point10V1>(first)) : std::make_unique<Point10V2>(first)); break;
            case 7: items.push_back(v1 ? std::unique_ptr<ItemV2>(std::make_unique<GpsTime11V1>(first)) : std::make_unique<GpsTime11V2>(first)); break;
            case 8: items.push_back(v1 ? std::unique_ptr<ItemV2>(std::make_unique<Rgb12V1>(first)) : std::make_unique<Rgb12V2>(first)); break;
            case 9: items.push_back(std::make_unique<WavePacket13V1>(first)); break;
            default: items.push_back(v1 ? std::unique_ptr<ItemV2>(std::make_unique<ByteV1>(first, it.size)) : std::make_unique<ByteV2>(first, it.size)); break;
        }
        offsets.push_back(off);
        off += it.size;
    }
    ArithDecoder dec;
    dec.init(data + rl, size - rl);
    // The layouts of point formats 0-3 without extra bytes (nearly all
    // pointwise files) get a loop with the item calls resolved at compile
    // time; anything else goes through the item list.
    const auto type = [&](std::size_t k) {
        return k < info.items.size() && info.items[k].version == 2 ? info.items[k].type : 0xFFFF;  // the fused loops are v2 only
    };
    const std::size_t n_items = info.items.size();
    if (n_items == 1 && type(0) == 6)
        decode_fused<false, false>(dec, items, out, rl, count);
    else if (n_items == 2 && type(0) == 6 && type(1) == 7)
        decode_fused<true, false>(dec, items, out, rl, count);
    else if (n_items == 2 && type(0) == 6 && type(1) == 8)
        decode_fused<false, true>(dec, items, out, rl, count);
    else if (n_items == 3 && type(0) == 6 && type(1) == 7 && type(2) == 8)
        decode_fused<true, true>(dec, items, out, rl, count);
    else
        for (uint64_t i = 1; i < count; ++i) {
            uint8_t* rec = out + i * rl;
            for (std::size_t k = 0; k < items.size(); ++k) items[k]->read(dec, rec + offsets[k]);
        }
    return rl + dec.pos();
}

// ============================================================ layered v3 / v4
// Item version 4 is version 3 with the two channel-context rules fixed (the
// channel is always handed on; a switch always predicts from the new channel).
// One arithmetic-coded layer of a chunk.
struct Layer {
    ArithDecoder dec;
    bool present = false;  // non-empty: the field changes within the chunk
    void open(const uint8_t* p, std::size_t n) {
        present = n > 0;
        if (present) dec.init(p, n);
    }
};

// Point record of formats 6-10 (first 30 bytes), unpacked.
struct Point14 {
    int32_t x = 0, y = 0, z = 0;
    uint16_t intensity = 0;
    uint32_t return_number = 0, number_of_returns = 0;
    uint32_t class_flags = 0, channel = 0, scan_dir = 0, edge = 0;
    uint32_t classification = 0, user_data = 0;
    int16_t scan_angle = 0;
    uint16_t point_source = 0;
    uint64_t gps_time = 0;
    bool gps_time_change = false;

    static Point14 unpack(const uint8_t* p) {
        Point14 q;
        q.x = bytes::get<int32_t>(p), q.y = bytes::get<int32_t>(p + 4), q.z = bytes::get<int32_t>(p + 8);
        q.intensity = bytes::get<uint16_t>(p + 12);
        q.return_number = p[14] & 15, q.number_of_returns = p[14] >> 4;
        q.class_flags = p[15] & 15, q.channel = (p[15] >> 4) & 3, q.scan_dir = (p[15] >> 6) & 1, q.edge = p[15] >> 7;
        q.classification = p[16], q.user_data = p[17];
        q.scan_angle = bytes::get<int16_t>(p + 18);
        q.point_source = bytes::get<uint16_t>(p + 20);
        q.gps_time = bytes::get<uint64_t>(p + 22);
        return q;
    }
    void pack(uint8_t* p) const {
        bytes::store<int32_t>(p, x), bytes::store<int32_t>(p + 4, y), bytes::store<int32_t>(p + 8, z);
        bytes::store<uint16_t>(p + 12, intensity);
        p[14] = static_cast<uint8_t>(return_number | (number_of_returns << 4));
        p[15] = static_cast<uint8_t>(class_flags | (channel << 4) | (scan_dir << 6) | (edge << 7));
        p[16] = static_cast<uint8_t>(classification);
        p[17] = static_cast<uint8_t>(user_data);
        bytes::store<int16_t>(p + 18, scan_angle);
        bytes::store<uint16_t>(p + 20, point_source);
        bytes::store<uint64_t>(p + 22, gps_time);
    }
};

struct Point14Context {
    Point14 last;
    std::array<uint16_t, 8> last_intensity{};
    std::array<Median5, 12> median_x{}, median_y{};
    std::array<int32_t, 8> last_z{};
    std::array<SymbolModel, 8> changed_values{SymbolModel(128), SymbolModel(128), SymbolModel(128), SymbolModel(128),
                                              SymbolModel(128), SymbolModel(128), SymbolModel(128), SymbolModel(128)};
    SymbolModel scanner_channel{3};
    std::array<LazyModel, 16> number_of_returns, return_number;
    SymbolModel return_number_gps_same{13};
    IntegerDecompressor ic_dx{32, 2}, ic_dy{32, 22}, ic_z{32, 20};
    std::array<LazyModel, 64> classification, flags, user_data;
    IntegerDecompressor ic_intensity{16, 4}, ic_scan_angle{16, 2}, ic_point_source{16, 1};
    GpsTimeState gps{true};

    explicit Point14Context(const Point14& seed) {
        last = seed;
        last.gps_time_change = false;
        last_z.fill(seed.z);
        last_intensity.fill(seed.intensity);
        gps.reset(seed.gps_time);
    }
};

class Point14V3 {
public:
    static constexpr int kLayers = 9;  // xy+returns, z, class, flags, intensity, scan angle, user data, source, gps
    Point14V3(const uint8_t* first, std::array<Layer, kLayers>& layers, bool v4) : layers_(layers), v4_(v4) {
        const Point14 p = Point14::unpack(first);
        current_ = p.channel;
        item_context_ = current_;
        contexts_[current_] = std::make_unique<Point14Context>(p);
    }
    /// The context the other items of this point use: the scanner channel on
    /// the first point and on points where it changes, 0 otherwise (LASzip v3
    /// and laz-perf pass it only on change; the format depends on that).
    uint32_t context() const { return v4_ ? current_ : item_context_; }  // v4 always passes the channel
    /// What the other layers of a point need of its XY layer (see decode_layered's split).
    struct Side {
        uint8_t changed, channel, nr, k;
    };
    /// The item context of a point from its Side (as context()).
    uint32_t context(const Side& s) const { return v4_ || (s.changed & (1 << 6)) ? s.channel : 0u; }
    enum Mode {
        kAll,  // every present layer; the whole record
        kXY,   // the XY layer only: x and y written, the point's Side recorded
    };
    /// Layers 1-8 as bits 1 << layer (see rest_loop).
    static constexpr uint32_t kRestLayers = 0x1FE;
    void read(uint8_t* item) { read_mode<kAll>(item, nullptr); }
    template <Mode M>
    [[gnu::always_inline]] void read_mode(uint8_t* item, Side* side) {
        // A local copy of the XY layer's decoder (registers, see decode_fused).
        ArithDecoder xy = layers_[0].dec;
        read_mode<M>(xy, item, side);
        layers_[0].dec = xy;
    }
    /// The XY layer (kXY) over points 1..count-1 of a chunk, its decoder in
    /// a local throughout.
    void xy_loop(uint8_t* out, std::size_t rl, Side* side, uint64_t count) {
        ArithDecoder xy = layers_[0].dec;
        for (uint64_t i = 1; i < count; ++i) read_mode<kXY>(xy, out + i * rl, side + i);
        layers_[0].dec = xy;
    }
    template <Mode M>
    [[gnu::always_inline]] void read_mode(ArithDecoder& xy, uint8_t* item, Side* side) {
        uint32_t n, r, k;
        Point14Context* c;
        read_xy(xy, c, n, r, k);
        if constexpr (M == kXY) {
            *side = {static_cast<uint8_t>(changed_), static_cast<uint8_t>(current_), static_cast<uint8_t>(n | (r << 4)),
                     static_cast<uint8_t>(k)};
            bytes::store<int32_t>(item, c->last.x);
            bytes::store<int32_t>(item + 4, c->last.y);
            c->last.gps_time_change = (changed_ & (1 << 4)) != 0;
            return;
        }
        rest<kRestLayers>(c, n, r, k, item, false, [this](int L) -> ArithDecoder& { return layers_[L].dec; });
    }
    /// The layers of `Layers` (a subset of kRestLayers) over points
    /// 1..count-1 of a chunk (records at base + i * rl), the XY layer's part
    /// replayed from each point's Side; only those layers' record bytes are
    /// written. The group's decoders are held in locals (registers) throughout.
    template <uint32_t Layers>
    void rest_loop(uint8_t* base, std::size_t rl, const Side* side, uint64_t count) {
        std::array<ArithDecoder, kLayers> d;
        for (int L = 1; L < kLayers; ++L)
            if ((Layers >> L) & 1u) d[L] = layers_[L].dec;
        for (uint64_t i = 1; i < count; ++i) {
            uint32_t n, r, k;
            Point14Context* c;
            replay(side[i], c, n, r, k);
            rest<Layers>(c, n, r, k, base + i * rl, true, [&d](int L) -> ArithDecoder& { return d[L]; });
        }
        for (int L = 1; L < kLayers; ++L)
            if ((Layers >> L) & 1u) layers_[L].dec = d[L];
    }

private:
    // The XY layer's part of a point from its Side: the scanner channel
    // switch (a new channel's context seeded as by read_xy), n, r, k.
    [[gnu::always_inline]] void replay(const Side& sd, Point14Context*& c, uint32_t& n, uint32_t& r, uint32_t& k) {
        item_context_ = 0;
        c = contexts_[current_].get();
        if (sd.changed & (1 << 6)) {
            const uint32_t channel = sd.channel;
            if (!contexts_[channel]) contexts_[channel] = std::make_unique<Point14Context>(c->last);
            current_ = channel;
            item_context_ = channel;
            c = contexts_[current_].get();
            c->last.channel = channel;
        }
        changed_ = sd.changed;
        n = sd.nr & 15u;
        r = sd.nr >> 4;
        k = sd.k;
        c->last.number_of_returns = n;
        c->last.return_number = r;
    }
    // The XY layer of a point: changed flags, scanner channel, returns, x, y;
    // n, r and the z context's k for the other layers.
    [[gnu::always_inline]] void read_xy(ArithDecoder& xy, Point14Context*& c_out, uint32_t& n_out, uint32_t& r_out, uint32_t& k_out) {
        item_context_ = 0;
        Point14Context* c = contexts_[current_].get();
        {
            const Point14& l = c->last;
            const uint32_t lpr = (l.return_number == 1 ? 1u : 0u) + (l.return_number >= l.number_of_returns ? 2u : 0u) +
                                 (l.gps_time_change ? 4u : 0u);
            const uint32_t changed = xy.decode_symbol(c->changed_values[lpr]);
            changed_ = changed;
            if (changed & (1 << 6)) {
                const uint32_t diff = xy.decode_symbol(c->scanner_channel);
                const uint32_t channel = (current_ + diff + 1) % 4;
                if (!contexts_[channel]) contexts_[channel] = std::make_unique<Point14Context>(c->last);
                current_ = channel;
                item_context_ = channel;
                c = contexts_[current_].get();
                c->last.channel = channel;
            }
        }
        Point14& last = c->last;
        const uint32_t changed = changed_;
        const bool gps_change = changed & (1 << 4);
        const uint32_t last_n = last.number_of_returns, last_r = last.return_number;
        uint32_t n = last_n;
        if (changed & (1 << 2)) {
            n = xy.decode_symbol(c->number_of_returns[last_n].get(16));
            last.number_of_returns = n;
        }
        uint32_t r;
        switch (changed & 3) {
            case 0: r = last_r; break;
            case 1: r = (last_r + 1) % 16; break;
            case 2: r = (last_r + 15) % 16; break;
            default:
                if (gps_change) r = xy.decode_symbol(c->return_number[last_r].get(16));
                else r = (last_r + xy.decode_symbol(c->return_number_gps_same) + 2) % 16;
                break;
        }
        last.return_number = r;
        const uint32_t m = kReturnMap6[n][r];
        const uint32_t mi = (m << 1) | (gps_change ? 1u : 0u);
        const int32_t dx = c->ic_dx.decompress(xy, c->median_x[mi].get(), n == 1);
        last.x = static_cast<int32_t>(static_cast<uint32_t>(last.x) + static_cast<uint32_t>(dx));
        c->median_x[mi].add(dx);
        const uint32_t kx = c->ic_dx.k();
        const int32_t dy = c->ic_dy.decompress(xy, c->median_y[mi].get(), (n == 1) + (kx < 20 ? (kx & ~1u) : 20));
        last.y = static_cast<int32_t>(static_cast<uint32_t>(last.y) + static_cast<uint32_t>(dy));
        c->median_y[mi].add(dy);
        c_out = c;
        n_out = n;
        r_out = r;
        k_out = (c->ic_dx.k() + c->ic_dy.k()) / 2;
    }
    // Layers 1-8 of a point (those present and in Layers), then the record:
    // all of it, or with `rest_only` the bytes of those layers (the flags
    // layer also writes the returns and the scanner channel).
    template <uint32_t Layers, typename Dec>
    [[gnu::always_inline]] void rest(Point14Context* c, uint32_t n, uint32_t r, uint32_t k, uint8_t* item, bool rest_only, Dec&& dec) {
        Point14& last = c->last;
        const uint32_t changed = changed_;
        const bool source_change = changed & (1 << 5);
        const bool gps_change = changed & (1 << 4);
        const bool angle_change = changed & (1 << 3);
        const uint32_t l = return_level(n, r, 7);
        const uint32_t cpr = (r == 1 ? 2u : 0u) + (r >= n ? 1u : 0u);
        if ((Layers & (1u << 1)) && layers_[1].present) {
            last.z = c->ic_z.decompress(dec(1), c->last_z[l], (n == 1) + (k < 18 ? (k & ~1u) : 18));
            c->last_z[l] = last.z;
        }
        if ((Layers & (1u << 2)) && layers_[2].present) {
            const uint32_t ccc = ((last.classification & 0x1F) << 1) + (cpr == 3 ? 1u : 0u);
            last.classification = dec(2).decode_symbol(c->classification[ccc].get(256));
        }
        if ((Layers & (1u << 3)) && layers_[3].present) {
            const uint32_t lf = (last.edge << 5) | (last.scan_dir << 4) | last.class_flags;
            const uint32_t f = dec(3).decode_symbol(c->flags[lf].get(64));
            last.edge = (f >> 5) & 1;
            last.scan_dir = (f >> 4) & 1;
            last.class_flags = f & 15;
        }
        if ((Layers & (1u << 4)) && layers_[4].present) {
            const uint32_t ii = (cpr << 1) | (gps_change ? 1u : 0u);
            const auto v = static_cast<uint16_t>(c->ic_intensity.decompress(dec(4), c->last_intensity[ii], cpr));
            c->last_intensity[ii] = v;
            last.intensity = v;
        }
        if ((Layers & (1u << 5)) && layers_[5].present && angle_change)
            last.scan_angle = static_cast<int16_t>(c->ic_scan_angle.decompress(dec(5), last.scan_angle, gps_change ? 1 : 0));
        if ((Layers & (1u << 6)) && layers_[6].present) last.user_data = dec(6).decode_symbol(c->user_data[last.user_data / 4].get(256));
        if ((Layers & (1u << 7)) && layers_[7].present && source_change)
            last.point_source = static_cast<uint16_t>(c->ic_point_source.decompress(dec(7), last.point_source));
        if ((Layers & (1u << 8)) && layers_[8].present && gps_change) {
            c->gps.read(dec(8));
            last.gps_time = c->gps.time[c->gps.last];
        }
        if (!rest_only) {
            last.pack(item);
        } else {
            // The group's own fields (as Point14::pack).
            if (Layers & (1u << 1)) bytes::store<int32_t>(item + 8, last.z);
            if (Layers & (1u << 4)) bytes::store<uint16_t>(item + 12, last.intensity);
            if (Layers & (1u << 3)) {  // returns, flags, channel
                item[14] = static_cast<uint8_t>(last.return_number | (last.number_of_returns << 4));
                item[15] = static_cast<uint8_t>(last.class_flags | (last.channel << 4) | (last.scan_dir << 6) | (last.edge << 7));
            }
            if (Layers & (1u << 2)) item[16] = static_cast<uint8_t>(last.classification);
            if (Layers & (1u << 6)) item[17] = static_cast<uint8_t>(last.user_data);
            if (Layers & (1u << 5)) bytes::store<int16_t>(item + 18, last.scan_angle);
            if (Layers & (1u << 7)) bytes::store<uint16_t>(item + 20, last.point_source);
            if (Layers & (1u << 8)) bytes::store<uint64_t>(item + 22, last.gps_time);
        }
        last.gps_time_change = gps_change;
    }

    std::array<Layer, kLayers>& layers_;
    bool v4_;
    std::array<std::unique_ptr<Point14Context>, 4> contexts_;
    uint32_t current_ = 0;
    uint32_t item_context_ = 0;
    uint32_t changed_ = 0;
};

// RGB14 / RGBNIR14 v3: per scanner channel contexts, RGB and NIR layers.
// The per-scanner-channel contexts of the layered items after POINT14
// (RGB14, RGBNIR14, WAVEPACKET14, BYTE14): up to four, each created on its
// channel's first point from the then-current context's last values. As in
// LASzip v3 (and laz-perf): on a switch to a channel seen before in this
// chunk, the models are the new channel's but the prediction (and its
// update) still uses the previous channel's last values; v4 fixed that.
// Part of the format.
template <typename Ctx>
class ChannelContexts {
public:
    ChannelContexts(uint32_t context, bool v4, std::unique_ptr<Ctx> first) : v4_(v4), current_(context) {
        slots_[context] = std::move(first);
    }
    // Switches to `context`; returns the context whose models decode this
    // point and sets `last` to the one whose last values predict it (and take
    // its values). `make(prev)` creates a channel's context from `prev`.
    template <typename Make>
    Ctx& select(uint32_t context, Ctx*& last, Make&& make) {
        last = slots_[current_].get();
        if (context != current_) {
            current_ = context;
            if (!slots_[context]) {
                slots_[context] = make(*last);
                last = slots_[context].get();
            } else if (v4_) {
                last = slots_[context].get();
            }
        }
        return *slots_[current_];
    }

private:
    bool v4_;
    uint32_t current_;
    std::array<std::unique_ptr<Ctx>, 4> slots_;
};

class Rgb14V3 {
public:
    Rgb14V3(const uint8_t* first, bool nir, uint32_t context, Layer& rgb, Layer* nir_layer, bool v4)
        : nir_(nir), rgb_(rgb), nir_layer_(nir_layer), contexts_(context, v4, std::make_unique<Ctx>(first, nir ? 8 : 6)) {}
    void read(uint8_t* item, uint32_t context) { read_with(rgb_.dec, nir_layer_ ? nir_layer_->dec : rgb_.dec, item, context); }
    /// Points 1..count-1 of a chunk (records at base + i * rl, item contexts
    /// context_of(i)), the decoders in locals throughout.
    template <typename ContextOf>
    void read_loop(uint8_t* base, std::size_t rl, uint64_t count, ContextOf&& context_of) {
        ArithDecoder rgb = rgb_.dec, nir = nir_layer_ ? nir_layer_->dec : ArithDecoder{};
        for (uint64_t i = 1; i < count; ++i) read_with(rgb, nir, base + i * rl, context_of(i));
        rgb_.dec = rgb;
        if (nir_layer_) nir_layer_->dec = nir;
    }

private:
    [[gnu::always_inline]] void read_with(ArithDecoder& rgb_dec, ArithDecoder& nir_dec, uint8_t* item, uint32_t context) {
        Ctx* prev = nullptr;
        Ctx& c = contexts_.select(context, prev, [](const Ctx& p) { return std::make_unique<Ctx>(reinterpret_cast<const uint8_t*>(p.last), 8); });
        uint16_t* last = prev->last;
        uint16_t out[4];
        if (rgb_.present) {
            c.rgb.read(rgb_dec, last, out);
            std::memcpy(last, out, 6);
        }
        std::memcpy(item, last, 6);
        if (nir_) {
            if (nir_layer_->present) {
                ArithDecoder& d = nir_dec;
                const uint32_t sym = d.decode_symbol(c.nir_used);
                int32_t lo = last[3] & 0xFF, hi = last[3] >> 8;
                if (sym & 1) lo = fold(static_cast<int32_t>(d.decode_symbol(c.nir_diff[0])) + lo);
                if (sym & 2) hi = fold(static_cast<int32_t>(d.decode_symbol(c.nir_diff[1])) + hi);
                last[3] = static_cast<uint16_t>(lo | (hi << 8));
            }
            std::memcpy(item + 6, &last[3], 2);
        }
    }

private:
    struct Ctx {
        Ctx(const uint8_t* seed, std::size_t n) { std::memcpy(last, seed, n); }
        uint16_t last[4] = {0, 0, 0, 0};
        RgbModels rgb;
        SymbolModel nir_used{4};
        std::array<SymbolModel, 2> nir_diff{SymbolModel(256), SymbolModel(256)};
    };
    bool nir_;
    Layer& rgb_;
    Layer* nir_layer_;
    ChannelContexts<Ctx> contexts_;
};

// BYTE14 v3: one layer per extra byte.
class Byte14V3 {
public:
    Byte14V3(const uint8_t* first, std::size_t n, uint32_t context, Layer* layers, bool v4)
        : n_(n), layers_(layers), contexts_(context, v4, std::make_unique<Ctx>(first, n)) {}
    void read(uint8_t* item, uint32_t context) {
        Ctx* prev = nullptr;
        Ctx& c = contexts_.select(context, prev, [this](const Ctx& p) { return std::make_unique<Ctx>(p.last.data(), n_); });
        uint8_t* last = prev->last.data();
        for (std::size_t i = 0; i < n_; ++i) {
            if (layers_[i].present)
                last[i] = fold(static_cast<int32_t>(last[i]) + static_cast<int32_t>(layers_[i].dec.decode_symbol(c.models[i])));
            item[i] = last[i];
        }
    }

private:
    struct Ctx {
        Ctx(const uint8_t* seed, std::size_t n) : last(seed, seed + n) {
            for (std::size_t i = 0; i < n; ++i) models.emplace_back(256);
        }
        std::vector<uint8_t> last;
        std::vector<SymbolModel> models;
    };
    std::size_t n_;
    Layer* layers_;
    ChannelContexts<Ctx> contexts_;
};

// WAVEPACKET14 v3/v4 (point formats 9 and 10): the WAVEPACKET13 coder with
// one set of models and last item per scanner channel, in a layer of its own
// (an empty layer: every point keeps the chunk's first descriptor); a new
// channel starts from the previous channel's last item with fresh models and
// counters.
class WavePacket14V3 {
public:
    WavePacket14V3(const uint8_t* first, uint32_t context, Layer& layer, bool v4)
        : layer_(layer), contexts_(context, v4, std::make_unique<Ctx>(first)) {}
    void read(uint8_t* item, uint32_t context) {
        Ctx* prev = nullptr;
        Ctx& c = contexts_.select(context, prev, [](const Ctx& p) { return std::make_unique<Ctx>(p.last); });
        uint8_t* last = prev->last;
        if (layer_.present) {
            c.coder.read(layer_.dec, last, item);
            std::memcpy(last, item, 29);
        } else {
            std::memcpy(item, last, 29);
        }
    }

private:
    struct Ctx {
        explicit Ctx(const uint8_t* seed) { std::memcpy(last, seed, 29); }
        uint8_t last[29];
        WavePacketCoder coder;
    };
    Layer& layer_;
    ChannelContexts<Ctx> contexts_;
};

// Layers of a layered item: POINT14 9, RGB14 1, RGBNIR14 2, WAVEPACKET14 1, BYTE14 one per byte.
std::size_t layer_count(const LazItem& it) {
    return it.type == 10 ? 9 : it.type == 11 || it.type == 13 ? 1 : it.type == 12 ? 2 : it.size;
}

// layers: 0 every layer, 1 the PointCloud fields, 2 the XY layer only.
// `split` (layers 0 and 1): the XY layer first, then the other layers as
// parallel tasks (see below); the same bytes.
std::size_t decode_layered(const LazInfo& info, int rl, const uint8_t* data, std::size_t size, uint64_t count, char* out_chars,
                           int layers_wanted, bool split = false) {
    const bool point_fields_only = layers_wanted == 1, xy_only = layers_wanted == 2;
    if (count == 0) return 0;
    auto* out = reinterpret_cast<uint8_t*>(out_chars);
    std::size_t pos = 0;
    auto need = [&](std::size_t n, const char* what) {
        if (n > size - pos) throw Corrupt{what};
    };
    need(rl, "truncated chunk (shorter than one raw point)");
    std::memcpy(out, data, rl);
    pos += rl;
    need(4, "truncated chunk (no point count)");
    const uint32_t stored_count = bytes::get<uint32_t>(data + pos);
    pos += 4;
    if (stored_count != count) throw Corrupt{"chunk point count disagrees with the chunk table"};
    // Layer sizes, in item order.
    std::size_t n_layers = 0;
    for (const LazItem& it : info.items) n_layers += layer_count(it);
    need(4 * n_layers, "truncated chunk (layer sizes)");
    std::vector<uint32_t> sizes(n_layers);
    for (std::size_t i = 0; i < n_layers; ++i, pos += 4) sizes[i] = bytes::get<uint32_t>(data + pos);
    std::vector<Layer> layers(n_layers);
    std::array<Layer, Point14V3::kLayers> point_layers;
    std::size_t li = 0;
    std::vector<Layer*> item_layers;  // first layer of each item
    for (const LazItem& it : info.items) {
        const std::size_t nl = layer_count(it);
        for (std::size_t j = 0; j < nl; ++j, ++li) {
            need(sizes[li], "truncated chunk (layer runs past the chunk)");
            Layer& layer = it.type == 10 ? point_layers[j] : layers[li];
            // Selective decoding: flags, scan angle, user data, point source, NIR
            // and extra bytes are not needed for a PointCloud; their layers are
            // independent of the others and are skipped (fields keep the chunk's
            // first value).
            const bool skip = (point_fields_only && ((it.type == 10 && (j == 3 || j == 5 || j == 6 || j == 7)) ||
                                                     (it.type == 12 && j == 1) || it.type == 13 || it.type == 14)) ||
                              (xy_only && (it.type != 10 || j != 0));
            layer.open(data + pos, skip ? 0 : sizes[li]);
            pos += sizes[li];
        }
        item_layers.push_back(it.type == 10 ? point_layers.data() : &layers[li - nl]);
    }
    // Point14 must be first (checked on open); it hands its scanner channel to the others.
    const bool v4 = info.items[0].version == 4;  // all items share one version (checked on open)
    Point14V3 point(out, point_layers, v4);
    std::vector<std::unique_ptr<Rgb14V3>> rgbs;
    std::vector<std::unique_ptr<Byte14V3>> bytes;
    std::vector<std::unique_ptr<WavePacket14V3>> waves;
    struct Slot {
        int kind;  // 0 point, 1 rgb, 2 byte, 3 wave packet
        std::size_t index, offset;
    };
    std::vector<Slot> slots;
    std::size_t off = 0;
    for (std::size_t i = 0; i < info.items.size(); ++i) {
        const LazItem& it = info.items[i];
        if (it.type == 10) {
            slots.push_back({0, 0, off});
        } else if (it.type == 11 || it.type == 12) {
            rgbs.push_back(std::make_unique<Rgb14V3>(out + off, it.type == 12, point.context(), item_layers[i][0],
                                                     it.type == 12 ? &item_layers[i][1] : nullptr, v4));
            slots.push_back({1, rgbs.size() - 1, off});
        } else if (it.type == 13) {
            waves.push_back(std::make_unique<WavePacket14V3>(out + off, point.context(), item_layers[i][0], v4));
            slots.push_back({3, waves.size() - 1, off});
        } else {
            bytes.push_back(std::make_unique<Byte14V3>(out + off, it.size, point.context(), item_layers[i], v4));
            slots.push_back({2, bytes.size() - 1, off});
        }
        off += it.size;
    }
    if (xy_only) {
        // The XY layer depends on no other layer: x and y (and the returns,
        // the scanner channel) are exact, every other field is stale.
        for (uint64_t i = 1; i < count; ++i) point.read(out + i * rl);
        return pos;
    }
    if (split && count > 1) {
        // Every layer but the XY layer depends only on the XY layer (its
        // changed flags, returns, scanner channel, z context): decode that
        // first, keeping per point what the others need (a Side), then the
        // POINT14 layers 1-8 and each further item as tasks that other
        // threads may take (a chunk then need not keep one core busy while the
        // other idles). Each task writes its own bytes of the records. A
        // corrupt chunk is decoded again in one piece, so that its error is
        // the same as without the split.
        try {
            std::array<Layer, Point14V3::kLayers> xy_layers;
            xy_layers[0] = point_layers[0];
            std::vector<Point14V3::Side> side(count);
            {
                Point14V3 xy(out, xy_layers, v4);
                xy.xy_loop(out, rl, side.data(), count);
            }
            // POINT14's layers 1-8 in four groups of about equal work, each
            // with its own predictor state (the groups' layers are disjoint),
            // then one task per further item.
            constexpr uint32_t kGroups[4] = {1u << 1, (1u << 2) | (1u << 3) | (1u << 6), (1u << 4) | (1u << 5) | (1u << 7), 1u << 8};
            struct Task {
                const Slot* slot;
                std::unique_ptr<Point14V3> point;  // kind 0: this group's own
                int group;
            };
            std::vector<Task> tasks;
            for (const Slot& sl : slots) {
                if (sl.kind != 0) {
                    tasks.push_back({&sl, nullptr, 0});
                    continue;
                }
                for (int g = 0; g < 4; ++g) {
                    bool any = false;
                    for (int L = 1; L <= 8; ++L) any |= ((kGroups[g] >> L) & 1u) && point_layers[L].present;
                    // Group 1 writes the returns and the scanner channel, whatever its layers.
                    if (any || g == 1) tasks.push_back({&sl, std::make_unique<Point14V3>(out, point_layers, v4), g});
                }
            }
            std::vector<char> failed(tasks.size(), 0);
            tbb::parallel_for(
                tbb::blocked_range<std::size_t>(0, tasks.size(), 1),
                [&](const tbb::blocked_range<std::size_t>& range) {
                    for (std::size_t t = range.begin(); t != range.end(); ++t) {
                        const Slot& sl = *tasks[t].slot;
                        Point14V3* p = tasks[t].point.get();
                        uint8_t* const base = out + sl.offset;
                        auto rest = [&]<uint32_t G>() { p->rest_loop<G>(base, rl, side.data(), count); };
                        try {
                            if (sl.kind == 0) {
                                switch (tasks[t].group) {
                                    case 0: rest.template operator()<kGroups[0]>(); break;
                                    case 1: rest.template operator()<kGroups[1]>(); break;
                                    case 2: rest.template operator()<kGroups[2]>(); break;
                                    default: rest.template operator()<kGroups[3]>(); break;
                                }
                                continue;
                            }
                            if (sl.kind == 1) {
                                rgbs[sl.index]->read_loop(base, rl, count, [&](uint64_t i) { return point.context(side[i]); });
                                continue;
                            }
                            for (uint64_t i = 1; i < count; ++i) {
                                uint8_t* rec = base + i * rl;
                                if (sl.kind == 2) bytes[sl.index]->read(rec, point.context(side[i]));
                                else waves[sl.index]->read(rec, point.context(side[i]));
                            }
                        } catch (...) {
                            failed[t] = 1;
                        }
                    }
                },
                tbb::simple_partitioner());
            if (std::find(failed.begin(), failed.end(), 1) == failed.end()) return pos;
        } catch (const Corrupt&) {
        }
        decode_layered(info, rl, data, size, count, out_chars, layers_wanted, false);
        throw Corrupt{"layers disagree (corrupt chunk)"};  // not reached: the one-piece decode throws
    }
    for (uint64_t i = 1; i < count; ++i) {
        uint8_t* rec = out + i * rl;
        for (const Slot& s : slots) {
            if (s.kind == 0) point.read(rec + s.offset);
            else if (s.kind == 1) rgbs[s.index]->read(rec + s.offset, point.context());
            else if (s.kind == 2) bytes[s.index]->read(rec + s.offset, point.context());
            else waves[s.index]->read(rec + s.offset, point.context());
        }
    }
    return pos;
}

const char* item_name(uint16_t type) {
    switch (type) {
        case 0: return "BYTE";
        case 1: return "SHORT";
        case 2: return "INT";
        case 3: return "LONG";
        case 4: return "FLOAT";
        case 5: return "DOUBLE";
        case 6: return "POINT10";
        case 7: return "GPSTIME11";
        case 8: return "RGB12";
        case 9: return "WAVEPACKET13";
        case 10: return "POINT14";
        case 11: return "RGB14";
        case 12: return "RGBNIR14";
        case 13: return "WAVEPACKET14";
        case 14: return "BYTE14";
    }
    return "UNKNOWN";
}

}  // namespace

std::string to_string(const LazItem& item) {
    std::string s = item_name(item.type);
    if (item.type == 0 || item.type == 14) s += "[" + std::to_string(item.size) + "]";
    return s + " v" + std::to_string(item.version);
}

std::string LazInfo::compressor_name() const {
    switch (compressor) {
        case 0: return "0 (none)";
        case 1: return "1 (pointwise)";
        case 2: return "2 (pointwise chunked)";
        case 3: return "3 (layered chunked)";
    }
    return std::to_string(compressor) + " (unknown)";
}

LazInfo parse_laszip_vlr(const std::vector<char>& payload, const std::string& path) {
    if (payload.size() < 34) throw Error(path, "LASzip VLR is too short (" + std::to_string(payload.size()) + " bytes)");
    const auto* p = reinterpret_cast<const uint8_t*>(payload.data());
    LazInfo info;
    info.compressor = bytes::get<uint16_t>(p);
    info.coder = bytes::get<uint16_t>(p + 2);
    info.version_major = p[4];
    info.version_minor = p[5];
    info.version_revision = bytes::get<uint16_t>(p + 6);
    info.options = bytes::get<uint32_t>(p + 8);
    info.chunk_size = bytes::get<uint32_t>(p + 12);
    const auto n_items = bytes::get<uint16_t>(p + 32);
    if (payload.size() < 34 + 6u * n_items)
        throw Error(path, "LASzip VLR lists " + std::to_string(n_items) + " items but holds only " + std::to_string(payload.size()) + " bytes");
    for (uint16_t i = 0; i < n_items; ++i) {
        const uint8_t* q = p + 34 + 6 * i;
        info.items.push_back({bytes::get<uint16_t>(q), bytes::get<uint16_t>(q + 2), bytes::get<uint16_t>(q + 4)});
    }
    return info;
}

void check_laz_supported(const LazInfo& info, int point_format, int record_length, const std::string& path) {
    auto items = [&] {
        std::string s;
        for (const LazItem& it : info.items) s += (s.empty() ? "" : "+") + to_string(it);
        return s;
    };
    if (info.coder != 0) throw Error(path, "LAZ coder " + std::to_string(info.coder) + " is unknown (only 0 = arithmetic exists)");
    if (info.compressor < 1 || info.compressor > 3)
        throw Error(path, "LAZ compressor " + info.compressor_name() +
                              " is not supported (only 1 = pointwise, 2 = pointwise chunked and 3 = layered chunked)");
    if (info.chunk_size == 0 && info.compressor != 1) throw Error(path, "LAZ chunk size 0 is invalid");
    if (info.items.empty()) throw Error(path, "LASzip VLR lists no items");
    int total = 0;
    for (std::size_t i = 0; i < info.items.size(); ++i) {
        const LazItem& it = info.items[i];
        total += it.size;
        bool ok;
        if (info.compressor <= 2) {
            // Item versions 1 (LASzip 1.x) and 2; WAVEPACKET13 has only version 1.
            ok = ((it.version == 1 || it.version == 2) &&
                  ((it.type == 6 && it.size == 20 && i == 0) || (it.type == 7 && it.size == 8) || (it.type == 8 && it.size == 6) ||
                   (it.type == 0 && it.size > 0))) ||
                 (it.version == 1 && it.type == 9 && it.size == 29);
        } else {
            ok = (it.version == 3 || it.version == 4) && it.version == info.items[0].version &&
                 ((it.type == 10 && it.size == 30 && i == 0) || (it.type == 11 && it.size == 6) || (it.type == 12 && it.size == 8) ||
                  (it.type == 13 && it.size == 29) || (it.type == 14 && it.size > 0));
        }
        if (!ok)
            throw Error(path, "LAZ item " + to_string(it) + " (" + std::to_string(it.size) + " bytes, position " + std::to_string(i) +
                                  ") is not supported with compressor " + info.compressor_name() + " (items: " + items() + ")");
    }
    if (total != record_length)
        throw Error(path, "LAZ items " + items() + " cover " + std::to_string(total) + " bytes but the point record is " +
                              std::to_string(record_length));
    const bool legacy = point_format <= 5;
    if ((info.compressor <= 2) != legacy || point_format > 10)
        throw Error(path, "LAZ compressor " + info.compressor_name() + " with point format " + std::to_string(point_format) +
                              " is not supported");
}

std::size_t decode_laz_chunk(const LazInfo& info, int record_length, const uint8_t* data, std::size_t size, uint64_t count,
                             char* out, const std::string& path, std::size_t chunk_index, bool point_fields_only, bool split_layers) {
    try {
        if (info.compressor == 3)
            return decode_layered(info, record_length, data, size, count, out, point_fields_only ? 1 : 0, split_layers);
        return decode_pointwise(info, record_length, data, size, count, out);
    } catch (const Corrupt& c) {
        throw Error(path, "chunk " + std::to_string(chunk_index) + ": " + c.what);
    } catch (const std::bad_alloc&) {
        throw Error(path, "chunk " + std::to_string(chunk_index) + ": out of memory while decoding");
    }
}

std::size_t decode_laz_chunk_xy(const LazInfo& info, int record_length, const uint8_t* data, std::size_t size, uint64_t count,
                                char* out, const std::string& path, std::size_t chunk_index) {
    if (info.compressor != 3) throw Error(path, "chunk " + std::to_string(chunk_index) + ": only layered LAZ chunks have an XY layer");
    try {
        return decode_layered(info, record_length, data, size, count, out, 2);
    } catch (const Corrupt& c) {
        throw Error(path, "chunk " + std::to_string(chunk_index) + ": " + c.what);
    } catch (const std::bad_alloc&) {
        throw Error(path, "chunk " + std::to_string(chunk_index) + ": out of memory while decoding");
    }
}

// ------------------------------------------------------------ streaming

LazPointSource::LazPointSource(const RandomAccessFile& file, const LazInfo& info, uint64_t offset_to_points, uint64_t point_count,
                               int record_length)
    : path_(file.path()), info_(info), record_length_(record_length), point_count_(point_count), file_(&file), file_size_(file.size()) {
    const std::string& path = path_;
    if (point_count == 0) return;
    if (info.compressor == 1) {
        // Pointwise, not chunked: no chunk-table pointer; the first point
        // raw at the start of the point data, then one arithmetic-coded
        // stream for all the others (a single "chunk").
        if (offset_to_points >= file_size_) throw Error(path, "LAZ file ends before its point data (truncated)");
        chunks_.push_back({0, 0, 0, point_count});
        sequential_offset_ = offset_to_points;
        std::vector<bool> all(1, true);
        select_chunks(all);
        return;
    }
    const uint64_t chunks_start = offset_to_points + 8;
    if (chunks_start > file_size_) throw Error(path, "LAZ file ends before its first chunk (truncated)");
    auto read_at = [&](uint64_t pos, void* dst, std::size_t n) { return file_->read_exact_at(pos, dst, n); };
    int64_t table_pos = 0;
    read_at(offset_to_points, &table_pos, 8);
    if (table_pos == -1 && file_size_ >= 8) read_at(file_size_ - 8, &table_pos, 8);
    const bool table_plausible = table_pos > static_cast<int64_t>(chunks_start) && static_cast<uint64_t>(table_pos) + 8 <= file_size_;
    const uint64_t expected_fixed = info.variable_chunks() ? 0 : (point_count + info.chunk_size - 1) / info.chunk_size;
    if (!table_plausible) {
        if (info.variable_chunks())
            throw Error(path, "LAZ chunk table is missing or its offset " + std::to_string(table_pos) +
                                  " lies outside the file (variable-size chunks cannot be read without it)");
        // Fixed chunks without a table: read them one after the other. Each
        // chunk takes at least one byte, so a count the file cannot hold is
        // refused before the list is built.
        if (expected_fixed > file_size_ - chunks_start)
            throw Error(path, "header says " + std::to_string(point_count) + " points, more LAZ chunks than the file has bytes (corrupt header)");
        for (uint64_t c = 0; c < expected_fixed; ++c) {
            const uint64_t first = c * info.chunk_size;
            chunks_.push_back({0, 0, first, std::min<uint64_t>(info.chunk_size, point_count - first)});
        }
        sequential_offset_ = chunks_start;
    } else {
        uint32_t head[2] = {0, 0};
        if (!read_at(static_cast<uint64_t>(table_pos), head, 8)) throw Error(path, "LAZ chunk table is truncated");
        if (head[0] != 0) throw Error(path, "LAZ chunk table version " + std::to_string(head[0]) + " is unknown (expected 0)");
        const uint32_t n = head[1];
        const uint64_t span = static_cast<uint64_t>(table_pos) - chunks_start;
        if (n == 0 || n > span || (!info.variable_chunks() && n != expected_fixed) || (info.variable_chunks() && n > point_count))
            throw Error(path, "LAZ chunk table lists " + std::to_string(n) + " chunks, which cannot be right for " +
                                  std::to_string(point_count) + " points in " + std::to_string(span) + " bytes");
        const uint64_t avail = file_size_ - (static_cast<uint64_t>(table_pos) + 8);
        std::vector<uint8_t> table(static_cast<std::size_t>(std::min<uint64_t>(avail, 16ull * n + 64)));
        read_at(static_cast<uint64_t>(table_pos) + 8, table.data(), table.size());
        try {
            ArithDecoder dec;
            dec.init(table.data(), table.size());
            IntegerDecompressor ic(32, 2);
            uint64_t offset = chunks_start, first = 0;
            uint32_t last_count = 0, last_bytes = 0;
            for (uint32_t i = 0; i < n; ++i) {
                uint64_t cnt;
                if (info.variable_chunks()) {
                    last_count = static_cast<uint32_t>(ic.decompress(dec, static_cast<int32_t>(last_count), 0));
                    cnt = last_count;
                } else {
                    cnt = std::min<uint64_t>(info.chunk_size, point_count - first);
                }
                last_bytes = static_cast<uint32_t>(ic.decompress(dec, static_cast<int32_t>(last_bytes), 1));
                if (last_bytes == 0 || offset + last_bytes > static_cast<uint64_t>(table_pos) || cnt == 0 || first + cnt > point_count)
                    throw Error(path, "LAZ chunk table entry " + std::to_string(i) + " (" + std::to_string(cnt) + " points, " +
                                          std::to_string(last_bytes) + " bytes at " + std::to_string(offset) +
                                          ") runs past the point data or the point count (corrupt chunk table)");
                chunks_.push_back({offset, last_bytes, first, cnt});
                offset += last_bytes;
                first += cnt;
            }
            if (first != point_count)
                throw Error(path, "LAZ chunk table holds " + std::to_string(first) + " points but the header says " +
                                      std::to_string(point_count) + " (corrupt chunk table)");
        } catch (const Corrupt&) {
            throw Error(path, "LAZ chunk table is corrupt (its arithmetic-coded data runs off its end)");
        }
        has_table_ = true;
    }
    std::vector<bool> all(chunks_.size(), true);
    select_chunks(all);
}

LazPointSource::~LazPointSource() = default;

bool LazPointSource::split_layers(const LazChunk& c) const {
    // Layered chunks of some size hand their layers after the XY layer to
    // idle threads (a file of 2 chunks then keeps 2 cores busy to its end);
    // it costs about nothing when every thread has a chunk of its own, and
    // the bytes are the same either way.
    return info_.compressor == 3 && c.point_count >= 4096;
}

void LazPointSource::select_chunks(const std::vector<bool>& keep) {
    order_.clear();
    selected_points_ = 0;
    for (std::size_t i = 0; i < chunks_.size() && i < keep.size(); ++i)
        if (keep[i]) {
            order_.push_back(i);
            selected_points_ += chunks_[i].point_count;
        }
    if (!has_table_ && order_.size() != chunks_.size())
        throw Error(path_, "LAZ file has no chunk table: chunks cannot be skipped");
    next_ = 0;
    decoded_.clear();
    batch_index_ = batch_pos_ = 0;
}

void LazPointSource::fill() {
    batch_index_ = batch_pos_ = 0;
    if (next_ >= order_.size() || !has_table_) decoded_.clear();
    if (next_ >= order_.size()) return;
    const std::size_t rl = static_cast<std::size_t>(record_length_);
    if (!has_table_) {
        // Sequential: the end of one chunk is the start of the next.
        const LazChunk& c = chunks_[order_[next_]];
        const uint64_t avail = file_size_ - std::min(file_size_, sequential_offset_);
        const uint64_t want = std::min<uint64_t>(avail, c.point_count * rl * 2 + 65536);
        std::vector<uint8_t> raw(static_cast<std::size_t>(want));
        raw.resize(file_->read_at(sequential_offset_, raw.data(), raw.size()));
        std::vector<char> out(static_cast<std::size_t>(c.point_count) * rl);
        const std::size_t used = decode_laz_chunk(info_, record_length_, raw.data(), raw.size(), c.point_count, out.data(), path_, order_[next_],
                                              point_fields_only_);
        sequential_offset_ += used;
        decoded_.push_back(std::move(out));
        ++next_;
        return;
    }
    // A batch of chunks: read sequentially, decode in parallel, hand out in order.
    const std::size_t threads = static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
    std::size_t batch = std::max<std::size_t>(2, 2 * threads);
    uint64_t budget = 0;
    std::size_t end = next_;
    while (end < order_.size() && end - next_ < batch) {
        budget += chunks_[order_[end]].point_count * rl;
        ++end;
        if (budget > (256ull << 20)) break;  // keep a batch's memory bounded
    }
    // Buffers keep their capacity from batch to batch (no page faults per chunk).
    std::vector<std::vector<uint8_t>>& raw = raw_;
    raw.resize(std::max(raw.size(), end - next_));
    decoded_.resize(end - next_);
    for (std::size_t i = next_; i < end; ++i) {
        read_raw(order_[i], raw[i - next_]);
        decoded_[i - next_].resize(static_cast<std::size_t>(chunks_[order_[i]].point_count) * rl);
    }
    const std::size_t base = next_;
    tbb::parallel_for(std::size_t(0), end - next_, [&](std::size_t k) {
        const LazChunk& c = chunks_[order_[base + k]];
        decode_laz_chunk(info_, record_length_, raw[k].data(), raw[k].size(), c.point_count, decoded_[k].data(), path_, order_[base + k],
                         point_fields_only_, split_layers(c));
    });
    next_ = end;
}

std::vector<bool> LazPointSource::chunks_meeting_box(const LazXYBox& box) {
    if (info_.compressor != 3 || !has_table_) return {};
    std::vector<bool> keep(chunks_.size(), false);
    const std::size_t rl = static_cast<std::size_t>(record_length_);
    // Batches bound the memory (compressed bytes and one XY scratch buffer per chunk).
    std::size_t i = 0;
    std::vector<std::vector<uint8_t>> raw;
    while (i < order_.size()) {
        std::size_t end = i;
        uint64_t bytes = 0;
        while (end < order_.size() && (end == i || bytes + chunks_[order_[end]].bytes <= (64ull << 20)) && end - i < 64) {
            bytes += chunks_[order_[end]].bytes;
            ++end;
        }
        raw.resize(std::max(raw.size(), end - i));
        for (std::size_t k = i; k < end; ++k) read_raw(order_[k], raw[k - i]);
        std::vector<char> hit(end - i, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(i, end, 1), [&](const tbb::blocked_range<std::size_t>& r) {
            std::vector<char> scratch;
            for (std::size_t k = r.begin(); k < r.end(); ++k) {
                const std::size_t ci = order_[k];
                const LazChunk& c = chunks_[ci];
                scratch.resize(static_cast<std::size_t>(c.point_count) * rl);
                decode_laz_chunk_xy(info_, record_length_, raw[k - i].data(), raw[k - i].size(), c.point_count, scratch.data(), path_, ci);
                for (uint64_t p = 0; p < c.point_count; ++p) {
                    const char* rec = scratch.data() + p * rl;
                    // The same arithmetic as the readers' coordinates.
                    const double x = bytes::get<int32_t>(rec) * box.scale_x + box.offset_x;
                    const double y = bytes::get<int32_t>(rec + 4) * box.scale_y + box.offset_y;
                    if (x >= box.min_x && x <= box.max_x && y >= box.min_y && y <= box.max_y) {
                        hit[k - i] = 1;
                        break;
                    }
                }
            }
        });
        for (std::size_t k = i; k < end; ++k) keep[order_[k]] = hit[k - i] != 0;
        i = end;
    }
    return keep;
}

std::size_t LazPointSource::decode_direct(char* out, std::size_t max_points) {
    // Whole chunks that fit into the caller's buffer, decoded in parallel
    // straight into it (no intermediate buffer, no copy). The chunks of one
    // call are many when the caller asks for many points, which keeps both
    // cores busy to the end of the call.
    const std::size_t rl = static_cast<std::size_t>(record_length_);
    std::size_t end = next_;
    uint64_t points = 0;
    uint64_t raw_bytes = 0;
    while (end < order_.size()) {
        const LazChunk& c = chunks_[order_[end]];
        if (points + c.point_count > max_points || raw_bytes + c.bytes > (256ull << 20)) break;
        points += c.point_count;
        raw_bytes += c.bytes;
        ++end;
    }
    if (end == next_) return 0;
    std::vector<std::vector<uint8_t>>& raw = raw_;
    raw.resize(std::max(raw.size(), end - next_));
    std::vector<std::size_t> first(end - next_);
    std::size_t at = 0;
    for (std::size_t i = next_; i < end; ++i) {
        const LazChunk& c = chunks_[order_[i]];
        read_raw(order_[i], raw[i - next_]);
        first[i - next_] = at;
        at += static_cast<std::size_t>(c.point_count);
    }
    const std::size_t base = next_;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, end - next_, 1), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k < r.end(); ++k) {
            const LazChunk& c = chunks_[order_[base + k]];
            decode_laz_chunk(info_, record_length_, raw[k].data(), raw[k].size(), c.point_count, out + first[k] * rl, path_,
                             order_[base + k], point_fields_only_, split_layers(c));
        }
    });
    next_ = end;
    return static_cast<std::size_t>(points);
}

void LazPointSource::read_raw(std::size_t chunk, std::vector<uint8_t>& raw) {
    const LazChunk& c = chunks_[chunk];
    raw.resize(static_cast<std::size_t>(c.bytes));
    if (!file_->read_exact_at(c.offset, raw.data(), raw.size()))
        throw Error(path_, "chunk " + std::to_string(chunk) + ": truncated (the file ends inside it)");
}

std::size_t LazPointSource::read(char* out, std::size_t max_points) {
    const std::size_t rl = static_cast<std::size_t>(record_length_);
    std::size_t done = 0;
    while (done < max_points) {
        if (batch_index_ >= decoded_.size()) {
            // Nothing buffered: whole chunks go straight into `out`; only a
            // chunk larger than what is left of the request is buffered.
            if (has_table_) {
                if (const std::size_t n = decode_direct(out + done * rl, max_points - done); n > 0) {
                    done += n;
                    continue;
                }
            }
            fill();
            if (decoded_.empty()) break;
        }
        const std::vector<char>& buf = decoded_[batch_index_];
        const std::size_t have = buf.size() / rl - batch_pos_;
        const std::size_t take = std::min(have, max_points - done);
        std::memcpy(out + done * rl, buf.data() + batch_pos_ * rl, take * rl);
        done += take;
        batch_pos_ += take;
        if (batch_pos_ * rl >= buf.size()) {
            ++batch_index_;
            batch_pos_ = 0;
        }
    }
    return done;
}

}  // namespace cityforge
