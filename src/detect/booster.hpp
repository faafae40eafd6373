#pragma once
// Gradient-boosted trees (XGBoost 1.7 C API) for segment classification:
// training from a feature matrix and prediction from a serialised model.
// Errors from XGBoost become cityforge::Error. No GDAL.
#include <cstdint>
#include <vector>

namespace cityforge::detect {

struct BoosterOptions {
    int rounds = 200;            ///< boosting rounds (trees)
    int max_depth = 6;
    double learning_rate = 0.1;  ///< eta
    double subsample = 0.8;      ///< row sampling per tree (seeded)
    double colsample = 0.8;      ///< column sampling per tree (seeded)
    double min_child_weight = 1.0;
    double lambda = 1.0;         ///< L2 regularisation
    uint64_t seed = 1;
    void validate() const;
};

/// Trains a binary (logistic) classifier on `rows` x `cols` features (NaN =
/// missing) with 0/1 `labels` and `weights` (one per row) and returns the
/// model in XGBoost's UBJSON format. Training always runs on one thread:
/// XGBoost's histogram sums depend on the thread count, and one thread
/// makes the bytes a function of the data and the seed alone.
std::vector<uint8_t> train_booster(const std::vector<float>& features, std::size_t rows, std::size_t cols, const std::vector<float>& labels,
                                   const std::vector<float>& weights, const BoosterOptions& options);

/// Building probability of every row. `threads` = 0: XGBoost's default.
/// Prediction sums fixed trees per row, so any thread count gives the same values.
std::vector<float> predict_booster(const std::vector<uint8_t>& model, const std::vector<float>& features, std::size_t rows, std::size_t cols,
                                   int threads = 0);

}  // namespace cityforge::detect
