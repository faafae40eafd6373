#include "detect/booster.hpp"

#include <xgboost/c_api.h>

#include <cmath>
#include <memory>
#include <string>

#include "core/error.hpp"

namespace cityforge::detect {

namespace {

void check(int rc, const char* what) {
    if (rc != 0) throw Error("xgboost", std::string(what) + ": " + XGBGetLastError());
}

struct Matrix {
    DMatrixHandle h = nullptr;
    ~Matrix() {
        if (h) XGDMatrixFree(h);
    }
};
struct Booster {
    BoosterHandle h = nullptr;
    ~Booster() {
        if (h) XGBoosterFree(h);
    }
};

void quiet() {
    static const bool once = [] {
        XGBSetGlobalConfig("{\"verbosity\": 0}");
        return true;
    }();
    (void)once;
}

void set(BoosterHandle b, const char* key, const std::string& value) { check(XGBoosterSetParam(b, key, value.c_str()), key); }

}  // namespace

void BoosterOptions::validate() const {
    if (rounds < 1 || rounds > 5000) throw Error("rounds", "must be between 1 and 5000");
    if (max_depth < 1 || max_depth > 16) throw Error("max_depth", "must be between 1 and 16");
    if (!(learning_rate > 0.0 && learning_rate <= 1.0)) throw Error("learning_rate", "must be in (0, 1]");
    if (!(subsample > 0.0 && subsample <= 1.0)) throw Error("subsample", "must be in (0, 1]");
    if (!(colsample > 0.0 && colsample <= 1.0)) throw Error("colsample", "must be in (0, 1]");
    if (!(min_child_weight >= 0.0)) throw Error("min_child_weight", "must be >= 0");
    if (!(lambda >= 0.0)) throw Error("lambda", "must be >= 0");
}

std::vector<uint8_t> train_booster(const std::vector<float>& features, std::size_t rows, std::size_t cols, const std::vector<float>& labels,
                                   const std::vector<float>& weights, const BoosterOptions& o) {
    o.validate();
    quiet();
    if (rows == 0) throw Error("training", "no training samples (no segments)");
    if (features.size() != rows * cols || labels.size() != rows || weights.size() != rows)
        throw Error("training", "internal: feature, label and weight sizes differ");
    Matrix m;
    check(XGDMatrixCreateFromMat(features.data(), rows, cols, NAN, &m.h), "training matrix");
    check(XGDMatrixSetFloatInfo(m.h, "label", labels.data(), rows), "labels");
    check(XGDMatrixSetFloatInfo(m.h, "weight", weights.data(), rows), "weights");
    Booster b;
    check(XGBoosterCreate(&m.h, 1, &b.h), "booster");
    set(b.h, "objective", "binary:logistic");
    set(b.h, "tree_method", "hist");
    set(b.h, "nthread", "1");
    set(b.h, "seed", std::to_string(o.seed % 2147483647ULL));
    set(b.h, "max_depth", std::to_string(o.max_depth));
    set(b.h, "eta", std::to_string(o.learning_rate));
    set(b.h, "subsample", std::to_string(o.subsample));
    set(b.h, "colsample_bytree", std::to_string(o.colsample));
    set(b.h, "min_child_weight", std::to_string(o.min_child_weight));
    set(b.h, "lambda", std::to_string(o.lambda));
    set(b.h, "max_bin", "256");
    for (int i = 0; i < o.rounds; ++i) check(XGBoosterUpdateOneIter(b.h, i, m.h), "training");
    bst_ulong len = 0;
    const char* buf = nullptr;
    check(XGBoosterSaveModelToBuffer(b.h, "{\"format\": \"ubj\"}", &len, &buf), "saving the model");
    return std::vector<uint8_t>(reinterpret_cast<const uint8_t*>(buf), reinterpret_cast<const uint8_t*>(buf) + len);
}

std::vector<float> predict_booster(const std::vector<uint8_t>& model, const std::vector<float>& features, std::size_t rows, std::size_t cols,
                                   int threads) {
    quiet();
    if (rows == 0) return {};
    if (features.size() != rows * cols) throw Error("prediction", "internal: feature matrix size");
    Booster b;
    check(XGBoosterCreate(nullptr, 0, &b.h), "booster");
    check(XGBoosterLoadModelFromBuffer(b.h, model.data(), model.size()), "loading the model");
    if (threads > 0) set(b.h, "nthread", std::to_string(threads));
    bst_ulong nfeat = 0;
    check(XGBoosterGetNumFeature(b.h, &nfeat), "model features");
    if (nfeat != cols) throw Error("model", "expects " + std::to_string(nfeat) + " features, the image gives " + std::to_string(cols));
    Matrix m;
    check(XGDMatrixCreateFromMat(features.data(), rows, cols, NAN, &m.h), "prediction matrix");
    bst_ulong len = 0;
    const float* out = nullptr;
    check(XGBoosterPredict(b.h, m.h, 0, 0, 0, &len, &out), "prediction");
    if (len != rows) throw Error("prediction", "internal: prediction count");
    return std::vector<float>(out, out + len);
}

}  // namespace cityforge::detect
