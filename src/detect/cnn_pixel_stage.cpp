#include "detect/cnn_pixel_stage.hpp"

#include <ATen/Parallel.h>
#include <tbb/parallel_for.h>
#include <torch/torch.h>

#include <algorithm>
#include <c10/core/CPUAllocator.h>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <new>
#include <vector>

#include "core/error.hpp"
#include "core/random.hpp"

namespace cityforge::detect {

void CnnOptions::validate() const {
    if (base_channels < 2 || base_channels > 64) throw Error("pixel.cnn.base_channels", "must be in [2, 64]");
    if (levels < 1 || levels > 4) throw Error("pixel.cnn.levels", "must be in [1, 4]");
    if (crop_cells < 16 || crop_cells > 512 || crop_cells % (1 << levels) != 0)
        throw Error("pixel.cnn.crop_cells", "must be in [16, 512] and divisible by 2^levels");
    if (batch < 1 || batch > 256) throw Error("pixel.cnn.batch", "must be in [1, 256]");
    if (steps < 1 || steps > 1000000) throw Error("pixel.cnn.steps", "must be in [1, 1000000]");
    if (!(learning_rate > 0.0 && learning_rate < 1.0)) throw Error("pixel.cnn.learning_rate", "must be in (0, 1)");
    if (tta != 1 && tta != 4 && tta != 8) throw Error("pixel.cnn.tta", "must be 1, 4 or 8");
}

void CnnTiling::validate() const {
    if (kept_cells < 16 || kept_cells > 1024 || kept_cells % 16 != 0)
        throw Error("pixel CNN tiling", "kept cells must be a multiple of 16 in [16, 1024]");
}

namespace {

constexpr char kMagic[] = "CFCNN1";
constexpr std::size_t kMagicLen = 6;
constexpr int kMargin = 32;  // context around a prediction tile's kept cells (cells; a multiple of 16)

// One torch intra-op thread on the calling thread (OpenMP ICVs are per
// thread; oneDNN and the BLAS follow them).
void single_thread() {
    if (at::get_num_threads() != 1) at::set_num_threads(1);
}

// Torch's CPU memory through a cache of freed blocks of 64 kB or more, by
// exact size. A prediction tile's convolutions allocate and free the same
// buffers of tens of MB for every tile and transform; glibc hands blocks that
// large back to the kernel on every free (mmap, or trimming a thread's heap),
// and the next tile faults them in again, zeroed: 2.6 M page faults and about
// 4 system seconds in bench_detect's two chains. The cache holds at most
// kCacheBytes and is emptied when the last prediction or training using it
// ends (CachedTorchMemory), so the process keeps no memory afterwards. Only
// where memory comes from changes, never a value (torch writes every output
// element it allocates).
class BlockCacheAllocator final : public c10::Allocator {
public:
    static constexpr std::size_t kHeader = 64;  // the block's size, and 64-byte alignment of the data after it
    static constexpr std::size_t kMinCached = std::size_t(64) << 10;
    static constexpr std::size_t kCacheBytes = std::size_t(512) << 20;

    c10::DataPtr allocate(std::size_t n) const override {
        void* p = take(n);
        return {p, p, &release, c10::Device(c10::DeviceType::CPU)};
    }
    c10::DeleterFnPtr raw_deleter() const override { return &release; }

    /// Starts (users 0 -> 1) or ends (1 -> 0, the cache freed) a use of the cache.
    static void use(int delta) {
        std::multimap<std::size_t, void*> freed;  // taken out under the lock, freed outside it; no allocation
        {
            State& s = state();
            std::lock_guard lock(s.mutex);
            s.users += delta;
            if (s.users > 0) return;
            freed.swap(s.blocks), s.cached = 0;
        }
        for (const auto& [size, raw] : freed) std::free(raw);
    }

private:
    struct State {
        std::mutex mutex;
        std::multimap<std::size_t, void*> blocks;  // size -> raw block (header first)
        std::size_t cached = 0;
        int users = 0;
    };
    static State& state() {
        static State* s = new State;  // never destroyed: tensors may be freed after static destructors ran
        return *s;
    }
    static void* take(std::size_t n) {
        if (n >= kMinCached) {
            State& s = state();
            std::lock_guard lock(s.mutex);
            if (const auto it = s.blocks.find(n); it != s.blocks.end()) {
                void* raw = it->second;
                s.blocks.erase(it), s.cached -= n;
                return static_cast<char*>(raw) + kHeader;
            }
        }
        void* raw = std::aligned_alloc(kHeader, kHeader + (n + kHeader - 1) / kHeader * kHeader);
        if (!raw) throw std::bad_alloc();
        *static_cast<std::size_t*>(raw) = n;
        return static_cast<char*>(raw) + kHeader;
    }
    static void release(void* p) {
        if (!p) return;
        void* raw = static_cast<char*>(p) - kHeader;
        const std::size_t n = *static_cast<const std::size_t*>(raw);
        if (n >= kMinCached) {
            State& s = state();
            std::lock_guard lock(s.mutex);
            if (s.users > 0 && s.cached + n <= kCacheBytes) {
                try {
                    s.blocks.emplace(n, raw), s.cached += n;
                    return;
                } catch (...) {  // no room to list it: freed below (a deleter must not throw)
                }
            }
        }
        std::free(raw);
    }
};

// While alive, torch's CPU tensors use BlockCacheAllocator (installed once,
// for the process: blocks it handed out must come back to it).
class CachedTorchMemory {
public:
    CachedTorchMemory() {
        static BlockCacheAllocator allocator;
        static std::once_flag installed;
        std::call_once(installed, [] { c10::SetCPUAllocator(&allocator, /*priority=*/1); });
        BlockCacheAllocator::use(+1);
    }
    ~CachedTorchMemory() { BlockCacheAllocator::use(-1); }
    CachedTorchMemory(const CachedTorchMemory&) = delete;
    CachedTorchMemory& operator=(const CachedTorchMemory&) = delete;
};

struct ConvBnImpl : torch::nn::Module {
    torch::nn::Conv2d conv{nullptr};
    torch::nn::BatchNorm2d bn{nullptr};
    ConvBnImpl(int in, int out) {
        conv = register_module("conv", torch::nn::Conv2d(torch::nn::Conv2dOptions(in, out, 3).padding(1).bias(false)));
        bn = register_module("bn", torch::nn::BatchNorm2d(out));
    }
    torch::Tensor forward(const torch::Tensor& x) { return torch::relu(bn->forward(conv->forward(x))); }
};
TORCH_MODULE(ConvBn);

struct UNetImpl : torch::nn::Module {
    std::vector<ConvBn> enc_a, enc_b, dec;
    torch::nn::Conv2d head{nullptr};
    int levels;
    UNetImpl(int in, const CnnOptions& o) : levels(o.levels) {
        std::vector<int> c;
        for (int l = 0; l <= levels; ++l) c.push_back(o.base_channels * (1 << std::min(l, 2)));
        for (int l = 0; l <= levels; ++l) {
            enc_a.push_back(register_module("enc" + std::to_string(l) + "a", ConvBn(l == 0 ? in : c[l - 1], c[l])));
            enc_b.push_back(register_module("enc" + std::to_string(l) + "b", ConvBn(c[l], c[l])));
        }
        for (int l = 0; l < levels; ++l) dec.push_back(register_module("dec" + std::to_string(l), ConvBn(c[l + 1] + c[l], c[l])));
        head = register_module("head", torch::nn::Conv2d(torch::nn::Conv2dOptions(c[0], 1, 1).bias(true)));
    }
    torch::Tensor forward(torch::Tensor x) {
        std::vector<torch::Tensor> skip;
        for (int l = 0; l <= levels; ++l) {
            if (l > 0) x = torch::max_pool2d(x, 2);
            x = enc_b[l]->forward(enc_a[l]->forward(x));
            skip.push_back(x);
        }
        for (int l = levels - 1; l >= 0; --l) {
            x = torch::upsample_nearest2d(x, {skip[l].size(2), skip[l].size(3)});
            x = dec[l]->forward(torch::cat({x, skip[l]}, 1));
        }
        return head->forward(x);
    }
};
TORCH_MODULE(UNet);

// The tensors that make the weights, in a fixed order: parameters, then the
// float buffers (BatchNorm running mean and variance).
std::vector<torch::Tensor> weight_tensors(UNet& net) {
    std::vector<torch::Tensor> t;
    for (const auto& p : net->named_parameters()) t.push_back(p.value());
    for (const auto& b : net->named_buffers())
        if (b.value().scalar_type() == torch::kFloat32) t.push_back(b.value());
    return t;
}

// Kaiming-uniform convolution weights from our RNG, zero biases (BatchNorm
// keeps its 1/0 defaults): no draw from torch's global generator.
void initialise(UNet& net, uint64_t seed) {
    torch::NoGradGuard ng;
    uint64_t k = 0;
    for (const auto& p : net->named_parameters()) {
        torch::Tensor v = p.value();
        const std::string& name = p.key();
        if (v.dim() == 4) {
            const double fan_in = double(v.size(1) * v.size(2) * v.size(3));
            const double bound = std::sqrt(6.0 / fan_in);
            float* d = v.data_ptr<float>();
            for (int64_t i = 0; i < v.numel(); ++i) d[i] = static_cast<float>((2.0 * unit_from_hash(hash64(seed, 0xc0de, k, uint64_t(i))) - 1.0) * bound);
        } else if (name.find("head") != std::string::npos) {
            v.zero_();
        }
        ++k;
    }
}

void put_u32(std::vector<uint8_t>& out, uint32_t v) {
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<uint8_t>(v >> (8 * i)));
}
uint32_t get_u32(const std::vector<uint8_t>& in, std::size_t at) {
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= uint32_t(in[at + i]) << (8 * i);
    return v;
}

std::vector<uint8_t> serialise(UNet& net) {
    std::vector<uint8_t> out(kMagic, kMagic + kMagicLen);
    const std::vector<torch::Tensor> ts = weight_tensors(net);
    put_u32(out, uint32_t(ts.size()));
    for (const torch::Tensor& t0 : ts) {
        const torch::Tensor t = t0.contiguous();
        put_u32(out, uint32_t(t.dim()));
        for (int64_t d = 0; d < t.dim(); ++d) put_u32(out, uint32_t(t.size(d)));
        const float* d = t.data_ptr<float>();
        for (int64_t i = 0; i < t.numel(); ++i) {
            uint32_t u;
            std::memcpy(&u, &d[i], 4);
            put_u32(out, u);
        }
    }
    return out;
}

// Loads a blob into `net` (its architecture fixed by the options); throws
// on any mismatch.
void load(UNet& net, const std::vector<uint8_t>& in, const std::string& subject) {
    torch::NoGradGuard ng;
    const std::vector<torch::Tensor> ts = weight_tensors(net);
    if (in.size() < kMagicLen + 4 || std::memcmp(in.data(), kMagic, kMagicLen) != 0) throw Error(subject, "corrupt CNN weights (no CFCNN1 magic)");
    if (get_u32(in, kMagicLen) != ts.size())
        throw Error(subject, "CNN weights hold " + std::to_string(get_u32(in, kMagicLen)) + " tensors; the network of the model's options has " +
                                 std::to_string(ts.size()));
    std::size_t at = kMagicLen + 4;
    auto need = [&](std::size_t n) {
        if (n > in.size() - at) throw Error(subject, "truncated CNN weights");
    };
    for (const torch::Tensor& t : ts) {
        need(4);
        const uint32_t rank = get_u32(in, at);
        at += 4;
        if (int64_t(rank) != t.dim()) throw Error(subject, "CNN weights do not match the network (tensor rank)");
        need(4 * std::size_t(rank));
        for (uint32_t d = 0; d < rank; ++d, at += 4)
            if (int64_t(get_u32(in, at)) != t.size(int64_t(d))) throw Error(subject, "CNN weights do not match the network (tensor shape)");
        need(4 * std::size_t(t.numel()));
        float* d = t.data_ptr<float>();
        for (int64_t i = 0; i < t.numel(); ++i, at += 4) {
            const uint32_t u = get_u32(in, at);
            std::memcpy(&d[i], &u, 4);
            if (!std::isfinite(d[i])) throw Error(subject, "corrupt CNN weights (a value is not finite)");
        }
    }
    if (at != in.size()) throw Error(subject, "corrupt CNN weights (" + std::to_string(in.size() - at) + " trailing bytes)");
}

}  // namespace

std::vector<uint8_t> train_cnn(const std::vector<const CnnGrid*>& grids, int channels, const CnnOptions& o) {
    o.validate();
    if (grids.empty() || channels < 1) throw Error("pixel CNN", "no training grid");
    const CachedTorchMemory memory;
    single_thread();
    const int S = o.crop_cells, B = o.batch;
    // Grids are drawn in proportion to their trainable cells.
    std::vector<double> cum;
    double total = 0.0;
    for (const CnnGrid* g : grids) {
        if (g->input.size() != std::size_t(channels) * g->width * g->height || g->target.size() != std::size_t(g->width) * g->height ||
            g->weight.size() != g->target.size())
            throw Error("pixel CNN", "internal: training grid sizes");
        double n = 0.0;
        for (const float w : g->weight) n += w > 0.0f;
        cum.push_back(total += n);
    }
    if (!(total > 0.0)) throw Error("pixel CNN", "no trainable cell");
    UNet net(channels, o);
    initialise(net, o.seed);
    net->train();
    torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(o.learning_rate));
    Rng rng(o.seed, 0xc7a1);
    std::vector<float> xb(std::size_t(B) * channels * S * S), tb(std::size_t(B) * S * S), wb(std::size_t(B) * S * S);
    for (int step = 0; step < o.steps; ++step) {
        std::fill(xb.begin(), xb.end(), 0.0f), std::fill(tb.begin(), tb.end(), 0.0f), std::fill(wb.begin(), wb.end(), 0.0f);
        std::vector<int> aug(B);
        for (int b = 0; b < B; ++b) {
            const double r = rng.uniform() * total;
            const std::size_t gi = std::min<std::size_t>(grids.size() - 1, std::size_t(std::upper_bound(cum.begin(), cum.end(), r) - cum.begin()));
            const CnnGrid& g = *grids[gi];
            const int x0 = g.width > S ? rng.integer(0, g.width - S) : 0, y0 = g.height > S ? rng.integer(0, g.height - S) : 0;
            aug[b] = rng.integer(0, 7);
            for (int y = 0; y < std::min(S, g.height - y0); ++y)
                for (int x = 0; x < std::min(S, g.width - x0); ++x) {
                    const std::size_t src = std::size_t(y0 + y) * g.width + (x0 + x), dst = std::size_t(y) * S + x;
                    tb[std::size_t(b) * S * S + dst] = g.target[src];
                    wb[std::size_t(b) * S * S + dst] = g.weight[src];
                    for (int c = 0; c < channels; ++c)
                        xb[(std::size_t(b) * channels + c) * S * S + dst] = g.input[std::size_t(c) * g.width * g.height + src];
                }
        }
        torch::Tensor x = torch::from_blob(xb.data(), {B, channels, S, S}, torch::kFloat32).clone();
        torch::Tensor t = torch::from_blob(tb.data(), {B, 1, S, S}, torch::kFloat32).clone();
        torch::Tensor w = torch::from_blob(wb.data(), {B, 1, S, S}, torch::kFloat32).clone();
        // Augmentation: rot90 k times and an optional flip, per crop.
        std::vector<torch::Tensor> xs, ts, ws;
        for (int b = 0; b < B; ++b) {
            auto f = [&](const torch::Tensor& v) {
                torch::Tensor u = v[b];
                if (aug[b] & 3) u = torch::rot90(u, aug[b] & 3, {1, 2});
                if (aug[b] & 4) u = torch::flip(u, {2});
                return u;
            };
            xs.push_back(f(x)), ts.push_back(f(t)), ws.push_back(f(w));
        }
        x = torch::stack(xs), t = torch::stack(ts), w = torch::stack(ws);
        const double lr = o.learning_rate * (step < 0.6 * o.steps ? 1.0 : step < 0.85 * o.steps ? 0.5 : 0.25);
        for (auto& group : opt.param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);
        const torch::Tensor logits = net->forward(x);
        const torch::Tensor loss =
            (torch::binary_cross_entropy_with_logits(logits, t, {}, {}, at::Reduction::None) * w).sum() / w.sum().clamp_min(1.0);
        opt.zero_grad();
        loss.backward();
        opt.step();
    }
    net->eval();
    return serialise(net);
}

std::vector<float> predict_cnn(const std::vector<uint8_t>& weights, const std::vector<float>& input, int w, int h, int channels,
                               const CnnOptions& o, const CnnTiling& tiling) {
    o.validate();
    tiling.validate();
    if (input.size() != std::size_t(channels) * w * h) throw Error("pixel CNN", "internal: input size");
    std::vector<float> out(std::size_t(w) * h, 0.0f);
    const CachedTorchMemory memory;
    const int K = tiling.kept_cells, step = 1 << o.levels;
    const int tx = (w + K - 1) / K, ty = (h + K - 1) / K;
    const int T = o.tta;
    // One network per task (modules are not shared between threads).
    tbb::parallel_for(0, tx * ty, [&](int k) {
        single_thread();
        torch::NoGradGuard ng;
        UNet net(channels, o);
        load(net, weights, "pixel CNN");
        net->eval();
        const int x0 = (k % tx) * K - kMargin, y0 = (k / tx) * K - kMargin;
        // The tile: its kx x ky kept cells (K x K but at the grid's far
        // edges) and a margin on each side; nx x ny cells in all (K + 2
        // margins, or clipped: a margin past the last kept cell rounded up
        // to a multiple of 2^levels). Cells outside the grid are 0.
        const int kx = std::min(K, w - (x0 + kMargin)), ky = std::min(K, h - (y0 + kMargin));
        const auto side = [&](int kept) { return tiling.clip_edges ? (kept + 2 * kMargin + step - 1) / step * step : K + 2 * kMargin; };
        const int nx = side(kx), ny = side(ky);
        std::vector<float> xb(std::size_t(channels) * ny * nx, 0.0f);
        for (int c = 0; c < channels; ++c)
            for (int y = std::max(0, -y0); y < std::min(ny, h - y0); ++y)
                for (int x = std::max(0, -x0); x < std::min(nx, w - x0); ++x)
                    xb[(std::size_t(c) * ny + y) * nx + x] = input[(std::size_t(c) * h + (y0 + y)) * w + (x0 + x)];
        // Transform t moves tile cell (y, x) to (y', x'): bit 0 flips x, bit 1
        // flips y, bit 2 then swaps the two (transpose: the moved tile is nx
        // high and ny wide). The network sees the moved tile; its output at
        // (y', x') belongs to (y, x).
        const auto moved = [nx, ny](int t, int y, int x) {
            if (t & 1) x = nx - 1 - x;
            if (t & 2) y = ny - 1 - y;
            return t & 4 ? std::size_t(x) * ny + y : std::size_t(y) * nx + x;
        };
        // (T = 1: the identity alone, the tile as it is; a mean of one value is that value.)
        std::vector<float> vals(std::size_t(T) * kx * ky), xt(T > 1 ? xb.size() : 0);
        for (int t = 0; t < T; ++t) {
            if (t > 0)
                for (int c = 0; c < channels; ++c)
                    for (int y = 0; y < ny; ++y)
                        for (int x = 0; x < nx; ++x) xt[std::size_t(c) * nx * ny + moved(t, y, x)] = xb[(std::size_t(c) * ny + y) * nx + x];
            const int64_t th = t & 4 ? nx : ny, tw = t & 4 ? ny : nx;
            const torch::Tensor p =
                torch::sigmoid(net->forward(torch::from_blob(t > 0 ? xt.data() : xb.data(), {1, channels, th, tw}, torch::kFloat32))).contiguous();
            const float* pd = p.data_ptr<float>();
            for (int y = 0; y < ky; ++y)
                for (int x = 0; x < kx; ++x) vals[(std::size_t(y) * kx + x) * T + t] = pd[moved(t, kMargin + y, kMargin + x)];
        }
        // Each cell's values sorted before the sum: the same mean whatever
        // the order of the transforms (exact equivariance under the group).
        for (int y = 0; y < ky; ++y)
            for (int x = 0; x < kx; ++x) {
                float* v = &vals[(std::size_t(y) * kx + x) * T];
                std::sort(v, v + T);
                double sum = 0.0;
                for (int t = 0; t < T; ++t) sum += v[t];
                out[std::size_t(y0 + kMargin + y) * w + (x0 + kMargin + x)] = static_cast<float>(sum / T);
            }
    });
    return out;
}

void check_cnn_weights(const std::vector<uint8_t>& weights, int channels, const CnnOptions& o, const std::string& subject) {
    o.validate();
    UNet net(channels, o);
    load(net, weights, subject);
}

}  // namespace cityforge::detect
