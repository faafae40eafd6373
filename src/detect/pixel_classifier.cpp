#include "detect/pixel_classifier.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "core/error.hpp"
#include "core/random.hpp"

namespace cityforge::detect {

void PixelClassifierOptions::validate() const {
    if (!(cell_m > 0.0 && cell_m <= 10.0)) throw Error("pixel.cell_m", "must be in (0, 10] metres");
    if (sigmas_m.empty()) throw Error("pixel.sigmas_m", "give at least one filter scale");
    for (std::size_t i = 0; i < sigmas_m.size(); ++i) {
        if (!(sigmas_m[i] > 0.0 && sigmas_m[i] <= 50.0)) throw Error("pixel.sigmas_m", "must be in (0, 50] metres");
        if (i > 0 && !(sigmas_m[i] > sigmas_m[i - 1])) throw Error("pixel.sigmas_m", "must be strictly increasing");
    }
    if (samples_per_image < 100) throw Error("pixel.samples_per_image", "must be at least 100");
    booster.validate();
    cnn.validate();
}

std::string to_string(PixelStageKind k) { return k == PixelStageKind::cnn ? "cnn" : k == PixelStageKind::both ? "both" : "boosted"; }

PixelStageKind parse_pixel_stage_kind(const std::string& name) {
    if (name == "boosted") return PixelStageKind::boosted;
    if (name == "cnn") return PixelStageKind::cnn;
    if (name == "both") return PixelStageKind::both;
    throw Error("pixel.kind", "'" + name + "' is not a pixel stage (boosted, cnn or both)");
}

std::vector<uint8_t> pack_pixel_models(const std::vector<uint8_t>& boosted, const std::vector<uint8_t>& cnn) {
    std::vector<uint8_t> out{'C', 'F', 'P', 'I', 'X', '2'};
    for (const std::vector<uint8_t>* m : {&boosted, &cnn}) {
        for (int i = 0; i < 8; ++i) out.push_back(static_cast<uint8_t>(uint64_t(m->size()) >> (8 * i)));
        out.insert(out.end(), m->begin(), m->end());
    }
    return out;
}

std::pair<std::vector<uint8_t>, std::vector<uint8_t>> unpack_pixel_models(const std::vector<uint8_t>& in, const std::string& subject) {
    if (in.size() < 6 || std::string(in.begin(), in.begin() + 6) != "CFPIX2") throw Error(subject, "corrupt pixel models (no CFPIX2 magic)");
    std::vector<uint8_t> part[2];
    std::size_t at = 6;
    for (std::vector<uint8_t>& m : part) {
        if (in.size() - at < 8) throw Error(subject, "truncated pixel models");
        uint64_t len = 0;
        for (int i = 0; i < 8; ++i) len |= uint64_t(in[at + i]) << (8 * i);
        at += 8;
        if (len > in.size() - at) throw Error(subject, "truncated pixel models");
        m.assign(in.begin() + std::ptrdiff_t(at), in.begin() + std::ptrdiff_t(at + len));
        at += len;
    }
    if (at != in.size()) throw Error(subject, "corrupt pixel models (trailing bytes)");
    return {std::move(part[0]), std::move(part[1])};
}

int pixel_cell_factor(double gsd_m, const PixelClassifierOptions& o) {
    if (!(gsd_m > 0.0)) throw Error("pixel classifier", "GSD must be > 0");
    return std::max(1, static_cast<int>(std::lround(o.cell_m / gsd_m)));
}

namespace {

// Colour bands (not NIR, not nDSM), in image order.
std::vector<int> colour_bands(const BandLayout& l) {
    std::vector<int> c;
    for (int b = 0; b < l.bands; ++b)
        if (b != l.nir_band && b != l.ndsm_band) c.push_back(b);
    return c;
}

std::string fmt_sigma(double s) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", s);
    return buf;
}

// Separable Gaussian blur (edges clamped), rows in parallel: each output
// value is written by one task, so any thread count gives the same values.
std::vector<float> blur(const std::vector<float>& in, int w, int h, double sigma_px) {
    if (sigma_px < 0.3) return in;
    const int r = std::max(1, static_cast<int>(std::ceil(3.0 * sigma_px)));
    std::vector<float> k(2 * r + 1);
    double sum = 0.0;
    for (int i = -r; i <= r; ++i) sum += k[i + r] = static_cast<float>(std::exp(-0.5 * i * i / (sigma_px * sigma_px)));
    for (float& v : k) v = static_cast<float>(v / sum);
    std::vector<float> tmp(in.size()), out(in.size());
    tbb::parallel_for(0, h, [&](int y) {
        const float* src = in.data() + std::size_t(y) * w;
        float* dst = tmp.data() + std::size_t(y) * w;
        for (int x = 0; x < w; ++x) {
            float acc = 0.0f;
            for (int i = -r; i <= r; ++i) acc += k[i + r] * src[std::clamp(x + i, 0, w - 1)];
            dst[x] = acc;
        }
    });
    tbb::parallel_for(0, h, [&](int y) {
        float* dst = out.data() + std::size_t(y) * w;
        for (int x = 0; x < w; ++x) dst[x] = 0.0f;
        for (int i = -r; i <= r; ++i) {
            const float kv = k[i + r];
            const float* src = tmp.data() + std::size_t(std::clamp(y + i, 0, h - 1)) * w;
            for (int x = 0; x < w; ++x) dst[x] += kv * src[x];
        }
    });
    return out;
}

// Central differences (edges clamped).
void derivatives(const std::vector<float>& v, int w, int h, std::vector<float>& dx, std::vector<float>& dy) {
    dx.assign(v.size(), 0.0f), dy.assign(v.size(), 0.0f);
    tbb::parallel_for(0, h, [&](int y) {
        const int ym = std::max(0, y - 1), yp = std::min(h - 1, y + 1);
        for (int x = 0; x < w; ++x) {
            const int xm = std::max(0, x - 1), xp = std::min(w - 1, x + 1);
            const std::size_t i = std::size_t(y) * w + x;
            dx[i] = 0.5f * (v[std::size_t(y) * w + xp] - v[std::size_t(y) * w + xm]);
            dy[i] = 0.5f * (v[std::size_t(yp) * w + x] - v[std::size_t(ym) * w + x]);
        }
    });
}

// Box averages of the valid pixels of every cell of f x f pixels, one
// vector per band (ceil(w / f) x ceil(h / f) cells); `cell_valid` = 1 where
// the cell holds a valid pixel. Invalid cells take the mean of the valid
// ones (no edge at nodata borders).
std::vector<std::vector<float>> box_average(const Image<float>& img, const std::vector<uint8_t>& valid, int f, std::vector<uint8_t>& cell_valid) {
    const int W = img.width, H = img.height;
    const int w = (W + f - 1) / f, h = (H + f - 1) / f;
    const std::size_t n = std::size_t(w) * h;
    const int B = img.bands;
    std::vector<std::vector<float>> band(B, std::vector<float>(n, 0.0f));
    std::vector<float> count(n, 0.0f);
    tbb::parallel_for(0, h, [&](int cy) {
        for (int y = cy * f; y < std::min(H, (cy + 1) * f); ++y)
            for (int x = 0; x < W; ++x) {
                const std::size_t i = std::size_t(y) * W + x;
                if (!valid.empty() && !valid[i]) continue;
                const std::size_t c = std::size_t(cy) * w + x / f;
                count[c] += 1.0f;
                for (int b = 0; b < B; ++b) band[b][c] += img.band_data(b)[i];
            }
    });
    std::vector<uint8_t>& cv = cell_valid;
    cv.assign(n, 0);
    for (std::size_t c = 0; c < n; ++c)
        if (count[c] > 0.0f) {
            cv[c] = 1;
            for (int b = 0; b < B; ++b) band[b][c] /= count[c];
        }
    for (int b = 0; b < B; ++b) {
        double s = 0.0, k = 0.0;
        for (std::size_t c = 0; c < n; ++c)
            if (cv[c]) s += band[b][c], k += 1.0;
        const float fill = k > 0 ? static_cast<float>(s / k) : 0.0f;
        for (std::size_t c = 0; c < n; ++c)
            if (!cv[c]) band[b][c] = fill;
    }
    return band;
}

// Eigenvalues (larger first) of [[a, b], [b, c]].
inline void eig2(float a, float b, float c, float& l1, float& l2) {
    const float m = 0.5f * (a + c), d = std::sqrt(0.25f * (a - c) * (a - c) + b * b);
    l1 = m + d, l2 = m - d;
}

}  // namespace

std::vector<std::string> pixel_feature_names(const BandLayout& layout, const PixelClassifierOptions& o) {
    std::vector<std::string> f;
    for (int b = 0; b < layout.bands; ++b) {
        const std::string n = b == layout.ndsm_band ? "ndsm" : "band" + std::to_string(b + 1);
        f.push_back(n);
        f.push_back(n + "_g" + fmt_sigma(o.sigmas_m[0]));
    }
    for (const double s : o.sigmas_m) {
        const std::string t = fmt_sigma(s);
        for (const char* n : {"bright_g", "grad_g", "hess1_g", "hess2_g", "st1_g", "st2_g", "std_g"}) f.push_back(n + t);
    }
    if (colour_bands(layout).size() >= 3)
        for (const char* n : {"chroma_r", "chroma_b", "exg", "saturation"}) f.emplace_back(n);
    if (layout.nir_band >= 0) f.emplace_back("ndvi");
    return f;
}

Image<float> pixel_feature_stack(const Image<float>& img, const std::vector<uint8_t>& valid, const BandLayout& layout, double gsd_m,
                                 const PixelClassifierOptions& o, std::vector<uint8_t>* cell_valid) {
    o.validate();
    if (img.bands != layout.bands) throw Error("pixel features", "image has " + std::to_string(img.bands) + " bands, layout " + std::to_string(layout.bands));
    const int f = pixel_cell_factor(gsd_m, o);
    std::vector<uint8_t> cv;
    std::vector<std::vector<float>> band = box_average(img, valid, f, cv);
    const int w = (img.width + f - 1) / f, h = (img.height + f - 1) / f;
    const std::size_t n = std::size_t(w) * h;
    const double cell_m = f * gsd_m;
    const int B = img.bands;
    const std::vector<int> colours = colour_bands(layout);
    std::vector<float> bright(n, 0.0f);
    for (const int b : colours)
        for (std::size_t c = 0; c < n; ++c) bright[c] += band[b][c];
    for (float& v : bright) v /= static_cast<float>(std::max<std::size_t>(1, colours.size()));
    std::vector<float> bright2(n);
    for (std::size_t c = 0; c < n; ++c) bright2[c] = bright[c] * bright[c];
    // Structure tensor from fine gradients (inner scale: one cell).
    std::vector<float> b0 = blur(bright, w, h, 0.7), gx, gy;
    derivatives(b0, w, h, gx, gy);
    std::vector<float> jxx(n), jyy(n), jxy(n);
    for (std::size_t c = 0; c < n; ++c) jxx[c] = gx[c] * gx[c], jyy[c] = gy[c] * gy[c], jxy[c] = gx[c] * gy[c];

    const std::vector<std::string> names = pixel_feature_names(layout, o);
    Image<float> out(w, h, int(names.size()), 0.0f);
    int k = 0;
    auto put = [&](const std::vector<float>& v) { std::copy(v.begin(), v.end(), out.band_data(k++)); };
    const double s0 = o.sigmas_m[0] / cell_m;
    std::vector<std::vector<float>> band_s0(B);
    for (int b = 0; b < B; ++b) {
        put(band[b]);
        band_s0[b] = blur(band[b], w, h, s0);
        put(band_s0[b]);
    }
    for (const double s_m : o.sigmas_m) {
        const double s = s_m / cell_m;
        const std::vector<float> g = blur(bright, w, h, s);
        put(g);
        std::vector<float> dx, dy, dxx, dxy, dyx, dyy;
        derivatives(g, w, h, dx, dy);
        derivatives(dx, w, h, dxx, dxy);
        derivatives(dy, w, h, dyx, dyy);
        std::vector<float> grad(n), h1(n), h2(n), s1(n), s2(n), sd(n);
        const float norm = static_cast<float>(s * s);  // scale-normalised second derivatives
        for (std::size_t c = 0; c < n; ++c) {
            grad[c] = std::sqrt(dx[c] * dx[c] + dy[c] * dy[c]) * static_cast<float>(s);
            eig2(dxx[c] * norm, 0.5f * (dxy[c] + dyx[c]) * norm, dyy[c] * norm, h1[c], h2[c]);
        }
        put(grad), put(h1), put(h2);
        const std::vector<float> a = blur(jxx, w, h, s), bb = blur(jxy, w, h, s), cc = blur(jyy, w, h, s);
        for (std::size_t c = 0; c < n; ++c) eig2(a[c], bb[c], cc[c], s1[c], s2[c]);
        for (float& v : s1) v = std::sqrt(std::max(v, 0.0f));
        for (float& v : s2) v = std::sqrt(std::max(v, 0.0f));
        put(s1), put(s2);
        const std::vector<float> g2 = blur(bright2, w, h, s);
        for (std::size_t c = 0; c < n; ++c) sd[c] = std::sqrt(std::max(0.0f, g2[c] - g[c] * g[c]));
        put(sd);
    }
    if (colours.size() >= 3) {
        const std::vector<float>&R = band_s0[colours[0]], &G = band_s0[colours[1]], &Bl = band_s0[colours[2]];
        std::vector<float> cr(n), cb(n), exg(n), sat(n);
        for (std::size_t c = 0; c < n; ++c) {
            const float s = R[c] + G[c] + Bl[c] + 1.0f;
            cr[c] = R[c] / s, cb[c] = Bl[c] / s, exg[c] = (2.0f * G[c] - R[c] - Bl[c]) / s;
            const float mx = std::max({R[c], G[c], Bl[c]}), mn = std::min({R[c], G[c], Bl[c]});
            sat[c] = (mx - mn) / (mx + 1.0f);
        }
        put(cr), put(cb), put(exg), put(sat);
    }
    if (layout.nir_band >= 0 && !colours.empty()) {
        const std::vector<float>& nir = band_s0[layout.nir_band];
        const std::vector<float>& red = band_s0[colours[0]];
        std::vector<float> ndvi(n);
        for (std::size_t c = 0; c < n; ++c) ndvi[c] = (nir[c] - red[c]) / (nir[c] + red[c] + 1.0f);
        put(ndvi);
    }
    if (k != out.bands) throw Error("pixel features", "internal: feature count mismatch");
    if (cell_valid) *cell_valid = std::move(cv);
    return out;
}

namespace {

// Row-major rows of the cells `cells` of a planar stack.
std::vector<float> rows_of(const Image<float>& stack, const std::vector<std::size_t>& cells) {
    const std::size_t F = std::size_t(stack.bands);
    std::vector<float> X(cells.size() * F);
    for (std::size_t r = 0; r < cells.size(); ++r)
        for (std::size_t b = 0; b < F; ++b) X[r * F + b] = stack.band_data(int(b))[cells[r]];
    return X;
}

// Predicts `cells` of a stack in chunks (bounded memory) into `p` (per cell).
void predict_cells(const std::vector<uint8_t>& model, const Image<float>& stack, const std::vector<std::size_t>& cells, std::vector<float>& p,
                   int threads) {
    constexpr std::size_t kChunk = 1 << 18;
    for (std::size_t a = 0; a < cells.size(); a += kChunk) {
        const std::vector<std::size_t> part(cells.begin() + std::ptrdiff_t(a), cells.begin() + std::ptrdiff_t(std::min(cells.size(), a + kChunk)));
        const std::vector<float> X = rows_of(stack, part);
        const std::vector<float> q = predict_booster(model, X, part.size(), std::size_t(stack.bands), threads);
        for (std::size_t j = 0; j < part.size(); ++j) p[part[j]] = q[j];
    }
}

// Cell probabilities -> image pixels: bilinear between cell centres, 0 outside `valid`.
std::vector<float> upsample(const std::vector<float>& cp, int w, int h, int f, int W, int H, const std::vector<uint8_t>& valid) {
    std::vector<float> out(std::size_t(W) * H, 0.0f);
    tbb::parallel_for(0, H, [&](int y) {
        const double cyf = (y + 0.5) / f - 0.5;
        const int y0 = std::clamp(int(std::floor(cyf)), 0, h - 1), y1 = std::min(h - 1, y0 + 1);
        const float ty = static_cast<float>(std::clamp(cyf - y0, 0.0, 1.0));
        for (int x = 0; x < W; ++x) {
            const std::size_t i = std::size_t(y) * W + x;
            if (!valid.empty() && !valid[i]) continue;
            const double cxf = (x + 0.5) / f - 0.5;
            const int x0 = std::clamp(int(std::floor(cxf)), 0, w - 1), x1 = std::min(w - 1, x0 + 1);
            const float tx = static_cast<float>(std::clamp(cxf - x0, 0.0, 1.0));
            const float a = cp[std::size_t(y0) * w + x0], b = cp[std::size_t(y0) * w + x1], c = cp[std::size_t(y1) * w + x0],
                        d = cp[std::size_t(y1) * w + x1];
            out[i] = (1 - ty) * ((1 - tx) * a + tx * b) + ty * ((1 - tx) * c + tx * d);
        }
    });
    return out;
}

// CNN input of an image: the box-averaged bands of its cells, scaled from
// 0..255 to about -2..2 (planar, bands x h x w); `cell_valid` as box_average.
CnnGrid cnn_grid(const Image<float>& img, const std::vector<uint8_t>& valid, int f, std::vector<uint8_t>& cell_valid) {
    const std::vector<std::vector<float>> band = box_average(img, valid, f, cell_valid);
    CnnGrid g;
    g.width = (img.width + f - 1) / f, g.height = (img.height + f - 1) / f;
    for (const std::vector<float>& b : band)
        for (const float v : b) g.input.push_back((v - 127.5f) / 64.0f);
    return g;
}

// Building share of every cell (valid pixels of `truth` inside it).
std::vector<float> cell_labels(const PixelTrainingImage& ti, int f, int w, std::size_t cells) {
    const int W = ti.normalised->width, H = ti.normalised->height;
    std::vector<float> n(cells, 0.0f), label(cells, 0.0f);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const std::size_t px = std::size_t(y) * W + x;
            if (!ti.valid->empty() && !(*ti.valid)[px]) continue;
            const std::size_t c = std::size_t(y / f) * w + x / f;
            n[c] += 1.0f, label[c] += (*ti.truth)[px] ? 1.0f : 0.0f;
        }
    for (std::size_t c = 0; c < cells; ++c) label[c] = n[c] > 0 ? label[c] / n[c] : 0.0f;
    return label;
}

// Fold of every cell (its centre's block).
std::vector<int> cell_folds(const FoldBlocks& folds, std::size_t image, int f, int w, std::size_t cells) {
    std::vector<int> fold(cells, 0);
    for (std::size_t c = 0; c < cells; ++c) fold[c] = folds.fold_at(image, (double(c % w) + 0.5) * f, (double(c / w) + 0.5) * f);
    return fold;
}

// The CNN kind of train_pixel_stage.
PixelStage train_cnn_stage(const std::vector<PixelTrainingImage>& images, const BandLayout& layout, const PixelClassifierOptions& o,
                           const FoldBlocks* folds, int fold_count, const Progress& progress) {
    struct Prepared {
        CnnGrid grid;
        std::vector<uint8_t> cell_valid;
        std::vector<int> fold;
        int factor = 1;
    };
    std::vector<Prepared> prep(images.size());
    for (std::size_t i = 0; i < images.size(); ++i) {
        const PixelTrainingImage& ti = images[i];
        if (ti.normalised->bands != layout.bands) throw Error("pixel CNN", "a training image's band count differs from the layout");
        Prepared& p = prep[i];
        p.factor = pixel_cell_factor(ti.gsd_m, o);
        p.grid = cnn_grid(*ti.normalised, *ti.valid, p.factor, p.cell_valid);
        p.grid.target = cell_labels(ti, p.factor, p.grid.width, p.cell_valid.size());
        if (folds) p.fold = cell_folds(*folds, i, p.factor, p.grid.width, p.cell_valid.size());
    }
    progress(0.05, "pixel CNN inputs");
    // Model `skip` (-1: all data) learns from the valid cells outside fold `skip`.
    auto train = [&](int skip) {
        std::vector<CnnGrid> grids;
        std::vector<const CnnGrid*> ptr;
        double pos = 0.0, n = 0.0;
        for (const Prepared& p : prep) {
            CnnGrid g;
            g.width = p.grid.width, g.height = p.grid.height;
            g.weight.assign(p.cell_valid.size(), 0.0f);
            for (std::size_t c = 0; c < g.weight.size(); ++c)
                if (p.cell_valid[c] && (skip < 0 || p.fold[c] != skip)) g.weight[c] = 1.0f, n += 1.0, pos += p.grid.target[c];
            g.input = p.grid.input, g.target = p.grid.target;
            grids.push_back(std::move(g));
        }
        if (!(pos > 0.0) || !(pos < n)) return std::vector<uint8_t>{};
        for (const CnnGrid& g : grids) ptr.push_back(&g);
        return train_cnn(ptr, layout.bands, o.cnn);
    };
    PixelStage out;
    const bool cv = folds && fold_count >= 2;
    const int models = cv ? fold_count + 1 : 1;
    std::vector<std::vector<uint8_t>> m(std::size_t(models), std::vector<uint8_t>{});
    // Each network trains on one thread (its bytes do not depend on the thread count), the fold models in parallel.
    tbb::parallel_for(0, models, [&](int f) { m[std::size_t(f)] = train(cv && f < fold_count ? f : -1); });
    progress(0.85, "pixel CNN trained");
    out.model = std::move(m.back());
    if (out.model.empty()) throw Error("pixel classifier", "the training images need building and non-building pixels");
    if (cv) {
        for (std::size_t i = 0; i < prep.size(); ++i) {
            const Prepared& p = prep[i];
            std::vector<float> cp(p.cell_valid.size(), 0.0f);
            for (int f = 0; f < fold_count; ++f) {
                if (m[std::size_t(f)].empty()) continue;
                const std::vector<float> q =
                    predict_cnn(m[std::size_t(f)], p.grid.input, p.grid.width, p.grid.height, layout.bands, o.cnn, kCnnTrainingTiling);
                for (std::size_t c = 0; c < cp.size(); ++c)
                    if (p.cell_valid[c] && p.fold[c] == f) cp[c] = q[c];
            }
            out.out_of_fold.push_back(upsample(cp, p.grid.width, p.grid.height, p.factor, images[i].normalised->width, images[i].normalised->height,
                                               *images[i].valid));
        }
    }
    progress(1.0, "pixel CNN");
    return out;
}

}  // namespace

std::vector<float> pixel_probability(const std::vector<uint8_t>& model, const Image<float>& img, const std::vector<uint8_t>& valid,
                                     const BandLayout& layout, double gsd_m, const PixelClassifierOptions& o, int threads,
                                     const CnnTiling& cnn_tiling) {
    if (o.kind == PixelStageKind::both) {
        const auto [boosted, cnn] = unpack_pixel_models(model, "pixel models");
        PixelClassifierOptions ob = o, oc = o;
        ob.kind = PixelStageKind::boosted, oc.kind = PixelStageKind::cnn;
        std::vector<float> p = pixel_probability(boosted, img, valid, layout, gsd_m, ob, threads, cnn_tiling);
        const std::vector<float> q = pixel_probability(cnn, img, valid, layout, gsd_m, oc, threads, cnn_tiling);
        for (std::size_t i = 0; i < p.size(); ++i) p[i] = 0.5f * (p[i] + q[i]);
        return p;
    }
    if (o.kind == PixelStageKind::cnn) {
        o.validate();
        if (img.bands != layout.bands) throw Error("pixel CNN", "image has " + std::to_string(img.bands) + " bands, layout " + std::to_string(layout.bands));
        const int f = pixel_cell_factor(gsd_m, o);
        std::vector<uint8_t> cv;
        const CnnGrid g = cnn_grid(img, valid, f, cv);
        std::vector<float> cp = predict_cnn(model, g.input, g.width, g.height, layout.bands, o.cnn, cnn_tiling);
        for (std::size_t c = 0; c < cp.size(); ++c)
            if (!cv[c]) cp[c] = 0.0f;
        return upsample(cp, g.width, g.height, f, img.width, img.height, valid);
    }
    std::vector<uint8_t> cv;
    const Image<float> stack = pixel_feature_stack(img, valid, layout, gsd_m, o, &cv);
    std::vector<std::size_t> cells;
    for (std::size_t c = 0; c < cv.size(); ++c)
        if (cv[c]) cells.push_back(c);
    std::vector<float> cp(cv.size(), 0.0f);
    predict_cells(model, stack, cells, cp, threads);
    return upsample(cp, stack.width, stack.height, pixel_cell_factor(gsd_m, o), img.width, img.height, valid);
}

PixelStage train_pixel_stage(const std::vector<PixelTrainingImage>& images, const BandLayout& layout, const PixelClassifierOptions& o,
                             const FoldBlocks* folds, int fold_count, int threads, const Progress& progress) {
    o.validate();
    if (images.empty()) throw Error("pixel classifier", "no training image");
    if (o.kind == PixelStageKind::cnn) return train_cnn_stage(images, layout, o, folds, fold_count, progress);
    if (o.kind == PixelStageKind::both) {
        PixelClassifierOptions ob = o;
        ob.kind = PixelStageKind::boosted;
        PixelStage b = train_pixel_stage(images, layout, ob, folds, fold_count, threads, progress.sub(0.0, 0.4));
        const PixelStage c = train_cnn_stage(images, layout, o, folds, fold_count, progress.sub(0.4, 1.0));
        for (std::size_t i = 0; i < b.out_of_fold.size(); ++i)
            for (std::size_t k = 0; k < b.out_of_fold[i].size(); ++k) b.out_of_fold[i][k] = 0.5f * (b.out_of_fold[i][k] + c.out_of_fold[i][k]);
        b.model = pack_pixel_models(b.model, c.model);
        return b;
    }
    const std::size_t F = pixel_feature_names(layout, o).size();
    struct Prepared {
        Image<float> stack;
        std::vector<uint8_t> cell_valid;
        std::vector<float> label;        // per cell: share of building pixels
        std::vector<int> fold;           // per cell (with folds)
        std::vector<std::size_t> sample; // sampled cells
        int factor = 1;
    };
    std::vector<Prepared> prep(images.size());
    for (std::size_t i = 0; i < images.size(); ++i) {
        const PixelTrainingImage& ti = images[i];
        Prepared& p = prep[i];
        p.factor = pixel_cell_factor(ti.gsd_m, o);
        p.stack = pixel_feature_stack(*ti.normalised, *ti.valid, layout, ti.gsd_m, o, &p.cell_valid);
        const int w = p.stack.width, f = p.factor;
        p.label = cell_labels(ti, f, w, p.cell_valid.size());
        if (folds) p.fold = cell_folds(*folds, i, f, w, p.cell_valid.size());
        // Samples: up to half building cells (share >= 0.5), the rest other
        // cells, each chosen by a hash of (seed, image, cell).
        std::vector<std::pair<uint64_t, std::size_t>> pos, neg;
        for (std::size_t c = 0; c < p.cell_valid.size(); ++c) {
            if (!p.cell_valid[c]) continue;
            // Mixed cells (edges) teach little and blur the boundary: left out.
            if (p.label[c] > 0.2f && p.label[c] < 0.8f) continue;
            (p.label[c] >= 0.5f ? pos : neg).push_back({hash64(o.booster.seed, i, c, 0x91e1), c});
        }
        const std::size_t half = o.samples_per_image / 2;
        const std::size_t np = std::min(pos.size(), half), nn = std::min(neg.size(), o.samples_per_image - np);
        auto take = [&](std::vector<std::pair<uint64_t, std::size_t>>& v, std::size_t k) {
            if (k < v.size()) std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(k), v.end());
            v.resize(k);
            for (const auto& e : v) p.sample.push_back(e.second);
        };
        take(pos, np), take(neg, nn);
        std::sort(p.sample.begin(), p.sample.end());
        progress(0.4 * double(i + 1) / double(images.size()), "pixel features");
    }
    // Training rows of the samples whose fold is not `skip` (-1: all). Positive
    // and negative samples weigh alike per image.
    auto train = [&](int skip) {
        std::vector<float> X, y, wt;
        for (std::size_t i = 0; i < prep.size(); ++i) {
            const Prepared& p = prep[i];
            std::vector<std::size_t> cells;
            for (const std::size_t c : p.sample)
                if (skip < 0 || p.fold[c] != skip) cells.push_back(c);
            const std::vector<float> rows = rows_of(p.stack, cells);
            X.insert(X.end(), rows.begin(), rows.end());
            std::size_t npos = 0;
            for (const std::size_t c : cells) npos += p.label[c] >= 0.5f;
            const std::size_t nneg = cells.size() - npos;
            for (const std::size_t c : cells) {
                const bool b = p.label[c] >= 0.5f;
                y.push_back(b ? 1.0f : 0.0f);
                wt.push_back(static_cast<float>(0.5 * double(cells.size()) / double(std::max<std::size_t>(1, b ? npos : nneg))));
            }
        }
        std::size_t npos = 0;
        for (const float v : y) npos += v > 0.5f;
        if (npos == 0 || npos == y.size()) return std::vector<uint8_t>{};
        return train_booster(X, y.size(), F, y, wt, o.booster);
    };
    PixelStage out;
    if (folds && fold_count >= 2) {
        std::vector<std::vector<float>> cell_p(prep.size());
        for (std::size_t i = 0; i < prep.size(); ++i) cell_p[i].assign(prep[i].cell_valid.size(), 0.0f);
        // The fold models train in parallel (each on one thread: the bytes
        // do not depend on the thread count), then predict their fold.
        std::vector<std::vector<uint8_t>> models(std::size_t(fold_count) + 1);
        tbb::parallel_for(0, fold_count + 1, [&](int f) { models[std::size_t(f)] = train(f < fold_count ? f : -1); });
        out.model = std::move(models.back());
        for (int f = 0; f < fold_count; ++f) {
            const std::vector<uint8_t>& m = models[std::size_t(f)];
            if (!m.empty())
                for (std::size_t i = 0; i < prep.size(); ++i) {
                    std::vector<std::size_t> cells;
                    for (std::size_t c = 0; c < prep[i].fold.size(); ++c)
                        if (prep[i].cell_valid[c] && prep[i].fold[c] == f) cells.push_back(c);
                    predict_cells(m, prep[i].stack, cells, cell_p[i], threads);
                }
            progress(0.4 + 0.5 * double(f + 1) / double(fold_count), "pixel cross-validation");
        }
        for (std::size_t i = 0; i < prep.size(); ++i)
            out.out_of_fold.push_back(upsample(cell_p[i], prep[i].stack.width, prep[i].stack.height, prep[i].factor, images[i].normalised->width,
                                               images[i].normalised->height, *images[i].valid));
    }
    if (out.model.empty()) out.model = train(-1);
    if (out.model.empty()) throw Error("pixel classifier", "the training images need building and non-building pixels");
    progress(1.0, "pixel model");
    return out;
}

}  // namespace cityforge::detect
